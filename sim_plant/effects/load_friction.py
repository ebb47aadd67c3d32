"""A ball screw's friction that grows with the axial load: the nut's preload and the bearings give a
friction torque independent of the load, the rolling contacts one proportional to the axial force
the screw carries (issue 24, item 3; Altintas, Verl et al., "Machine tool feed drives", CIRP Annals
2011; the ball screw makers' catalogues).

On the motor, with p the pitch and eta the screw's mechanical efficiency (0.85 .. 0.95)::

    T_fric = T_pre + |F_axial| p / (2 pi) (1/eta - 1),      T_pre = k_p F_pre p / (2 pi)

always against the motion; k_p about 0.1 .. 0.3, F_pre the nut's preload. In the chain's linear
units (mass 1 the motor's inertia reflected through the pitch) the friction force on mass 1 is
F_pre_level + mu |F_link|, mu = 1/eta - 1 (dimensionless, 0 .. 0.5 from the efficiency) and F_link
the force in the transmission link, k1 (x1 - x2) + c1 (v1 - v2): while the axis accelerates it is
the load's inertia m_load a (and, moving, what the load side's own damping asks), so the friction
grows with |m_load a|. Both parts are one dry friction level on the motor (kernel term
``LOAD_FRICTION`` on top of the Coulomb level): at rest the motor sticks while the torque stays
inside it, sliding it acts against the motion (sim_plant.kernel.friction_force, the way the
Coulomb friction is treated). The link's force is the chain's spring and damper; what other link
terms change in it (backlash's dead zone, a stiffness along the travel) it leaves out.

Closed form (the paper bench, no damping on the load side): at constant speed the link carries no
force and the torque the effect adds is T_pre alone; during a constant acceleration a (or
deceleration) it is T_pre + mu |m_load a| p / (2 pi), against the motion in both.

It contains ``coulomb_friction`` (mu = 0: the preload's level alone). While the axis accelerates
in the direction of motion it looks like Coulomb friction plus a larger load mass; braking, the
same friction looks like a smaller one (mu |m a| sign(v) is +mu m a accelerating, -mu m a
braking): the signature, in the force residual while moving, is |F_link| sign(v), not sign(v)
alone nor a. Its start and evidence: the least squares of the force residual r while moving on
[sign(v), |F_link| sign(v) / k] (k = force_to_load, 2 pi / p), F_link estimated from the measured
motion through the inverse model of a rigid load (m_load a + c_load v, ``ctx.motion``).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from sim_plant import terms
from sim_plant.effects.base import Effect, Param, level_guess, motor_force_kind, no_link, register, to_linear
from sim_plant.effects.friction import MIN_MOVING
from sim_plant.plant import Friction

__all__ = ["LoadDependentFriction", "link_force_estimate"]


def link_force_estimate(plant, v, a, link: int = 0) -> np.ndarray:
    """The force in ``link`` (N) a rigid load beyond it needs to move with velocity ``v`` and
    acceleration ``a`` (m/s, m/s^2, the measured motion): its masses times a, plus its ground
    damping times v (the inverse model of the load side; its effects' forces left out)."""
    ch = plant.chain
    m_load = float(sum(ch.m[link + 1:]))
    c_load = float(sum(ch.c_ground[link + 1:]))
    return m_load * np.asarray(a, float) + c_load * np.asarray(v, float)


@register
class LoadDependentFriction(Effect):
    name = "load_dependent_friction"
    description = ("a ball screw's friction: the nut's preload and the bearings (a Coulomb level) plus a part "
                   "growing with the axial load the screw carries, (1/eta - 1) |F_link| p / (2 pi) (replaces the "
                   "config's motor Coulomb friction)")
    params = (Param("preload", motor_force_kind, 0.0, 1e4, 1.0,
                    "friction of the nut's preload and the bearings on the motor, independent of the load"),
              Param("coefficient", "dimensionless", 0.0, 0.5, 0.05,
                    "load-dependent friction per unit of the link's axial force, 1/eta - 1 (eta the efficiency)"))
    nests = ("coulomb_friction",)
    # accelerating in the direction of motion the load part is a larger mass, braking a smaller one:
    # Coulomb friction and a mass change together can do the half of its work a record's moves show one way
    mimicked_by = (("coulomb_friction", "mass_change"),)
    synth_strength = {"preload": 1.0, "coefficient": 0.15}

    def unsuited(self, plant):
        return no_link(plant)

    def apply(self, plant, values):
        self._need_link(plant)
        f = values["preload"] * to_linear(plant)
        ch = plant.chain
        return dataclasses.replace(plant, friction=Friction(f, f, f, f, 0.0), effects=plant.effects + (
            (terms.LOAD_FRICTION, (0.0, values["coefficient"], ch.k[0], ch.c[0])),))

    def guess(self, plant, scale):
        return {"preload": level_guess(plant, scale.get("force", 1.0) / to_linear(plant)),
                "coefficient": self.param("coefficient").guess}

    def _regression(self, ctx):
        """(b0, b1, fit share) of the force residual while moving, r = b0 sign(v) + b1 |F_link| sign(v) / k
        (b0 in the force channel's unit, b1 dimensionless like the coefficient), and the share of
        r's sum of squares it explains against sign(v) alone; None without a force channel or motion."""
        r = ctx.force_residual
        if r is None or int(ctx.moving.sum()) < MIN_MOVING or ctx.plant.n < 2:
            return None
        mv = ctx.moving
        v, a = ctx.motion
        s = np.sign(ctx.v_cmd[mv])
        load = np.abs(link_force_estimate(ctx.plant, v[mv], a[mv])) / ctx.force_to_load
        X = np.column_stack([s, load * s])
        y = np.asarray(r, float)[mv]
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        c0, *_ = np.linalg.lstsq(X[:, :1], y, rcond=None)
        ssr_sign = float(np.sum((y - X[:, :1] @ c0) ** 2))
        ssr = float(np.sum((y - X @ coef) ** 2))
        return float(coef[0]), float(coef[1]), (1.0 - ssr / ssr_sign) if ssr_sign > 0 else 0.0

    def regression_start(self, ctx):
        reg = self._regression(ctx)
        if reg is None:
            return None
        sp = ctx.plant.speed_scale
        level = 0.5 * (ctx.plant.friction.coulomb_pos + ctx.plant.friction.coulomb_neg) / sp
        hi = self.param("coefficient").upper
        return {"preload": max(level + reg[0], 0.0),
                "coefficient": min(max(ctx.configured(self.name, "coefficient") + reg[1], 0.0), hi)}

    def evidence(self, ctx, values):
        mu = values.get("coefficient", 0.0)
        unit = "N m" if ctx.rotary else "N"
        fit = (f"a ball screw's friction: {ctx.fmt_si(values.get('preload', 0.0), unit, 3)} of "
               f"preload and {mu:.3g} of the axial load (1/eta - 1: efficiency {1.0 / (1.0 + mu):.3f}), like "
               f"coulomb_friction plus a mass change while accelerating but a mass lost while braking; ")
        reg = self._regression(ctx)
        if reg is None:
            return fit
        return (f"{ctx.force_channel} residual while moving follows |link force| sign(v), {reg[1]:.3g} of the "
                f"link's force on top of {ctx.fmt_si(reg[0], ctx.force_unit, 3)} following sign(v) (explains "
                f"{100 * reg[2]:.0f} % of what sign(v) leaves); " + fit)
