"""Jerk-limited sine-square motion profiles (the paper's Eq. 15-16), parameterised as an NC is.

The velocity rises as v(t) = V sin^2(pi t / (2 T_r)) over the ramp time T_r, cruises, and falls
symmetrically. Then a_max = pi V / (2 T_r) and j_max = pi^2 V / (2 T_r^2) = 2 a_max^2 / V.
An NC gives the ramp by its acceleration time t_acc to reach the rapid speed G0: for a feed V_f,
T_r = t_acc V_f / G0 and a_max = pi G0 / (2 t_acc) (see ../shared/paper/NOTES.md).

Three ways to say how fast to accelerate (:class:`MoveSpec`): ``t_acc`` (with ``g0``), ``a_max``
or ``j_max``. A stroke too short to reach the feed keeps the quantity the user gave and lowers
the peak speed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from hil.errors import LimitError

__all__ = ["MoveSpec", "SineSquareMove", "Dwell", "Trajectory", "LimitError", "AxisLimits",
           "plan_move", "check_limits", "check_sampled", "is_null_stroke"]


# the longest trajectory run or sampled (s), and the most samples of one: beyond them a typo
# (a feed in mm/min read as m/min the other way, a dwell of 1e12 s), never a test move
MAX_DURATION = 3600.0
MAX_SAMPLES = 20_000_000


@dataclass(frozen=True)
class MoveSpec:
    """What the user asks for (SI): a signed stroke, a feed, and one of t_acc (with g0), a_max, j_max."""
    stroke: float
    feed: float
    t_acc: float | None = None
    g0: float | None = None
    a_max: float | None = None
    j_max: float | None = None

    def __post_init__(self):
        # LimitError (a ValueError): the command line reports it in one line
        given = [n for n in ("t_acc", "a_max", "j_max") if getattr(self, n) is not None]
        if len(given) != 1:
            raise LimitError(f"give exactly one of t_acc, a_max, j_max (got {', '.join(given) or 'none'})")
        if self.t_acc is not None and self.g0 is None:
            raise LimitError("t_acc needs the rapid speed g0 (nc.g0 in the config, or --g0)")
        if not math.isfinite(self.stroke):
            raise LimitError(f"stroke must be a finite length, got {self.stroke:g} m")
        if not self.feed > 0 or not math.isfinite(self.feed):
            raise LimitError(f"feed must be positive and finite, got {self.feed:g} m/s")
        for n in given + (["g0"] if self.g0 is not None else []):
            if not getattr(self, n) > 0 or not math.isfinite(getattr(self, n)):
                raise LimitError(f"{n} must be positive and finite, got {getattr(self, n):g}")

    @property
    def keeps(self) -> str:
        """The quantity kept when the stroke is too short for the feed."""
        return "j_max" if self.j_max is not None else "a_max"


@dataclass(frozen=True)
class SineSquareMove:
    """A planned point-to-point move. Times from the move's start; positions from ``start``."""
    start: float
    stroke: float          # signed
    peak_speed: float      # V > 0, reached after the ramp
    ramp_time: float       # T_r
    cruise_time: float
    spec: MoveSpec | None = None
    reduced: bool = False  # peak speed lowered because the stroke is short

    @property
    def direction(self) -> float:
        return 1.0 if self.stroke >= 0 else -1.0

    @property
    def duration(self) -> float:
        return 2.0 * self.ramp_time + self.cruise_time

    @property
    def a_max(self) -> float:
        return math.pi * self.peak_speed / (2.0 * self.ramp_time)

    @property
    def j_max(self) -> float:
        return math.pi ** 2 * self.peak_speed / (2.0 * self.ramp_time ** 2)

    @property
    def end(self) -> float:
        return self.start + self.stroke

    def _phase(self, t):
        t = np.asarray(t, float)
        tr, tc = self.ramp_time, self.cruise_time
        return t, tr, tc

    def velocity(self, t):
        t, tr, tc = self._phase(t)
        V = self.peak_speed
        v = np.where(t < tr, V * np.sin(np.pi * t / (2 * tr)) ** 2,
                     np.where(t < tr + tc, V, V * np.cos(np.pi * (t - tr - tc) / (2 * tr)) ** 2))
        v = np.where((t < 0) | (t > self.duration), 0.0, v)
        return self.direction * v

    def acceleration(self, t):
        t, tr, tc = self._phase(t)
        A = self.a_max
        a = np.where(t < tr, A * np.sin(np.pi * t / tr), np.where(t < tr + tc, 0.0,
                     -A * np.sin(np.pi * (t - tr - tc) / tr)))
        a = np.where((t < 0) | (t > self.duration), 0.0, a)
        return self.direction * a

    def jerk(self, t):
        t, tr, tc = self._phase(t)
        J = self.j_max
        j = np.where(t < tr, J * np.cos(np.pi * t / tr), np.where(t < tr + tc, 0.0,
                     -J * np.cos(np.pi * (t - tr - tc) / tr)))
        j = np.where((t < 0) | (t > self.duration), 0.0, j)
        return self.direction * j

    def position(self, t):
        t, tr, tc = self._phase(t)
        V = self.peak_speed
        ramp = V * tr / 2.0
        tt = np.clip(t, 0.0, self.duration)
        up = V / 2.0 * (tt - tr / np.pi * np.sin(np.pi * tt / tr))
        cruise = ramp + V * (tt - tr)
        td = tt - tr - tc
        down = ramp + V * tc + V / 2.0 * (td + tr / np.pi * np.sin(np.pi * td / tr))
        s = np.where(tt < tr, up, np.where(tt < tr + tc, cruise, down))
        return self.start + self.direction * s


