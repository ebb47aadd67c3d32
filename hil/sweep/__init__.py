"""Jerk sweeps: overshoot against commanded jerk, and the largest jerk a tolerance allows.

One *run* is one sine-square move (stroke, feed, jerk) from rest plus a dwell long enough to
capture the residual vibration; its figures are :class:`hil.analysis.MoveFigures` (overshoot of
table and tip over the whole move and dwell, floored at 0; peak following errors; residual tip
vibration; settling). Two analyses, as in the paper:

- ``mechatronic``: the whole closed loop on the simulated plant (:func:`hil.simulate.simulate`,
  recorded every ``record_every`` velocity steps, 0.5 ms by default, so that overshoot is not
  sampled at the 4 ms position clock only), or on a real axis through ``hil.runtime``;
- ``transmission`` (Section 3): the motor x1 follows the sine-square path exactly; x2 = TF2 x1 and
  x3 = TF3 x2, computed as the response of masses 2..N of the chain to the prescribed x1, v1
  (exactly TF2 and TF3 of Table 1), with a first-order-hold discretization (exact for a
  piecewise-linear input).

On top of the runs: the most conservative largest jerk for a tip tolerance (the first crossing,
refined by bisection on the simulated overshoot), the admissible intervals of a non-monotonic
curve, the local minima (vibration cancellation, explained with the dominant frequency), and a
proposal of the jerk that minimizes tip overshoot within a move-time budget.

Runs are independent: they go to a process pool (all cores) or a Dask cluster, and each finished
run is appended to ``runs.jsonl`` in the output folder, so an interrupted sweep resumes where it
stopped. The numbers do not depend on where a run was computed.
"""
from __future__ import annotations

import hashlib
import json
import math
import multiprocessing
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
from numba import njit

from sim_plant.chain import Chain

from hil.analysis import move_figures
from hil.profiles import MoveSpec, Trajectory, plan_move

__all__ = ["RunSpec", "SweepSettings", "run_one", "run_sweep", "admissible_intervals", "crossing",
           "local_minima", "tolerance_answer", "dominant_frequency", "cancellation_jerks",
           "t_acc_to_jmax", "jmax_to_t_acc", "ResultStore", "fingerprint", "jerk_grid", "warm_up",
           "transmission_response", "default_dwell"]

ANALYSES = ("mechatronic", "transmission")
RUN_FIELDS = ("j_max", "a_max", "t_acc", "peak_speed", "ramp_time", "duration",
              "overshoot_table_um", "overshoot_tip_um", "peak_following_error_table_um",
              "peak_following_error_tip_um", "residual_tip_um", "settling_time_table",
              "settling_time_tip", "peak_torque", "f_dom_tip_hz")


# --- the paper's Eq. (15)-(16) ---------------------------------------------------------------------

def t_acc_to_jmax(t_acc: float, feed: float, g0: float) -> float:
    """j_max = 2 a_max^2 / V_f with a_max = pi G0 / (2 t_acc)."""
    a = math.pi * g0 / (2.0 * t_acc)
    return 2.0 * a * a / feed


def jmax_to_t_acc(j_max: float, feed: float, g0: float) -> float:
    a = math.sqrt(j_max * feed / 2.0)
    return math.pi * g0 / (2.0 * a)


def jerk_grid(lo: float, hi: float, points: int) -> list[float]:
    """``points`` log-spaced jerks from lo to hi (both included)."""
    if not (lo > 0 and hi > lo):
        raise ValueError(f"jerk range: need 0 < low < high, got {lo:g}..{hi:g}")
    if points < 2:
        raise ValueError(f"--points: need at least 2, got {points}")
    return [float(x) for x in np.geomspace(lo, hi, points)]


# --- one run ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RunSpec:
    """One move of a sweep, SI units. Exactly one of ``t_acc`` (with g0) and ``j_max``."""
    analysis: str
    stroke: float
    feed: float
    g0: float | None
    t_acc: float | None
    j_max: float | None
    dwell: float
    record_every: int = 8
    refine: bool = False          # a bisection/proposal point, not a grid point

    def move_spec(self) -> MoveSpec:
        if self.t_acc is not None:
            return MoveSpec(self.stroke, self.feed, t_acc=self.t_acc, g0=self.g0)
        return MoveSpec(self.stroke, self.feed, j_max=self.j_max, g0=self.g0)

    def key(self, fp: str) -> str:
        what = f"t_acc={self.t_acc!r}" if self.t_acc is not None else f"j_max={self.j_max!r}"
        return (f"{fp}|{self.analysis}|stroke={self.stroke!r}|feed={self.feed!r}|g0={self.g0!r}|{what}"
                f"|dwell={self.dwell!r}|rec={self.record_every}")


