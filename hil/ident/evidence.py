"""The evidence of a fitted candidate: what in the residual before the fit points at the effect,
then the fall of the error the fit brought, as one line of text.

Per effect (r the residual before the fit, v the commanded velocity, "moving" |v| > 2 % of
max|v|):

* friction and force effects: the regression of the force residual while moving,
  r = Fc sign(v) + c v + f0 (per direction, level and slope, for asymmetric friction);
* position-periodic effects: the fitted period (x_motor - x_table for a lead error);
* an added mode: its frequency, against the model's modes (the chain's undamped natural
  frequencies sqrt(eig(M^-1 K)) / 2 pi);
* backlash, mass change and ``parameter:<key>``: the fitted value;
* flexible_transmission: the residual's ringing after the record's edges, and the link fitted
  (its own hook, :meth:`hil.sim_plant.effects.FlexibleTransmission.evidence`);
* the delays (actuator_delay, alias time_delay; feedback_delay): the fitted delay in the loop's
  periods, and where it sits;
* channel_skew, tip_skew: the skew in samples, said to be a logging artefact, not physics;
* force_offset, position_offset: the offset, said to be a sensor's, not a load (the force
  residual's mean at rest and moving: a sensor offset is the same in both);
* stiffness_along_travel: k1 and the transmission mode's frequency (hil.sim_plant.modal) at both ends
  of the stretch, and whether the record can see the variation at all: a constant k1 (the best of
  the two end values and their middle) scored against the fit (BIC, hil.ident.scores); when it
  does as well, the variation cannot be seen over the stroke the record covers;
* a combination: each member's evidence, then the fall of the joint fit.

It ends with "RMS <channel> error <before> -> <after> (<fall> % less)", each error in its
engineering unit (hil.units.fmt).
"""
from __future__ import annotations

import math

import numpy as np

from hil.ident.replay import Replay
from hil.ident.scores import MIN_SCORE, bic_score
from hil.plant_config import candidate, configure, plant_from_config
from hil.sim_plant.effects import ALIASES, effect
from hil.sim_plant.modal import transmission_mode
from hil.units import fmt_si

__all__ = ["evidence", "model_modes"]


