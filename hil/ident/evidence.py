"""The evidence of a fitted candidate: what in the residual before the fit points at the effect,
then the fall of the error the fit brought, as one line of text.

Per effect (r the residual before the fit, v the commanded velocity, "moving" |v| > 2 % of
max|v|):

* friction and force effects: the regression of the force residual while moving,
  r = Fc sign(v) + c v + f0 (per direction, level and slope, for asymmetric friction);
* position-periodic effects: the fitted period (x_motor - x_table for a lead error);
* an added mode: its frequency, against the model's modes (the chain's undamped natural
  frequencies sqrt(eig(M^-1 K)) / 2 pi);
* backlash, time delay, mass change and ``parameter:<key>``: the fitted value;
* a combination: each member's evidence, then the fall of the joint fit.

It ends with "RMS <channel> error <before> -> <after> <unit> (<fall> % less)".
"""
from __future__ import annotations

import numpy as np

from hil.ident.replay import Replay
from hil.plant_config import candidate, plant_from_config

__all__ = ["evidence", "model_modes"]


def evidence(eff_name: str, vals: dict, replay: Replay, res0: dict, chan: str, before: float, after: float,
              base_modes) -> str:
    unit = replay.unit(chan)
    fall = f"RMS {chan} error {before:.3g} -> {after:.3g} {unit} ({100 * (1 - after / before) if before else 0:.0f} % less)"
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


def model_modes(cfg):
    try:
        pl = plant_from_config(cfg)
        w = np.sqrt(np.maximum(np.linalg.eigvals(np.linalg.solve(pl.chain.M, pl.chain.K)).real, 0))
        return sorted(float(x / (2 * np.pi)) for x in w if x > 1e-6)
    except Exception:  # noqa: BLE001 - evidence text only
        return []