def fingerprint(cfg) -> str:
    """A short hash of a configuration's values: runs of different models never mix in a store."""
    return hashlib.sha1(cfg.to_toml().encode()).hexdigest()[:12]


_MODELS: dict = {}


def _model(cfg):
    """(plant, controller) of a config, built once per process."""
    fp = fingerprint(cfg)
    if fp not in _MODELS:
        from hil.plant_config import plant_from_config
        from hil.control import controller_from_config
        plant = plant_from_config(cfg)
        ctrl = controller_from_config(cfg, plant)
        # the exact ZOH of the chain (a matrix exponential) once per model, not once per run
        plant = replace(plant, chain=_DiscretizedChain.of(plant.chain, ctrl.velocity_period))
        _MODELS[fp] = (plant, ctrl)
    return _MODELS[fp]


class _DiscretizedChain(Chain):
    """A chain that keeps its discretization at one sample time (the simulator asks for it every run)."""

    @classmethod
    def of(cls, chain: Chain, dt: float) -> "_DiscretizedChain":
        out = cls(chain.m, chain.k, chain.c, chain.c_ground)
        object.__setattr__(out, "_cache", {("all", dt): Chain.discretize(chain, dt, inputs="all")})
        return out

    def discretize(self, dt: float, inputs: str = "all"):
        cache = self.__dict__.setdefault("_cache", {})
        if (inputs, dt) not in cache:
            cache[(inputs, dt)] = Chain.discretize(self, dt, inputs=inputs)
        return cache[(inputs, dt)]


def dominant_frequency(t, x, t_from: float, fmin: float = 1.0) -> float | None:
    """Frequency (Hz) of the largest spectral peak of ``x`` after ``t_from`` (Hann window,
    zero-padded FFT, parabolic interpolation); None when there is too little signal."""
    t = np.asarray(t, float)
    sel = t >= t_from
    if np.count_nonzero(sel) < 16:
        return None
    y = np.asarray(x, float)[sel]
    tt = t[sel] - t[sel].mean()
    y = y - y.mean() - tt * (np.dot(tt, y) / np.dot(tt, tt))       # drop offset and drift
    if not np.any(np.abs(y) > 1e-12):
        return None
    dt = t[1] - t[0]
    nfft = max(1 << 15, 1 << int(math.ceil(math.log2(len(y) * 8))))
    spec = np.abs(np.fft.rfft(y * np.hanning(len(y)), nfft))
    f = np.fft.rfftfreq(nfft, dt)
    spec[f < fmin] = 0.0
    i = int(np.argmax(spec))
    if 0 < i < len(spec) - 1:
        a, b, c = np.log(spec[i - 1:i + 2] + 1e-300)
        den = a - 2 * b + c
        shift = 0.5 * (a - c) / den if den != 0 else 0.0
        return float(f[i] + shift * (f[1] - f[0]))
    return float(f[i])


def _figures(t, x_cmd, x_table, x_tip, u, move, spec: RunSpec, t_end=None) -> dict:
    fig = move_figures(t, x_cmd, x_table, x_tip, u, move, t_end=t_end).as_dict()
    fig.pop("settle_band_um", None)
    if fig.get("t_acc") is None and spec.g0:
        fig["t_acc"] = math.pi * spec.g0 / (2.0 * move.a_max)
    fig["ramp_time"] = move.ramp_time
    fig["duration"] = move.duration
    sel = np.asarray(t) <= (t[-1] if t_end is None else t_end)
    fig["f_dom_tip_hz"] = dominant_frequency(np.asarray(t)[sel], np.asarray(x_tip)[sel], move.duration)
    return {k: (None if v is None else float(v)) for k, v in fig.items()}


def _run_mechatronic(cfg, spec: RunSpec) -> dict:
    from hil.simulate import simulate
    plant, ctrl = _model(cfg)
    traj = Trajectory()
    move = traj.move(spec.move_spec())
    traj.dwell(spec.dwell)
    _, x = traj.sample(ctrl.position_period)
    r = simulate(plant, ctrl, x, record_every=spec.record_every)
    return _figures(r.t, r.x_cmd, r.x_table, r.x_tip, r.u, move, spec)


# transmission: masses 2..N driven by the prescribed motor motion x1 (TF2, TF3 of Table 1)

_TRANS: dict = {}


