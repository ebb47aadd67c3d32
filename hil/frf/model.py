"""The model's frequency responses: what the measurement of :mod:`hil.frf.estimation` should show.

The responses are the exact ones of the sampled loop (zero-order hold of the chain over a velocity
period, output delay and current-loop lag included; the controller and the speed measurement as
drivers.control's law), so that on the simulated plant measured and modelled responses agree to the
measurement's uncertainty. The position loop is multirate and modelled with the usual hold
approximation (:func:`position_hold`: a delay of half a position period and a sinc).
Names and units of the responses as in :mod:`hil.frf.estimation`.
"""
from __future__ import annotations

import math

import numpy as np

from drivers.control import loop_terms

__all__ = ["model_responses", "position_hold"]


def model_responses(plant, ctrl, f, tip_measured: bool = True) -> dict[str, np.ndarray]:
    """Exact responses of the sampled loop at ``f`` (Hz): zero-order hold of the chain over the
    velocity period, output delay and current-loop lag; controller and speed measurement as
    drivers.control's law. Position loop: hold approximation (delay Tp/2, sinc)."""
    f = np.asarray(f, float)
    tv, tp = ctrl.velocity_period, ctrl.position_period
    disc = plant.chain.discretize(tv, inputs="motor")
    A, b = disc.A, disc.B[:, 0] * plant.force_gain
    n = plant.n
    z = np.exp(2j * np.pi * f * tv)
    X = np.empty((f.size, 2 * n), complex)
    I = np.eye(2 * n)
    for i, zi in enumerate(z):
        X[i] = np.linalg.solve(zi * I - A, b)
    terms = loop_terms(plant, ctrl)
    d_int, d_frac = terms.delay_parts
    D = (1 - d_frac) * z ** (-d_int) + d_frac * z ** (-(d_int + 1))
    a = terms.lag_alpha
    D = D * a / (1 - (1 - a) / z)
    X = X * D[:, None]
    scale = ctrl.speed_scale
    taps = ctrl.velocity_filter if ctrl.velocity_feedback == "position_difference" else ()
    if taps:
        Fz = sum(t * z ** (-i) for i, t in enumerate(taps))
        gw = scale * Fz * (1 - 1 / z) / tv * X[:, 0]
    else:
        gw = scale * X[:, n]
    jw = 2j * np.pi * f
    out = {"TF1p": gw, "TF2": X[:, plant.table] / X[:, 0]}
    if tip_measured and plant.tip != plant.table:
        out["TF3"] = X[:, plant.tip] / X[:, plant.table]
        # tip speed from the tip position's DFT (as measured): j w x_tip
        out["tip"] = jw * X[:, plant.tip]
    C = ctrl.kp * (1 + (tv / ctrl.ti if math.isfinite(ctrl.ti) else 0.0) / (1 - 1 / z))
    lv = C * gw
    out["Lv"] = lv
    out["Tv"] = lv / (1 + lv)
    P = C * X[:, plant.table] / (1 + lv)
    hold = position_hold(f, tp)
    lp = ctrl.kv * scale * P * hold
    ff = ctrl.ffv * (np.exp(jw * tp) - 1) / tp
    out["Lp"] = lp
    out["Tp"] = (ctrl.kv + ff) * scale * P * hold / (1 + lp)
    return out


def position_hold(f, tp):
    """Sample-and-hold of the position loop seen at the fundamental: delay Tp/2 and sinc."""
    x = np.pi * np.asarray(f) * tp
    return np.exp(-1j * x) * np.sinc(x / np.pi)

