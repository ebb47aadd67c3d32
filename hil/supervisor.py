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
import logging
import math
import os
import time
from collections import deque
from datetime import datetime, timezone
from pathlib import Path

from hil.config import Field, register_section
from hil.errors import SupervisorTripped, UserError

logger = logging.getLogger(__name__)

__all__ = ["Supervisor", "SupervisorTripped", "SECTION", "state_dir", "latch_path", "refuse_if_tripped",
           "check_record", "is_latch", "remove_latch", "trip_hint"]

APP = "compliant-axis-hil"

# the keys every latch file written by Supervisor.trip holds, and the largest one it writes
# (a history of at most supervisor.history cycles of about ten numbers)
LATCH_KEYS = ("reason", "cycle", "t")
LATCH_MAX_BYTES = 64 * 1024 * 1024


def state_dir() -> Path:
    """The user's state directory of this tool: ``$HIL_STATE_DIR`` (tests point it at a temporary
    folder), else ``$XDG_STATE_HOME/compliant-axis-hil``, else ``~/.local/state/compliant-axis-hil``."""
    d = os.environ.get("HIL_STATE_DIR")
    if d:
        return Path(d)
    base = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return Path(base) / APP


# the units of a length in a trip's reason, largest first (no pint in the real-time path)
_LENGTH_UNITS = (("m", 1.0), ("mm", 1e-3), ("um", 1e-6), ("nm", 1e-9))


def exceeds(value: float, limit: float) -> str:
    """``"1.6 um > 1 um"``: a length past its limit, both in the limit's unit, with as many digits
    as tell them apart (1.6 um past a 1 um window read ``0.002 mm > 0.001 mm``)."""
    name, scale = next(((n, s) for n, s in _LENGTH_UNITS if abs(limit) >= s), _LENGTH_UNITS[-1])
    a, b = value / scale, limit / scale
    for digits in range(3, 12):
        va, vb = f"{a:.{digits}g}", f"{b:.{digits}g}"
        if va != vb:
            break
    return f"{va} {name} > {vb} {name}"


def latch_path(cfg=None) -> Path:
    """The latch file: ``supervisor.latch_file`` where the configuration gives one, else
    ``latch.json`` in :func:`state_dir`."""
    lf = cfg.get("supervisor.latch_file", "") if cfg is not None else ""
    return Path(lf).expanduser() if lf else state_dir() / "latch.json"


def trip_hint(cfg) -> str:
    """What to tell after a run that did not complete: where its trip is latched, or that nothing
    is (a dry run on the simulated plant trips on its record, hil.runtime, and latches nothing;
    neither does an interrupted run)."""
    if latch_path(cfg).exists():
        return "'hil status' shows the trip, 'hil reset' clears it"
    return "nothing is latched ('hil status' stays clear): on an axis this run would have stopped here"


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
                                      maximum=1_000_000,
                                      default=10, positive=True),
    "supervisor.history": Field("int", "cycles kept for the trip record", default=50, positive=True,
                                maximum=1_000_000),
    "supervisor.unsupervised": Field("bool", "true: let a real backend (canopen, serial) run without the "
                                     "supervisor's windows (limits.following_error_table); default false: refused "
                                     "before anything connects", default=False),
    "supervisor.latch_file": Field("str", "file that keeps a trip across processes until 'hil reset'; default "
                                   "latch.json in $HIL_STATE_DIR, $XDG_STATE_HOME/compliant-axis-hil or "
                                   "~/.local/state/compliant-axis-hil", default=""),
}
register_section("supervisor", lambda key: SECTION.get(key), lambda: list(SECTION))


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
                                    f"then 'hil reset {self._config_options()}' clears it (latch {self.latch_file})")
        self.start()

    def _config_options(self) -> str:
        """The --config and --set options of the run refused, for the hint's ``hil reset``."""
        line = getattr(self.cfg, "command_line", None)
        return line() if callable(line) else f"--config {self.cfg.source}"

    def reset(self) -> None:
        if self.latch_file is not None:
            remove_latch(self.latch_file)        # refuses (before clearing) a file that is no latch
        self.tripped, self.reason, self.trip_cycle, self.trip_time, self.record = False, "", None, None, {}
        self.tripped_at = ""

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
            # info, not warning: the command reports the trip in its own one line
            logger.info("supervisor tripped at t = %.4f s: %s", t, reason)
        return reason

    def _write_latch(self) -> None:
        """The trip to the latch file (not real-time: once, in the cycle of the trip; a file that
        cannot be written does not stop the stop: the trip is then latched in this process only)."""
        try:
            self.latch_file.parent.mkdir(parents=True, exist_ok=True)
            # at once, never through a link planted at its name (hil.io.safe_write)
            from hil.io.safe_write import write_atomic
            write_atomic(self.latch_file, json.dumps(self.record, indent=1, default=float))
        except (OSError, UserError) as exc:
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

    def check_setpoint(self, t: float, x_next: float) -> str | None:
        """Check the position setpoint about to go out (the command of the next tick, which a
        position-mode drive receives this cycle): the travel, and the commanded speed,
        acceleration and jerk it makes with the commands before it. A trip here stops the axis
        before the setpoint is sent (hil.loop calls it after :meth:`check`, before writing)."""
        if self.tripped:
            return self.reason
        r = _command_rule(self.cfg, 1.0 + self.tol, self.period, list(self._cmd) + [x_next], "command")
        return self.trip(t, r) if r else None

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
        r = _command_rule(cfg, tol, T, c, None)
        if r:
            return r
        if abs(fb.v_motor) > 1.5 * cfg["limits.speed"]:
            return f"speed limit: measured {abs(fb.v_motor):.4g} m/s > 1.5 x {cfg['limits.speed']:g} m/s"
        tq = cfg.get("limits.torque")
        if tq and abs(fb.output) > tq * tol:
            return f"torque limit: {abs(fb.output):.4g} > {tq:g}"
        w = cfg.get("limits.following_error_table")
        if w and abs(x_cmd - fb.x_table) > w:
            return f"following error at the table: {exceeds(abs(x_cmd - fb.x_table), w)}"
        w = cfg.get("limits.following_error_tip")
        if w and not math.isnan(fb.x_tip) and abs(x_cmd - fb.x_tip) > w:
            return f"following error at the tool tip: {exceeds(abs(x_cmd - fb.x_tip), w)}"
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