def evidence(eff_name: str, vals: dict, replay: Replay, res0: dict, chan: str, before: float, after: float,
              base_modes) -> str:
    unit = replay.unit(chan)
    # each figure in its engineering unit (203 um -> 337 nm), hil.units
    fall = (f"RMS {chan} error {fmt_si(before, unit, 3)} -> {fmt_si(after, unit, 3)} "
            f"({100 * (1 - after / before) if before else 0:.0f} % less)")
    if "+" in eff_name:
        # a combination: each member's evidence, then the fall of the joint fit
        heads = []
        for m, v in zip(eff_name.split("+"), candidate(eff_name).split(vals)):
            h = evidence(m, v, replay, res0, chan, before, after, base_modes)
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
        if eff_name == "constant_force":
            return f"{fch} residual has a mean of {fmt_si(coef[2], fu, 3)} in both directions; " + fall
        if eff_name == "viscous_friction":
            return f"{fch} residual grows with velocity, {coef[1]:.3g} {fu} per m/s; " + fall
        if eff_name == "asymmetric_friction":
            vm = v[moving]
            p = (vm > 0).astype(float)
            cp, *_ = np.linalg.lstsq(np.column_stack([p, 1 - p, vm * p, vm * (1 - p)]), rf[moving], rcond=None)
            return (f"{fch} residual differs per direction: level {fmt_si(cp[0], fu, 3)} and slope {cp[2]:.3g} {fu} per m/s "
                    f"moving +, level {fmt_si(cp[1], fu, 3)} and slope {cp[3]:.3g} {fu} per m/s moving -; " + fall)
        return f"{fch} residual follows sign(v), {fmt_si(abs(coef[0]), fu, 3)}; " + fall
    if eff_name in ("pitch_error", "torque_ripple"):
        what = "x_motor - x_table" if eff_name == "pitch_error" and "x_table" in res0 else chan
        per = vals.get("period", 0.0)
        return f"{what} residual periodic in position with period {fmt_si(per, replay.unit('x_motor'), 3)}; " + fall
    if eff_name == "compliant_mode":
        f = vals.get("frequency", 0.0)
        near = [fm for fm in base_modes if abs(fm - f) < 0.1 * f]
        tail = "not a mode of the model" if not near else f"near the model's {near[0]:.1f} Hz mode"
        return f"residual peak at {f:.1f} Hz in {chan}, {tail}; " + fall
    if eff_name == "flexible_transmission":     # its own hook: the ringing after the edges and the link
        return effect(eff_name).evidence(_context(replay, vals, res0, chan)) + fall
    if eff_name == "backlash":
        return (f"x_motor - x_table jumps by about {vals.get('gap', 0) * 1e6:.3g} um at reversals; " + fall)
    name = ALIASES.get(eff_name, eff_name)
    if name == "actuator_delay":
        d, tv = vals.get("delay", 0.0), replay.cfg["control.velocity_period"]
        return (f"the {fch or 'force'} command reaches the motor {d * 1e3:.3g} ms late ({d / tv:.1f} velocity periods "
                f"of {tv * 1e6:.3g} us): a drive's computation and transport delay; " + fall)
    if name == "feedback_delay":
        d, tp = vals.get("delay", 0.0), replay.cfg["control.position_period"]
        fb = "motor" if replay.cfg.get("control.position_feedback") == "motor" else "table"
        return (f"the {fb} position the position loop uses arrives {d * 1e3:.3g} ms late ({d / tp:.2f} position "
                f"periods of {tp * 1e3:.3g} ms; a scale read over a fieldbus); the recorded positions are the true "
                f"ones; " + fall)
    if name in ("channel_skew", "tip_skew"):
        sk = vals.get("skew", 0.0)
        which = "x_tip" if name == "tip_skew" else (fch or "force")
        return (f"a logging artefact, not physics: the {which} channel is recorded {abs(sk) * 1e3:.3g} ms "
                f"({abs(sk) / replay.sample_period:.2f} samples) {'late' if sk >= 0 else 'early'} against the "
                f"others; the model of the axis needs no change; " + fall)
    if name == "force_offset":
        off = vals.get("offset", 0.0)
        still = ~moving
        parts = [f"{float(np.mean(rf[sel])):+.3g} {fu} {what}" for sel, what in ((still, "at rest"), (moving, "moving"))
                 if rf is not None and sel.sum() >= 8]
        # an open-loop record compares no force channel: the offset is in the actuator's unit
        ou = fu or ("N*m" if replay.cfg.rotary else "N")
        sign = "+" if off >= 0 else "-"
        return (f"a sensor offset, not a load: the {fch or ('torque' if replay.cfg.rotary else 'force')} channel "
                f"reads {sign}{fmt_si(abs(off), ou, 3)} more than the "
                f"actuator delivers" + (f" (residual mean {' and '.join(parts)})" if parts else "") +
                "; a load would move the axis and show in the positions, this changes the recorded channel alone; "
                + fall)
    if name == "position_offset":
        return (f"a sensor offset, not a motion: the x_tip channel reads {vals.get('offset', 0.0) * 1e6:+.3g} um "
                f"from the drive's positions, at rest and in motion alike; " + fall)
    if name in ("stiffness_along_travel", "stiffness_along_travel_fixed_fixed"):
        return _stiffness_evidence(name, vals, replay, res0) + fall
    if eff_name == "mass_change":
        return f"{chan} residual follows the acceleration: {vals.get('mass', 0):+.3g} kg on the table; " + fall
    if eff_name.startswith("parameter:"):
        key = eff_name.split(":", 1)[1]
        old = replay.cfg.get(key)
        from hil.config import field_for
        from hil.units import DIMENSIONS, fmt
        f = field_for(key)
        kind = f.kind_for(replay.cfg.values) if f is not None else None
        if isinstance(old, (int, float)) and kind in DIMENSIONS:
            return (f"{key} {fmt(old, kind)} -> {fmt(vals.get('value', 0), kind)} explains the {chan} residual; "
                    + fall)
        return f"{key} {old:.4g} -> {vals.get('value', 0):.4g} explains the {chan} residual; " + fall
    return fall