def plan_move(spec: MoveSpec, start: float = 0.0) -> SineSquareMove:
    """Plan a sine-square move; a short stroke keeps ``spec.keeps`` and lowers the peak speed."""
    D = abs(spec.stroke)
    V = spec.feed
    if spec.t_acc is not None:
        a = math.pi * spec.g0 / (2.0 * spec.t_acc)
        tr = math.pi * V / (2.0 * a)            # = t_acc V_f / G0
    elif spec.a_max is not None:
        a = spec.a_max
        tr = math.pi * V / (2.0 * a)
    else:
        tr = math.pi * math.sqrt(V / (2.0 * spec.j_max))
    reduced = False
    if D == 0.0:
        # no distance: a standstill (a peak speed here would ramp away and jump back at the end)
        return SineSquareMove(start, 0.0, 0.0, tr, 0.0, spec, False)
    if V * tr > D:                               # the two ramps alone would overshoot the stroke
        reduced = True
        if spec.j_max is not None:
            V = (D * math.sqrt(2.0 * spec.j_max) / math.pi) ** (2.0 / 3.0)
            tr = math.pi * math.sqrt(V / (2.0 * spec.j_max))
        else:
            V = math.sqrt(2.0 * a * D / math.pi)
            tr = math.pi * V / (2.0 * a)
    cruise = max(D / V - tr, 0.0)
    return SineSquareMove(start, spec.stroke, V, tr, cruise, spec, reduced)


@dataclass(frozen=True)
class Dwell:
    """Standing still at the current position."""
    duration: float


@dataclass
class Trajectory:
    """A sequence of moves and dwells from a start position, sampled on the position-loop clock."""
    start: float = 0.0
    segments: list = field(default_factory=list)

    @property
    def position_now(self) -> float:
        for seg in reversed(self.segments):
            if isinstance(seg, SineSquareMove):
                return seg.end
        return self.start

    def move(self, spec: MoveSpec) -> SineSquareMove:
        m = plan_move(spec, self.position_now)
        self.segments.append(m)
        return m

    def dwell(self, duration: float) -> None:
        if not 0 <= duration <= MAX_DURATION:
            raise LimitError(f"dwell must be between 0 and {MAX_DURATION:g} s, got {duration:g} s")
        if duration > 0:
            self.segments.append(Dwell(duration))

    @property
    def moves(self) -> list[SineSquareMove]:
        return [s for s in self.segments if isinstance(s, SineSquareMove)]

    @property
    def duration(self) -> float:
        return sum(s.duration for s in self.segments)

    def _evaluate(self, t, what: str):
        t = np.asarray(t, float)
        out = np.zeros_like(t) + (self.start if what == "position" else 0.0)
        t0 = 0.0
        for seg in self.segments:
            if isinstance(seg, SineSquareMove):
                inside = (t >= t0) & (t <= t0 + seg.duration)
                after = t > t0 + seg.duration
                out = np.where(inside, getattr(seg, what)(t - t0), out)
                if what == "position":
                    out = np.where(after, seg.end, out)
            t0 += seg.duration
        return out

    def shifted(self, offset: float) -> "Trajectory":
        """The same moves and dwells from ``start + offset`` (every position moved by ``offset``)."""
        segs = [replace(s, start=s.start + offset) if isinstance(s, SineSquareMove) else s for s in self.segments]
        return Trajectory(self.start + offset, segs)

    def position(self, t):
        return self._evaluate(t, "position")

    def velocity(self, t):
        return self._evaluate(t, "velocity")

    def acceleration(self, t):
        return self._evaluate(t, "acceleration")

    def jerk(self, t):
        return self._evaluate(t, "jerk")

    def sample(self, period: float, settle: float = 0.0):
        """Times t_k = k period and the commanded positions x_cmd[k], covering the whole trajectory
        plus ``settle`` seconds standing at the end."""
        total = self.duration + settle
        if not total <= MAX_DURATION + settle or not period > 0 or total / period > MAX_SAMPLES:
            raise LimitError(f"the trajectory lasts {total:g} s: at most {MAX_DURATION:g} s and {MAX_SAMPLES} "
                             f"samples of {period:g} s are run")
        n = int(math.ceil(total / period - 1e-9)) + 1
        t = np.arange(n) * period
        return t, self.position(t)


