"""Where the runs of a sweep go: a process pool, a Dask cluster, or an axis, one run after another.

Every executor has the same three methods: ``map(cfg, tasks)`` yields ``(key, figures)`` for
``tasks``, a list of ``(key, RunSpec)``, in the order they finish (so the store keeps each run as
soon as it is done and an interrupted sweep loses little); ``one(cfg, key, spec)`` computes one
run (a refinement step waits for it); ``close()`` lets the workers go. The numbers do not depend
on the executor: every run is :func:`hil.sweep.run.run_task` on the same configuration.

``dask.distributed`` is optional and imported only when a scheduler is given. Its protocol
unpickles what it receives: use only a scheduler you trust.
"""
from __future__ import annotations

import hashlib
import ipaddress
import logging
import multiprocessing
import os
import re
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from hil.errors import UserError
from hil.pool import die_with_parent
from hil.sweep.run import run_on_backend, run_task

__all__ = ["LocalExecutor", "DaskExecutor", "BackendExecutor", "run_trace_name", "check_scheduler_address"]

log = logging.getLogger(__name__)

# Dask's protocols; tls:// and wss:// are encrypted and authenticate the scheduler
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")
_ENCRYPTED = ("tls", "wss")
_HOST_NAME = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*")
_REMOTE_RISK = ("Dask's protocol unpickles what it receives: the scheduler, or anyone on the path to it, can run "
                "code in this process")


def check_scheduler_address(address: str, allow_remote: bool = False, what: str = "--scheduler") -> str:
    """A Dask scheduler address, ``[protocol://]host:port``, checked before anything connects (a bad
    one is a mistake: one line, exit 2; Dask itself would fail late, or resolve a word as a host).

    The loopback (127.0.0.0/8, ::1, ``localhost``) is taken as it is. Another address is refused
    unless it is encrypted (``tls://``, ``wss://``) or ``allow_remote`` (``--allow-remote-scheduler``)
    says the user trusts the network and the scheduler; then the risk is said once (a warning).
    A host name other than ``localhost`` is resolved through DNS and may name any machine: it
    counts as remote. Returns the address as given."""
    def refuse(why: str):
        shown = address if address.isprintable() and len(address) <= 80 else repr(address[:80])
        raise UserError(f"{what} {shown}: {why}")
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme not in SCHEDULER_SCHEMES:
        refuse(f"unknown protocol {scheme!r} (expected one of {', '.join(SCHEDULER_SCHEMES)})")
    host, sep, port = rest.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        refuse("expected [tcp://]HOST:PORT with a port 1..65535, e.g. tcp://127.0.0.1:8786")
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        ip = None
        if not _HOST_NAME.fullmatch(host):
            refuse(f"{host!r} is neither an IP address nor a host name; expected [tcp://]HOST:PORT, "
                   f"e.g. tcp://127.0.0.1:8786")
    if host == "localhost" or (ip is not None and ip.is_loopback):
        return address
    if scheme not in _ENCRYPTED and not allow_remote:
        refuse(f"not a loopback address, and not encrypted: {_REMOTE_RISK}. Use tls://, or "
               f"--allow-remote-scheduler where you trust the network and the scheduler")
    log.warning("%s %s: a scheduler on another machine: %s; only use one you trust", what, address, _REMOTE_RISK)
    return address


def _chunk(cfg, tasks):
    return [run_task(cfg, key, spec) for key, spec in tasks]


