"""Compiled pieces of the plant used inside the simulation loop: dry friction on the motor
(time-stepping, with stiction) and the force terms of plant effects.

Effects reach the compiled loop as rows of a small table: a code and up to ``N_EFFECT_PARAMS``
numbers. The Python side of each effect (sim_plant.effects) writes its rows; this module is the
only place that knows what the codes mean.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

N_EFFECT_PARAMS = 8

# effect term codes
CONSTANT_FORCE = 1       # [mass, force N]
BACKLASH = 2             # [link i (between mass i and i+1), half gap m, stiffness N/m, damping N s/m]: dead zone in link i
PITCH_ERROR = 3          # [link, amplitude m, period m, phase rad, stiffness N/m]: lead error x1 -> nut
TORQUE_RIPPLE = 4        # [amplitude N, period m (of x1), phase rad]: cogging on mass 1
VISCOUS_ASYMMETRIC = 5   # [mass, extra damping for v>0 N s/m, extra for v<0 N s/m]
TIME_DELAY = 6           # [delay s]: read by the loop (hil.simulate), no force here


def empty_effects():
    return np.zeros(0, np.int64), np.zeros((0, N_EFFECT_PARAMS))


@njit(cache=True)     # not inlined: a large body that most runs never enter
def effect_forces(codes, params, x, v, f):
    """Add the forces of the effect terms at state (x, v) to ``f`` (one entry per mass)."""
    for r in range(codes.shape[0]):
        c = codes[r]
        q = params[r]
        if c == CONSTANT_FORCE:
            f[int(q[0])] += q[1]
        elif c == BACKLASH:
            # the linear chain already applies k (x_i - x_i+1); a dead zone of +-gap removes that force
            # inside the gap and shifts it outside: correction = k (dz(d) - d)
            i = int(q[0])
            gap, k = q[1], q[2]
            d = x[i] - x[i + 1]
            if d > gap:
                dz = d - gap
            elif d < -gap:
                dz = d + gap
            else:
                dz = 0.0
            corr = k * (dz - d)
            if dz == 0.0:
                # inside the gap the link's damper carries no force either
                corr -= q[3] * (v[i] - v[i + 1])
            f[i] -= corr
            f[i + 1] += corr
        elif c == PITCH_ERROR:
            # the nut sits at x1 + e(x1): the link sees k (x1 + e - x2)
            i = int(q[0])
            e = q[1] * math.sin(2.0 * math.pi * x[i] / q[2] + q[3])
            f[i] -= q[4] * e
            f[i + 1] += q[4] * e
        elif c == TORQUE_RIPPLE:
            f[0] += q[0] * math.sin(2.0 * math.pi * x[0] / q[1] + q[2])
        elif c == VISCOUS_ASYMMETRIC:
            i = int(q[0])
            if v[i] > 0.0:
                f[i] -= q[1] * v[i]
            else:
                f[i] -= q[2] * v[i]


@njit(cache=True, inline="always")
def friction_force(fric, v_start, v_free, b):
    """Dry friction force on mass 1 over one step, and whether the motor sticks (time-stepping treatment of Coulomb friction).

    ``v_free``: mass 1's velocity at the end of the step without dry friction; ``b``: the
    velocity change per newton over the step. If the force that brings the motor to rest within
    the step lies inside the friction level, that force is applied (the motor sticks, exactly);
    otherwise the full level acts against the motion. This keeps a stuck axis stuck while the
    torque stays below the level, instead of creeping as a smoothed sign() would.

    fric = [sliding +, sliding -, break-away +, break-away -, Stribeck velocity]."""
    f_stop = -v_free / b
    # level in the direction the motor would move
    if f_stop > 0.0:          # it would move in -x
        slide, stat = fric[1], fric[3]
    else:
        slide, stat = fric[0], fric[2]
    vs = fric[4]
    if v_start == 0.0:
        level = stat          # at rest: break-away level
    elif vs > 0.0:
        level = slide + (stat - slide) * math.exp(-(v_start / vs) ** 2)
    else:
        level = slide
    if abs(f_stop) <= level:
        return f_stop, True
    return (level if f_stop > 0.0 else -level), False