def _transmission_matrices(cfg, dt: float):
    """First-order-hold discretization of masses 2..N with inputs (x1, v1):
    z[k+1] = Phi z[k] + G0 u[k] + G1 u[k+1]."""
    import scipy.linalg
    fp = (fingerprint(cfg), dt)
    if fp in _TRANS:
        return _TRANS[fp]
    plant, _ = _model(cfg)
    ch = plant.chain
    if ch.n < 2:
        raise ValueError("the transmission analysis needs a chain of at least 2 masses")
    M, K = ch.M, ch.K
    Cl = ch._tridiagonal(ch.c, ch.n)       # links only: mass 1's ground damping does not act on x2..
    d = slice(1, ch.n)
    nd = ch.n - 1
    Minv = np.diag(1.0 / np.diag(M)[d])
    A = np.zeros((2 * nd, 2 * nd))
    A[:nd, nd:] = np.eye(nd)
    A[nd:, :nd] = -Minv @ K[d, d]
    A[nd:, nd:] = -Minv @ Cl[d, d]
    B = np.zeros((2 * nd, 2))
    B[nd:, 0] = -Minv @ K[d, 0]
    B[nd:, 1] = -Minv @ Cl[d, 0]
    nx, nu = 2 * nd, 2
    blk = np.zeros((nx + 2 * nu, nx + 2 * nu))
    blk[:nx, :nx] = A * dt
    blk[:nx, nx:nx + nu] = B * dt
    blk[nx:nx + nu, nx + nu:] = np.eye(nu)
    e = scipy.linalg.expm(blk)
    Phi, Gam1, Gam2 = e[:nx, :nx], e[:nx, nx:nx + nu], e[:nx, nx + nu:]
    out = (np.ascontiguousarray(Phi), np.ascontiguousarray(Gam1 - Gam2), np.ascontiguousarray(Gam2),
           plant.table - 1, plant.tip - 1)
    _TRANS[fp] = out
    return out


@njit(cache=True)
def _lti_foh(Phi, G0, G1, z0, U):
    n_steps = U.shape[0]
    nx = Phi.shape[0]
    nu = U.shape[1]
    Z = np.zeros((n_steps, nx))
    z = z0.copy()
    Z[0, :] = z
    zn = np.zeros(nx)
    for k in range(n_steps - 1):
        for r in range(nx):
            acc = 0.0
            for c in range(nx):
                acc += Phi[r, c] * z[c]
            for c in range(nu):
                acc += G0[r, c] * U[k, c] + G1[r, c] * U[k + 1, c]
            zn[r] = acc
        for r in range(nx):
            z[r] = zn[r]
        Z[k + 1, :] = z
    return Z


def transmission_response(cfg, move, t):
    """(x1, x2, x_tip) on the uniform grid ``t`` for the motor following ``move`` exactly."""
    dt = float(t[1] - t[0])
    Phi, G0, G1, itab, itip = _transmission_matrices(cfg, dt)
    x1 = move.position(t)
    U = np.ascontiguousarray(np.column_stack([x1, move.velocity(t)]))
    nd = Phi.shape[0] // 2
    z0 = np.zeros(2 * nd)
    z0[:nd] = x1[0]
    Z = _lti_foh(Phi, G0, G1, z0, U)
    return x1, Z[:, itab], Z[:, itip]


def _run_transmission(cfg, spec: RunSpec) -> dict:
    _, ctrl = _model(cfg)
    move = plan_move(spec.move_spec())
    dt = spec.record_every * ctrl.velocity_period
    n = int(math.ceil((move.duration + spec.dwell) / dt)) + 1
    t = np.arange(n) * dt
    x1, x2, x3 = transmission_response(cfg, move, t)
    return _figures(t, x1, x2, x3, np.zeros(0), move, spec)


def run_one(cfg, spec: RunSpec) -> dict:
    """The figures of one run on the simulated plant (what a worker computes)."""
    if spec.analysis == "mechatronic":
        return _run_mechatronic(cfg, spec)
    if spec.analysis == "transmission":
        return _run_transmission(cfg, spec)
    raise ValueError(f"unknown analysis {spec.analysis!r} (mechatronic or transmission)")


def _task(cfg, key: str, spec: RunSpec):
    return key, run_one(cfg, spec)


def _chunk(cfg, tasks):
    return [_task(cfg, key, spec) for key, spec in tasks]