@dataclass(frozen=True)
class AxisLimits:
    travel_min: float
    travel_max: float
    speed: float
    acceleration: float
    jerk: float
    g0: float | None = None     # the rapid speed (nc.g0): no feed above it, as on an NC

    @classmethod
    def from_config(cls, cfg) -> "AxisLimits":
        return cls(cfg["limits.travel_min"], cfg["limits.travel_max"], cfg["limits.speed"],
                   cfg["limits.acceleration"], cfg["limits.jerk"], cfg.get("nc.g0"))


def _fit_hint(move: SineSquareMove, which: str, lim: AxisLimits) -> str:
    """What would fit, in the terms the user gave the move."""
    spec = move.spec
    V = move.peak_speed
    if which == "speed":
        return f"a feed of at most {lim.speed * 60e3:.0f} mm/min ({lim.speed:g} m/s) would fit"
    if which == "acceleration":
        if spec is not None and spec.t_acc is not None:
            return f"t_acc >= {math.pi * spec.g0 / (2 * lim.acceleration) * 1e3:.1f} ms would fit"
        if spec is not None and spec.j_max is not None:
            # a = sqrt(j V / 2) <= a_lim  ->  j <= 2 a_lim^2 / V
            return f"j_max <= {2 * lim.acceleration ** 2 / V:.4g} m/s^3 would fit"
        return f"a_max <= {lim.acceleration:g} m/s^2 would fit"
    # jerk: j = 2 a^2 / V
    if spec is not None and spec.t_acc is not None:
        a_ok = math.sqrt(lim.jerk * V / 2.0)
        if not move.reduced:
            return f"t_acc >= {math.pi * spec.g0 / (2 * a_ok) * 1e3:.1f} ms would fit"
        return f"a_max <= {a_ok:.4g} m/s^2 would fit"
    if spec is not None and spec.a_max is not None:
        return f"a_max <= {math.sqrt(lim.jerk * V / 2.0):.4g} m/s^2 would fit"
    return f"j_max <= {lim.jerk:g} m/s^3 would fit"


def _feed_problems(move: SineSquareMove, lim: AxisLimits, label: str) -> list[str]:
    """The feed asked for, above G0 or limits.speed: refused even where the stroke is too short to
    reach it (the planned peak speed stays below; the move would silently run slower than asked)."""
    spec = move.spec
    if spec is None:
        return []
    g0 = spec.g0 or lim.g0
    source = "nc.g0" if g0 == lim.g0 else "--g0"
    if g0 and g0 <= lim.speed and spec.feed > g0 * (1 + 1e-9):       # G0 is the tighter limit
        return [f"{label}: feed {spec.feed * 60e3:.0f} mm/min ({spec.feed:.4g} m/s) is above the rapid speed G0 "
                f"{g0 * 60e3:.0f} mm/min ({g0:g} m/s, {source}); a feed of at most {g0 * 60e3:.0f} mm/min would fit"]
    if spec.feed > lim.speed * (1 + 1e-9) and not move.peak_speed > lim.speed * (1 + 1e-9):
        return [f"{label}: feed {spec.feed * 60e3:.0f} mm/min ({spec.feed:.4g} m/s) exceeds limits.speed "
                f"{lim.speed:g} m/s (the stroke is too short to reach it); {_fit_hint(move, 'speed', lim)}"]
    return []