class LocalExecutor:
    """Runs in this process, or on a process pool (fork: the workers inherit the compiled kernel
    and the discretized models of the parent)."""

    def __init__(self, jobs: int | None):
        self.jobs = max(1, jobs or os.cpu_count() or 1)
        self.pool = None

    def map(self, cfg, tasks):
        if self.jobs == 1 or len(tasks) <= 1:
            for key, spec in tasks:
                yield run_task(cfg, key, spec)
            return
        if self.pool is None:
            try:
                ctx = multiprocessing.get_context("fork")
            except ValueError:              # pragma: no cover - platforms without fork
                ctx = None
            self.pool = ProcessPoolExecutor(max_workers=self.jobs, mp_context=ctx, initializer=die_with_parent,
                                            initargs=(os.getpid(),))
        # a few chunks per worker: little inter-process traffic, yet results stream in for the
        # store (resume) and the progress bar
        n_chunks = min(len(tasks), 4 * self.jobs)
        chunks = [tasks[i::n_chunks] for i in range(n_chunks)]
        futs = [self.pool.submit(_chunk, cfg, c) for c in chunks]
        try:
            for fut in as_completed(futs):
                yield from fut.result()
        finally:
            for f in futs:
                f.cancel()

    def one(self, cfg, key, spec):
        return run_task(cfg, key, spec)

    def close(self):
        if self.pool is not None:
            self.pool.shutdown(wait=False, cancel_futures=True)   # workers exit on their own
            self.pool = None


class DaskExecutor:
    """Runs on a dask.distributed cluster (``scheduler``: an address or a Client)."""

    def __init__(self, scheduler):
        from distributed import Client  # optional: only for --scheduler
        if isinstance(scheduler, Client):
            self.client, self.own = scheduler, False
        else:
            # a scheduler that does not answer: a clear error after 10 s, not dask's 60 s
            self.client, self.own = Client(scheduler, set_as_default=False, timeout=10), True

    def map(self, cfg, tasks):
        yield from dask_results(self.client, run_task, [(key, (cfg, key, spec)) for key, spec in tasks], "sweep")

    def one(self, cfg, key, spec):
        return self.client.submit(run_task, cfg, key, spec, pure=False).result()

    def close(self):
        if self.own:
            self.client.close()


class BackendExecutor:
    """A real axis: one run after the other. The first run starts where the axis stands; every run
    returns to that start (its return move), and the next one is refused unless the axis is found
    back there (``limits.start_window``). ``can_log`` (``hil --can-log FILE``): each run's CAN bus
    traced into a file of its own, FILE's name numbered in the order the runs are made
    (:func:`run_trace_name`: ``bus.asc`` -> ``bus-001.asc``, ``bus-002.asc``, ...): a trace file
    is written once, from the start (python-can's ASC and TRC writers cannot append)."""

    def __init__(self, backend, out_dir, scope=None, can_log: str | None = None):
        self.backend, self.out_dir, self.scope = backend, out_dir, scope     # scope: the live scope's ring
        self.start: float | None = None          # the sweep's start, as measured before the first run
        self.can_log, self.runs = can_log, 0     # runs: made on the axis so far (numbers the traces)

    def map(self, cfg, tasks):
        for key, spec in tasks:
            yield self.one(cfg, key, spec)

    def one(self, cfg, key, spec):
        if spec.analysis == "transmission":      # a model analysis: the axis is not needed
            return run_task(cfg, key, spec)
        self.runs += 1
        trace = None if self.can_log is None else run_trace_name(self.can_log, self.runs)
        fig = run_on_backend(cfg, spec, self.backend, self.out_dir, start=self.start, scope=self.scope,
                             can_log=trace)
        if self.start is None:
            self.start = fig.get("start_m")
        return key, fig

    def close(self):
        pass


def run_trace_name(path: str, run: int) -> str:
    """The CAN trace of run ``run`` (1-based) of a sweep: ``path``'s name with the run's number
    before its suffix, which names the format (``bus.asc``, 3 -> ``bus-003.asc``)."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}-{run:03d}{p.suffix}"))


def dask_results(client, fn, calls, prefix: str):
    """``fn(*args)`` of every ``(name, args)`` of ``calls`` on the cluster of ``client``, each
    result as it finishes; the task keys are ``prefix`` and a hash of the name (a rerun finds its
    own); what has not finished is cancelled when the caller stops early (Ctrl-C, an error)."""
    from distributed import as_completed as das_completed
    if not calls:
        return
    futs = [client.submit(fn, *args, key=f"{prefix}-{hashlib.sha1(name.encode()).hexdigest()}", pure=False)
            for name, args in calls]
    try:
        with client.as_current():
            done = das_completed(futs)
        for fut in done:
            yield fut.result()
    finally:
        for f in futs:
            f.cancel()
