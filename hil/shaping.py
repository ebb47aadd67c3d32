"""Input shaping of the position command: the host's command convolved with a few impulses that
cancel the residual vibration of a mode (Singer and Seering 1990; the shapers of Klipper's
``shaper_defs.py``), so that the tool tip arrives still without lowering the jerk of the whole move.

A shaper is impulses of amplitudes ``A_i`` (positive, summing to 1) at times ``t_i`` (the first at
0): the shaped command is ``x_s(t) = sum_i A_i x(t - t_i)``. Being a convex combination of delayed
copies, its speed, acceleration and jerk never exceed the unshaped command's, so the limits
checked on the move hold for the shaped one; the move lasts ``t_last`` longer. The shaping is done
where the host generates the command, so it acts on every backend (the simulated plant, CANopen,
serial), and the record's ``x_cmd`` is the command the axis received.

Each shaper is designed for a mode of frequency ``f`` and damping ratio ``zeta`` (``K = exp(-zeta pi
/ sqrt(1 - zeta^2))``, damped period ``T_d = 1 / (f sqrt(1 - zeta^2))``):

- ``zv``: 2 impulses over ``T_d / 2``, zero vibration at the design mode, the shortest;
- ``zvd``: 3 impulses over ``T_d``, zero vibration and zero slope there: robust to about +-15 %
  of frequency error (5 % residual);
- ``ei``: 3 impulses over ``T_d``, a residual of ``V_TOL`` (5 %) at the design mode, traded for a
  wider band (about +-20 %);
- ``si``: specified insensitivity: impulses every ``T_d / 2``, as few as keep the residual within
  ``V_TOL`` over the whole band ``SI_BAND`` (+-30 %) around the design mode, their amplitudes the
  solution of a linear programme (the residual's in-phase and quadrature parts bounded at every
  frequency of the band; Singhose, Seering and Singer 1994): the longest, and the widest.

:func:`residual_vibration` is the shaper's sensitivity: the vibration left, as a share of the
unshaped command's, at any frequency and damping (the curve that shows how far a mode may lie
from the design before the shaping stops working).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

__all__ = ["Shaper", "KINDS", "ALL_KINDS", "SI_BAND", "V_TOL", "residual_vibration", "parse_shaper", "ShapedTrajectory", "model_modes",
           "config_shaper", "shaped"]

V_TOL = 0.05            # the EI shaper's residual vibration at its design mode (Klipper's 1/20)
KINDS = ("zv", "zvd", "ei")          # the closed forms
ALL_KINDS = KINDS + ("si",)          # and the specified-insensitivity shaper, designed numerically
SI_BAND = 0.3                        # the SI shaper's band: +-30 % of its frequency
SI_MAX_IMPULSES = 9


@dataclass(frozen=True)
class Shaper:
    """An input shaper: ``amplitudes`` (summing to 1) at ``times`` (s, the first 0), designed for a
    mode of ``frequency`` (Hz) and ``damping`` (ratio)."""
    kind: str
    frequency: float
    damping: float
    amplitudes: tuple
    times: tuple

    @classmethod
    def design(cls, kind: str, frequency: float, damping: float = 0.0) -> "Shaper":
        """The ``kind`` shaper (:data:`ALL_KINDS`) for a mode at ``frequency`` Hz, ``damping`` ratio."""
        if kind not in ALL_KINDS:
            raise ValueError(f"shaper {kind!r}: one of {', '.join(ALL_KINDS)}")
        if not (frequency > 0 and math.isfinite(frequency)):
            raise ValueError(f"shaper frequency must be positive and finite, got {frequency!r} Hz")
        if not 0 <= damping < 1:
            raise ValueError(f"shaper damping ratio must be in [0, 1), got {damping!r}")
        df = math.sqrt(1.0 - damping * damping)
        k = math.exp(-damping * math.pi / df)
        td = 1.0 / (frequency * df)
        if kind == "si":
            a, t = _specified_insensitivity(frequency, damping)
        elif kind == "zv":
            a, t = [1.0, k], [0.0, 0.5 * td]
        elif kind == "zvd":
            a, t = [1.0, 2.0 * k, k * k], [0.0, 0.5 * td, td]
        else:
            a1 = 0.25 * (1.0 + V_TOL)
            a, t = [a1, 0.5 * (1.0 - V_TOL) * k, a1 * k * k], [0.0, 0.5 * td, td]
        s = sum(a)
        return cls(kind, float(frequency), float(damping), tuple(x / s for x in a), tuple(t))

    @property
    def duration(self) -> float:
        """How much longer the shaped move lasts (s): the last impulse's time."""
        return self.times[-1]

    def __str__(self) -> str:
        return f"{self.kind}@{self.frequency:.4g}Hz:{self.damping:.4g}"

    def as_json(self) -> dict:
        return {"kind": self.kind, "frequency_hz": self.frequency, "damping_ratio": self.damping,
                "amplitudes": list(self.amplitudes), "times_s": list(self.times), "duration_s": self.duration}