def backend_trajectory(spec: RunSpec, start: float = 0.0) -> tuple[Trajectory, object]:
    """The sequence run on an axis for one run: the move, a dwell, the return move, a dwell."""
    traj = Trajectory(start=start)
    move = traj.move(spec.move_spec())
    traj.dwell(spec.dwell)
    back = spec.move_spec()
    traj.move(replace(back, stroke=-back.stroke))
    traj.dwell(spec.dwell)
    return traj, move


def run_on_backend(cfg, spec: RunSpec, backend: str, out_dir=None) -> dict:
    """One run on a runtime backend (``hil.runtime.run_trajectory``): the move, a dwell, the
    return move and a dwell, so the axis ends where it started. Limits are checked first."""
    from drivers import open_backend
    from hil.runtime import run_trajectory
    traj, move = backend_trajectory(spec)
    rec = run_trajectory(cfg, traj, backend=open_backend(cfg, backend), out_file=None, settle=0.0)
    if getattr(rec, "status", "complete") != "complete":
        from hil.errors import UserError
        raise UserError(f"run at j_max {move.j_max:.4g} m/s^3 stopped: {rec.status}: {rec.reason}; the runs "
                        f"finished before it are kept and the sweep resumes from there")
    ch = rec.channels
    t = np.asarray(ch["t"], float)
    u = ch.get("torque", ch.get("command", np.zeros(0)))
    tip = ch.get("x_tip", ch["x_table"])
    return _figures(t, ch["x_cmd"], ch["x_table"], tip, u, move, spec, t_end=move.duration + spec.dwell)


# --- where runs go: a process pool, a Dask cluster, or this process ---------------------------------

class _Local:
    """Runs in this process, or on a process pool (fork: the workers inherit the compiled kernel
    and the discretized models of the parent)."""

    def __init__(self, jobs: int | None):
        self.jobs = max(1, jobs or os.cpu_count() or 1)
        self.pool = None

    def map(self, cfg, tasks):
        if self.jobs == 1 or len(tasks) <= 1:
            for key, spec in tasks:
                yield _task(cfg, key, spec)
            return
        if self.pool is None:
            try:
                ctx = multiprocessing.get_context("fork")
            except ValueError:              # pragma: no cover - platforms without fork
                ctx = None
            self.pool = ProcessPoolExecutor(max_workers=self.jobs, mp_context=ctx)
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
        return _task(cfg, key, spec)

    def close(self):
        if self.pool is not None:
            self.pool.shutdown(wait=False, cancel_futures=True)   # workers exit on their own
            self.pool = None


class _Dask:
    """Runs on a dask.distributed cluster (``scheduler``: an address or a Client)."""

    def __init__(self, scheduler):
        from distributed import Client
        if isinstance(scheduler, Client):
            self.client, self.own = scheduler, False
        else:
            self.client, self.own = Client(scheduler, set_as_default=False), True

    def map(self, cfg, tasks):
        from distributed import as_completed as das_completed
        if not tasks:
            return
        futs = [self.client.submit(_task, cfg, key, spec, key=f"sweep-{hashlib.sha1(key.encode()).hexdigest()}",
                                   pure=False) for key, spec in tasks]
        try:
            with self.client.as_current():
                done = das_completed(futs)
            for fut in done:
                yield fut.result()
        finally:
            for f in futs:
                f.cancel()

    def one(self, cfg, key, spec):
        return self.client.submit(_task, cfg, key, spec, pure=False).result()

    def close(self):
        if self.own:
            self.client.close()


class _Backend:
    """A real axis: one run after the other."""

    def __init__(self, backend, out_dir):
        self.backend, self.out_dir = backend, out_dir

    def map(self, cfg, tasks):
        for key, spec in tasks:
            yield self.one(cfg, key, spec)

    def one(self, cfg, key, spec):
        if spec.analysis == "transmission":      # a model analysis: the axis is not needed
            return _task(cfg, key, spec)
        return key, run_on_backend(cfg, spec, self.backend, self.out_dir)

    def close(self):
        pass


# --- the store of finished runs ----------------------------------------------------------------------

