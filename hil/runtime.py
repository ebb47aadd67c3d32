"""Run a trajectory on a backend and record it: what ``hil move`` and ``hil sweep`` call.

On the embedded simulated plant the whole command goes through the compiled loop at once (a dry
run); on any other backend it goes through :class:`hil.loop.ControlLoop`, cycle by cycle, on the
real-time clock, with the supervisor watching. Either way the record is written in the
measurement format as it goes.

Every run first checks the supervisor's latch (a trip not yet reset refuses it, on every
backend). Where the run starts: the simulated plant is put at the planned start (a dry run starts
where it is told). A backend that drives an axis (``Backend.read_position`` answers) is asked
where the axis stands after it is opened and before it is enabled, and ``start`` says what
then:

* ``"follow"``: the trajectory is moved to start there (its strokes are relative: ``hil move``
  without ``--start``, ``hil jog``, the first run of a sweep) and checked against the limits
  again, before anything moves;
* ``"check"``: the trajectory's start is where the axis must be; beyond ``limits.start_window``
  (default 0.1 mm) the run is refused with one line naming both positions (``hil move --start``,
  a sweep's later runs, which must find the axis back at the sweep's start); within it the
  trajectory starts at the measured position, so that the first command is no step.

Never does a run command a jump from where the axis is to where the plan assumed it to be.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers.base import BackendFault, fault_kind
from drivers.control import controller_from_config
from hil.backends import open_backend
from hil.closed_loop import check_loop_stability
from hil.errors import HilError, RunStatus, StopKind, UserError
from hil.io.recorder import Recorder, RowBuffer
from hil.loop import ControlLoop, LoopResult, check_loop_cpu
from hil.profiles import AxisLimits, Trajectory, check_limits, check_sampled
from hil.scope.ring import ScopeRing
from hil.scope.ring import feed as feed_scope
from hil.simulate import simulate
from hil.supervisor import check_record, refuse_if_tripped

logger = logging.getLogger(__name__)

__all__ = ["RunRecord", "run_trajectory", "record_channels"]


def record_channels(rotary: bool, stale: bool = False) -> list[str]:
    """The channels of a run's record; ``stale`` (a backend whose answers can miss, a real axis's
    fieldbus or line): a last column, 1 where the row's feedback repeats the last answer."""
    return ["t", "x_cmd", "v_cmd", "x_motor", "x_table", "x_tip", "torque" if rotary else "command",
            "e_table", "e_tip"] + (["stale"] if stale else [])


@dataclass
class RunRecord:
    """A recorded run: channels (SI), how it ended, and where the file is."""
    channels: dict[str, np.ndarray]
    status: RunStatus = RunStatus.COMPLETE
    reason: str = ""
    path: Path | None = None
    loop: dict = field(default_factory=dict)
    start: float | None = None          # where the run started (m; on an axis: as measured)
    stop: StopKind = StopKind.COMPLETE  # how it ended: the command's exit code (hil.errors.StopKind)
    # the controlled stop commanded when the run ended early ({"how", "ok", "error"}); None: none was
    controlled_stop: dict | None = None

    def __getitem__(self, name):
        return self.channels[name]


def start_position(cfg, backend, fb) -> float:
    """The position a run starts from, of the measured ``fb``: the reading the position loop closes
    on (the drive's own, the motor's, where the backend closes both loops)."""
    if backend.closes == "both" or cfg.get("control.position_feedback", "table") == "motor":
        return float(fb.x_motor)
    return float(fb.x_table)


def plan_from_measured(cfg, traj: Trajectory, measured: float, start: str) -> Trajectory:
    """``traj`` moved to start at the ``measured`` position (see the module docstring: ``start`` is
    ``"follow"`` or ``"check"``), checked against the limits; raises UserError (one line, both
    positions) where a ``"check"`` start is beyond ``limits.start_window``."""
    if start not in ("follow", "check"):
        raise ValueError(f"start: follow or check, not {start!r}")
    window = float(cfg.get("limits.start_window", 1e-4))
    off = measured - traj.start
    if start == "check" and abs(off) > window:
        raise UserError(f"motion refused: the axis stands at {measured * 1e3:.3f} mm, the run was planned from "
                        f"{traj.start * 1e3:.3f} mm ({abs(off) * 1e3:.3f} mm apart, limits.start_window "
                        f"{window * 1e3:g} mm); move it there first (hil jog) or plan from where it is")
    moved = traj.shifted(off) if off else traj
    check_limits(moved, AxisLimits.from_config(cfg))
    return moved


