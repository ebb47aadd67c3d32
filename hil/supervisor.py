"""The safety supervisor: watches every cycle of every backend and trips on the first violation.

Checks, in order, each position tick: a drive fault or lost communication (``Feedback.fault``),
software travel limits (command and measurement), commanded speed / acceleration / jerk (from
the command's differences), measured speed, torque, following-error windows at the table and
(where measured) the tool tip, a frozen position feedback, and a loop-overrun watchdog (real-time
clocks). A trip returns the reason; hil.loop.ControlLoop commands the controlled stop
(``backend.quick_stop()``) in the same cycle. The supervisor records the reason and the last
cycles, and refuses motion (:meth:`Supervisor.arm`) until :meth:`reset`, across processes: the
trip is written to a latch file, by default ``latch.json`` in the user's state directory
(:func:`state_dir`: ``$HIL_STATE_DIR``, else ``$XDG_STATE_HOME/compliant-axis-hil``, else
``~/.local/state/compliant-axis-hil``), or ``supervisor.latch_file`` where given. Every motion
command on every backend checks it first (:func:`refuse_if_tripped`); ``hil status`` shows it,
``hil reset`` clears it.

This monitoring is no substitute for the drive's certified safety functions (STO, SS1).
"""
from __future__ import annotations

import json
import math
import os
import time
from collections import deque
from datetime import datetime, timezone
from pathlib import Path

from hil.config import Field, register_section
from hil.errors import SupervisorTripped

__all__ = ["Supervisor", "SupervisorTripped", "SECTION", "state_dir", "latch_path", "refuse_if_tripped"]

APP = "compliant-axis-hil"


def state_dir() -> Path:
    """The user's state directory of this tool: ``$HIL_STATE_DIR`` (tests point it at a temporary
    folder), else ``$XDG_STATE_HOME/compliant-axis-hil``, else ``~/.local/state/compliant-axis-hil``."""
    d = os.environ.get("HIL_STATE_DIR")
    if d:
        return Path(d)
    base = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return Path(base) / APP


def latch_path(cfg=None) -> Path:
    """The latch file: ``supervisor.latch_file`` where the configuration gives one, else
    ``latch.json`` in :func:`state_dir`."""
    lf = cfg.get("supervisor.latch_file", "") if cfg is not None else ""
    return Path(lf).expanduser() if lf else state_dir() / "latch.json"


def refuse_if_tripped(cfg) -> None:
    """Raise :class:`SupervisorTripped` (one line: the trip, its time, how to clear it) while a trip
    is latched; every motion command calls it before anything moves, on every backend."""
    Supervisor(cfg).arm()

SECTION = {
    "supervisor.stop": Field("str", "controlled stop on a trip: quick_stop (CiA 402 quick stop) or disable",
                             default="quick_stop", choices=("quick_stop", "disable")),
    "supervisor.tolerance": Field("dimensionless", "relative margin on the speed/acceleration/jerk/torque limits",
                                  default=0.05, nonnegative=True),
    "supervisor.overrun_cycles": Field("dimensionless", "watchdog: a cycle that starts this many periods late "
                                       "trips (real-time clock only)", default=2.0, positive=True),
    "supervisor.frozen_cycles": Field("int", "position reading unchanged this many ticks while commanded to move",
                                      default=10, positive=True),
    "supervisor.history": Field("int", "cycles kept for the trip record", default=50, positive=True),
    "supervisor.latch_file": Field("str", "file that keeps a trip across processes until 'hil reset'; default "
                                   "latch.json in $HIL_STATE_DIR, $XDG_STATE_HOME/compliant-axis-hil or "
                                   "~/.local/state/compliant-axis-hil", default=""),
}
register_section("supervisor", lambda key: SECTION.get(key))