def _context(replay, vals, res0, chan):
    """What an effect's ``evidence`` hook reads (duck-typed, SI): the fitted values, the plant, the
    record's times and command, and the residual before the fit of the channel where it shows."""
    from types import SimpleNamespace
    return SimpleNamespace(values=vals, plant=replay.plant, t=replay.meas.t, x_cmd=replay.meas["x_cmd"],
                           residual=res0[chan], channel=chan)


def _stiffness_evidence(name, vals, replay, res0) -> str:
    """k1 and the transmission mode at both ends of the stretch (and midway, for a screw held at
    both ends); whether the record sees the change at all."""
    eff = candidate(name)
    cfg = replay.cfg
    x0, x1, k0, k1 = vals["x_start"], vals["x_end"], vals["k_start"], vals["k_end"]
    chain = replay.plant.chain

    def mode(k):
        return transmission_mode(type(chain)(chain.m, (k,) + tuple(chain.k[1:]), chain.c, chain.c_ground))
    kmean = 2.0 / (1.0 / k0 + 1.0 / k1)
    change = 100.0 * (k1 - k0) / kmean
    text = (f"k1 {k0:.4g} N/m with the nut at {x0 * 1e3:.4g} mm, {k1:.4g} N/m at {x1 * 1e3:.4g} mm ({change:+.0f} % "
            f"along the travel); the transmission mode at {mode(k0):.1f} Hz and {mode(k1):.1f} Hz there; ")
    if "k_middle" in vals:
        km = vals["k_middle"]
        # the compliance c(s) = c0 (2s-1)(s-1) + 4 cm s(1-s) + c1 s(2s-1) on s in [0, 1]: its vertex
        c0, cm, c1 = 1 / k0, 1 / km, 1 / k1
        curv = 2 * (c0 + c1) - 4 * cm           # c(s) = curv s^2 + ..., softest inside where curv < 0
        slope = 4 * cm - 3 * c0 - c1
        s_v = -slope / (2 * curv) if curv != 0 else math.nan
        text += f"{km:.4g} N/m midway ({mode(km):.1f} Hz); "
        if curv < 0 and 0.0 < s_v < 1.0:
            text += (f"softest with the nut at {(x0 + s_v * (x1 - x0)) * 1e3:.4g} mm, between the bearings of a "
                     f"screw held at both ends (EA L/(a (L - a)) in series with the fixed compliances); ")
        else:
            text += "no softest point inside the travel: a screw held at one end does as well; "
    else:
        text += ("the compliance 1/k1 linear in the nut position, as EA/L of a screw held at one end in series "
                 "with the fixed compliances; ")
    xs = replay.meas["x_cmd"]
    lo, hi = float(np.min(xs)), float(np.max(xs))
    if hi - lo < 0.5 * (x1 - x0):
        text += f"the record covers {lo * 1e3:.4g} .. {hi * 1e3:.4g} mm only; "
    # can the record see the change? a constant k1 (the best of the ends' values and their mean) against the fit
    chans = list(replay.objective.weights)
    ks = [k for n, k in vals.items() if n.startswith("k_")]
    try:
        res1 = replay.residuals(configure(eff, cfg, vals))
        best = None
        for k in (k0, kmean, k1):
            r = replay.residuals(configure(eff, cfg, dict(vals, **{n: k for n in vals if n.startswith("k_")})))
            cost = float(np.sum(replay.objective.vector(r) ** 2))
            if best is None or cost < best[0]:
                best = (cost, r)
        seen = bic_score(best[1], res1, chans, len(ks) - 1, replay.noise) > MIN_SCORE
    except ValueError:
        seen = True
    if not seen or not math.isfinite(change):
        text += (f"the variation cannot be seen over the stroke this record covers ({lo * 1e3:.4g} .. {hi * 1e3:.4g} "
                 f"mm): a constant k1 fits as well; ")
    return text


def model_modes(cfg):
    try:
        pl = plant_from_config(cfg)
        w = np.sqrt(np.maximum(np.linalg.eigvals(np.linalg.solve(pl.chain.M, pl.chain.K)).real, 0))
        return sorted(float(x / (2 * np.pi)) for x in w if x > 1e-6)
    except Exception:  # noqa: BLE001 - evidence text only
        return []