class ResultStore:
    """Finished runs, one JSON line each, appended as they finish (``runs.jsonl``)."""

    def __init__(self, path: Path | None, resume: bool = True):
        self.path = None if path is None else Path(path)
        self.done: dict[str, dict] = {}
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if not resume and self.path.exists():
                self.path.unlink()
            if self.path.exists():
                with open(self.path, "rb+") as fh:     # end a line cut by an interruption
                    fh.seek(0, os.SEEK_END)
                    if fh.tell() > 0:
                        fh.seek(-1, os.SEEK_END)
                        if fh.read(1) != b"\n":
                            fh.write(b"\n")
                with open(self.path) as fh:
                    for line in fh:
                        try:
                            row = json.loads(line)
                            self.done[row["key"]] = row["figures"]
                        except (ValueError, KeyError, TypeError):
                            continue       # a line cut by an interruption
        self.computed = 0
        self.reused = 0

    def add(self, key: str, figures: dict, spec: RunSpec) -> None:
        self.done[key] = figures
        self.computed += 1
        if self.path is not None:
            with open(self.path, "a") as fh:
                fh.write(json.dumps({"key": key, "spec": asdict(spec), "figures": figures}) + "\n")
                fh.flush()


# --- the analyses of a curve (pure functions, tested on hand-made curves) ------------------------------

def crossing(ok_j: float, over_j: float, f: Callable[[float], float], tol: float,
             rel: float = 0.002, max_iter: int = 30) -> float:
    """Bisection (in log jerk) between an admissible jerk ``ok_j`` (f <= tol) and an inadmissible one
    ``over_j``; returns the admissible end of the final bracket (relative width ``rel``)."""
    a, b = ok_j, over_j
    for _ in range(max_iter):
        if abs(b / a - 1.0) <= rel:
            break
        m = math.sqrt(a * b)
        if f(m) <= tol:
            a = m
        else:
            b = m
    return a


def admissible_intervals(j, y, tol: float, f: Callable[[float], float] | None = None,
                         rel: float = 0.002) -> list[list[float]]:
    """The [low, high] jerk intervals where ``y`` (overshoot at the jerks ``j``, ascending) stays
    within ``tol``; interval ends between grid points are refined with ``f`` when given."""
    j = [float(v) for v in j]
    ok = [float(v) <= tol for v in y]
    out = []
    i, n = 0, len(j)
    while i < n:
        if not ok[i]:
            i += 1
            continue
        k = i
        while k + 1 < n and ok[k + 1]:
            k += 1
        lo = j[i] if (i == 0 or f is None) else crossing(j[i], j[i - 1], f, tol, rel)
        hi = j[k] if (k == n - 1 or f is None) else crossing(j[k], j[k + 1], f, tol, rel)
        out.append([lo, hi])
        i = k + 1
    return out


def tolerance_answer(j, y, tol: float, f: Callable[[float], float] | None = None,
                     rel: float = 0.002, unit: str = "m/s^3", y_scale: float = 1.0, y_unit: str = "") -> dict:
    """``max_jerk`` (the most conservative: where the overshoot first exceeds ``tol``, refined),
    ``admissible`` intervals, and a ``note`` when there is no answer in the range."""
    j = [float(v) for v in j]
    y = [float(v) for v in y]
    intervals = admissible_intervals(j, y, tol, f, rel)
    res = {"max_jerk": None, "admissible": intervals, "note": None}
    def q(v):
        return f"{v * y_scale:.3g}{(' ' + y_unit) if y_unit else ''}"

    if not j:
        res["note"] = "no runs"
    elif y[0] > tol:
        res["note"] = (f"the lowest jerk of the range, {j[0]:.4g} {unit}, already overshoots "
                       f"{q(y[0])} > {q(tol)}: the most conservative jerk lies below it; extend the "
                       f"range down (e.g. --jmax {j[0] / 10:.3g}..{j[0]:.4g})")
        if intervals:
            res["note"] += f" (higher up, admissible intervals exist: see 'admissible')"
    elif all(v <= tol for v in y):
        res["note"] = (f"no jerk of the range exceeds the tolerance (largest overshoot {q(max(y))} <= "
                       f"{q(tol)}): the limit lies above {j[-1]:.4g} {unit}; extend the range up "
                       f"(e.g. --jmax {j[-1]:.4g}..{j[-1] * 10:.3g})")
    else:
        res["max_jerk"] = intervals[0][1]
    return res


def local_minima(j, y, floor: float = 0.0) -> list[int]:
    """Indices of the interior local minima of ``y`` (a dip: lower than the point before, not higher
    than the one after); flat stretches at ``floor`` (no overshoot at all) are not dips."""
    out = []
    for i in range(1, len(y) - 1):
        if y[i] < y[i - 1] and y[i] <= y[i + 1] and not (y[i] <= floor and y[i + 1] <= floor):
            out.append(i)
    return out