def run_trajectory(cfg, traj: Trajectory, backend=None, out_file: str | Path | None = None, settle: float = 1.0,
                   supervisor=None, meta: dict | None = None, check: bool = True, start: str = "check",
                   scope: ScopeRing | None = None, realtime: bool = False,
                   samples: np.ndarray | None = None) -> RunRecord:
    """Check ``traj`` against the axis limits, run it (plus ``settle`` seconds standing at the end)
    and record every position tick.

    ``start``: on a backend that drives an axis, ``"follow"`` plans the run from where the axis
    stands, ``"check"`` (default) refuses it unless the axis stands at ``traj.start`` (within
    ``limits.start_window``); see the module docstring. A latched trip refuses the run.

    ``scope``: a :class:`~hil.scope.ring.ScopeRing` the live scope reads. Cycle by cycle, the loop
    writes every position tick into it. A dry run is computed at once by the compiled loop: its
    rows go into the ring after it, at real-time pace with ``realtime`` (the call then takes the
    run's duration), else all at once; the record is the same either way.

    ``samples``: ``traj`` sampled already on the position clock with ``settle`` (a caller that
    checked them keeps them: the trajectory is sampled once)."""
    if supervisor is None or not hasattr(supervisor, "arm"):
        refuse_if_tripped(cfg)           # a trip not reset refuses motion on every backend
    if check:
        check_limits(traj, AxisLimits.from_config(cfg))
        check_loop_stability(cfg)
    tp = cfg["control.position_period"]
    x_cmd = traj.sample(tp, settle)[1] if samples is None else np.asarray(samples, float)
    # the sequence as it will be sent, sample by sample, before the first setpoint (always)
    check_sampled(x_cmd, tp, AxisLimits.from_config(cfg))
    backend = backend if backend is not None else open_backend(cfg)
    rotary = cfg.rotary
    names = record_channels(rotary, stale=getattr(backend, "misses_answers", False))
    info = {"sample_period": f"{tp:g} s", "config": cfg.source, "backend": backend.name}
    info.update(meta or {})
    model = backend.dry_run_model()
    if model is not None:
        check_loop_cpu(cfg.get("runtime.loop_cpu"))      # the same line as on a backend, though nothing is pinned
        backend.start_at(x_cmd[0])
        # a dry run: the whole command through the compiled closed loop, as fast as the computer can
        sim = simulate(*model, x_cmd)
        ch = sim.channels()
        chans = {n: ch[n] for n in names}
        # the supervisor's rules on the record: the run ends where the axis would have tripped
        status, reason, kind = RunStatus.COMPLETE, "", StopKind.COMPLETE
        trip = check_record(cfg, chans, v_motor=sim.v[:, 0], period=tp)
        if trip is not None:
            k, reason, kind = trip
            status = RunStatus.TRIPPED
            chans = {n: v[:k + 1] for n, v in chans.items()}
        if out_file is not None:
            with Recorder(out_file, names, info) as rec:
                rec.extend(chans)
                rec.close(status, reason)
        if scope is not None:
            feed_scope(scope, chans, speed=sim.v[:len(chans["t"]), 0], status=status, reason=reason,
                       pace=1.0 if realtime else None)
        return RunRecord(chans, status, reason, Path(out_file) if out_file else None, start=float(x_cmd[0]),
                         stop=kind)
    # cycle by cycle, on the backend's clock
    ctrl = controller_from_config(cfg, getattr(backend, "plant", None) or _plant_scales(cfg))
    # the run's rows, preallocated: the cycle stores each into memory, a thread drains them to the file
    rec = Recorder(out_file, names, info, rows=x_cmd.size) if out_file is not None else RowBuffer(names, x_cmd.size)
    backend.start_at(x_cmd[0])         # a simulated stand-in starts where the run does
    if supervisor is None:
        from hil.supervisor import Supervisor
        supervisor = Supervisor(cfg, real_time=not backend.simulated)
        supervisor.arm()           # refuses motion while an earlier trip is not reset
    loop = ControlLoop(backend, ctrl, recorder=rec, supervisor=supervisor, rotary=rotary,
                       priority=cfg.get("runtime.priority", 0), cpu_latency=cfg.get("runtime.cpu_latency", 0.0),
                       scope=scope, loop_cpu=cfg.get("runtime.loop_cpu"))
    started = {"planned_m": float(traj.start), "mode": start}
    try:
        with backend:                    # opened here; shut down (disabled, closed) however the run ends
            fb = backend.read_position()
            if fb is not None:           # an axis: the run starts where it stands, or not at all
                started["measured_m"] = measured = start_position(cfg, backend, fb)
                moved = plan_from_measured(cfg, traj, measured, start)
                if moved is not traj:    # the same samples, every one moved by the offset
                    x_cmd = x_cmd + (moved.start - traj.start)
            backend.enable()
            result: LoopResult = loop.run(x_cmd)
    except BackendFault as exc:          # open, read_position or enable failed: nothing moved
        result = LoopResult(0, RunStatus.FAULT, exc.reason, stop=fault_kind(exc.kind, StopKind.LINK))
    except HilError as exc:              # refused before motion (the start, the limits): one line, exit 2
        rec.close(RunStatus.REFUSED, str(exc), {"start": started})
        raise
    except BaseException as exc:         # e.g. an interface not installed, Ctrl-C: the record says why
        rec.close(RunStatus.ABORTED, "interrupted (Ctrl-C)" if isinstance(exc, KeyboardInterrupt) else
                  f"{type(exc).__name__}: {exc}")
        raise
    logger.info("run on %s: %s%s", getattr(backend, "name", "sim"), result.status,
                f" ({result.reason})" if result.reason else "")
    rec.close(result.status, result.reason, {"loop": result.clock, "supervisor": getattr(supervisor, "record", {}),
                                             "start": started})
    # from memory (the file holds the same rows as text); a run stopped before it moved (e.g. the
    # drive did not answer at start-up) has fewer than two rows: none is a record
    chans = rec.channels() if rec.rows >= 2 else {n: np.zeros(0) for n in names}
    return RunRecord(chans, result.status, result.reason, Path(out_file) if out_file else None, result.clock,
                     start=float(x_cmd[0]), stop=result.stop, controlled_stop=result.controlled_stop)


def _plant_scales(cfg):
    """Speed and force scales for the controller when the backend has no model of its own."""
    from hil.plant_config import plant_from_config
    return plant_from_config(cfg)
