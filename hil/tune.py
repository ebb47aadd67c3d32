"""Commissioning in one command (``hil tune``): the cascade's gains against stated margins, the
command shaped (or its jerk lowered) so that the tool tip arrives still, then a verification move.

The stages, each a function of its own, in the order they run:

1. :func:`stable_start`: a configuration whose model loop is unstable gets its velocity gain
   halved until it is stable (nothing can be measured on an unstable loop);
2. :func:`tune_gains`: the frequency responses measured as ``hil frf`` measures them; the velocity
   gain ``control.kp`` set to :data:`BACKOFF` of the largest that keeps the phase and gain margins
   on the *measured* velocity loop (bounded by the measured band, so by the first modes it
   reaches), measured again; the position gain ``control.kv`` likewise on the measured position
   loop; measured a third time, and backed off while a margin is short;
3. :func:`choose_command`: for the move asked (stroke, feed), every NC acceleration time of
   :data:`T_ACC` the limits allow, each unshaped and through the ZV, ZVD, EI and SI shapers designed
   for the tip's mode *as measured*, is run on the model with the tuned gains and the mode where it
   was measured (:func:`matched`), and with the plant's modes :func:`mode_error` away on either side; the option whose tip is within the
   tolerance earliest in the worst of the three is chosen (robustness taken from the fit, as the
   issue asks, not assumed);
4. the caller verifies the choice with a move on the backend (``hil.commands.tune``).

Every figure is measured here; nothing is taken from the paper's bench.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hil.shaping import ALL_KINDS, Shaper, shaped

__all__ = ["Change", "Candidate", "TuneResult", "stable_start", "tune_gains", "choose_command", "mode_error",
           "tip_settle_time", "margins_of", "value_text", "matched", "command_trajectory", "BACKOFF", "T_ACC"]

BACKOFF = 0.9        # share of the largest gain that keeps the margins (the measurement has its error)
T_ACC = (0.1, 0.125, 0.15, 0.175, 0.2, 0.25, 0.3, 0.4)     # NC acceleration times tried (s)
MIN_MODE_ERROR = 0.05     # the least frequency error a shaper must tolerate (5 %)
HOLD = 0.2                # s the tip must stay within the tolerance at a record's end to count as arrived


@dataclass
class Change:
    """A config key the tuning changed: its value before and after, and why."""
    key: str
    before: object
    after: object
    reason: str

    def as_json(self) -> dict:
        return {"key": self.key, "before": self.before, "after": self.after, "reason": self.reason}


@dataclass
class Candidate:
    """A command tried for the move: the NC acceleration time, the shaper (None: the sine-square
    profile alone), and when the tip is within the tolerance for good, counted from the start of
    the move (s; inf: not within the record), nominal and in the worst of the mode errors."""
    t_acc: float
    shaper: Shaper | None
    settle_s: float
    settle_worst_s: float
    move_s: float

    @property
    def label(self) -> str:
        return f"t_acc {self.t_acc * 1e3:.0f} ms, " + (f"{self.shaper.kind.upper()} at {self.shaper.frequency:.4g} Hz"
                                                     if self.shaper else "no shaper")

    def as_json(self) -> dict:
        fin = lambda v: v if math.isfinite(v) else None   # noqa: E731
        return {"t_acc_s": self.t_acc, "shaper": str(self.shaper) if self.shaper else "none",
                "settle_s": fin(self.settle_s), "settle_worst_s": fin(self.settle_worst_s), "move_s": self.move_s}


@dataclass
class TuneResult:
    """What ``hil tune`` found: the answer first, then the changes with their reasons, the margins
    measured before and after, the modes, the commands tried and the one chosen, the verification."""
    answer: str
    changes: list[Change]
    margins_before: dict
    margins_after: dict
    modes: list
    mode_error: float
    candidates: list[Candidate]
    choice: Candidate | None
    verified: dict = field(default_factory=dict)
    steps: list[str] = field(default_factory=list)

    def as_json(self) -> dict:
        return {"answer": self.answer, "changes": [c.as_json() for c in self.changes],
                "margins_before": self.margins_before, "margins_after": self.margins_after,
                "modes": self.modes, "mode_error": self.mode_error,
                "candidates": [c.as_json() for c in self.candidates],
                "choice": self.choice.as_json() if self.choice else None, "verified": self.verified,
                "steps": self.steps}


def value_text(key: str, value) -> str:
    """A config value as the user reads it: in an engineering unit where the key has one."""
    from hil.config import field_for
    from hil.units import DIMENSIONS, fmt
    if value is None:
        return "none"
    kind = getattr(field_for(key), "kind", None)
    if isinstance(value, float) and isinstance(kind, str) and kind in DIMENSIONS:
        return fmt(value, kind)
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def margins_of(result) -> dict:
    """The measured loops' margins of an :class:`~hil.frf.FrfResult`: phase margin (deg), gain margin
    (dB; None: no phase crossover in the band), crossover (Hz), for the velocity and the position
    loop."""
    out = {}
    for loop in ("velocity_loop", "position_loop"):
        m = result.tuning.get(loop)
        if m:
            out[loop] = {"phase_margin_deg": m.get("phase_margin_deg"), "gain_margin_db": m.get("gain_margin_db"),
                         "crossover_hz": m.get("crossover_hz"), "bandwidth_hz": m.get("bandwidth_hz")}
    return out


def _short(m: dict, pm_min: float, gm_min_db: float) -> bool:
    """A margin below the template (a missing gain margin: no phase crossover, so none to lose)."""
    pm, gm = m.get("phase_margin_deg"), m.get("gain_margin_db")
    return (pm is not None and pm < pm_min) or (gm is not None and gm < gm_min_db)


def stable_start(cfg, changes: list[Change], limit: int = 8):
    """``cfg`` with ``control.kp`` halved until the model's loop is stable (at most ``limit``
    times); each halving a :class:`Change`."""
    from hil.closed_loop import loop_stability
    kp0 = cfg["control.kp"]
    for _ in range(limit):
        res = loop_stability(cfg)
        if res is None or res[0]:
            break
        cfg = cfg.with_values({"control.kp": cfg["control.kp"] / 2})
    if cfg["control.kp"] != kp0:
        changes.append(Change("control.kp", kp0, cfg["control.kp"], "the model's loop was unstable: halved until "
                              "stable, so that the frequency responses can be measured"))
    return cfg


def tune_gains(cfg, measure, pm_min: float, gm_min_db: float, changes: list[Change], steps: list[str]):
    """The velocity gain, then the position gain, each :data:`BACKOFF` of the largest that keeps
    the margins on the loop as measured (``measure(cfg) -> FrfResult``), then measured again and
    backed off by 20 % while a margin is short (at most twice). Returns the tuned config and the
    first and the last measurement (their margins: :func:`margins_of`)."""
    first = result = measure(cfg)
    steps.append("measured the frequency responses with the gains as given")
    for loop, key, name in (("velocity_loop", "control.kp", "kp_max"), ("position_loop", "control.kv", "kv_max")):
        best = (result.tuning.get(loop) or {}).get(name)
        if not best or not math.isfinite(best):
            steps.append(f"{key}: no gain keeps the margins in the measured band; left as it is")
            continue
        before = cfg[key]
        after = float(f"{BACKOFF * best:.4g}")
        cfg = cfg.with_values({key: after})
        changes.append(Change(key, before, after, f"{BACKOFF:g} x the largest {key.split('.')[1]} ({best:.4g}) that "
                              f"keeps PM >= {pm_min:g} deg and GM >= {gm_min_db:g} dB on the measured "
                              f"{loop.replace('_', ' ')}"))
        result = measure(cfg)
        steps.append(f"measured again with {key} = {after:.4g}")
    for _ in range(2):
        short = [loop for loop, m in margins_of(result).items() if _short(m, pm_min, gm_min_db)]
        if not short:
            break
        for loop in short:
            key = "control.kp" if loop == "velocity_loop" else "control.kv"
            before = cfg[key]
            cfg = cfg.with_values({key: float(f"{0.8 * before:.4g}")})
            changes.append(Change(key, before, cfg[key], f"the {loop.replace('_', ' ')}'s margin measured short: "
                                  f"20 % less"))
        result = measure(cfg)
        steps.append("measured again after backing off")
    return cfg, first, result


def mode_error(mode: dict, least: float = MIN_MODE_ERROR) -> float:
    """The relative frequency error a shaper for ``mode`` (a fitted mode of ``hil frf``) must
    tolerate: three standard errors of the fit, at least ``least`` (:data:`MIN_MODE_ERROR`: a
    load, a position, a temperature move a mode by a few per cent from the day it was measured)."""
    f = mode["measured"]["frequency_hz"]
    sigma = mode["measured"].get("frequency_std_hz") or 0.0
    return float(max(least, 3 * sigma / f))


def matched(cfg, mode: dict):
    """``cfg`` with the stiffness the mode is most sensitive to scaled so that the model's mode
    nearest the measurement lies at the measured frequency (the commands are judged on the plant
    as measured, not as modelled). Unchanged where the model has no stiffness or no such mode."""
    from hil.shaping import model_modes
    f_meas = mode["measured"]["frequency_hz"]

    def nearest(c):
        fs = [f for f, _ in model_modes(c)]
        return min(fs, key=lambda f: abs(math.log(f / f_meas))) if fs else None
    f0 = nearest(cfg)
    keys = [k for k in cfg.values if k.startswith("plant.k") and k[7:].isdigit() and cfg.values[k]]
    if f0 is None or not keys:
        return cfg
    # d ln f / d ln k of each stiffness, by a 1 % step: the most sensitive one carries the match
    sens = {k: math.log(nearest(cfg.with_values({k: cfg[k] * 1.01})) / f0) / math.log(1.01) for k in keys}
    key = max(sens, key=lambda k: abs(sens[k]))
    if abs(sens[key]) < 1e-3:
        return cfg
    out, f = cfg, f0
    for _ in range(4):                        # Newton on ln k: f ~ k^sens near the model
        if abs(math.log(f_meas / f)) < 1e-4:
            break
        out = out.with_values({key: out[key] * (f_meas / f) ** (1 / sens[key])})
        f = nearest(out)
    return out


def tip_mode(modes: list) -> dict | None:
    """The mode the tool tip rings in: the lowest fitted in the tip's response, else the lowest."""
    tip = [m for m in modes if m.get("response") == "tip"]
    pool = tip or list(modes)
    return min(pool, key=lambda m: m["measured"]["frequency_hz"]) if pool else None


