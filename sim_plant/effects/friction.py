"""Friction and force effects on the motor and the load: Coulomb, viscous, Stribeck, per
direction, and a constant force.

Their evidence and starting values come from the linear regression of the force residual r
(measured - simulated, in the force channel's units: the motor torque on a rotary axis) while the
axis moves (|v| > 2 % of max|v|, v the commanded velocity): r = Fc sign(v) + c v + f0
(:func:`force_levels`), or per direction r = Fc+ [v > 0] - Fc- [v < 0] + c+ v [v > 0] + c- v [v < 0]
(:func:`force_levels_per_direction`); a start adds what the residual asks for to what the model
has. Coulomb and viscous friction, the constant force and a mass change are linear in their one
parameter through the inverse model of a rigid axis (hil.ident.joint): their regressors are
sign(v), s v (s = speed_scale), -1/k (k = force_to_load) and a/k.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from sim_plant import terms
from sim_plant.effects.base import (
    Effect,
    Param,
    level_guess,
    motor_damping_kind,
    motor_force_kind,
    register,
    to_linear,
)
from sim_plant.plant import Friction

__all__ = ["CoulombFriction", "ViscousFriction", "StribeckFriction", "AsymmetricFriction", "ConstantForce",
           "force_levels", "force_levels_per_direction", "MIN_MOVING"]

MIN_MOVING = 16       # moving samples a regression start needs
COLLINEAR = 0.95      # |correlation| of sign(v) and v beyond which a record cannot split Fc from c
PLACES = ("motor", "table")     # where a constant force acts (its setting ``place``)


def force_levels(ctx):
    """(Fc, c, f0) of r = Fc sign(v) + c v + f0 on the moving samples (least squares). Where the
    record's moves run at one speed, sign(v) and v are one column (their correlation beyond
    :data:`COLLINEAR`) and the joint split is arbitrary: Fc and f0 then come from
    r = Fc sign(v) + f0 and c from r = c v + f0, each effect's start taking the whole of what it
    can explain alone. (2 N m of Coulomb friction at one feed: the joint split gave Fc -0.94 N m and
    a viscous coefficient 304 times too large, the Coulomb fit started from 0 and stayed there.)"""
    v, moving = ctx.v_cmd[ctx.moving], ctx.moving
    r, sign, one = ctx.force_residual[moving], np.sign(v), np.ones(v.size)
    coef, *_ = np.linalg.lstsq(np.column_stack([sign, v, one]), r, rcond=None)
    # (one direction only: sign(v) is the offset's column and has no correlation; as before)
    if v.size > 2 and np.std(v) > 0 and np.std(sign) > 0 and abs(float(np.corrcoef(sign, v)[0, 1])) > COLLINEAR:
        fc, f0 = np.linalg.lstsq(np.column_stack([sign, one]), r, rcond=None)[0]
        c = np.linalg.lstsq(np.column_stack([v, one]), r, rcond=None)[0][0]
        coef = np.array([fc, c, f0])
    return coef


def force_levels_per_direction(ctx):
    """(Fc+, Fc-, c+, c-) of r = Fc+ [v > 0] - Fc- [v < 0] + c+ v [v > 0] + c- v [v < 0] (least squares).
    The two directions share no column, so each is its own regression r = Fc + c v. Where one
    direction's moves run at one speed (the cosine of its constant and v beyond :data:`COLLINEAR`),
    its split is arbitrary and its level takes the whole (slope 0), as :func:`force_levels` does:
    2 N m both ways at one feed had split into Fc+ 0.90 and Fc- -3.61 N m."""
    vm, r = ctx.v_cmd[ctx.moving], ctx.force_residual[ctx.moving]
    pos = (vm > 0).astype(float)
    X = np.column_stack([pos, -(1 - pos), vm * pos, vm * (1 - pos)])
    cp, *_ = np.linalg.lstsq(X, r, rcond=None)
    for i, (side, sign) in enumerate(((vm > 0, 1.0), (vm < 0, -1.0))):
        v = vm[side]
        if v.size > 2 and abs(float(v.mean())) / float(np.sqrt(np.mean(v * v))) > COLLINEAR:
            cp[i], cp[2 + i] = sign * float(r[side].mean()), 0.0
    return cp


def _can_regress(ctx) -> bool:
    """A regression start needs a force channel and some motion."""
    return ctx.force_channel is not None and int(ctx.moving.sum()) >= MIN_MOVING


def _model_levels(ctx):
    """The model's Coulomb levels (+, -) and viscous coefficient on the motor, motor units."""
    plant = ctx.plant
    sp = plant.speed_scale                       # rad/s (rotary) or m/s per m/s of the load
    return (plant.friction.coulomb_pos / sp, plant.friction.coulomb_neg / sp,
            plant.chain.c_ground[0] / (sp * sp))


