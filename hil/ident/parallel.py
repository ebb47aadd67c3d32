"""Fitting many candidates (hil.ident.fit.evaluate), on threads or in worker processes.

In this process (the default) the candidates are fitted at once on the idle cores' threads
(:func:`in_threads`): the compiled loops release the GIL, the threads share the replay's cached
simulations, and each fit is deterministic, so the candidates are those of one thread, bit for bit
(6 s record: 6.3 s for hil diagnose against 7.0-7.6 s with two processes, docs/benchmarks.md).

The replay and its residuals reach the workers by fork, as the arguments of the pool's
initializer (:func:`_start_worker`: a forked process inherits them, nothing large is pickled),
which keeps them for the worker process's tasks; the parent process holds no module state. A
worker sends its Candidate back without its config, which the parent rebuilds from the fitted
parameters. Without fork, or with one job, they are fitted in this process. A candidate that
cannot be fitted (ValueError) gives None.
"""
from __future__ import annotations

import multiprocessing as mp
import os

from hil.ident.fit import evaluate
from hil.plant_config import candidate, configure
from hil.simulate import batch_threads, batches_on_this_thread
from sim_plant.blas_threads import one_blas_thread

__all__ = ["evaluate_many", "in_threads", "Beside"]


def _safe_eval(replay, res0, name, max_nfev, start=None, n_starts=2):
    try:
        return evaluate(replay, name, res0, max_nfev, start, n_starts)
    except ValueError:
        return None


# the replay and its residuals in a worker process (set there by _start_worker; empty in the parent)
_worker_inputs: dict = {}


def _start_worker(replay, res0) -> None:
    """The pool's initializer, in each worker process: keep what the worker's tasks evaluate."""
    _worker_inputs.update(replay=replay, res0=res0)


def _work(args):
    try:
        c = _safe_eval(_worker_inputs["replay"], _worker_inputs["res0"], *args)
    except Exception as exc:
        # handed back as a value (with the worker's traceback, as the pool would attach it), raised
        # by the parent once every reply is in: a pool terminated while a worker is mid-reply (it
        # holds the result queue's lock) deadlocks its task handler
        from multiprocessing.pool import ExceptionWithTraceback
        return ExceptionWithTraceback(exc, exc.__traceback__)
    if c is not None:
        c.cfg = None            # configs stay in the parent (rebuilt there)
    return c


def _alone(fn, item):
    """``fn(item)`` on a thread of :func:`in_threads`'s pool: one BLAS thread and its batches on it
    alone (the pool's threads share the cores), as the caller's own thread would run it."""
    with one_blas_thread(), batches_on_this_thread():
        return fn(item)


def in_threads(fn, items, progress=None) -> list:
    """``[fn(item) for item in items]``, the items on the idle cores' threads
    (hil.simulate.batch_threads) where there are two or more, else here; ``progress(item)`` as each
    result arrives, in order. The compiled loops release the GIL and the fits are deterministic, so
    the results are those of one thread, bit for bit; an error is raised as there, and the items
    not yet started are dropped."""
    items = list(items)
    threads = min(batch_threads(), len(items))
    if threads <= 1:
        out = []
        for item in items:
            if progress:
                progress(item)
            out.append(fn(item))
        return out
    from concurrent.futures import ThreadPoolExecutor
    out = []
    pool = ThreadPoolExecutor(max_workers=threads)
    try:
        futures = [pool.submit(_alone, fn, item) for item in items]
        for item, f in zip(items, futures):
            out.append(f.result())
            if progress:
                progress(item)
    finally:
        # an error or Ctrl-C: the items not started are dropped (one by one, they would not run)
        pool.shutdown(wait=True, cancel_futures=True)
    return out


class Beside:
    """``fn()`` computed beside the caller's work, on one BLAS thread: on a thread of its own
    (:func:`_alone`) where the caller leaves a core idle (hil.simulate.batch_threads, counted when
    made), else here when :meth:`result` is asked for. ``result()`` gives its value or raises its error, as a call
    would; :meth:`wait` waits for it and drops both (the caller failed first)."""

    def __init__(self, fn):
        self._fn, self._future = fn, None
        if batch_threads() > 1:
            from concurrent.futures import ThreadPoolExecutor
            pool = ThreadPoolExecutor(max_workers=1)
            self._future = pool.submit(_alone, lambda _: fn(), None)
            pool.shutdown(wait=False)       # its one thread ends with the task

    def result(self):
        if self._future is not None:
            return self._future.result()
        with one_blas_thread():
            return self._fn()

    def wait(self) -> None:
        if self._future is not None:
            self._future.exception()


def evaluate_many(replay, work, res0, jobs, progress):
    """Evaluate the (name, max_nfev, start, n_starts) items, in ``jobs`` processes; with one job, in
    this process (:func:`in_threads`). A fit's error (other than a ValueError, a fit that failed)
    is raised; from the processes, once the others are in."""
    from hil.ident.progress import expect
    expect(progress, len(work))
    if jobs > 1 and len(work) > 1:
        try:
            ctx = mp.get_context("fork")
        except ValueError:
            ctx = None
        if ctx is not None:
            out, failed = [], None
            from hil.pool import die_with_parent
            with ctx.Pool(min(jobs, len(work)), initializer=die_with_parent,
                          initargs=(os.getpid(), _start_worker, replay, res0)) as pool:
                for c in pool.imap(_work, work):
                    if isinstance(c, Exception):
                        failed = failed or c
                        continue
                    if progress:
                        progress(c.effect if c else "?")
                    if c is not None and failed is None:
                        c.cfg = configure(candidate(c.effect, replay.cfg), replay.cfg, c.params)
                    out.append(c)
            if failed is not None:
                raise failed
            return out
    return in_threads(lambda item: _safe_eval(replay, res0, *item), work,
                      (lambda item: progress(item[0])) if progress else None)