def check_limits(traj: Trajectory, lim: AxisLimits) -> None:
    """Refuse a trajectory that would break a limit of the axis, before any motion."""
    problems = []
    if not traj.duration <= MAX_DURATION:
        problems.append(f"the trajectory lasts {traj.duration:.4g} s, more than {MAX_DURATION:g} s (a feed or an "
                        f"acceleration far too small?)")
    for i, seg in enumerate(traj.segments):
        if not isinstance(seg, SineSquareMove):
            continue
        label = f"move {i + 1}" if len(traj.moves) > 1 else "the move"
        for p, name in ((seg.start, "start"), (seg.end, "end")):
            if p > lim.travel_max + 1e-12:
                problems.append(f"{label}: {name} position {p * 1e3:.3f} mm is beyond limits.travel_max "
                                f"{lim.travel_max * 1e3:.3f} mm by {(p - lim.travel_max) * 1e3:.3f} mm; "
                                f"a stroke of at most {(lim.travel_max - seg.start) * 1e3:.3f} mm from "
                                f"{seg.start * 1e3:.3f} mm would fit")
            if p < lim.travel_min - 1e-12:
                problems.append(f"{label}: {name} position {p * 1e3:.3f} mm is beyond limits.travel_min "
                                f"{lim.travel_min * 1e3:.3f} mm by {(lim.travel_min - p) * 1e3:.3f} mm; "
                                f"a stroke of at most {(seg.start - lim.travel_min) * 1e3:.3f} mm (negative) "
                                f"from {seg.start * 1e3:.3f} mm would fit")
        problems += _feed_problems(seg, lim, label)
        for which, value, limit, unit in (("speed", seg.peak_speed, lim.speed, "m/s"),
                                          ("acceleration", seg.a_max, lim.acceleration, "m/s^2"),
                                          ("jerk", seg.j_max, lim.jerk, "m/s^3")):
            if value > limit * (1 + 1e-9):
                problems.append(f"{label}: {which} {value:.4g} {unit} exceeds limits.{which} {limit:g} {unit} "
                                f"by {(value / limit - 1) * 100:.1f} %; {_fit_hint(seg, which, lim)}")
    if problems:
        raise LimitError("move refused before motion: " + "; ".join(problems))


def is_null_stroke(stroke: float, resolution: float = 0.0) -> bool:
    """Whether a stroke is no move: zero, or smaller than the axis can resolve (the encoder
    quantum ``resolution``; 1 nm at least)."""
    return abs(stroke) < max(resolution, 1e-9)


def check_sampled(x_cmd, period: float, lim: AxisLimits, what: str = "the command") -> None:
    """Refuse a command sequence, as it will be sent, whose samples break a limit: every sample
    within the travel and finite, and the speed, acceleration and jerk of the sampled command
    (its first, second and third backward differences over ``period``, the command standing at
    its first sample before and at its last sample after) within the axis limits.

    The sampled differences of a planned sine-square move are weighted means of its continuous
    speed, acceleration and jerk, so a plan that keeps the limits keeps them sample by sample;
    what this catches is a sequence that does not match its plan (a jump, a planning error)."""
    x = np.asarray(x_cmd, float)
    if x.ndim != 1 or x.size == 0:
        raise LimitError(f"{what}: no samples to send")
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise LimitError(f"{what}: sample {bad[0]} is not a finite position; nothing was sent")
    out = np.flatnonzero((x > lim.travel_max + 1e-12) | (x < lim.travel_min - 1e-12))
    if out.size:
        i = out[0]
        raise LimitError(f"{what}: sample {i} (t = {i * period:.4f} s) at {x[i] * 1e3:.3f} mm is outside the travel "
                         f"[{lim.travel_min * 1e3:g}, {lim.travel_max * 1e3:g}] mm; nothing was sent")
    xp = np.concatenate([np.full(3, x[0]), x, x[-1:]])
    d = np.diff(xp)
    # (name, sampled value, limit, unit, absolute slack for rounding)
    # (name, sampled value, limit, unit, absolute slack for rounding); value i of the difference of
    # order n ends at padded sample i + n, that is at command sample i + n - 3
    rows = ((1, "speed", np.abs(d) / period, lim.speed, "m/s", 1e-9),
            (2, "acceleration", np.abs(np.diff(d)) / period ** 2, lim.acceleration, "m/s^2", 1e-6),
            (3, "jerk", np.abs(np.diff(d, 2)) / period ** 3, lim.jerk, "m/s^3", 1e-3))
    for order, name, v, limit, unit, slack in rows:
        over = np.flatnonzero(v > limit * (1.0 + 1e-9) + slack)
        if over.size:
            i = over[0]
            k = min(max(i + order - 3, 0), x.size - 1)
            raise LimitError(f"{what}: the sampled {name} {v[i]:.4g} {unit} at sample {k} (t = {k * period:.4f} s) "
                             f"exceeds limits.{name} {limit:g} {unit}; nothing was sent")