def _sign_evidence(ctx) -> str:
    """The force residual following sign(v): the head of a dry friction's evidence."""
    if ctx.force_residual is None:
        return ""
    coef = force_levels(ctx)
    return f"{ctx.force_channel} residual follows sign(v), {ctx.fmt_si(abs(coef[0]), ctx.force_unit, 3)}; "


@register
class CoulombFriction(Effect):
    name = "coulomb_friction"
    description = "Coulomb (dry) friction on the motor, with stiction: tau_fc sign(v) (Eq. 11)"
    params = (Param("level", motor_force_kind, 0.0, 1e4, 1.0, "sliding friction level on the motor"),)
    nests = ()

    def apply(self, plant, values):
        f = values["level"] * to_linear(plant)
        return dataclasses.replace(plant, friction=Friction(f, f, f, f, 0.0))

    def guess(self, plant, scale):
        return {"level": scale.get("force", 1.0) / to_linear(plant)}

    synth_strength = {"level": 2.2}
    linear_param = "level"

    def evidence(self, ctx, values):
        return _sign_evidence(ctx)

    def regression_start(self, ctx):
        if not _can_regress(ctx):
            return None
        fp, fn, _ = _model_levels(ctx)
        return {"level": max(0.5 * (fp + fn) + float(force_levels(ctx)[0]), 0.0)}

    def linear_column(self, ctx):
        # sign(v); it replaces the model's level: the value now is the model's mean level
        fric, s = ctx.plant.friction, ctx.plant.speed_scale
        return np.sign(ctx.v), 0.5 * (fric.coulomb_pos + fric.coulomb_neg) / s


@register
class ViscousFriction(Effect):
    name = "viscous_friction"
    description = "viscous friction on the motor, c_m omega (Eq. 11), added to what the config has"
    params = (Param("coefficient", motor_damping_kind, -1e6, 1e6, 1e-3, "extra viscous coefficient on the motor"),)

    def apply(self, plant, values):
        c = values["coefficient"] * to_linear(plant) ** 2
        chain = plant.chain
        cg = (chain.c_ground[0] + c,) + tuple(chain.c_ground[1:])
        return dataclasses.replace(plant, chain=dataclasses.replace(chain, c_ground=cg))

    def guess(self, plant, scale):
        return {"coefficient": scale.get("force", 1.0) / max(scale.get("speed", 1.0), 1e-9) / to_linear(plant) ** 2}

    synth_strength = {"coefficient": 0.02}
    linear_param = "coefficient"

    def evidence(self, ctx, values):
        if ctx.force_residual is None:
            return ""
        coef = force_levels(ctx)
        return f"{ctx.force_channel} residual grows with velocity, {coef[1]:.3g} {ctx.force_unit} per m/s; "

    def regression_start(self, ctx):
        if not _can_regress(ctx):
            return None
        cv = ctx.configured(self.name, "coefficient")
        return {"coefficient": cv + float(force_levels(ctx)[1]) / ctx.plant.speed_scale}

    def linear_column(self, ctx):
        return ctx.plant.speed_scale * ctx.v, ctx.configured(self.name, "coefficient")


