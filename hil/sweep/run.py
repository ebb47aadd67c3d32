"""One run of a sweep: one sine-square move from rest plus a dwell, and its figures.

A :class:`RunSpec` names the move (stroke, feed and either ``t_acc`` with G0 or ``j_max``; SI
units), the dwell after it, how densely it is recorded and which analysis computes it:

- ``mechatronic``: the whole closed loop on the simulated plant (:func:`hil.simulate.simulate`),
  or on an axis through a runtime backend
  (:func:`run_on_backend`: the move, a dwell, the return move and a dwell, so the axis ends
  where it started);
- ``transmission``: the motor follows the path exactly and masses 2..N respond
  (:mod:`hil.sweep.transmission`).

On the simulated plant every figure but one is taken on the velocity-loop grid (every velocity
step, 62.5 us on the paper's bench): a peak never falls between samples, so overshoot, peak
following error, residual vibration and settling do not depend on ``record_every`` (issue 30:
a 40 ms record answered 23.92 m/s^3 where the velocity grid answers 14.03). ``record_every``
(velocity steps per sample) is the sampling of the dominant-frequency estimate only, an FFT
whose length it keeps small; :func:`hil.sweep.sweep.check_sampling` bounds it.

A run's figures are :class:`hil.analysis.MoveFigures` over the move and its dwell (overshoot of
table and tip floored at 0, peak following errors, residual tip vibration, settling, peak torque)
plus the ramp time T_r, the move's duration and the dominant frequency of the tip after the move;
``t_acc`` is filled from G0 by Eq. (15) when the run was given a jerk. :data:`RUN_FIELDS` are the
figures a report row keeps.

``RunSpec.key(fingerprint, backend)`` identifies a run in ``runs.jsonl``: the model, the code
version (a hash of the sources that compute a run: a changed kernel never reuses old figures),
the backend (a simulated sweep's runs are never an axis's) and the move. :func:`run_task` is what a worker computes: module-level, so that a process
pool and Dask can pickle it by name.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from hil.analysis import move_figures
from hil.backends import open_backend
from hil.errors import RunStopped, UserError
from hil.profiles import MoveSpec, Trajectory, plan_move
from hil.runtime import run_trajectory
from hil.shaping import config_shaper, shaped
from hil.simulate import simulate
from hil.sweep.model import model_of
from hil.sweep.transmission import transmission_response

__all__ = ["ANALYSES", "RUN_FIELDS", "RunSpec", "dominant_frequency", "run_one", "run_task",
           "backend_trajectory", "run_on_backend"]

ANALYSES = ("mechatronic", "transmission")
RUN_FIELDS = ("j_max", "a_max", "t_acc", "peak_speed", "ramp_time", "duration",
              "overshoot_table_um", "overshoot_tip_um", "peak_following_error_table_um",
              "peak_following_error_tip_um", "residual_tip_um", "settling_time_table",
              "settling_time_tip", "peak_torque", "f_dom_tip_hz")


def code_files() -> list:
    """The sources that compute a run's figures (their hash keys the store: a change recomputes)."""
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]          # the folder that holds hil/, drivers/, sim_plant/
    return [root / rel for rel in (
        "drivers/control.py", "hil/simulate.py", "hil/profiles.py", "hil/analysis.py", "hil/runtime.py",
        "hil/plant_config.py", "hil/sweep/run.py", "hil/sweep/transmission.py", "hil/sweep/model.py",
        "sim_plant/kernel.py", "sim_plant/chain.py", "sim_plant/plant.py")]


def _code_version() -> str:
    """A short hash of the project's version and of the sources that compute a run's figures."""
    import hashlib

    import hil
    h = hashlib.sha1(str(getattr(hil, "__version__", "")).encode())
    for path in code_files():
        try:
            h.update(path.read_bytes())
        except OSError:
            h.update(path.name.encode())
    return h.hexdigest()[:10]


CODE_VERSION = _code_version()


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

    def key(self, fp: str, backend: str = "model") -> str:
        """The run's key in ``runs.jsonl``: everything that changes its figures: the model
        (``fp``, :func:`hil.sweep.model.fingerprint`), the code that computes it
        (:data:`CODE_VERSION`), the backend it ran on (``"model"``: the sweep's own compiled runs),
        the analysis and the move."""
        what = f"t_acc={self.t_acc!r}" if self.t_acc is not None else f"j_max={self.j_max!r}"
        return (f"{fp}|code={CODE_VERSION}|backend={backend}|{self.analysis}|stroke={self.stroke!r}"
                f"|feed={self.feed!r}|g0={self.g0!r}|{what}|dwell={self.dwell!r}|rec={self.record_every}")


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


def _figures(t, x_cmd, x_table, x_tip, u, move, spec: RunSpec, t_end=None, every: int = 1, tail: float = 0.0) -> dict:
    """The run's figures from its samples; ``every``: the dominant frequency from every
    ``every``-th sample only (the others take them all); ``tail``: the command ends this much after
    the move (an input shaper's, hil.shaping)."""
    fig = move_figures(t, x_cmd, x_table, x_tip, u, move, t_end=t_end, tail=tail).as_dict()
    fig.pop("settle_band_um", None)
    fig.pop("observed_after_s", None)
    if fig.get("t_acc") is None and spec.g0:
        fig["t_acc"] = math.pi * spec.g0 / (2.0 * move.a_max)
    fig["ramp_time"] = move.ramp_time
    fig["duration"] = move.duration
    sel = np.asarray(t) <= (t[-1] if t_end is None else t_end)
    fig["f_dom_tip_hz"] = dominant_frequency(np.asarray(t)[sel][::every], np.asarray(x_tip)[sel][::every],
                                             move.duration)
    return {k: (None if v is None else float(v)) for k, v in fig.items()}


