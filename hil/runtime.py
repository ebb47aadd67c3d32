"""Run a trajectory on a backend and record it: what ``hil move`` and ``hil sweep`` call.

On the embedded simulated plant the whole command goes through the compiled loop at once (a dry
run); on any other backend it goes through :class:`hil.loop.ControlLoop`, cycle by cycle, on the
real-time clock, with the supervisor watching. Either way the record is written in the
measurement format as it goes.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers import open_backend
from drivers.base import BackendFault
from drivers.sim import SimulatedPlant
from hil.closed_loop import check_loop_stability
from hil.control import controller_from_config
from hil.io.measurement import read as read_measurement
from hil.io.recorder import Recorder
from hil.loop import ControlLoop, LoopResult
from hil.profiles import AxisLimits, Trajectory, check_limits, check_sampled
from hil.simulate import simulate
from hil.supervisor import check_record

__all__ = ["RunRecord", "run_trajectory", "record_channels"]


def record_channels(rotary: bool) -> list[str]:
    return ["t", "x_cmd", "v_cmd", "x_motor", "x_table", "x_tip", "torque" if rotary else "command",
            "e_table", "e_tip"]


@dataclass
class RunRecord:
    """A recorded run: channels (SI), how it ended, and where the file is."""
    channels: dict[str, np.ndarray]
    status: str = "complete"
    reason: str = ""
    path: Path | None = None
    loop: dict = field(default_factory=dict)

    def __getitem__(self, name):
        return self.channels[name]


def run_trajectory(cfg, traj: Trajectory, backend=None, out_file: str | Path | None = None, settle: float = 1.0,
                   supervisor=None, meta: dict | None = None, check: bool = True) -> RunRecord:
    """Check ``traj`` against the axis limits, run it (plus ``settle`` seconds standing at the end)
    and record every position tick."""
    if check:
        check_limits(traj, AxisLimits.from_config(cfg))
        check_loop_stability(cfg)
    tp = cfg["control.position_period"]
    t, x_cmd = traj.sample(tp, settle)
    # the sequence as it will be sent, sample by sample, before the first setpoint (always)
    check_sampled(x_cmd, tp, AxisLimits.from_config(cfg))
    backend = backend if backend is not None else open_backend(cfg)
    rotary = cfg.rotary
    names = record_channels(rotary)
    info = {"sample_period": f"{tp:g} s", "config": cfg.source, "backend": backend.name}
    info.update(meta or {})
    if isinstance(backend, SimulatedPlant) and backend.closes == "none":
        backend.home_at(x_cmd[0])
        # a dry run: the whole command through the compiled closed loop, as fast as the computer can
        sim = simulate(backend.plant, backend.ctrl, x_cmd)
        ch = sim.channels()
        chans = {n: ch[n] for n in names}
        # the supervisor's rules on the record: the run ends where the axis would have tripped
        status, reason = "complete", ""
        trip = check_record(cfg, chans, v_motor=sim.v[:, 0], period=tp)
        if trip is not None:
            k, reason = trip
            status = "tripped"
            chans = {n: v[:k + 1] for n, v in chans.items()}
        if out_file is not None:
            rec = Recorder(out_file, names, info)
            rec.extend(chans)
            rec.close(status, reason)
        return RunRecord(chans, status, reason, Path(out_file) if out_file else None)
    # cycle by cycle, on the backend's clock
    ctrl = controller_from_config(cfg, getattr(backend, "plant", None) or _plant_scales(cfg))
    rec = Recorder(out_file, names, info) if out_file is not None else _MemoryRecorder(names)
    if isinstance(backend, SimulatedPlant):
        backend.home_at(x_cmd[0])
    if supervisor is None:
        from hil.supervisor import Supervisor
        supervisor = Supervisor(cfg, real_time=not backend.simulated)
        supervisor.arm()           # refuses motion while an earlier trip is not reset
    loop = ControlLoop(backend, ctrl, recorder=rec, supervisor=supervisor, rotary=rotary,
                       priority=cfg.get("runtime.priority", 0))
    try:
        with backend:                    # opened here; shut down (disabled, closed) however the run ends
            backend.enable()
            result: LoopResult = loop.run(x_cmd)
    except BackendFault as exc:          # open or enable failed: nothing moved
        result = LoopResult(0, "fault", exc.reason)
    except BaseException as exc:         # e.g. an interface not installed, Ctrl-C: the record says why
        rec.close("aborted", "interrupted (Ctrl-C)" if isinstance(exc, KeyboardInterrupt) else
                  f"{type(exc).__name__}: {exc}")
        raise
    rec.close(result.status, result.reason, {"loop": result.clock, "supervisor": getattr(supervisor, "record", {})})
    if isinstance(rec, _MemoryRecorder):
        chans = rec.channels()
    elif rec.rows >= 2:
        chans = read_measurement(out_file).channels
    else:                  # stopped before it moved (e.g. the drive did not answer at start-up)
        chans = {n: np.zeros(0) for n in names}
    return RunRecord(chans, result.status, result.reason, Path(out_file) if out_file else None, result.clock)


def _plant_scales(cfg):
    """Speed and force scales for the controller when the backend has no model of its own."""
    from hil.plant_config import plant_from_config
    return plant_from_config(cfg)


class _MemoryRecorder:
    """The recorder's interface, kept in memory (runs that write no file)."""

    def __init__(self, names):
        self.names = names
        self.rows = []

    def append(self, **values):
        self.rows.append([values[n] for n in self.names])

    def close(self, *args, **kw):
        pass

    def channels(self):
        arr = np.array(self.rows) if self.rows else np.zeros((0, len(self.names)))
        return {n: arr[:, i] for i, n in enumerate(self.names)}
