"""One record of a fleet, diagnosed: what a worker computes, and where the workers run.

:func:`diagnose_record` reads one record (its bytes travel with the task, so a worker on another
machine needs no shared folder), replays it through its axis's config, runs the diagnosis chain
(hil.ident.chain) and the fit of the axis's tracked effects together on the night's plant
(hil.ident.tracking.fit_tracked), and returns plain figures (SI): the tracked values and their
standard errors (``effect.param`` keys), the chain's verdict, the effects it named and its end.
A record that cannot be read or replayed gives ``{"error": one line}``: the others go on.

Executors (:func:`executor`): local processes by default (a fork pool: the workers inherit the
compiled kernels), or an existing ``dask.distributed`` cluster (``--scheduler ADDRESS``). Both map
the same module-level function over the same tasks, so the figures are the same wherever they ran.
Dask's protocol unpickles what it receives: use only a scheduler you trust.

Results are stored per record in the fleet's ``results.jsonl`` (hil.sweep.store.ResultStore, as a
sweep's runs are) under :func:`record_key`: the record's content, the config, the settings and the
code version, so that a rerun diagnoses only new or changed records and Ctrl-C loses nothing
finished.
"""
from __future__ import annotations

import hashlib
import multiprocessing
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

from hil.errors import HilError

__all__ = ["Settings", "Task", "diagnose_record", "record_key", "tracked_kinds", "executor", "CODE_VERSION"]


def code_files() -> list[Path]:
    """The sources that compute a record's figures (their hash keys the store: a change recomputes)."""
    root = Path(__file__).resolve().parents[2]          # the folder that holds hil/, drivers/, sim_plant/
    ident = ("chain", "diagnosis", "fit", "replay", "starts", "noise", "tracking", "tolerance")
    rels = ["hil/fleet/run.py", *(f"hil/ident/{m}.py" for m in ident), "sim_plant/kernel.py",
            *sorted(f"sim_plant/effects/{f.name}" for f in (root / "sim_plant" / "effects").glob("*.py")),
            "hil/plant_config.py", "hil/simulate.py", "drivers/control.py"]
    return [root / rel for rel in rels]


def _code_version() -> str:
    """The project's version and a hash of the sources that compute a record's figures."""
    import hil
    h = hashlib.sha1(str(getattr(hil, "__version__", "")).encode())
    for path in code_files():
        try:
            h.update(path.read_bytes())
        except OSError:
            h.update(path.name.encode())
    return h.hexdigest()[:16]


CODE_VERSION = _code_version()


@dataclass(frozen=True)
class Settings:
    """What a record's figures depend on besides the record and the config: the tracked effects,
    the chain's candidates (None: the catalogue) and its steps (0: no chain), the fits' budget."""
    track: tuple = ()
    candidates: tuple | None = None
    max_steps: int = 4
    fit_nfev: int = 40
    mapping: tuple = ()          # --map items


@dataclass(frozen=True)
class Task:
    """One record to diagnose (``spec`` of the store's line): the manifest's entry, as plain text."""
    record: str
    axis: str
    timestamp: str
    config: str


def _config_text(cfg) -> str:
    return "\n".join(f"{k}={cfg.values[k]!r}" for k in sorted(cfg.values))


def record_key(data: bytes, cfg, settings: Settings) -> str:
    """The store key of one record: sha256 of its content, of the config's values and of the
    settings, and the code version."""
    h = hashlib.sha256()
    h.update(hashlib.sha256(data).digest())
    h.update(_config_text(cfg).encode())
    h.update(repr(sorted(asdict(settings).items())).encode())
    return f"fleet|{h.hexdigest()[:32]}|code={CODE_VERSION}"


def tracked_kinds(cfg, track) -> dict[str, str]:
    """``effect.param`` -> unit kind (hil.units) of every fitted parameter of the tracked effects;
    an unknown effect raises a ConfigError naming it."""
    from hil.errors import ConfigError
    from hil.plant_config import candidate
    out = {}
    for name in track:
        try:
            eff = candidate(name, cfg)
        except KeyError as exc:
            raise ConfigError(f"fleet.track: {str(exc).strip(chr(39) + chr(34))}") from None
        for p in eff.fitted_params:
            out[f"{name}.{p.name}"] = p.kind_for(cfg.rotary)
    return out


def _read(data: bytes, name: str, cfg, mapping):
    from hil.io.importers import parse_mapping, read_any
    from hil.io.measurement import check_usable
    with tempfile.TemporaryDirectory(prefix="hil-fleet-") as tmp:
        path = Path(tmp) / Path(name).name
        path.write_bytes(data)
        try:
            meas = read_any(path, parse_mapping(list(mapping)) or None)
            check_usable(meas, (cfg["limits.travel_min"], cfg["limits.travel_max"]), cfg["control.position_period"],
                         cfg["control.velocity_period"])
        except HilError as exc:
            # the worker's copy is named as the record is
            raise type(exc)(str(exc).replace(str(path), name)) from None
    return meas


def _tracked(rp, track, fit_nfev):
    """The tracked effects fitted on the night's plant (hil.ident.tracking): ({effect.param: value},
    {effect.param: standard error}, the night's plant {config key: value}; {} when nothing is tracked)."""
    from hil.ident.tracking import fit_tracked
    plant: dict = {}
    vals, ses = fit_tracked(rp, track, max_nfev=fit_nfev, plant=plant)
    return vals, ses, plant