def _run_mechatronic(cfg, spec: RunSpec) -> dict:
    plant, ctrl = model_of(cfg)
    traj = Trajectory()
    move = traj.move(spec.move_spec())
    traj.dwell(spec.dwell)
    shaper = config_shaper(cfg)           # the config's nc.shaper: a sweep compares shaped and plain by configs
    _, x = shaped(traj, shaper).sample(ctrl.position_period)
    r = simulate(plant, ctrl, x, record_every=1)          # the velocity-loop grid (module docstring)
    return _figures(r.t, r.x_cmd, r.x_table, r.x_tip, r.u, move, spec, every=spec.record_every,
                    tail=shaper.duration if shaper else 0.0)


def _run_transmission(cfg, spec: RunSpec) -> dict:
    _, ctrl = model_of(cfg)
    move = plan_move(spec.move_spec())
    dt = ctrl.velocity_period                             # the velocity-loop grid, as the mechatronic runs
    n = int(math.ceil((move.duration + spec.dwell) / dt)) + 1
    t = np.arange(n) * dt
    x1, x2, x3 = transmission_response(cfg, move, t)
    return _figures(t, x1, x2, x3, np.zeros(0), move, spec, every=spec.record_every)


def run_one(cfg, spec: RunSpec) -> dict:
    """The figures of one run on the simulated plant (what a worker computes)."""
    if spec.analysis == "mechatronic":
        return _run_mechatronic(cfg, spec)
    if spec.analysis == "transmission":
        return _run_transmission(cfg, spec)
    raise ValueError(f"unknown analysis {spec.analysis!r} (mechatronic or transmission)")


def run_task(cfg, key: str, spec: RunSpec) -> tuple[str, dict]:
    """``(key, figures)`` of one run on the simulated plant: a worker's unit of work.

    Parameters
    ----------
    cfg : hil.config.Config
        The axis configuration (pickled to the worker).
    key : str
        The run's store key, ``spec.key(fingerprint(cfg))``, handed back with the figures.
    spec : RunSpec
        The run.
    """
    return key, run_one(cfg, spec)


def backend_trajectory(spec: RunSpec, start: float = 0.0) -> tuple[Trajectory, object]:
    """The sequence run on an axis for one run: the move, a dwell, the return move, a dwell."""
    traj = Trajectory(start=start)
    move = traj.move(spec.move_spec())
    traj.dwell(spec.dwell)
    back = spec.move_spec()
    traj.move(replace(back, stroke=-back.stroke))
    traj.dwell(spec.dwell)
    return traj, move


def run_on_backend(cfg, spec: RunSpec, backend: str, out_dir=None, start: float | None = None, scope=None,
                   can_log: str | None = None) -> dict:
    """One run on a runtime backend (``hil.runtime.run_trajectory``): the move, a dwell, the
    return move and a dwell, so the axis ends where it started. Limits are checked first.

    ``start``: the sweep's start, where the axis must stand (within ``limits.start_window``) before
    this run, else it is refused; ``None`` (the first run): the run starts where the axis stands.
    The figures carry ``start_m``, where the run started. ``scope``: the live scope's ring (see
    ``hil.runtime.run_trajectory``); ``can_log``: the file this run's CAN bus is traced into (a
    backend on a CAN bus, ``drivers.open_backend``)."""
    traj, move = backend_trajectory(spec, 0.0 if start is None else start)
    shaper = config_shaper(cfg)
    rec = run_trajectory(cfg, shaped(traj, shaper), backend=open_backend(cfg, backend, can_log=can_log), out_file=None,
                         settle=0.0, start="follow" if start is None else "check", scope=scope)
    if len(rec.channels["t"]) < 2:       # the backend could not be opened or enabled: nothing moved
        raise UserError(f"the run at j_max {move.j_max:.4g} m/s^3 did not start on {backend}: {rec.status}: "
                        f"{rec.reason}")
    if getattr(rec, "status", "complete") != "complete":
        raise RunStopped(f"run at j_max {move.j_max:.4g} m/s^3 stopped: {rec.status}: {rec.reason}; the runs "
                         f"finished before it are kept and the sweep resumes from there", rec.status, rec.reason,
                         rec.stop)
    if rec.start is not None and rec.start != traj.start:     # planned from where the axis stood
        move = traj.shifted(rec.start - traj.start).moves[0]
    ch = rec.channels
    t = np.asarray(ch["t"], float)
    u = ch.get("torque", ch.get("command", np.zeros(0)))
    tip = ch.get("x_tip", ch["x_table"])
    out = _figures(t, ch["x_cmd"], ch["x_table"], tip, u, move, spec, t_end=move.duration + spec.dwell,
                   tail=shaper.duration if shaper else 0.0)
    out["start_m"] = rec.start
    return out
