"""The swept variable: acceleration time and jerk of a sine-square move (the paper's Eq. 15-16).

In a sine-square ramp of length T_r the speed rises as v = V_f sin^2(pi t / (2 T_r)): the
acceleration is a half-sine pulse of peak a_max = pi V_f / (2 T_r) and the jerk peaks at
j_max = pi^2 V_f / (2 T_r^2). An NC states the dynamics as the acceleration time ``t_acc`` of a
ramp to the rapid speed G0; at the feed V_f the move then has

    a_max = pi G0 / (2 t_acc)                    (15)
    j_max = 2 a_max^2 / V_f                      (16)

and ``jmax_to_t_acc`` is the inverse, a_max = sqrt(j_max V_f / 2). SI units throughout (m/s,
m/s^2, m/s^3, s). A sweep's grid is log-spaced: overshoot changes over decades of jerk.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["t_acc_to_jmax", "jmax_to_t_acc", "jerk_grid"]


def t_acc_to_jmax(t_acc: float, feed: float, g0: float) -> float:
    """j_max = 2 a_max^2 / V_f with a_max = pi G0 / (2 t_acc)."""
    a = math.pi * g0 / (2.0 * t_acc)
    return 2.0 * a * a / feed


def jmax_to_t_acc(j_max: float, feed: float, g0: float) -> float:
    a = math.sqrt(j_max * feed / 2.0)
    return math.pi * g0 / (2.0 * a)


def jerk_grid(lo: float, hi: float, points: int) -> list[float]:
    """``points`` log-spaced jerks from lo to hi (both included)."""
    if not (lo > 0 and hi > lo):
        raise ValueError(f"jerk range: need 0 < low < high, got {lo:g}..{hi:g}")
    if points < 2:
        raise ValueError(f"--points: need at least 2, got {points}")
    return [float(x) for x in np.geomspace(lo, hi, points)]