class Supervisor:
    def __init__(self, cfg, period: float | None = None, real_time: bool = False, latch_file: str | None = None):
        self.cfg = cfg
        self.period = period or cfg["control.position_period"]
        self.real_time = real_time
        self.tol = float(cfg.get("supervisor.tolerance", 0.05))
        self.stop = cfg.get("supervisor.stop", "quick_stop")
        self.overrun = float(cfg.get("supervisor.overrun_cycles", 2.0))
        self.frozen_n = int(cfg.get("supervisor.frozen_cycles", 10))
        self.history = deque(maxlen=int(cfg.get("supervisor.history", 50)))
        self.latch_file = Path(latch_file) if latch_file else latch_path(cfg)
        self.tripped = False
        self.reason = ""
        self.tripped_at = ""          # wall-clock time of the trip (UTC, ISO 8601)
        self.trip_cycle: int | None = None
        self.trip_time: float | None = None
        self.record: dict = {}
        self._load_latch()
        self.start()

    # -- state -------------------------------------------------------------------------------------
    def start(self) -> None:
        """A new run: the cycle count and the command history start afresh."""
        self.k = 0
        self._cmd = deque(maxlen=4)
        self._last_x = None
        self._same = 0
        self._wall = None

    def arm(self) -> None:
        """Refuse motion while tripped."""
        self._load_latch()
        if self.tripped:
            when = f" at {self.tripped_at}" if self.tripped_at else ""
            raise SupervisorTripped(f"motion refused: the supervisor tripped{when} ({self.reason}); find the cause, "
                                    f"then 'hil reset --config {self.cfg.source}' clears it (latch {self.latch_file})")
        self.start()

    def reset(self) -> None:
        self.tripped, self.reason, self.trip_cycle, self.trip_time, self.record = False, "", None, None, {}
        self.tripped_at = ""
        if self.latch_file is not None and self.latch_file.exists():
            self.latch_file.unlink()

    def _load_latch(self) -> None:
        if self.latch_file is not None and self.latch_file.exists():
            try:
                info = json.loads(self.latch_file.read_text())
                self.tripped, self.reason = True, info.get("reason", "tripped")
                self.tripped_at = info.get("time", "")
            except (OSError, ValueError, AttributeError):
                self.tripped, self.reason = True, "unreadable latch file"

    def trip(self, t: float, reason: str, fb=None) -> str:
        if not self.tripped:
            self.tripped, self.reason, self.trip_cycle, self.trip_time = True, reason, max(self.k - 1, 0), t
            self.tripped_at = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
            self.record = {"reason": reason, "time": self.tripped_at, "config": str(self.cfg.source),
                           "cycle": max(self.k - 1, 0), "t": t, "stop": self.stop, "last_cycles": list(self.history)}
            self._write_latch()
        return reason

    def _write_latch(self) -> None:
        """The trip to the latch file (not real-time: once, in the cycle of the trip; a file that
        cannot be written does not stop the stop: the trip is then latched in this process only)."""
        try:
            self.latch_file.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.latch_file.with_suffix(".tmp")
            tmp.write_text(json.dumps(self.record, indent=1, default=float))
            os.replace(tmp, self.latch_file)
        except OSError as exc:
            self.record["latch_error"] = str(exc)

    # -- the check, every position tick --------------------------------------------------------------------
    def check(self, t: float, fb, x_cmd: float) -> str | None:
        k = self.k
        self.k += 1
        self.history.append({"k": k, "t": t, "x_cmd": x_cmd, "x_motor": fb.x_motor, "x_table": fb.x_table,
                             "x_tip": fb.x_tip, "v_motor": fb.v_motor, "output": fb.output, "fault": fb.fault})
        if self.tripped:
            return self.reason
        r = self._check(t, fb, x_cmd)
        return self.trip(t, r, fb) if r else None

    def _check(self, t, fb, x_cmd) -> str | None:
        cfg, tol, T = self.cfg, 1.0 + self.tol, self.period
        if fb.fault:
            return fb.fault
        if self.real_time:
            now = time.perf_counter()
            if self._wall is not None and now - self._wall > (1.0 + self.overrun) * T:
                late = now - self._wall - T
                self._wall = now
                return f"loop overrun: cycle {late * 1e3:.2f} ms late (watchdog {self.overrun:g} periods)"
            self._wall = now
        lo, hi = cfg["limits.travel_min"], cfg["limits.travel_max"]
        for name, x in (("command", x_cmd), ("table", fb.x_table), ("motor", fb.x_motor)):
            if not lo <= x <= hi:
                return f"travel limit: {name} at {x * 1e3:.3f} mm outside [{lo * 1e3:g}, {hi * 1e3:g}] mm"
        c = self._cmd
        c.append(x_cmd)
        if len(c) >= 2 and abs(c[-1] - c[-2]) / T > cfg["limits.speed"] * tol + 1e-9:
            return f"speed limit: commanded {abs(c[-1] - c[-2]) / T:.4g} m/s > {cfg['limits.speed']:g} m/s"
        if len(c) >= 3:
            a = abs(c[-1] - 2 * c[-2] + c[-3]) / T ** 2
            if a > cfg["limits.acceleration"] * tol + 1e-6:
                return f"acceleration limit: commanded {a:.4g} m/s^2 > {cfg['limits.acceleration']:g} m/s^2"
        if len(c) >= 4:
            j = abs(c[-1] - 3 * c[-2] + 3 * c[-3] - c[-4]) / T ** 3
            if j > cfg["limits.jerk"] * tol + 1e-3:
                return f"jerk limit: commanded {j:.4g} m/s^3 > {cfg['limits.jerk']:g} m/s^3"
        if abs(fb.v_motor) > 1.5 * cfg["limits.speed"]:
            return f"speed limit: measured {abs(fb.v_motor):.4g} m/s > 1.5 x {cfg['limits.speed']:g} m/s"
        tq = cfg.get("limits.torque")
        if tq and abs(fb.output) > tq * tol:
            return f"torque limit: {abs(fb.output):.4g} > {tq:g}"
        w = cfg.get("limits.following_error_table")
        if w and abs(x_cmd - fb.x_table) > w:
            return f"following error at the table: {abs(x_cmd - fb.x_table) * 1e3:.3f} mm > {w * 1e3:g} mm"
        w = cfg.get("limits.following_error_tip")
        if w and not math.isnan(fb.x_tip) and abs(x_cmd - fb.x_tip) > w:
            return f"following error at the tool tip: {abs(x_cmd - fb.x_tip) * 1e3:.3f} mm > {w * 1e3:g} mm"
        # frozen feedback: the reading does not change while the command moves
        moving = len(c) >= 2 and abs(c[-1] - c[-2]) / T > 1e-3
        if self._last_x is not None and fb.x_table == self._last_x[0] and fb.x_motor == self._last_x[1] and moving:
            self._same += 1
            if self._same >= self.frozen_n:
                return f"position feedback frozen for {self._same} cycles while commanded to move"
        else:
            self._same = 0
        self._last_x = (fb.x_table, fb.x_motor)
        return None