def tip_settle_time(t, x_tip, target: float, tol: float, hold: float = HOLD) -> float:
    """When the tip is within ``tol`` of ``target`` for good (s after ``t[0]``): the first sample
    after the last one outside, provided the record stays inside for at least ``hold`` seconds
    after it (inf otherwise: a tip that passes through the band at the record's end has not
    arrived)."""
    t = np.asarray(t, float)
    out = np.abs(np.asarray(x_tip, float) - target) > tol
    k = np.flatnonzero(out)
    if not k.size:
        return 0.0
    if k[-1] + 1 >= t.size or t[-1] - t[k[-1] + 1] < hold:
        return math.inf
    return float(t[k[-1] + 1] - t[0])


def _stiffer(cfg, scale: float):
    """``cfg`` with every mode of the plant ``scale`` times its frequency: each stiffness by
    scale^2, each damping constant by scale (damping ratios kept)."""
    changes = {}
    for k, v in cfg.values.items():
        if v is None or not k.startswith("plant."):
            continue
        name = k.split(".", 1)[1]
        if name[:1] == "k" and name[1:].isdigit():
            changes[k] = v * scale ** 2
        elif name[:1] == "c" and name[1:].isdigit():
            changes[k] = v * scale
    return cfg.with_values(changes) if changes else cfg