def cancellation_jerks(f_dom: float, feed: float, j_lo: float, j_hi: float) -> list[dict]:
    """Jerks whose ramp T_r lasts (k + 1/2) periods of ``f_dom`` (k >= 1): the half-sine
    acceleration pulse of a sine-square ramp has no spectral content at 1.5/T_r, 2.5/T_r, ...,
    so a ramp of that length leaves (almost) no vibration at f_dom."""
    out = []
    for k in range(1, 200):
        tr = (k + 0.5) / f_dom
        j = math.pi ** 2 * feed / (2.0 * tr * tr)
        if j < j_lo:
            break
        if j <= j_hi:
            out.append({"k": k, "cycles": k + 0.5, "ramp_time": tr, "j_max": j})
    return out


# --- the sweep ----------------------------------------------------------------------------------------

@dataclass
class SweepSettings:
    """What to sweep (SI). ``values`` are t_acc (``by="t_acc"``, needs g0) or j_max values."""
    stroke: float
    feed: float
    values: list
    by: str = "j_max"
    g0: float | None = None
    dwell: float | None = None          # None: max(1 s, 10 periods of the lowest elastic mode)
    record_every: int = 8
    analysis: str = "mechatronic"       # mechatronic | transmission | both
    tolerance: float | None = None      # m, on the tip overshoot
    budget: float | None = None         # s, longest acceptable move time for the proposal
    budget_pct: float | None = 5.0      # or: percent over the fastest move of the range
    refine_rel: float = 0.002

    def analyses(self) -> list[str]:
        return list(ANALYSES) if self.analysis == "both" else [self.analysis]

    @property
    def primary(self) -> str:
        return "transmission" if self.analysis == "transmission" else "mechatronic"


def default_dwell(cfg) -> float:
    plant, _ = _model(cfg)
    w, _ = plant.chain.modes()
    el = w[w > 1e-6]
    if el.size == 0:
        return 1.0
    return float(max(1.0, 10.0 / (el.min() / (2 * math.pi))))


class _Runner:
    """Runs specs through an executor and a store, with a progress bar."""

    def __init__(self, cfg, executor, store: ResultStore, progress: bool):
        self.cfg, self.ex, self.store, self.progress = cfg, executor, store, progress
        self.fp = fingerprint(cfg)

    def many(self, specs: list[RunSpec], desc: str) -> list[dict]:
        keys = [s.key(self.fp) for s in specs]
        todo, seen = [], set()
        for k, s in zip(keys, specs):
            if k in self.store.done:
                self.store.reused += 1
            elif k not in seen:
                todo.append((k, s))
                seen.add(k)
        if todo:
            from tqdm import tqdm
            specs_by_key = dict(todo)
            with tqdm(total=len(todo), desc=desc, unit="run", file=sys.stderr, disable=not self.progress,
                      leave=False) as bar:
                for key, fig in self.ex.map(self.cfg, todo):
                    self.store.add(key, fig, specs_by_key[key])
                    bar.update(1)
        return [self.store.done[k] for k in keys]

    def one(self, spec: RunSpec) -> dict:
        k = spec.key(self.fp)
        if k in self.store.done:
            self.store.reused += 1
        else:
            key, fig = self.ex.one(self.cfg, k, spec)
            self.store.add(key, fig, spec)
        return self.store.done[k]


def _specs(s: SweepSettings, analysis: str, dwell: float) -> list[RunSpec]:
    out = []
    for v in s.values:
        if s.by == "t_acc":
            out.append(RunSpec(analysis, s.stroke, s.feed, s.g0, float(v), None, dwell, s.record_every))
        else:
            out.append(RunSpec(analysis, s.stroke, s.feed, s.g0, None, float(v), dwell, s.record_every))
    return out


def _rows(specs, figs) -> list[dict]:
    rows = []
    for s, f in zip(specs, figs):
        row = {k: f.get(k) for k in RUN_FIELDS}
        row["refine"] = s.refine
        rows.append(row)
    rows.sort(key=lambda r: r["j_max"])
    return rows


def _model_side(runner: _Runner, s: SweepSettings, dwell: float, tag: str) -> dict:
    """Grid runs of every analysis, and the tolerance answer of the primary one."""
    side = {}
    for an in s.analyses():
        specs = _specs(s, an, dwell)
        side[an] = _rows(specs, runner.many(specs, f"{tag} {an}"))
    if s.tolerance is not None:
        rows = side[s.primary]
        j = [r["j_max"] for r in rows]
        y = [r["overshoot_tip_um"] * 1e-6 for r in rows]

        def f(jm):
            spec = RunSpec(s.primary, s.stroke, s.feed, s.g0, None, float(jm), dwell, s.record_every, True)
            return runner.one(spec)["overshoot_tip_um"] * 1e-6

        side["tolerance"] = tolerance_answer(j, y, s.tolerance, f, s.refine_rel, y_scale=1e6, y_unit="um")
    return side