@register
class StribeckFriction(Effect):
    name = "stribeck_friction"
    description = ("dry friction with a Stribeck curve: break-away level at rest falling to the sliding "
                   "level as exp(-(v/v_s)^2)")
    params = (Param("level", motor_force_kind, 0.0, 1e4, 1.0, "sliding (Coulomb) level on the motor"),
              Param("static", motor_force_kind, 0.0, 1e4, 1.5, "break-away level at rest"),
              Param("velocity", "speed", 1e-5, 1.0, 2e-3, "Stribeck velocity (load side)"))
    nests = ("coulomb_friction",)

    replaces = ("coulomb_friction",)              # it sets the dry friction anew
    replaces_keys = ("friction.coulomb", "friction.static")
    def apply(self, plant, values):
        r = to_linear(plant)
        fc, fs = values["level"] * r, max(values["static"], values["level"]) * r
        return dataclasses.replace(plant, friction=Friction(fc, fc, fs, fs, values["velocity"]))

    def guess(self, plant, scale):
        f0 = level_guess(plant, 0.0)     # the model's Coulomb level, when it has one
        f = f0 or scale.get("force", 1.0) / to_linear(plant)
        return {"level": f, "static": (1.1 if f0 else 1.5) * f,
                "velocity": max(0.05 * scale.get("speed", 0.04), 1e-4)}

    synth_strength = {"level": 1.5, "static": 3.5, "velocity": 3e-3}

    def evidence(self, ctx, values):
        return _sign_evidence(ctx)


@register
class AsymmetricFriction(Effect):
    name = "asymmetric_friction"
    description = ("friction with different levels per direction: Coulomb and viscous for v > 0 and v < 0 "
                   "(replaces the config's motor friction)")
    params = (Param("level_pos", motor_force_kind, 0.0, 1e4, 1.0, "Coulomb level moving in +x"),
              Param("level_neg", motor_force_kind, 0.0, 1e4, 1.0, "Coulomb level moving in -x"),
              Param("viscous_pos", motor_damping_kind, 0.0, 1e7, 0.0, "viscous coefficient moving in +x"),
              Param("viscous_neg", motor_damping_kind, 0.0, 1e7, 0.0, "viscous coefficient moving in -x"))
    nests = ("coulomb_friction", "viscous_friction", "constant_force")
    # while moving, (Fc+ + Fc-)/2 sign(v) + (Fc+ - Fc-)/2 is Coulomb friction plus a constant force
    mimicked_by = (("coulomb_friction", "constant_force"),)

    # it sets the dry friction and the motor's viscous damping anew
    replaces = ("coulomb_friction", "viscous_friction", "stribeck_friction")
    replaces_keys = ("friction.coulomb", "friction.static", "friction.viscous")   # the motor's friction and damping
    def apply(self, plant, values):
        r = to_linear(plant)
        fp, fn = values["level_pos"] * r, values["level_neg"] * r
        chain = plant.chain
        cg = (0.0,) + tuple(chain.c_ground[1:])
        return dataclasses.replace(
            plant, chain=dataclasses.replace(chain, c_ground=cg), friction=Friction(fp, fn, fp, fn, 0.0),
            effects=plant.effects + ((terms.VISCOUS_ASYMMETRIC, (0.0, values["viscous_pos"] * r * r,
                                                                   values["viscous_neg"] * r * r)),))

    def guess(self, plant, scale):
        r = to_linear(plant)
        f = level_guess(plant, scale.get("force", 1.0) / r)
        c = plant.chain.c_ground[0] / (r * r)
        return {"level_pos": f, "level_neg": f, "viscous_pos": c, "viscous_neg": c}

    synth_strength = {"level_pos": 1.2, "level_neg": 3.0, "viscous_pos": 0.0076, "viscous_neg": 0.02}

    def evidence(self, ctx, values):
        rf, fch, fu = ctx.force_residual, ctx.force_channel, ctx.force_unit
        if rf is None:
            return ""
        vm = ctx.v_cmd[ctx.moving]
        p = (vm > 0).astype(float)
        cp, *_ = np.linalg.lstsq(np.column_stack([p, 1 - p, vm * p, vm * (1 - p)]), rf[ctx.moving], rcond=None)
        return (f"{fch} residual differs per direction: level {ctx.fmt_si(cp[0], fu, 3)} and slope {cp[2]:.3g} {fu} per m/s "
                f"moving +, level {ctx.fmt_si(cp[1], fu, 3)} and slope {cp[3]:.3g} {fu} per m/s moving -; ")

    def regression_start(self, ctx):
        if not _can_regress(ctx):
            return None
        fp, fn, c0 = _model_levels(ctx)
        cp = force_levels_per_direction(ctx)
        sp = ctx.plant.speed_scale
        return {"level_pos": max(fp + float(cp[0]), 0.0), "level_neg": max(fn + float(cp[1]), 0.0),
                "viscous_pos": max(c0 + float(cp[2]) / sp, 0.0), "viscous_neg": max(c0 + float(cp[3]) / sp, 0.0)}