def command_trajectory(stroke: float, feed: float, t_acc: float, g0: float, dwell: float, shaper: Shaper | None):
    """The move of ``stroke`` at ``feed`` (SI) with the NC acceleration time ``t_acc`` and the rapid
    ``g0``, then ``dwell``, through ``shaper`` (None: unshaped): what :func:`choose_command` tries
    and the verification move runs."""
    from hil.profiles import MoveSpec, Trajectory
    tr = Trajectory()
    tr.move(MoveSpec(stroke, feed, t_acc=t_acc, g0=g0))
    tr.dwell(dwell)
    return shaped(tr, shaper)


def choose_command(cfg, mode: dict | None, stroke: float, feed: float, tol: float, dwell: float,
                   progress=None, least_error: float = MIN_MODE_ERROR) -> tuple[list[Candidate], Candidate | None, float]:
    """Every NC acceleration time of :data:`T_ACC` the limits allow, unshaped and through each
    shaper for ``mode`` (none without a mode), run on the model of ``cfg`` with the mode where it
    was measured (:func:`matched`), and with its modes :func:`mode_error` away either side; the candidates, the one whose tip is within ``tol``
    earliest in the worst case (None: none is), and the mode error used."""
    from hil.profiles import AxisLimits, LimitError, check_limits
    from hil.simulate import simulate_config
    limits = AxisLimits.from_config(cfg)
    g0 = cfg.get("nc.g0") or limits.speed
    eps = mode_error(mode, least_error) if mode else 0.0
    shapers = [None] + ([Shaper.design(k, mode["measured"]["frequency_hz"], mode["measured"]["damping_ratio"])
                         for k in ALL_KINDS] if mode else [])
    centre = matched(cfg, mode) if mode else cfg
    plants = [centre] + ([_stiffer(centre, 1 - eps), _stiffer(centre, 1 + eps)] if mode else [])
    tp = cfg["control.position_period"]
    out = []
    for i, t_acc in enumerate(T_ACC):
        for sh in shapers:
            traj = command_trajectory(stroke, feed, t_acc, g0, dwell, sh)
            try:
                check_limits(traj, limits)
            except LimitError:
                continue
            t, x = traj.sample(tp)
            times = [tip_settle_time(t, simulate_config(c, x).channels()["x_tip"], x[-1], tol) for c in plants]
            out.append(Candidate(t_acc, sh, times[0], max(times), traj.moves[0].duration + (sh.duration if sh else 0)))
        if progress is not None:
            progress((i + 1) / len(T_ACC))
    finite = [c for c in out if math.isfinite(c.settle_worst_s)]
    choice = min(finite, key=lambda c: (c.settle_worst_s, c.settle_s)) if finite else None
    return out, choice, eps
