"""Effects that grow along the travel: the screw's thermal elongation (a lead error linear in the
position), a cable carrier's force (linear in the position).

* ``screw_elongation``: a screw ``strain`` longer than nominal (steel 11.5e-6 per K: a screw 5 K
  warmer grows 58 um per m) moves the nut to x1 + strain (x1 - x_ref), x_ref the fixed bearing's
  position (a setting). Kernel term LEAD_ERROR_LINEAR, the lead error's term of ``pitch_error``
  with a linear error for the periodic one. Closed form: at rest (no force on the table), and by
  as much between any two positions at one constant speed, x_motor - x_table = -strain (x1 - x_ref).
* ``cable_carrier``: a cable carrier (energy chain) pulls the table with a force that changes as
  it unrolls, f0 + f1 x (kernel term FORCE_ALONG_TRAVEL): the motor torque at constant speed
  changes by -(f0 + f1 x) / k (k = force_to_load, 2 pi / pitch). Its starts and evidence: the
  regression of the force residual while moving on 1 and the position. ``constant_force`` is its
  special case f1 = 0.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from sim_plant import terms
from sim_plant.effects.base import Effect, Param, no_link, no_travel, register

__all__ = ["ScrewElongation", "CableCarrier", "STEEL_EXPANSION"]

STEEL_EXPANSION = 11.5e-6      # 1/K, a steel screw's linear thermal expansion


def _motor_table_slope(ctx, x_ref: float):
    """The slope of the residual x_motor - x_table against the position (x_motor, else the
    command) less ``x_ref``, least squares with an offset; None without both channels."""
    res0 = ctx.res0
    if "x_motor" not in res0 or "x_table" not in res0:
        return None
    x = np.asarray(ctx.meas["x_motor"] if "x_motor" in ctx.meas else ctx.meas["x_cmd"], float) - x_ref
    if float(np.ptp(x)) <= 0:
        return None
    d = np.asarray(res0["x_motor"], float) - np.asarray(res0["x_table"], float)
    coef, *_ = np.linalg.lstsq(np.column_stack([x, np.ones_like(x)]), d, rcond=None)
    return float(coef[0])


@register
class ScrewElongation(Effect):
    name = "screw_elongation"
    description = ("the screw's thermal elongation: a lead error growing linearly with the position, the nut at "
                   "x1 + strain (x1 - x_ref)")
    params = (Param("strain", "dimensionless", -2e-3, 2e-3, 1e-5,
                    "lead error per unit of travel (the screw's thermal strain, 11.5e-6 per K of steel)"),
              Param("x_ref", "length", -1e3, 1e3, 0.0, "the fixed bearing's position (a setting, not fitted)",
                    fit=False))
    synth_strength = {"strain": 60e-6, "x_ref": 0.0}

    def unsuited(self, plant):
        return no_travel(plant) or no_link(plant)

    def apply(self, plant, values):
        self._need_link(plant)
        return dataclasses.replace(plant, effects=plant.effects + (
            (terms.LEAD_ERROR_LINEAR, (0.0, values["strain"], values["x_ref"], plant.chain.k[0])),))

    def evidence(self, ctx, values):
        eps = values.get("strain", 0.0)
        slope = _motor_table_slope(ctx, values.get("x_ref", 0.0))
        seen = (f"x_motor - x_table residual changes {slope * 1e6:+.3g} um per m of travel; "
                if slope is not None else "")
        dt = eps / STEEL_EXPANSION
        return (seen + f"the screw's lead {abs(eps) * 1e6:.3g} um per m {'longer' if eps >= 0 else 'shorter'} than "
                f"nominal: a steel screw {abs(dt):.2g} K {'warmer' if dt >= 0 else 'cooler'} than when it was measured; ")

    def regression_start(self, ctx):
        g = self.guess(ctx.plant, ctx.scale)
        slope = _motor_table_slope(ctx, g["x_ref"])
        if slope is None:
            return None
        # x_motor - x_table = -strain (x1 - x_ref): the residual's slope is minus the strain missing
        return dict(g, strain=ctx.configured(self.name, "strain") - slope)


@register
class CableCarrier(Effect):
    name = "cable_carrier"
    description = ("a cable carrier's force on the table, changing along the travel as it unrolls: "
                   "f0 + f1 x (+ in +x)")
    params = (Param("force", "force", -1e5, 1e5, 0.0, "force on the table at x = 0, + in +x"),
              Param("slope", "stiffness", -1e7, 1e7, 0.0, "its change per m of travel"))
    nests = ("constant_force",)
    synth_strength = {"force": 200.0, "slope": -3000.0}

    def unsuited(self, plant):
        return no_travel(plant)

    def apply(self, plant, values):
        return dataclasses.replace(plant, effects=plant.effects + (
            (terms.FORCE_ALONG_TRAVEL, (float(plant.table), values["force"], values["slope"])),))

    def guess(self, plant, scale):
        return {"force": 0.1 * scale.get("force", 1.0), "slope": 0.0}

    def _fit(self, ctx):
        """(a, b) of the force residual while moving, r = a + b x (x the command), or None."""
        if ctx.force_residual is None or int(ctx.moving.sum()) < 16:
            return None
        x = np.asarray(ctx.meas["x_cmd"], float)[ctx.moving]
        coef, *_ = np.linalg.lstsq(np.column_stack([np.ones_like(x), x]), ctx.force_residual[ctx.moving],
                                   rcond=None)
        return float(coef[0]), float(coef[1])

    def evidence(self, ctx, values):
        ab = self._fit(ctx)
        fu = ctx.force_unit
        seen = (f"{ctx.force_channel} residual moving changes along the travel, {ctx.fmt_si(ab[1], fu, 3)} per m; "
                if ab else "")
        return seen + (f"a cable carrier pulls the table with {values.get('force', 0.0):.4g} N at x = 0, "
                       f"{values.get('slope', 0.0):+.4g} N per m of travel; ")

    def regression_start(self, ctx):
        ab = self._fit(ctx)
        if ab is None:
            return None
        k = ctx.force_to_load
        # the motor supplies the missing load force: r = -(f0 + f1 x) / k
        return {"force": ctx.configured(self.name, "force") - ab[0] * k,
                "slope": ctx.configured(self.name, "slope") - ab[1] * k}
