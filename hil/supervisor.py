"""The safety supervisor: watches every cycle of every backend and trips on the first violation.

Checks, in order, each position tick: a drive fault or lost communication (``Feedback.fault``),
software travel limits (command and measurement), commanded speed / acceleration / jerk (from
the command's differences), measured speed, torque, following-error windows at the table and
(where measured) the tool tip, a frozen position feedback, and a loop-overrun watchdog (real-time
clocks). The rules are one ordered table, :data:`RULES` (the quantity each looks at, its test,
its reason, the kind of stop it makes, :class:`hil.errors.StopKind`): :class:`Supervisor` runs it
per cycle on numbers, :func:`check_record` vectorised on a record's arrays (the dry run), so the
two trip at the same tick with the same reason. A trip returns the reason; hil.loop.ControlLoop commands the controlled stop
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
from typing import NamedTuple

from hil.config import SUPERVISOR_SECTION
from hil.errors import StopKind, SupervisorTripped, UserError, fault_kind

logger = logging.getLogger(__name__)

__all__ = ["Supervisor", "SupervisorTripped", "SECTION", "state_dir", "latch_path", "refuse_if_tripped",
           "check_record", "is_latch", "remove_latch", "trip_hint", "RULES", "Rule", "Limits", "Trip"]

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


SECTION = SUPERVISOR_SECTION        # the [supervisor] keys (their schema is hil.config's)


class Trip(NamedTuple):
    """Where and how a record trips (:func:`check_record`): the position tick, the reason, the kind."""
    cycle: int
    reason: str
    kind: StopKind


class Limits:
    """The supervisor's limits and thresholds, read from the configuration once (never per cycle).

    ``period``: the position period T (s); ``tol``: 1 + supervisor.tolerance; ``lo``, ``hi``: the
    travel; ``speed``, ``acceleration``, ``jerk``, ``torque`` and the following-error windows
    ``fe_table``, ``fe_tip`` as configured (a torque or window that is not set turns its rule off);
    ``frozen_n``, ``overrun``: supervisor.frozen_cycles and supervisor.overrun_cycles."""
    __slots__ = ("period", "tol", "lo", "hi", "speed", "acceleration", "jerk", "torque", "fe_table", "fe_tip",
                 "frozen_n", "overrun", "speed_max", "acceleration_max", "jerk_max", "overrun_elapsed")

    def __init__(self, cfg, period: float | None = None):
        self.period = float(period or cfg["control.position_period"])
        self.tol = 1.0 + float(cfg.get("supervisor.tolerance", 0.05))
        self.lo, self.hi = cfg["limits.travel_min"], cfg["limits.travel_max"]
        self.speed, self.acceleration, self.jerk = cfg["limits.speed"], cfg["limits.acceleration"], cfg["limits.jerk"]
        self.torque = cfg.get("limits.torque")
        self.fe_table = cfg.get("limits.following_error_table")
        self.fe_tip = cfg.get("limits.following_error_tip")
        self.frozen_n = int(cfg.get("supervisor.frozen_cycles", 10))
        self.overrun = float(cfg.get("supervisor.overrun_cycles", 2.0))
        # the commanded kinematics' thresholds, with the margins that keep rounding from tripping
        self.speed_max = self.speed * self.tol + 1e-9
        self.acceleration_max = self.acceleration * self.tol + 1e-6
        self.jerk_max = self.jerk * self.tol + 1e-3
        self.overrun_elapsed = (1.0 + self.overrun) * self.period


# The quantities the rules look at, one slot each: per cycle a number of the tick (Supervisor),
# over a record an array with one per tick (check_record). *_cmd: the tick's command and its
# speed, acceleration and jerk (absolute differences over T^n; NaN where the history is too
# short); *_next: the same of the setpoint about to go out (the next tick's command); v_motor,
# output, e_table, e_tip: absolute values; frozen: ticks the readings stood still while the
# command moved; elapsed: wall time since the last tick (real-time clocks only, else NaN).
QUANTITIES = ("fault", "elapsed", "x_cmd", "x_table", "x_motor", "v_cmd", "a_cmd", "j_cmd", "v_motor", "output",
              "e_table", "e_tip", "frozen", "x_next", "v_next", "a_next", "j_next")
(Q_FAULT, Q_ELAPSED, Q_X_CMD, Q_X_TABLE, Q_X_MOTOR, Q_V_CMD, Q_A_CMD, Q_J_CMD, Q_V_MOTOR, Q_OUTPUT, Q_E_TABLE,
 Q_E_TIP, Q_FROZEN, Q_X_NEXT, Q_V_NEXT, Q_A_NEXT, Q_J_NEXT) = range(len(QUANTITIES))


class Rule:
    """One supervisor rule: ``trips(limits, value)`` on its quantity (a number per cycle, an array
    over a record: written with operators both take), ``says(limits, value)`` the reason of a trip
    (one value), ``kind`` the stop it makes (None: the backend's, :func:`drivers.base.fault_kind`),
    ``active(limits)`` whether the configuration turns it on, ``setpoint``: checked on the setpoint
    about to go out (:meth:`Supervisor.check_setpoint`) rather than on the tick's readings."""
    __slots__ = ("name", "quantity", "trips", "says", "kind", "active", "setpoint")

    def __init__(self, name, quantity, trips, says, kind=StopKind.TRIP, active=None, setpoint=False):
        self.name, self.quantity, self.trips, self.says, self.kind = name, quantity, trips, says, kind
        self.active = active or (lambda lim: True)
        self.setpoint = setpoint


def _outside(lim: Limits, x):
    """Outside the travel, for a number or an array (NaN is outside): ``^ True`` negates both."""
    return ((x >= lim.lo) & (x <= lim.hi)) ^ True


def _travel(name: str):
    return lambda lim, x: (f"travel limit: {name} at {x * 1e3:.3f} mm outside [{lim.lo * 1e3:g}, "
                           f"{lim.hi * 1e3:g}] mm")


def _speed_says(lim, v):
    return f"speed limit: commanded {v:.4g} m/s > {lim.speed:g} m/s"


def _acceleration_says(lim, a):
    return f"acceleration limit: commanded {a:.4g} m/s^2 > {lim.acceleration:g} m/s^2"


def _jerk_says(lim, j):
    return f"jerk limit: commanded {j:.4g} m/s^3 > {lim.jerk:g} m/s^3"


# The rules in the order they are checked every position tick: the first that trips names the stop.
RULES = (
    Rule("fault", Q_FAULT, lambda lim, f: bool(f), lambda lim, f: f, kind=None),
    Rule("overrun", Q_ELAPSED, lambda lim, e: e > lim.overrun_elapsed,
         lambda lim, e: f"loop overrun: cycle {(e - lim.period) * 1e3:.2f} ms late (watchdog {lim.overrun:g} periods)",
         kind=StopKind.OVERRUN),
    Rule("travel_command", Q_X_CMD, _outside, _travel("command")),
    Rule("travel_table", Q_X_TABLE, _outside, _travel("table")),
    Rule("travel_motor", Q_X_MOTOR, _outside, _travel("motor")),
    Rule("speed_command", Q_V_CMD, lambda lim, v: v > lim.speed_max, _speed_says),
    Rule("acceleration_command", Q_A_CMD, lambda lim, a: a > lim.acceleration_max, _acceleration_says),
    Rule("jerk_command", Q_J_CMD, lambda lim, j: j > lim.jerk_max, _jerk_says),
    Rule("speed_measured", Q_V_MOTOR, lambda lim, v: v > 1.5 * lim.speed,
         lambda lim, v: f"speed limit: measured {v:.4g} m/s > 1.5 x {lim.speed:g} m/s"),
    Rule("torque", Q_OUTPUT, lambda lim, u: u > lim.torque * lim.tol, lambda lim, u: f"torque limit: {u:.4g} > {lim.torque:g}",
         active=lambda lim: bool(lim.torque)),
    Rule("following_error_table", Q_E_TABLE, lambda lim, e: e > lim.fe_table,
         lambda lim, e: f"following error at the table: {exceeds(e, lim.fe_table)}", active=lambda lim: bool(lim.fe_table)),
    Rule("following_error_tip", Q_E_TIP, lambda lim, e: e > lim.fe_tip,           # NaN (no tip sensor): never
         lambda lim, e: f"following error at the tool tip: {exceeds(e, lim.fe_tip)}", active=lambda lim: bool(lim.fe_tip)),
    Rule("frozen", Q_FROZEN, lambda lim, n: n >= lim.frozen_n,
         lambda lim, n: f"position feedback frozen for {n} cycles while commanded to move"),
    # then the setpoint about to go out: a trip here stops the axis before it is sent
    Rule("travel_setpoint", Q_X_NEXT, _outside, _travel("command"), setpoint=True),
    Rule("speed_setpoint", Q_V_NEXT, lambda lim, v: v > lim.speed_max, _speed_says, setpoint=True),
    Rule("acceleration_setpoint", Q_A_NEXT, lambda lim, a: a > lim.acceleration_max, _acceleration_says,
         setpoint=True),
    Rule("jerk_setpoint", Q_J_NEXT, lambda lim, j: j > lim.jerk_max, _jerk_says, setpoint=True),
)

# one row of the trip record's history per tick (a tuple in the cycle; these keys in the record)
HISTORY_KEYS = ("k", "t", "x_cmd", "x_motor", "x_table", "x_tip", "v_motor", "output", "fault")
_NAN = math.nan


def _kinematics(q: list, i: int, x0: float, c, skip: int, T: float) -> None:
    """``q[i:i + 3]``: the absolute speed, acceleration and jerk of the command ``x0`` after the
    commands of ``c`` (oldest first) up to ``c[-1 - skip]``; NaN where too few came before."""
    older = len(c) - skip
    x1 = c[-1 - skip] if older >= 1 else _NAN
    q[i] = abs(x0 - x1) / T if older >= 1 else _NAN
    q[i + 1] = abs(x0 - 2 * x1 + c[-2 - skip]) / T ** 2 if older >= 2 else _NAN
    q[i + 2] = abs(x0 - 3 * x1 + 3 * c[-2 - skip] - c[-3 - skip]) / T ** 3 if older >= 3 else _NAN


class Supervisor:
    """Checks :data:`RULES` every position tick (:meth:`check`, then :meth:`check_setpoint`), trips
    on the first that fails (:meth:`trip`: the reason, its :class:`~hil.errors.StopKind` in
    ``trip_kind``, the latch). The cycle allocates no container: the quantities go into one
    preallocated list, the last cycles into a preallocated ring of rows (:attr:`history`)."""

    def __init__(self, cfg, period: float | None = None, real_time: bool = False, latch_file: str | None = None):
        self.cfg = cfg
        self.period = period or cfg["control.position_period"]
        self.real_time = real_time
        self.limits = lim = Limits(cfg, self.period)
        self.tol = float(cfg.get("supervisor.tolerance", 0.05))
        self.stop = cfg.get("supervisor.stop", "quick_stop")
        self.overrun = lim.overrun
        self.frozen_n = lim.frozen_n
        # the last cycles for the trip record: a preallocated ring of rows, written in place
        self._ring = [[0.0] * len(HISTORY_KEYS) for _ in range(int(cfg.get("supervisor.history", 50)))]
        self._ring_n = 0
        self.latch_file = Path(latch_file) if latch_file else latch_path(cfg)
        active = [r for r in RULES if r.active(lim)]
        self._tick_rules = tuple(r for r in active if not r.setpoint)
        self._setpoint_rules = tuple(r for r in active if r.setpoint)
        self._q: list = [_NAN] * len(QUANTITIES)
        self.tripped = False
        self.reason = ""
        self.trip_kind: StopKind | None = None
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
        self._last_table = self._last_motor = None
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
        self.tripped_at, self.trip_kind = "", None

    def _load_latch(self) -> None:
        if self.latch_file is not None and self.latch_file.exists():
            try:
                info = json.loads(self.latch_file.read_text())
                self.tripped, self.reason = True, info.get("reason", "tripped")
                self.tripped_at = info.get("time", "")
            except (OSError, ValueError, AttributeError):
                self.tripped, self.reason = True, "unreadable latch file"

    def trip(self, t: float, reason: str, fb=None, kind: StopKind | None = None) -> str:
        """Latch a trip at time ``t``: ``reason``, and ``kind`` (default: a fault the feedback
        ``fb`` reported, :func:`~drivers.base.fault_kind`, else a supervisor trip)."""
        if not self.tripped:
            if kind is None:
                kind = fault_kind(fb.fault_kind, StopKind.TRIP) if fb is not None else StopKind.TRIP
            self.tripped, self.reason, self.trip_cycle, self.trip_time = True, reason, max(self.k - 1, 0), t
            self.trip_kind = kind
            self.tripped_at = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
            self.record = {"reason": reason, "time": self.tripped_at, "config": str(self.cfg.source),
                           "cycle": max(self.k - 1, 0), "t": t, "stop": self.stop,
                           "last_cycles": [dict(zip(HISTORY_KEYS, row)) for row in self.history]}
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

    @property
    def history(self) -> list[tuple]:
        """The last cycles checked, oldest first: one tuple each, :data:`HISTORY_KEYS` (not real-time)."""
        ring, n = self._ring, self._ring_n
        return [tuple(ring[i % len(ring)]) for i in range(max(0, n - len(ring)), n)]

    # -- the check, every position tick --------------------------------------------------------------------
    def check(self, t: float, fb, x_cmd: float) -> str | None:
        """The tick's rules on the feedback ``fb`` and the tick's command ``x_cmd`` (real-time):
        the reason of a trip, else None."""
        k = self.k
        self.k += 1
        ring = self._ring
        row = ring[self._ring_n % len(ring)]
        self._ring_n += 1
        row[0], row[1], row[2], row[3], row[4] = k, t, x_cmd, fb.x_motor, fb.x_table
        row[5], row[6], row[7], row[8] = fb.x_tip, fb.v_motor, fb.output, fb.reason
        if self.tripped:
            return self.reason
        self._measure(fb, x_cmd)
        return self._apply(self._tick_rules, t, fb)

    def check_setpoint(self, t: float, x_next: float) -> str | None:
        """Check the position setpoint about to go out (the command of the next tick, which a
        position-mode drive receives this cycle): the travel, and the commanded speed,
        acceleration and jerk it makes with the commands before it. A trip here stops the axis
        before the setpoint is sent (hil.loop calls it after :meth:`check`, before writing)."""
        if self.tripped:
            return self.reason
        q, c = self._q, self._cmd
        q[Q_X_NEXT] = x_next
        _kinematics(q, Q_V_NEXT, x_next, c, 0, self.limits.period)
        return self._apply(self._setpoint_rules, t, None)

    def _apply(self, rules: tuple, t: float, fb) -> str | None:
        """The first of ``rules`` that trips on the quantities of this tick: trip on it."""
        q, lim = self._q, self.limits
        for rule in rules:
            v = q[rule.quantity]
            if rule.trips(lim, v):
                return self.trip(t, rule.says(lim, v), fb, rule.kind)
        return None

    def _measure(self, fb, x_cmd: float) -> None:
        """The tick's quantities into ``self._q`` (real-time: numbers into the preallocated list;
        the states of the command history, the frozen count and the watchdog move on)."""
        q, T = self._q, self.limits.period
        q[Q_FAULT] = fb.fault_line
        if self.real_time:
            now = time.perf_counter()
            q[Q_ELAPSED] = now - self._wall if self._wall is not None else _NAN
            self._wall = now
        q[Q_X_CMD], q[Q_X_TABLE], q[Q_X_MOTOR] = x_cmd, fb.x_table, fb.x_motor
        c = self._cmd
        c.append(x_cmd)
        _kinematics(q, Q_V_CMD, x_cmd, c, 1, T)
        q[Q_V_MOTOR], q[Q_OUTPUT] = abs(fb.v_motor), abs(fb.output)
        q[Q_E_TABLE] = abs(x_cmd - fb.x_table)
        q[Q_E_TIP] = abs(x_cmd - fb.x_tip)
        # frozen feedback: the reading does not change while the command moves
        moving = len(c) >= 2 and abs(c[-1] - c[-2]) / T > 1e-3
        if self._last_table is not None and fb.x_table == self._last_table and fb.x_motor == self._last_motor \
                and moving:
            self._same += 1
        else:
            self._same = 0
        self._last_table, self._last_motor = fb.x_table, fb.x_motor
        q[Q_FROZEN] = self._same


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


def check_record(cfg, ch: dict, v_motor=None, period: float | None = None) -> Trip | None:
    """:data:`RULES` on a whole record, vectorized: the first position tick at which
    :class:`Supervisor` would trip, run cycle by cycle on the same readings, its reason and kind;
    None where it would not trip. What the compiled dry run calls on its record (hil.runtime), so
    that a dry run trips where the axis would.

    ``ch``: the record's channels, one row per position tick (``x_cmd``, ``x_table``,
    ``x_motor``, ``x_tip``, ``torque`` or ``command``); ``v_motor``: the motor speed (m/s) at
    the same ticks, where known. The rules whose quantity a record lacks are left out: a
    backend's fault, the real-time watchdog (a simulated clock), the measured speed without
    ``v_motor``."""
    import numpy as np  # here: the command line imports this module without numpy
    lim = Limits(cfg, period)
    T = lim.period
    x = np.asarray(ch["x_cmd"], float)
    K = x.size
    if K == 0:
        return None
    xt, xm = np.asarray(ch["x_table"], float), np.asarray(ch["x_motor"], float)
    tip = np.asarray(ch.get("x_tip", np.full(K, np.nan)), float)
    out = np.asarray(ch["torque"] if "torque" in ch else ch.get("command", np.zeros(K)), float)

    def kin(c, ahead):
        """|first, second, third differences| / T^n ending at c[k + ahead] (ticks k; 0 where too few)"""
        d = [np.full(K, 0.0), np.full(K, 0.0), np.full(K, 0.0)]
        idx = np.arange(K) + ahead              # the newest command of tick k
        ok = idx < c.size
        i = idx[ok]
        for n, coef in ((1, (1, -1)), (2, (1, -2, 1)), (3, (1, -3, 3, -1))):
            m = i >= n
            v = np.zeros(i.size)
            for j, a in enumerate(coef):
                v[m] += a * c[i[m] - j]
            d[n - 1][np.flatnonzero(ok)[m]] = np.abs(v[m])
        return d[0] / T, d[1] / T ** 2, d[2] / T ** 3

    # frozen feedback: readings unchanged (from the tick before) while the command moved
    same = np.zeros(K, bool)
    if K > 1:
        moving = np.abs(np.diff(x)) / T > 1e-3
        same[1:] = (xt[1:] == xt[:-1]) & (xm[1:] == xm[:-1]) & moving
    run = np.zeros(K, int)
    if same.any():
        # length of the run of unchanged readings ending at each tick
        c = np.cumsum(same)
        reset = np.maximum.accumulate(np.where(~same, c, 0))
        run = c - reset
    nxt = np.append(x, x[-1])         # the setpoint about to go out: the next tick's command, held after the last
    q: list = [None] * len(QUANTITIES)
    q[Q_X_CMD], q[Q_X_TABLE], q[Q_X_MOTOR] = x, xt, xm
    q[Q_V_CMD], q[Q_A_CMD], q[Q_J_CMD] = kin(x, 0)
    q[Q_V_MOTOR] = None if v_motor is None else np.abs(np.asarray(v_motor, float))
    q[Q_OUTPUT], q[Q_E_TABLE], q[Q_E_TIP], q[Q_FROZEN] = np.abs(out), np.abs(x - xt), np.abs(x - tip), run
    q[Q_X_NEXT] = nxt[1:]
    q[Q_V_NEXT], q[Q_A_NEXT], q[Q_J_NEXT] = kin(nxt, 1)
    rules = [(r, r.trips(lim, q[r.quantity])) for r in RULES if r.active(lim) and q[r.quantity] is not None]
    first = K
    for _, mask in rules:
        hit = np.flatnonzero(mask)
        if hit.size and hit[0] < first:
            first = int(hit[0])
    if first == K:
        return None
    rule = next(r for r, mask in rules if mask[first])      # the first rule in the supervisor's order
    return Trip(first, rule.says(lim, q[rule.quantity][first]), rule.kind)
