"""Fitting plant effects to a measurement and ranking the candidates (``hil diagnose``, ``hil fit``).

The measured command is replayed through the model (hil.compare.Replay). For a candidate effect
its parameters are fitted by :func:`scipy.optimize.least_squares` on the residuals of every
measured channel (x_motor, x_table, x_tip, torque or force), each channel weighted by the inverse
of its residual RMS before the fit so that no unit dominates.

Model choice: the Gaussian log-likelihood with one unknown variance per channel gives
BIC = N ln(SSR / N) + k ln N per channel. Replay residuals are strongly correlated in time (a
missing effect leaves a smooth error), so N is the *effective* number of independent samples of
the residual after the fit, N / (1 + 2 sum rho_k) (:func:`effective_samples`). The score of a
candidate is BIC(before) - BIC(after) (higher is better, :func:`bic_score`); it is significant
when the score exceeds :data:`MIN_SCORE` (6: strong evidence) and the channel's error before the
fit stands above its noise floor (the residual's third difference). Otherwise the verdict is
``"none"``: no significant missing effect. Ranking prefers a simpler catalogue effect nested in
a richer one (coulomb_friction inside asymmetric_friction) unless the richer one's score is higher
by more than :data:`MIN_SCORE` (the same criterion: its extra parameters must pay for themselves).

:func:`idim_ls` is the inverse-model least-squares fit (IDIM-LS) of a rigid axis on its force
channel: a linear regression that gives starting values for the output-error fits.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from sim_plant.effects import CATALOGUE, Combination, Effect

from hil.ident.replay import Replay, noise_floor, periodic_in_position, spectrum_peaks
from hil.plant_config import candidate, default_parameters

__all__ = ["Candidate", "fit_effects", "diagnose", "MIN_SCORE", "bic_score", "effective_samples", "idim_ls"]

MIN_SCORE = 6.0          # a BIC difference above 6: "strong" evidence (Kass and Raftery)
SIGNIFICANT_ABOVE_NOISE = 1.2
EXPLAINED = 0.8          # a combination of simpler effects explaining this share of a richer one's gain goes first


@dataclass
class Candidate:
    effect: str
    params: dict
    channel: str
    error_before: float
    error_after: float
    score: float
    evidence: str
    gain: float = 0.0            # fraction of the weighted residual energy removed
    significant: bool = False
    cfg: object = None
    errors_after: dict = field(default_factory=dict)
    nfev: int = 0
    res: dict = field(default=None, repr=False)     # residuals after the fit (for pairwise comparisons)

    def as_json(self) -> dict:
        return {"effect": self.effect, "params": {k: float(v) for k, v in self.params.items()},
                "channel": self.channel, "error_before": float(self.error_before),
                "error_after": float(self.error_after), "score": float(self.score), "evidence": self.evidence,
                "gain": float(self.gain), "significant": bool(self.significant)}


class _Objective:
    """Weighted residual vector of a config (the replay's channels)."""

    def __init__(self, replay: Replay, weights: dict[str, float]):
        self.replay = replay
        self.weights = weights

    def residuals(self, cfg) -> dict[str, np.ndarray]:
        return self.replay.residuals(cfg)

    def vector(self, res: dict) -> np.ndarray:
        return np.concatenate([res[c] * self.weights[c] for c in self.weights])


def _neg2loglik(res: dict, chans) -> float:
    tot = 0.0
    for c in chans:
        r = res[c]
        tot += r.size * math.log(max(float(np.mean(r * r)), 1e-300))
    return tot


def effective_samples(r) -> float:
    """Effective number of independent samples of a residual: N / (1 + 2 sum rho_k), the sum of
    its autocorrelation over the lags up to the first that is not positive (Bartlett/Bayley-Hammersley).
    A white residual keeps N; a smooth one (a model error) keeps about one sample per correlation time."""
    r = np.asarray(r, float) - np.mean(r)
    n = r.size
    if n < 8 or not np.any(r):
        return float(n)
    m = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(r, m)
    ac = np.fft.irfft(f * np.conj(f), m)[:n // 2]
    ac = ac / ac[0]
    neg = np.flatnonzero(ac[1:] <= 0.0)
    k = int(neg[0]) + 1 if neg.size else ac.size
    tau = 1.0 + 2.0 * float(np.sum(ac[1:k]))
    return float(min(n, max(1.0, n / max(tau, 1.0))))


def bic_score(res0: dict, res1: dict, chans, n_params: int, floor: dict | None = None) -> float:
    """BIC(before) - BIC(after) with one unknown variance per channel, counted on the effective
    number of independent samples of the residual after the fit (see :func:`effective_samples`):
    sum_c N_eff,c ln(SSR0_c / SSR1_c) - k ln(sum_c N_eff,c). Replay residuals are correlated in
    time; counting every sample as independent would rate any small gain as significant. A
    residual variance below the channel's noise floor (``floor``, RMS) counts as the floor: fitting
    the sensor noise is no evidence."""
    tot, n_eff = 0.0, 0.0
    floor = floor or {}
    for c in chans:
        ne = effective_samples(res1[c])
        f2 = float(floor.get(c, 0.0)) ** 2
        s0 = max(float(np.mean(res0[c] ** 2)), f2, 1e-300)
        s1 = max(float(np.mean(res1[c] ** 2)), f2, 1e-300)
        tot += ne * math.log(s0 / s1)
        n_eff += ne
    return tot - n_params * math.log(max(n_eff, 2.0))


def _scales(replay: Replay, res0: dict) -> dict:
    """Typical magnitudes of the record for starting guesses (SI)."""
    m = replay.meas
    v = np.gradient(m["x_cmd"], m.t)
    sc = {"speed": float(np.percentile(np.abs(v), 90)) or 1e-3, "period": replay.sample_period}
    fch = replay.force_channel
    if fch is not None:
        sc["force"] = max(float(np.sqrt(np.mean(res0[fch] ** 2))) * replay.force_to_load, 1e-6)
    else:
        a = np.gradient(v, m.t)
        sc["force"] = 0.05 * replay.plant.total_mass * float(np.sqrt(np.mean(a * a))) + 1e-6
    return sc


def _param_scale(p, g):
    if g != 0.0 and math.isfinite(g):
        return abs(g)
    span = p.upper - p.lower
    return max(abs(p.upper), abs(p.lower), 1e-12) * 1e-3 if not math.isfinite(span) else span * 1e-3


def _fit_one(obj: _Objective, base_cfg, eff: Effect, starts: list[dict], max_nfev: int = 40,
             fixed: dict | None = None):
    """Least squares from each start; returns (values, cfg, residuals, nfev) of the best."""
    best = None
    total = 0
    names = [p.name for p in eff.params]
    for start in starts:
        scale = np.array([_param_scale(p, start[p.name]) for p in eff.params])
        lo = np.array([p.lower for p in eff.params]) / scale
        hi = np.array([p.upper for p in eff.params]) / scale
        z0 = np.clip(np.array([start[n] for n in names]) / scale, lo + 1e-12 * abs(lo), hi - 1e-12 * abs(hi))

        def fun(z):
            vals = dict(zip(names, z * scale))
            try:
                cfg = eff.configure(base_cfg, vals)
                return obj.vector(obj.residuals(cfg))
            except (ValueError, ZeroDivisionError, FloatingPointError):
                return np.full(obj.n, 1e3)
        try:
            sol = least_squares(fun, z0, bounds=(lo, hi), diff_step=1e-3, max_nfev=max_nfev, x_scale=1.0,
                                xtol=1e-5, ftol=1e-5)
        except ValueError:
            continue
        total += sol.nfev * (1 + len(names))
        cost = float(sol.cost)
        if best is None or cost < best[0]:
            best = (cost, dict(zip(names, (sol.x * scale).tolist())))
    if best is None:
        raise ValueError(f"{eff.name}: no start could be fitted")
    vals = best[1]
    cfg = eff.configure(base_cfg, vals)
    return vals, cfg, obj.residuals(cfg), total


def _starts(eff: Effect, replay: Replay, res0: dict, scale: dict, cfg) -> list[dict]:
    g = eff.guess(replay.plant, scale)
    g = {p.name: g.get(p.name, p.guess) for p in eff.params}
    if eff.name in ("pitch_error", "torque_ripple"):
        starts = []
        chan = "x_motor-x_table" if eff.name == "pitch_error" and "x_table" in res0 and "x_motor" in res0 else None
        r = (res0["x_motor"] - res0["x_table"]) if chan else res0[replay.primary_channel(res0)]
        found = periodic_in_position(replay.meas["x_cmd"], r, replay.meas.t, n=2)
        periods = [p for p, _, _ in found] + [g["period"]]
        for per in periods:
            for ph in (0.0, math.pi / 2, math.pi, -math.pi / 2):
                starts.append(dict(g, period=per, phase=ph))
        return _prefilter(eff, replay, starts, cfg)
    if eff.name == "compliant_mode":
        return _prefilter(eff, replay, _mode_starts(eff, replay, res0, g), cfg)
    if eff.name == "time_delay":
        return [g, dict(g, delay=4 * g["delay"])]
    reg = _regression_start(eff, replay, res0)
    return [reg, g] if reg else [g]


def _regression_start(eff: Effect, replay: Replay, res0: dict) -> dict | None:
    """Starting values of the friction and force effects from a linear regression of the force
    residual while moving: residual = Fc sign(v) + c v + f0 (or per direction for
    asymmetric_friction), v the commanded velocity. The replayed axis follows its command closely,
    so the missing force shows almost unchanged in the force channel; None without one."""
    fch = replay.force_channel
    names = [m.name for m in eff.members] if isinstance(eff, Combination) else [eff.name]
    known = ("coulomb_friction", "constant_force", "asymmetric_friction", "viscous_friction")
    if fch is None or not all(n in known for n in names):
        return None
    m = replay.meas
    v = np.gradient(m["x_cmd"], m.t)
    moving = np.abs(v) > 0.02 * max(float(np.max(np.abs(v))), 1e-12)
    if moving.sum() < 16:
        return None
    vm, r = v[moving], res0[fch][moving]
    pos = (vm > 0).astype(float)
    X = np.column_stack([pos, -(1 - pos), vm * pos, vm * (1 - pos), np.ones(vm.size)])
    coef, *_ = np.linalg.lstsq(np.column_stack([np.sign(vm), vm, np.ones(vm.size)]), r, rcond=None)
    cp, *_ = np.linalg.lstsq(X[:, :4], r, rcond=None)
    plant, cfg = replay.plant, replay.cfg
    sp = plant.speed_scale                       # rad/s (rotary) or m/s per m/s of the load
    c0 = plant.chain.c_ground[0] / (sp * sp)     # the model's viscous coefficient, motor units
    fp = plant.friction.coulomb_pos / sp         # the model's Coulomb levels, motor units
    fn = plant.friction.coulomb_neg / sp
    f0 = float(cfg.get("effects.constant_force.force", 0.0) or 0.0)
    cv = float(cfg.get("effects.viscous_friction.coefficient", 0.0) or 0.0)
    # what the model has plus what the residual asks for; the force channel is in motor units
    # (torque on a rotary axis): a load-side force is that times force_to_load
    vals = {"coulomb_friction": {"level": max(0.5 * (fp + fn) + float(coef[0]), 0.0)},
            "constant_force": {"force": f0 - float(coef[2]) * replay.force_to_load},
            "viscous_friction": {"coefficient": cv + float(coef[1]) / sp},
            "asymmetric_friction": {"level_pos": max(fp + float(cp[0]), 0.0), "level_neg": max(fn + float(cp[1]), 0.0),
                                    "viscous_pos": max(c0 + float(cp[2]) / sp, 0.0),
                                    "viscous_neg": max(c0 + float(cp[3]) / sp, 0.0)}}
    if isinstance(eff, Combination):
        return {f"{n}.{k}": v for n in names for k, v in vals[n].items()}
    return vals[eff.name]


def _mode_starts(eff, replay, res0, g) -> list[dict]:
    """Starts of an added mode. Coupled to the chain, the new mode does not show at its own
    frequency: the measured resonances move. So for each modal mass on a grid (relative to the
    tip mass) solve for the natural frequency that puts one of the coupled chain's modes on a
    peak of the residual spectrum (the strongest channel, weighted), with a low damping."""
    fmax = 0.45 / replay.sample_period
    w = replay.objective.weights
    chan = max((c for c in res0 if c in w), key=lambda c: float(np.mean(res0[c] ** 2)) * w[c] ** 2)
    peaks = [f for f, _ in spectrum_peaks(res0[chan], replay.sample_period, n=6) if 0.5 < f < fmax]
    targets = list(dict.fromkeys(round(f, 2) for f in peaks))[:2] or [g["frequency"]]
    plant = replay.plant
    m_tip = plant.chain.m[plant.tip]
    f_grid = np.geomspace(0.5, fmax, 240)
    starts = []
    for ratio in (0.05, 0.15, 0.5, 1.5):
        m = ratio * m_tip
        for ft in targets:
            best = None
            for fn in f_grid:
                ch = eff.apply(plant, {"mass": m, "frequency": fn, "damping_ratio": 0.0}).chain
                ev = np.linalg.eigvals(np.linalg.solve(ch.M, ch.K)).real
                fm = np.sqrt(np.maximum(ev, 0.0)) / (2 * np.pi)
                d = float(np.min(np.abs(fm - ft))) / ft
                if best is None or d < best[0]:
                    best = (d, fn)
            if best[0] < 0.03:
                starts.append({"mass": m, "frequency": float(best[1]), "damping_ratio": 0.01})
        starts.append({"mass": m, "frequency": targets[0], "damping_ratio": 0.01})
    return starts


def _prefilter(eff, replay, starts, cfg, keep=2):
    """Keep the few starts with the lowest cost (one simulation each)."""
    obj = replay.objective
    costs = []
    for s in starts:
        try:
            costs.append(float(np.sum(obj.vector(obj.residuals(eff.configure(cfg, s))) ** 2)))
        except ValueError:
            costs.append(math.inf)
    order = np.argsort(costs)[:keep]
    return [starts[i] for i in order]


def _evidence(eff_name: str, vals: dict, replay: Replay, res0: dict, chan: str, before: float, after: float,
              base_modes) -> str:
    unit = replay.unit(chan)
    fall = f"RMS {chan} error {before:.3g} -> {after:.3g} {unit} ({100 * (1 - after / before) if before else 0:.0f} % less)"
    if "+" in eff_name:
        # a combination: each member's evidence, then the fall of the joint fit
        heads = []
        for m, v in zip(eff_name.split("+"), candidate(eff_name).split(vals)):
            h = _evidence(m, v, replay, res0, chan, before, after, base_modes)
            heads.append(h[:-len(fall)].rstrip("; ") if h.endswith(fall) and h != fall else "")
        return "; ".join([h for h in heads if h] + [fall])
    m = replay.meas
    v = np.gradient(m["x_cmd"], m.t)
    moving = np.abs(v) > 0.02 * np.max(np.abs(v))
    fch = replay.force_channel
    rf = res0.get(fch) if fch else None
    fu = replay.unit(fch) if fch else ""
    if eff_name in ("coulomb_friction", "stribeck_friction", "asymmetric_friction", "constant_force",
                    "viscous_friction") and rf is not None:
        X = np.column_stack([np.sign(v[moving]), v[moving], np.ones(moving.sum())])
        coef, *_ = np.linalg.lstsq(X, rf[moving], rcond=None)
        pos, neg = rf[moving & (v > 0)], rf[moving & (v < 0)]
        if eff_name == "constant_force":
            return f"{fch} residual has a mean of {coef[2]:.3g} {fu} in both directions; " + fall
        if eff_name == "viscous_friction":
            return f"{fch} residual grows with velocity, {coef[1]:.3g} {fu} per m/s; " + fall
        if eff_name == "asymmetric_friction":
            vm = v[moving]
            p = (vm > 0).astype(float)
            cp, *_ = np.linalg.lstsq(np.column_stack([p, 1 - p, vm * p, vm * (1 - p)]), rf[moving], rcond=None)
            return (f"{fch} residual differs per direction: level {cp[0]:.3g} {fu} and slope {cp[2]:.3g} {fu} per m/s "
                    f"moving +, level {cp[1]:.3g} {fu} and slope {cp[3]:.3g} {fu} per m/s moving -; " + fall)
        return f"{fch} residual follows sign(v), {abs(coef[0]):.3g} {fu}; " + fall
    if eff_name in ("pitch_error", "torque_ripple"):
        r = res0["x_motor"] - res0["x_table"] if (eff_name == "pitch_error" and "x_table" in res0) else res0[chan]
        what = "x_motor - x_table" if eff_name == "pitch_error" and "x_table" in res0 else chan
        per = vals.get("period", 0.0)
        return f"{what} residual periodic in position with period {per * 1e3:.3g} mm; " + fall
    if eff_name == "compliant_mode":
        f = vals.get("frequency", 0.0)
        near = [fm for fm in base_modes if abs(fm - f) < 0.1 * f]
        tail = "not a mode of the model" if not near else f"near the model's {near[0]:.1f} Hz mode"
        return f"residual peak at {f:.1f} Hz in {chan}, {tail}; " + fall
    if eff_name == "backlash":
        return (f"x_motor - x_table jumps by about {vals.get('gap', 0) * 1e6:.3g} um at reversals; " + fall)
    if eff_name == "time_delay":
        return f"residual correlates with the command shifted by {vals.get('delay', 0) * 1e3:.3g} ms; " + fall
    if eff_name == "mass_change":
        return f"{chan} residual follows the acceleration: {vals.get('mass', 0):+.3g} kg on the table; " + fall
    if eff_name.startswith("parameter:"):
        key = eff_name.split(":", 1)[1]
        old = replay.cfg.get(key)
        return f"{key} {old:.4g} -> {vals.get('value', 0):.4g} explains the {chan} residual; " + fall
    return fall


def _model_modes(cfg):
    try:
        from hil.plant_config import plant_from_config
        pl = plant_from_config(cfg)
        w = np.sqrt(np.maximum(np.linalg.eigvals(np.linalg.solve(pl.chain.M, pl.chain.K)).real, 0))
        return sorted(float(x / (2 * np.pi)) for x in w if x > 1e-6)
    except Exception:  # noqa: BLE001 - evidence text only
        return []


def evaluate(replay: Replay, name: str, res0: dict | None = None, max_nfev: int = 40,
             start: dict | None = None, n_starts: int = 2) -> Candidate:
    """Fit one candidate (catalogue name or parameter:<key>) and score it: from ``start`` when
    given (a screened fit to refine), else from the ``n_starts`` best of its starting guesses."""
    cfg = replay.cfg
    res0 = res0 if res0 is not None else replay.residuals(cfg)
    eff = candidate(name, cfg)
    if not eff.applicable(replay.plant):
        raise ValueError(f"{name}: not applicable to this plant")
    obj = replay.objective
    scale = _scales(replay, res0)
    starts = [dict(start)] if start else _starts(eff, replay, res0, scale, cfg)[:max(1, n_starts)]
    vals, cfg1, res1, nfev = _fit_one(obj, cfg, eff, starts, max_nfev=max_nfev)
    chans = list(obj.weights)
    score = bic_score(res0, res1, chans, len(eff.params), replay.noise)
    e0 = float(np.sum(obj.vector(res0) ** 2))
    e1 = float(np.sum(obj.vector(res1) ** 2))
    gain = 1.0 - e1 / e0 if e0 > 0 else 0.0
    # the channel where it shows: the largest relative fall
    rel = {c: 1 - math.sqrt(np.mean(res1[c] ** 2) / max(np.mean(res0[c] ** 2), 1e-300)) for c in chans}
    chan = max(rel, key=rel.get)
    before = float(np.sqrt(np.mean(res0[chan] ** 2)))
    after = float(np.sqrt(np.mean(res1[chan] ** 2)))
    floor = replay.noise[chan]
    significant = score > MIN_SCORE and before > SIGNIFICANT_ABOVE_NOISE * floor
    ev = _evidence(name, vals, replay, res0, chan, before, after, _model_modes(cfg))
    return Candidate(name, vals, chan, before, after, float(score), ev, gain, significant, cfg1,
                     {c: float(np.sqrt(np.mean(res1[c] ** 2))) for c in chans}, nfev, res1)


def candidate_names(cfg, plant, include_parameters: bool = True) -> list[str]:
    names = [n for n, e in CATALOGUE.items() if e.applicable(plant)]
    if include_parameters:
        names += default_parameters(cfg)
    return names


def _close(simple: Candidate, rich: Candidate, tol: float = 0.05) -> bool:
    """The simpler fit leaves no more than ``tol`` more RMS error than the richer one in every
    channel: the richer one's BIC lead is then the fits' convergence (stick-slip makes the cost
    rough), not the data."""
    return bool(simple.errors_after) and all(
        simple.errors_after[c] <= (1 + tol) * rich.errors_after.get(c, 0.0) for c in simple.errors_after)


def _rank(cands: list[Candidate], combos: list | None = None, floor=None):
    """The candidates best first, and the combination that leads the ranking (or None).

    A combination of simpler effects is preferred over the richer effect it mimics when its score is
    not lower by more than :data:`MIN_SCORE` (the richer effect's extra parameters do not pay for
    themselves) or it leaves no more error (:func:`_close`); a preferred combination takes the
    richer effect's place if that is higher, and stands in the ranking for its leading member (the
    one whose removal costs the most)."""
    entries = _rank_single(list(cands) + [c for c in combos or () if _prefer(c, floor=floor)])
    out, lead = [], None
    for e in entries:
        if isinstance(e, Combo):
            if lead is None and not out:
                lead = e
            single = next((c for c in cands if c.effect == e.leader), None)
            if single is not None and single not in out:
                rest = [m["effect"] for m in e.members if m["effect"] != e.leader]
                single.evidence += (f"; with {' and '.join(rest)} it explains {100 * e.explained:.0f} % of the gain of "
                                    f"{e.rich.effect} (whose remainder scores {e.pair:.1f}: judged once these are fitted)")
                out.append(single)
        elif e not in out:
            out.append(e)
    return out, lead


def pair_score(simple: Candidate, rich: Candidate, chans, floor=None) -> float:
    """The same BIC score between two fits: the richer model against the simpler one (its residual
    as "before", the extra parameters as the penalty). Each candidate's own score counts the
    effective samples of its own residual; comparing two scores would reward a whiter residual
    twice."""
    k = len(candidate(rich.effect).params) - len(candidate(simple.effect).params)
    return bic_score(simple.res, rich.res, chans, max(k, 0), floor)


def _log_fall(c: Candidate) -> float:
    """ln(weighted error before / after) of a fit."""
    return math.log(max(1.0 / max(1.0 - c.gain, 1e-300), 1.0))


def _prefer(combo, chans=None, floor=None) -> bool:
    """Whether the combination of simpler effects is named before the richer effect it mimics.

    Marginality (lower-order terms first, as in hierarchical regression): asymmetric friction is
    Coulomb friction and an offset plus a direction-dependent remainder; the remainder is only judged
    once the lower-order terms are in the model. So a significant combination is named first when
    the richer effect's extra parameters do not pay against it (their BIC score against the
    combination, :func:`pair_score`, at most :data:`MIN_SCORE`), or when it accounts for at least
    :data:`EXPLAINED` of the richer effect's fall of the log weighted error; the richer effect's
    score against the combination is reported, and the next diagnosis (with the combination fitted)
    judges the remainder by the same criterion."""
    combo.explained = _log_fall(combo.cand) / _log_fall(combo.rich) if _log_fall(combo.rich) > 0 else 1.0
    if combo.cand.res is not None and combo.rich.res is not None:
        combo.pair = pair_score(combo.cand, combo.rich, chans or list(combo.cand.res), floor)
        pays = combo.pair > MIN_SCORE
    else:
        pays = combo.rich.score - combo.score > MIN_SCORE
    combo.preferred = bool(combo.significant and (not pays or combo.explained >= EXPLAINED
                                                  or _close(combo.cand, combo.rich)))
    return combo.preferred


def _rank_single(cands: list) -> list:
    # best score first; the same fit twice (mass_change is parameter:plant.m<table> by another name)
    # puts the catalogue effect, which names the physics, before the parameter
    cands = sorted(cands, key=lambda c: -c.score)
    for i in range(len(cands) - 1):
        a, b = cands[i], cands[i + 1]
        if a.effect.startswith("parameter:") and not b.effect.startswith("parameter:") \
                and abs(a.score - b.score) <= 1e-4 * abs(a.score) + 0.05:
            cands[i], cands[i + 1] = b, a
    # a preferred combination before the richer effect it mimics
    for c in [c for c in cands if isinstance(c, Combo)]:
        i, j = cands.index(c.rich), cands.index(c)
        if j > i:
            cands.insert(i, cands.pop(j))
    # a simpler nested effect first when it explains most of the richer one's gain
    changed = True
    while changed:
        changed = False
        for i in range(len(cands)):
            for j in range(i + 1, len(cands)):
                rich, simple = cands[i], cands[j]
                if isinstance(rich, Combo) or isinstance(simple, Combo):
                    continue
                eff = CATALOGUE.get(rich.effect)
                if eff and simple.effect in getattr(eff, "nests", ()) and simple.significant \
                        and (rich.score - simple.score < MIN_SCORE or _close(simple, rich)):
                    cands.insert(i, cands.pop(j))
                    changed = True
                    break
            if changed:
                break
    return cands


def diagnose(replay: Replay, names: list[str] | None = None, progress=None, max_nfev: int = 30,
             jobs: int | None = None, screen_nfev: int = 6, refine: int = 3) -> dict:
    """Try every candidate; returns {"candidates": [...ranked Candidate], "verdict": name | "none",
    "noise_floor": {...}, "error_before": {...}}.

    Every candidate is first fitted briefly (``screen_nfev`` evaluations), then the ``refine``
    best are fitted fully (``max_nfev``); ``jobs`` processes share the work (default: the CPUs)."""
    cfg = replay.cfg
    res0 = replay.residuals(cfg)
    names = names or candidate_names(cfg, replay.plant)
    jobs = jobs or os.cpu_count() or 1
    # the costly candidates first, so that the processes finish together
    names = sorted(names, key=lambda n: -_cost_hint(n, cfg))
    out = [c for c in _map(replay, [(n, screen_nfev, None, 1) for n in names], res0, jobs, progress)
           if c is not None]
    ranked = sorted(out, key=lambda c: -c.score)
    top = [c.effect for c in ranked[:refine]]
    # and the simpler effects nested in those, so that the ranking compares refined fits
    for c in list(top):
        top += [n for n in getattr(CATALOGUE.get(c), "nests", ()) if n in names and n not in top]
    by_name = {c.effect: c for c in out}
    if top and max_nfev > screen_nfev:
        work = [(n, max_nfev, by_name[n].params, 1) for n in top]
        better = {c.effect: c for c in _map(replay, work, res0, jobs, progress) if c is not None}
        out = [better.get(c.effect, c) if better.get(c.effect, c).score >= c.score else c for c in out]
    combos = _combinations(replay, out, res0, jobs, progress, max_nfev, refine)
    ranked, lead = _rank(out, combos, replay.noise)
    also = []
    if lead is not None:
        verdict = lead.leader if lead.significant else "none"
        also = [m for m in lead.members if m["effect"] != lead.leader and m["significant"]] if lead.significant else []
    else:
        verdict = ranked[0].effect if ranked and ranked[0].significant else "none"
    return {"candidates": ranked, "verdict": verdict, "also_missing": also,
            "combinations": [c.as_json() for c in combos], "noise_floor": dict(replay.noise),
            "error_before": {c: float(np.sqrt(np.mean(res0[c] ** 2))) for c in replay.objective.weights}}


@dataclass
class Combo:
    """A combination of simpler catalogue effects fitted jointly against the richer effect it can
    mimic (``Effect.mimicked_by``): its candidate (scored like any other), the richer one, and per
    member its marginal score (the BIC score of the joint fit against the fit without that member)."""
    cand: Candidate
    rich: Candidate
    members: list            # [{"effect", "params", "score" (marginal), "significant", "evidence"}]
    leader: str = ""
    preferred: bool = False
    pair: float = math.nan   # BIC score of the richer effect against the combination
    explained: float = math.nan   # the combination's share of the richer effect's fall of the log error

    @property
    def score(self):
        return self.cand.score

    @property
    def effect(self):
        return self.cand.effect

    @property
    def significant(self):
        return self.cand.significant

    def as_json(self) -> dict:
        return {"effects": [m["effect"] for m in self.members], "explains": self.rich.effect,
                "preferred": bool(self.preferred), "score": float(self.cand.score),
                "rich_against_combination": float(self.pair), "explained": float(self.explained),
                "rich_score": float(self.rich.score), "params": {k: float(v) for k, v in self.cand.params.items()},
                "channel": self.cand.channel, "error_before": float(self.cand.error_before),
                "error_after": float(self.cand.error_after), "evidence": self.cand.evidence,
                "members": [{k: (float(v) if isinstance(v, float) else v) for k, v in m.items()} for m in self.members]}


def _combinations(replay, out, res0, jobs, progress, max_nfev, refine) -> list[Combo]:
    """Fit jointly the combinations of simpler effects that can mimic a significant richer effect
    among the best ``refine``, when every member was a candidate; their members' single fits give the
    starting values and the fits without each member (for the marginal scores)."""
    by_name = {c.effect: c for c in out}
    work, rich_of = [], {}
    for c in sorted(out, key=lambda c: -c.score)[:max(refine, 1)]:
        if not c.significant:
            continue
        for combo in getattr(CATALOGUE.get(c.effect), "mimicked_by", ()):
            if not all(m in by_name for m in combo):
                continue
            name = "+".join(combo)
            if name in rich_of:
                continue
            start = {f"{m}.{k}": v for m in combo for k, v in by_name[m].params.items()}
            rich_of[name] = c
            work.append((name, max_nfev, start, 1))
    if not work:
        return []
    fits = [c for c in _map(replay, work, res0, jobs, progress) if c is not None]
    chans = list(replay.objective.weights)
    combos = []
    for fc in fits:
        eff = candidate(fc.effect, replay.cfg)
        res1 = replay.residuals(fc.cfg)
        members = []
        for m, vals in zip(eff.members, eff.split(fc.params)):
            others = [o.name for o in eff.members if o is not m]
            if len(others) == 1:
                without = by_name[others[0]]
            else:
                without = evaluate(replay, "+".join(others), res0, max_nfev,
                                   start={k: v for k, v in fc.params.items() if not k.startswith(m.name + ".")})
            sc = bic_score(replay.residuals(without.cfg), res1, chans, len(m.params), replay.noise)
            members.append({"effect": m.name, "params": vals, "score": float(sc), "significant": sc > MIN_SCORE,
                            "evidence": _evidence(m.name, vals, replay, res0, fc.channel, fc.error_before,
                                                  fc.error_after, [])})
        lead = max(members, key=lambda d: d["score"])["effect"]
        combos.append(Combo(fc, rich_of[fc.effect], members, lead))
    return combos


def _safe_eval(replay, res0, name, max_nfev, start=None, n_starts=2):
    try:
        return evaluate(replay, name, res0, max_nfev, start, n_starts)
    except ValueError:
        return None


_WORK = {}


def _cost_hint(name, cfg) -> float:
    try:
        eff = candidate(name, cfg)
    except KeyError:
        return 0.0
    return (1 + len(eff.params)) * (3 if (eff.periodic or name == "compliant_mode") else 1)


def _work(args):
    c = _safe_eval(_WORK["replay"], _WORK["res0"], *args)
    if c is not None:
        c.cfg = None            # configs stay in the parent (rebuilt there)
    return c


def _map(replay, work, res0, jobs, progress):
    """Evaluate the (name, max_nfev, start, n_starts) items, in ``jobs`` processes."""
    if jobs > 1 and len(work) > 1:
        import multiprocessing as mp
        try:
            ctx = mp.get_context("fork")
        except ValueError:
            ctx = None
        if ctx is not None:
            _WORK.update(replay=replay, res0=res0)
            out = []
            with ctx.Pool(min(jobs, len(work))) as pool:
                for c in pool.imap(_work, work):
                    if progress:
                        progress(c.effect if c else "?")
                    if c is not None:
                        c.cfg = candidate(c.effect, replay.cfg).configure(replay.cfg, c.params)
                    out.append(c)
            _WORK.clear()
            return out
    out = []
    for item in work:
        if progress:
            progress(item[0])
        out.append(_safe_eval(replay, res0, *item))
    return out


def fit_effects(replay: Replay, names: list[str], max_nfev: int = 60, progress=None):
    """Add the effects one after the other, each fitted on top of the previous ones (greedy).
    Returns the final config and a list of (name, params, errors) steps."""
    steps = []
    cur = replay
    for name in names:
        if progress:
            progress(name)
        c = evaluate(cur, name, max_nfev=max_nfev)
        steps.append(c)
        cur = cur.with_config(c.cfg)
    if len(names) > 1 and len(set(names)) == len(names):
        # then all of them together from the greedy values: the greedy fit of a later effect cannot
        # move the earlier ones (an offset is correlated with the friction levels)
        name = "+".join(names)
        if progress:
            progress(name)
        start = {f"{s.effect}.{k}": v for s in steps for k, v in s.params.items()}
        joint = evaluate(replay, name, max_nfev=max_nfev, start=start)
        obj = replay.objective
        if np.sum(obj.vector(joint.res) ** 2) < np.sum(obj.vector(cur.base_residuals) ** 2):
            steps.append(joint)
            return joint.cfg, steps
    return cur.cfg, steps


def joint_refit(replay: Replay, cfg, keys: list[str], max_nfev: int = 60):
    """Refit several config keys together (after greedy additions), from their current values."""
    obj = replay.objective
    x0 = np.array([float(cfg[k]) for k in keys])
    # steps large enough to see through the stick-slip's non-smoothness
    scale = np.maximum(np.abs(x0), 0.05 * np.max(np.abs(x0)) + 1e-12)

    def fun(z):
        try:
            return obj.vector(obj.residuals(cfg.with_values(dict(zip(keys, (z * scale).tolist())))))
        except ValueError:
            return np.full(obj.n, 1e3)
    sol = least_squares(fun, x0 / scale, diff_step=1e-2, max_nfev=max_nfev, xtol=1e-8, ftol=1e-8)
    return cfg.with_values(dict(zip(keys, (sol.x * scale).tolist())))


def idim_ls(t, x, force, *, cutoff: float = 100.0, order: int = 4, decimation: int = 10,
            asymmetric: bool = False) -> dict:
    """Inverse dynamic model, least squares (IDIM-LS, Gautier): the force of a rigid axis,
    ``force = M a + Fv v + Fc sign(v) + offset`` (or with separate levels per direction,
    ``asymmetric``: Fv+, Fv-, Fc+, Fc-, no offset), regressed on the measured position.

    The position is low-pass filtered forward and backward (Butterworth, ``order``, ``cutoff``
    Hz), differentiated by central differences, and the regressors and the force are decimated by
    ``decimation`` (each through scipy.signal.decimate's anti-aliasing filter, zero phase), as in
    the EMPS benchmark's reference recipe. Returns the parameters (SI), the relative 2-norm force
    error % and the condition number of the column-scaled regressor."""
    from scipy.signal import butter, decimate, filtfilt
    t, x, force = (np.asarray(a, float) for a in (t, x, force))
    dt = float(np.median(np.diff(t)))
    b, a = butter(order, cutoff / (0.5 / dt))
    xf = filtfilt(b, a, x)
    v = np.gradient(xf, dt)
    acc = np.gradient(v, dt)
    if asymmetric:
        pos = v > 0
        cols = {"M": acc, "Fv+": v * pos, "Fv-": v * ~pos, "Fc+": pos * 1.0, "Fc-": -1.0 * (v < 0)}
    else:
        cols = {"M": acc, "Fv": v, "Fc": np.sign(v), "offset": np.ones_like(v)}

    def dec(y):
        return decimate(y, decimation, zero_phase=True) if decimation > 1 else y
    X = np.column_stack([dec(c) for c in cols.values()])
    y = dec(force)
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    err = 100.0 * float(np.linalg.norm(y - X @ theta) / np.linalg.norm(y))
    cond = float(np.linalg.cond(X / np.linalg.norm(X, axis=0)))
    return {"params": dict(zip(cols, theta.tolist())), "relative_error": err, "condition": cond}