def is_latch(path: str | Path) -> bool:
    """Whether ``path`` is a latch file as :meth:`Supervisor.trip` writes it: a regular file (not
    a symbolic link), UTF-8 JSON, an object with exactly the trip record's keys."""
    p = Path(path)
    try:
        if p.is_symlink() or not p.is_file() or p.stat().st_size > LATCH_MAX_BYTES:
            return False
        info = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(info, dict) and set(LATCH_KEYS) <= set(info) and isinstance(info["reason"], str)


def remove_latch(path: str | Path) -> bool:
    """Delete the latch file at ``path`` if it is one (:func:`is_latch`); False where there is
    none. Anything else at that name (a configuration, a link, a folder) is left alone and refused
    with a ConfigError: ``supervisor.latch_file`` names no latch."""
    from hil.errors import ConfigError
    p = Path(path)
    if not p.exists() and not p.is_symlink():
        return False
    if not is_latch(p):
        raise ConfigError(f"supervisor.latch_file {p}: not a latch file written by the supervisor (a link, a "
                          f"folder or another file); not deleted")
    p.unlink()
    return True


def _command_rule(cfg, tol: float, T: float, c, travel: str | None) -> str | None:
    """The rules on the commanded positions ``c`` (oldest first, the newest last): the travel of
    the newest (where ``travel`` names it), and the speed, acceleration and jerk of the newest
    first, second and third differences."""
    if travel is not None:
        lo, hi = cfg["limits.travel_min"], cfg["limits.travel_max"]
        if not lo <= c[-1] <= hi:
            return f"travel limit: {travel} at {c[-1] * 1e3:.3f} mm outside [{lo * 1e3:g}, {hi * 1e3:g}] mm"
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
    return None