def _specified_insensitivity(frequency: float, damping: float, band: float = SI_BAND,
                              v_tol: float = V_TOL) -> tuple[list, list]:
    """Amplitudes and times of the shortest shaper with impulses every half damped period whose
    residual vibration stays within ``v_tol`` from ``(1 - band)`` to ``(1 + band)`` times
    ``frequency``: for 3, 4, ... impulses, the amplitudes (>= 0, summing to 1) that minimise the
    largest of the residual's in-phase and quadrature parts over the band (scipy's linprog), the
    first whose exact residual is within the tolerance."""
    from scipy.optimize import linprog
    df = math.sqrt(1.0 - damping * damping)
    td = 1.0 / (frequency * df)
    w = 2.0 * np.pi * frequency * np.linspace(1.0 - band, 1.0 + band, 61)
    best = None
    for n in range(3, SI_MAX_IMPULSES + 1):
        t = 0.5 * td * np.arange(n)
        # the residual at w: exp(-zeta w t_n) sum_i A_i exp(zeta w t_i) (cos, sin)(w_d t_i)
        e = np.exp(damping * np.outer(w, t - t[-1]))
        rows = np.vstack([e * np.cos(np.outer(w * df, t)), e * np.sin(np.outer(w * df, t))])
        # variables (A_1..A_n, s): minimise s with -s <= rows A <= s, sum A = 1, A >= 0
        m = rows.shape[0]
        a_ub = np.vstack([np.hstack([rows, -np.ones((m, 1))]), np.hstack([-rows, -np.ones((m, 1))])])
        res = linprog(np.r_[np.zeros(n), 1.0], A_ub=a_ub, b_ub=np.zeros(2 * m),
                      A_eq=np.r_[np.ones(n), 0.0][None, :], b_eq=[1.0], bounds=[(0, None)] * (n + 1),
                      method="highs")
        if not res.success:
            continue
        amps = np.clip(res.x[:n], 0.0, None)
        amps /= amps.sum()
        keep = amps > 1e-9                     # an impulse the programme left at zero is none
        cand = (list(amps[keep]), list(t[keep] - t[keep][0]))
        shaper = Shaper("si", float(frequency), float(damping), tuple(cand[0]), tuple(cand[1]))
        worst = float(np.max(residual_vibration(shaper, w / (2 * np.pi))))
        best = cand
        if worst <= v_tol:
            return cand
    if best is None:
        raise ValueError(f"no specified-insensitivity shaper found for {frequency:g} Hz, damping {damping:g}")
    return best


def residual_vibration(shaper: Shaper, frequency, damping: float | None = None):
    """The vibration a mode at ``frequency`` (Hz, array or scalar) and ``damping`` (the shaper's
    when None) keeps after the shaped command, as a share of the unshaped one's (1: no reduction,
    0: none left): ``exp(-zeta w t_n) |sum_i A_i exp(zeta w t_i) exp(j w_d t_i)|``, w = 2 pi f,
    w_d = w sqrt(1 - zeta^2), t_n the last impulse (Singer and Seering)."""
    zeta = shaper.damping if damping is None else float(damping)
    w = 2.0 * np.pi * np.asarray(frequency, float)
    wd = w * math.sqrt(1.0 - zeta * zeta)
    a, t = np.asarray(shaper.amplitudes), np.asarray(shaper.times)
    e = np.exp(zeta * np.multiply.outer(w, t))
    c = np.sum(a * e * np.cos(np.multiply.outer(wd, t)), axis=-1)
    s = np.sum(a * e * np.sin(np.multiply.outer(wd, t)), axis=-1)
    return np.exp(-zeta * w * t[-1]) * np.hypot(c, s)


_SPEC = re.compile(r"^\s*(?P<kind>[a-zA-Z]+)\s*@\s*(?P<freq>[^:]+?)\s*(?::\s*(?P<zeta>.+?))?\s*$")