def _explain_minima(rows, s: SweepSettings) -> tuple[list[dict], float | None, list[dict]]:
    j = [r["j_max"] for r in rows]
    y = [r["overshoot_tip_um"] for r in rows]
    fd = [r["f_dom_tip_hz"] for r in rows if r["f_dom_tip_hz"] and r["residual_tip_um"] and r["residual_tip_um"] > 0.01]
    f_dom = float(np.median(fd)) if fd else None
    mins = []
    for i in local_minima(j, y):
        r = rows[i]
        m = {"j_max": r["j_max"], "t_acc": r["t_acc"], "overshoot_tip_um": r["overshoot_tip_um"],
             "ramp_time": r["ramp_time"]}
        if f_dom:
            c = f_dom * r["ramp_time"]
            k = max(1, int(round(c - 0.5)))
            m.update(f_dom_hz=f_dom, cycles=c,
                     explanation=(f"the ramp lasts T_r = {r['ramp_time'] * 1e3:.1f} ms = {c:.2f} periods of the "
                                  f"dominant {f_dom:.2f} Hz; a sine-square ramp leaves no vibration at f_dom when "
                                  f"f_dom T_r = k + 1/2 (here nearest {k + 0.5:.1f}, jerk "
                                  f"{math.pi ** 2 * s.feed / (2 * ((k + 0.5) / f_dom) ** 2):.4g} m/s^3)"))
        mins.append(m)
    pred = cancellation_jerks(f_dom, s.feed, min(j), max(j)) if f_dom and j else []
    return mins, f_dom, pred


def _propose(runner: _Runner, rows, s: SweepSettings, dwell: float, predicted) -> dict:
    """The jerk minimizing the tip overshoot among moves no longer than the budget: the grid, the
    predicted cancellation jerks, then a golden-section search between the best point's neighbours."""
    an = s.primary

    def ev(jm):
        spec = RunSpec(an, s.stroke, s.feed, s.g0, None, float(jm), dwell, s.record_every, True)
        return runner.one(spec)

    fastest = min(r["duration"] for r in rows)
    budget = s.budget
    if budget is None and s.budget_pct is not None:
        budget = fastest * (1.0 + s.budget_pct / 100.0)

    def fits(f):
        return budget is None or f["duration"] <= budget * (1 + 1e-12)

    cands = [r for r in rows if fits(r)]
    for p in predicted:
        f = ev(p["j_max"])
        if fits(f):
            cands.append(f)
    if not cands:
        return {"j_max": None, "note": f"no move of the range fits the time budget of {budget:.4g} s "
                                       f"(the fastest takes {fastest:.4g} s): raise --budget or the jerk range"}
    grid = sorted(rows, key=lambda r: r["j_max"])
    best = min(cands, key=lambda r: (r["overshoot_tip_um"], -r["j_max"]))
    # golden-section search (log jerk) between the best point's grid neighbours
    js = [r["j_max"] for r in grid]
    lo = max([v for v in js if v < best["j_max"]], default=best["j_max"])
    hi = min([v for v in js if v > best["j_max"]], default=best["j_max"])
    if hi > lo:
        g = (math.sqrt(5) - 1) / 2
        a, b = math.log(lo), math.log(hi)
        c, d = b - g * (b - a), a + g * (b - a)

        def cost(x):
            f = ev(math.exp(x))
            return (f["overshoot_tip_um"] if fits(f) else math.inf), f

        fc, rc = cost(c)
        fdd, rd = cost(d)
        for _ in range(14):
            if fc <= fdd:
                b, d, fdd, rd = d, c, fc, rc
                c = b - g * (b - a)
                fc, rc = cost(c)
            else:
                a, c, fc, rc = c, d, fdd, rd
                d = a + g * (b - a)
                fdd, rd = cost(d)
            for r, fv in ((rc, fc), (rd, fdd)):
                if fv < best["overshoot_tip_um"]:
                    best = r
    out = {k: best.get(k) for k in ("j_max", "t_acc", "a_max", "duration", "overshoot_tip_um",
                                    "overshoot_table_um", "residual_tip_um")}
    out["budget_s"] = budget
    out["fastest_s"] = fastest
    out["analysis"] = an
    return out