def check_record(cfg, ch: dict, v_motor=None, period: float | None = None) -> tuple[int, str] | None:
    """The supervisor's rules on a whole record, vectorized: the first position tick at which
    :class:`Supervisor` would trip, run cycle by cycle on the same readings, and its reason; None
    where it would not trip. What the compiled dry run calls on its record (hil.runtime), so
    that a dry run trips where the axis would.

    ``ch``: the record's channels, one row per position tick (``x_cmd``, ``x_table``,
    ``x_motor``, ``x_tip``, ``torque`` or ``command``); ``v_motor``: the motor speed (m/s) at
    the same ticks, where known. Per tick the order is :meth:`Supervisor.check`'s and then
    :meth:`Supervisor.check_setpoint`'s (the next command); the real-time watchdog does not apply
    to a simulated clock. The messages are the supervisor's."""
    import numpy as np  # here: the command line imports this module without numpy
    T = float(period or cfg["control.position_period"])
    tol = 1.0 + float(cfg.get("supervisor.tolerance", 0.05))
    x = np.asarray(ch["x_cmd"], float)
    K = x.size
    if K == 0:
        return None
    xt, xm = np.asarray(ch["x_table"], float), np.asarray(ch["x_motor"], float)
    tip = np.asarray(ch.get("x_tip", np.full(K, np.nan)), float)
    out = np.asarray(ch["torque"] if "torque" in ch else ch.get("command", np.zeros(K)), float)
    lo, hi = cfg["limits.travel_min"], cfg["limits.travel_max"]
    nothing = np.zeros(K, bool)

    def kin(c, ahead):
        """speed, acceleration, jerk rules of the differences ending at c[k + ahead] (ticks k)"""
        d1 = np.full(K, 0.0)
        d2 = np.full(K, 0.0)
        d3 = np.full(K, 0.0)
        idx = np.arange(K) + ahead              # the newest command of tick k
        ok = idx < c.size
        i = idx[ok]
        for arr, n in ((d1, 1), (d2, 2), (d3, 3)):
            m = i >= n
            coef = {1: (1, -1), 2: (1, -2, 1), 3: (1, -3, 3, -1)}[n]
            v = np.zeros(i.size)
            for j, a in enumerate(coef):
                v[m] += a * c[i[m] - j]
            arr[np.flatnonzero(ok)[m]] = np.abs(v[m])
        return [(d1 / T > cfg["limits.speed"] * tol + 1e-9, lambda k: f"speed limit: commanded {d1[k] / T:.4g} m/s "
                 f"> {cfg['limits.speed']:g} m/s"),
                (d2 / T ** 2 > cfg["limits.acceleration"] * tol + 1e-6, lambda k: f"acceleration limit: commanded "
                 f"{d2[k] / T ** 2:.4g} m/s^2 > {cfg['limits.acceleration']:g} m/s^2"),
                (d3 / T ** 3 > cfg["limits.jerk"] * tol + 1e-3, lambda k: f"jerk limit: commanded {d3[k] / T ** 3:.4g} "
                 f"m/s^3 > {cfg['limits.jerk']:g} m/s^3")]

    def travel(v, name):
        return (~((lo <= v) & (v <= hi)), lambda k: f"travel limit: {name} at {v[k] * 1e3:.3f} mm outside "
                f"[{lo * 1e3:g}, {hi * 1e3:g}] mm")

    rules = [travel(x, "command"), travel(xt, "table"), travel(xm, "motor")]
    rules += kin(x, 0)
    if v_motor is not None:
        vm = np.abs(np.asarray(v_motor, float))
        rules.append((vm > 1.5 * cfg["limits.speed"], lambda k: f"speed limit: measured {vm[k]:.4g} m/s > 1.5 x "
                      f"{cfg['limits.speed']:g} m/s"))
    tq = cfg.get("limits.torque")
    if tq:
        rules.append((np.abs(out) > tq * tol, lambda k: f"torque limit: {abs(out[k]):.4g} > {tq:g}"))
    w = cfg.get("limits.following_error_table")
    if w:
        et = np.abs(x - xt)
        rules.append((et > w, lambda k: f"following error at the table: {exceeds(et[k], w)}"))
    w2 = cfg.get("limits.following_error_tip")
    if w2:
        ep = np.abs(x - tip)
        rules.append((~np.isnan(tip) & (ep > w2), lambda k: f"following error at the tool tip: "
                      f"{exceeds(ep[k], w2)}"))
    # frozen feedback: readings unchanged (from the tick before) while the command moved
    frozen_n = int(cfg.get("supervisor.frozen_cycles", 10))
    same = nothing.copy()
    if K > 1:
        moving = np.abs(np.diff(x)) / T > 1e-3
        same[1:] = (xt[1:] == xt[:-1]) & (xm[1:] == xm[:-1]) & moving
    run = np.zeros(K, int)
    if same.any():
        # length of the run of unchanged readings ending at each tick
        c = np.cumsum(same)
        reset = np.maximum.accumulate(np.where(~same, c, 0))
        run = c - reset
    rules.append((run >= frozen_n, lambda k: f"position feedback frozen for {run[k]} cycles while commanded to move"))
    # then the setpoint about to go out: the command of the next tick (held after the last)
    nxt = np.append(x, x[-1])
    tr_next = ~((lo <= nxt[1:]) & (nxt[1:] <= hi))
    rules.append((tr_next, lambda k: f"travel limit: command at {nxt[k + 1] * 1e3:.3f} mm outside "
                  f"[{lo * 1e3:g}, {hi * 1e3:g}] mm"))
    rules += kin(nxt, 1)
    first = K
    for mask, _ in rules:
        hit = np.flatnonzero(mask)
        if hit.size and hit[0] < first:
            first = int(hit[0])
    if first == K:
        return None
    for mask, msg in rules:            # the first rule in the supervisor's order at that tick
        if mask[first]:
            return first, msg(first)
    return None