def parse_shaper(text: str, what: str = "--shaper", modes=()) -> Shaper | None:
    """``KIND@FREQUENCY[:DAMPING]`` (``zvd@14.94Hz``, ``ei@86.6Hz:0.09``) as a :class:`Shaper`;
    ``none`` or empty: None. Without a damping ratio, the damping of the model's mode nearest to
    the frequency (``modes``: [(frequency Hz, damping ratio)]), else 0. ``auto``: a ZVD shaper at
    the model's lowest elastic mode. A ValueError names ``what`` and the form expected."""
    from hil.units import parse
    text = (text or "").strip()
    if text.lower() in ("", "none", "off"):
        return None
    if text.lower() == "auto":
        if not modes:
            raise ValueError(f"{what} auto: the model has no elastic mode to shape for; give KIND@FREQUENCY")
        f, z = min(modes)
        return Shaper.design("zvd", f, z)
    m = _SPEC.match(text)
    if not m or m.group("kind").lower() not in ALL_KINDS:
        raise ValueError(f"{what} {text!r}: expected KIND@FREQUENCY[:DAMPING] with KIND one of "
                         f"{', '.join(ALL_KINDS)} (e.g. zvd@14.94Hz, ei@86.6Hz:0.09), auto, or none")
    try:
        f = float(parse(m.group("freq"), "frequency"))
    except ValueError as exc:
        raise ValueError(f"{what} {text!r}: {exc}") from None
    try:
        z = None if m.group("zeta") is None else float(m.group("zeta"))
    except ValueError:
        raise ValueError(f"{what} {text!r}: the damping ratio after ':' must be a plain number in [0, 1) "
                         f"(e.g. 0.015), got {m.group('zeta')!r}") from None
    if not (f > 0 and math.isfinite(f)):
        raise ValueError(f"{what} {text!r}: the frequency must be positive and finite")
    if z is None:
        z = min(modes, key=lambda fz: abs(math.log(fz[0] / f)))[1] if modes else 0.0
    try:
        return Shaper.design(m.group("kind").lower(), f, z)
    except ValueError as exc:
        raise ValueError(f"{what} {text!r}: {exc}") from None


def model_modes(cfg) -> list[tuple[float, float]]:
    """(frequency Hz, damping ratio) of the config's elastic modes, the motor's viscous friction
    included (as ``hil model`` reports them)."""
    from hil.plant_config import plant_from_config
    ch = plant_from_config(cfg).chain
    if ch.n < 2:
        return []
    w, _ = ch.modes()
    zeta = ch.modal_damping_ratios(include_ground=True)
    return [(float(x / (2 * math.pi)), float(z)) for x, z in zip(w[1:], zeta)]


def config_shaper(cfg, option: str | None = None) -> Shaper | None:
    """The move's shaper: ``option`` (``--shaper``), else the config's ``nc.shaper``; None for none.
    A ValueError names where the bad one came from."""
    text = option if option is not None else cfg.get("nc.shaper", "none")
    if str(text).strip().lower() in ("", "none", "off"):
        return None
    what = "--shaper" if option is not None else f"{cfg.source}: nc.shaper"
    return parse_shaper(str(text), what, model_modes(cfg))


def shaped(traj, shaper: Shaper | None):
    """``traj`` through ``shaper`` (:class:`ShapedTrajectory`), or ``traj`` itself without one."""
    return traj if shaper is None else ShapedTrajectory(traj, shaper)


class ShapedTrajectory:
    """A :class:`hil.profiles.Trajectory` whose command passes through a :class:`Shaper`: the same
    moves and dwells, the positions (and their derivatives) the shaper's convex combination of
    delayed copies, the duration longer by the shaper's. Everything else is the trajectory's."""

    def __init__(self, traj, shaper: Shaper):
        self.traj, self.shaper = traj, shaper

    def __getattr__(self, name):           # start, segments, moves, position_now, dwell, move
        return getattr(self.traj, name)

    @property
    def duration(self) -> float:
        return self.traj.duration + self.shaper.duration

    def _shaped(self, t, what: str):
        t = np.asarray(t, float)
        f = getattr(self.traj, what)
        return sum(a * f(t - ti) for a, ti in zip(self.shaper.amplitudes, self.shaper.times))

    def position(self, t):
        return self._shaped(t, "position")

    def velocity(self, t):
        return self._shaped(t, "velocity")

    def acceleration(self, t):
        return self._shaped(t, "acceleration")

    def jerk(self, t):
        return self._shaped(t, "jerk")

    def shifted(self, offset: float) -> "ShapedTrajectory":
        return ShapedTrajectory(self.traj.shifted(offset), self.shaper)

    def sample(self, period: float, settle: float = 0.0):
        from hil.profiles import Trajectory
        return Trajectory.sample(self, period, settle)