def run_sweep(cfg, settings: SweepSettings, *, compare_cfg=None, out_dir: str | Path | None = None,
              jobs: int | None = None, scheduler=None, backend: str | None = None, progress: bool = True,
              resume: bool = True, propose: bool = True) -> dict:
    """Run a sweep and its analyses; returns the report (the issue's JSON object, and more).

    ``scheduler``: a dask.distributed address (or Client) to run on; ``jobs``: local processes
    (default: all cores); ``backend``: run the mechatronic moves on that runtime backend instead of
    the simulated plant; ``out_dir``: where ``runs.jsonl`` (resume) lives."""
    s = settings
    if s.by == "t_acc" and not s.g0:
        raise ValueError("a t_acc sweep needs the rapid speed g0 (nc.g0 in the config, or --g0)")
    if s.analysis not in ANALYSES + ("both",):
        raise ValueError(f"analysis: mechatronic, transmission or both, not {s.analysis!r}")
    dwell = s.dwell if s.dwell is not None else default_dwell(cfg)
    store = ResultStore(None if out_dir is None else Path(out_dir) / "runs.jsonl", resume=resume)
    if backend:
        from hil.profiles import AxisLimits, check_limits
        lim = AxisLimits.from_config(cfg)
        for spec in _specs(s, "mechatronic", dwell):      # refuse before any motion
            check_limits(backend_trajectory(spec)[0], lim)
        ex = _Backend(backend, out_dir)
    elif scheduler is not None:
        ex = _Dask(scheduler)
    else:
        ex = _Local(jobs)
        # compile (or load from the cache) and build the models here, before the workers fork
        for c in (cfg, compare_cfg):
            if c is not None:
                warm_up(c, s.analyses())
    report = {"config": cfg.source, "name": cfg.get("meta.name", ""),
              "move": {"stroke_m": s.stroke, "feed_m_per_s": s.feed, "g0_m_per_s": s.g0, "dwell_s": dwell,
                       "record_period_s": s.record_every * _model(cfg)[1].velocity_period, "swept": s.by},
              "analysis": s.analysis}
    try:
        runner = _Runner(cfg, ex, store, progress)
        main = _model_side(runner, s, dwell, "sweep")
        report["runs"] = main[s.primary]
        if s.analysis == "both":
            report["runs_transmission"] = main["transmission"]
        notes = []
        if s.tolerance is not None:
            t = main["tolerance"]
            report.update(tolerance_um=s.tolerance * 1e6, max_jerk=t["max_jerk"], admissible=t["admissible"])
            report["max_jerk_t_acc"] = (jmax_to_t_acc(t["max_jerk"], s.feed, s.g0)
                                        if t["max_jerk"] and s.g0 else None)
            if t["note"]:
                notes.append(t["note"])
        if compare_cfg is not None:
            cmp_runner = _Runner(compare_cfg, ex, store, progress)
            other = _model_side(cmp_runner, s, dwell, "compare")
            report["compare_config"] = compare_cfg.source
            report["compare_runs"] = other[s.primary]
            if s.analysis == "both":
                report["compare_runs_transmission"] = other["transmission"]
            if s.tolerance is not None:
                t = other["tolerance"]
                report.update(max_jerk_compare=t["max_jerk"], admissible_compare=t["admissible"])
                if t["note"]:
                    notes.append("compare model: " + t["note"])
                mj, mc = report["max_jerk"], report["max_jerk_compare"]
                report["estimate_error_pct"] = (100.0 * (mc - mj) / mc if mj is not None and mc else None)
                if report["estimate_error_pct"] is None:
                    notes.append("estimate_error_pct needs max_jerk and max_jerk_compare")
        mins, f_dom, pred = _explain_minima(report["runs"], s)
        report["dominant_frequency_hz"] = f_dom
        report["local_minima"] = mins
        report["predicted_cancellation"] = pred
        if propose and report["runs"]:
            report["proposal"] = _propose(runner, report["runs"], s, dwell, pred)
        report["note"] = "; ".join(notes) if notes else None
    finally:
        ex.close()
    report["stats"] = {"computed": store.computed, "reused": store.reused}
    return report


def warm_up(cfg, analyses: Iterable[str] = ANALYSES) -> None:
    """Build the model and run a tiny move so that the compiled code is loaded in this process."""
    spec = MoveSpec(1e-3, 0.01, j_max=10.0)
    plant, ctrl = _model(cfg)
    for an in analyses:
        rs = RunSpec(an, spec.stroke, spec.feed, None, None, spec.j_max, 0.02, 8)
        if an == "transmission" and plant.n < 2:
            continue
        run_one(cfg, rs)