@register
class ConstantForce(Effect):
    name = "constant_force"
    description = ("a constant force on the motor's mass or on the table (gravity on an inclined axis, a weight "
                   "compensation, a cable)")
    params = (Param("force", "force", -1e5, 1e5, 0.0, "force on the load side, + in +x"),
              Param("place", "dimensionless", 0.0, 1.0, 0.0,
                    "the mass it acts on: motor (the motor's reflected mass) or table (a setting)",
                    fit=False, choices=PLACES))

    def apply(self, plant, values):
        place = int(round(values.get("place", 0.0)))
        if place not in (0, 1):
            raise ValueError(f"{self.name}: place must be motor or table (got {values['place']!r})")
        mass = float(plant.table) if place == 1 else 0.0
        return dataclasses.replace(plant, effects=plant.effects + ((terms.CONSTANT_FORCE, (mass, values["force"])),))

    def guess(self, plant, scale):
        return {"force": 0.1 * scale.get("force", 1.0), "place": 0.0}

    synth_strength = {"force": 400.0, "place": 0.0}
    linear_param = "force"

    def evidence(self, ctx, values):
        if ctx.force_residual is None:
            return ""
        coef = force_levels(ctx)
        seen = f"{ctx.force_channel} residual has a mean of {ctx.fmt_si(coef[2], ctx.force_unit, 3)} in both directions; "
        if ctx.plant.table != 0:
            # where it acts shows in the positions only: on the table it leans the table on the screw
            # by F / k1 (a static motor - table offset), on the motor it does not
            seen += f"acting on the {PLACES[int(round(values.get('place', 0.0)))]}; "
        return seen

    def regression_start(self, ctx):
        if not _can_regress(ctx):
            return None
        # the force channel is in motor units (torque on a rotary axis): a load-side force is that times k
        return {"force": ctx.configured(self.name, "force") - float(force_levels(ctx)[2]) * ctx.force_to_load,
                "place": ctx.configured(self.name, "place")}

    def starts(self, ctx, guess):
        """The regression's start and the guess at the place the config gives; where it gives none
        and the table is a mass of its own, at both places, the cheaper two kept (one simulation each):
        the torque is the same, the motor - table offset is not."""
        starts = super().starts(ctx, guess)
        if ctx.given(self.name, "place") is not None or ctx.plant.table == 0:
            return starts
        return ctx.prefilter(self, [dict(s, place=float(p)) for s in starts for p in range(len(PLACES))])

    def linear_column(self, ctx):
        return -np.ones_like(ctx.v) / ctx.force_to_load, ctx.configured(self.name, "force")