def diagnose_record(key: str, task: Task, data: bytes, cfg, settings: Settings) -> tuple[str, dict]:
    """The figures of one record (see the module's conventions): ``(key, figures)``."""
    import math
    try:
        from hil.ident.parallel import Beside
        from hil.ident.replay import Replay
        meas = _read(data, task.record, cfg, settings.mapping)
        rp = Replay(meas, cfg)
        fig = {"samples": int(meas.channels["t"].size) if hasattr(meas, "channels") else None}
        # the tracked fit does not depend on the chain: on a core the chain leaves idle
        tracked = Beside(lambda: _tracked(rp, settings.track, settings.fit_nfev))
        try:
            _chain_figures(fig, rp, settings)
        except BaseException:
            tracked.wait()
            raise
        vals, ses, plant = tracked.result()
        fig["values"] = {k: float(v) for k, v in vals.items()}
        fig["stderr"] = {k: (float(v) if v is not None and math.isfinite(v) else None) for k, v in ses.items()}
        if plant:
            fig["plant"] = plant
        return key, fig
    except (HilError, ValueError, OSError, ArithmeticError, KeyError, IndexError) as exc:
        # one record's failure is its own line in the summary; the fleet goes on
        return key, {"error": f"{task.record}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"}


def _chain_figures(fig: dict, rp, settings: Settings) -> None:
    """The chain's figures of a record into ``fig`` (none where ``max_steps`` is 0)."""
    from hil.ident.chain import diagnose_chain
    if settings.max_steps >= 1:
        cands = list(settings.candidates) if settings.candidates else None
        # the tracked effects are fitted on the night's plant apart (_tracked): the chain names them
        d = diagnose_chain(rp, cands, max_steps=settings.max_steps, jobs=1, fit_nfev=settings.fit_nfev,
                           nights_plant=False)
        named = []
        for s in d["chain"]:        # what the model holds: less what a later step dropped
            gone = {x["effect"] for x in s.dropped or []}
            named = [e for e in named + s.effects if e not in gone]
        fig.update(verdict=d["verdict"], named=named, end=d["final"]["end"],
                   final_error=d["final"]["error"], noise_floor=d["final"]["noise_floor"],
                   above_floor=d["final"]["above_floor"], at_noise_floor=bool(d["final"]["at_noise_floor"]),
                   chain=[{"step": s.step, "effects": s.effects, "params": s.params, "score": s.score}
                          for s in d["chain"]])


def _chunk(items, alone: bool = False):
    """The records ``items`` in a worker of the pool; ``alone``: the pool's workers fill the cores,
    so each runs its fits and batches on its own thread (hil.simulate.batches_on_this_thread)
    rather than by the load average, which lags the pool's start by a minute."""
    from contextlib import nullcontext

    from hil.simulate import batches_on_this_thread
    with batches_on_this_thread() if alone else nullcontext():
        return [diagnose_record(*it) for it in items]


class LocalExecutor:
    """This process (``jobs`` 1) or a fork pool of ``jobs`` processes."""

    def __init__(self, jobs: int | None):
        self.jobs = max(1, jobs or os.cpu_count() or 1)
        self.pool = None

    def map(self, items):
        """Yield ``(key, figures)`` of each ``(key, task, data, cfg, settings)`` as it finishes."""
        if self.jobs == 1 or len(items) <= 1:
            for it in items:
                yield diagnose_record(*it)
            return
        try:
            ctx = multiprocessing.get_context("fork")
        except ValueError:          # pragma: no cover - platforms without fork
            ctx = None
        from hil.pool import die_with_parent
        self.pool = ProcessPoolExecutor(max_workers=self.jobs, mp_context=ctx, initializer=die_with_parent,
                                        initargs=(os.getpid(),))
        from hil.simulate import usable_cpus
        allowed = usable_cpus()
        alone = self.jobs >= (len(allowed) if allowed else (os.cpu_count() or 1))
        futs = [self.pool.submit(_chunk, [it], alone) for it in items]
        try:
            for fut in as_completed(futs):
                yield from fut.result()
            self.finished = True
        finally:
            for f in futs:
                f.cancel()

    def close(self):
        if self.pool is not None:
            # every record done: the idle workers are joined (their resources counted, nothing left
            # behind); else (an error) they are left to exit on their own
            self.pool.shutdown(wait=getattr(self, "finished", False), cancel_futures=True)
            self.pool = None


class DaskExecutor:
    """An existing dask.distributed cluster (``scheduler``: an address or a Client)."""

    def __init__(self, scheduler):
        try:
            from distributed import Client
        except ImportError:         # pragma: no cover - dask is a dependency of the sweeps
            from hil.errors import UserError
            raise UserError("--scheduler: dask.distributed is not installed (pip install distributed)") from None
        if isinstance(scheduler, Client):
            self.client, self.own = scheduler, False
        else:
            try:
                self.client, self.own = Client(scheduler, set_as_default=False, timeout=10), True
            except (OSError, TimeoutError, ValueError) as exc:
                from hil.errors import UserError
                raise UserError(f"--scheduler {scheduler}: no Dask scheduler answers there ({exc})") from None

    def map(self, items):
        from hil.sweep.executors import dask_results
        yield from dask_results(self.client, diagnose_record, [(it[0], it) for it in items], "fleet")

    def close(self):
        if self.own:
            self.client.close()


def executor(scheduler=None, jobs: int | None = None):
    """Where the records run: a Dask cluster when ``scheduler`` is given, else local processes."""
    return DaskExecutor(scheduler) if scheduler else LocalExecutor(jobs)
