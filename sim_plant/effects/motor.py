"""Effects of the motor: cogging and torque ripple, a torque periodic in the motor angle.

Starts: the periodic starts of the identification (``ctx.periodic_starts``: every order per
revolution screened on the residual's spectrum against the motor position, the strongest solved
in closed form for amplitude and phase); evidence: the fitted period.
"""
from __future__ import annotations

import dataclasses
import math

from sim_plant import terms
from sim_plant.effects.base import Effect, Param, motor_force_kind, register, to_linear

__all__ = ["TorqueRipple"]


@register
class TorqueRipple(Effect):
    name = "torque_ripple"
    description = "cogging / torque ripple: a motor torque periodic in the motor angle"
    params = (Param("amplitude", motor_force_kind, 0.0, 1e4, 0.1, "ripple amplitude on the motor"),
              Param("period", "length", 1e-5, 1.0, 1e-3, "period along the travel (pitch / ripples per turn)"),
              Param("phase", "dimensionless", -4 * math.pi, 4 * math.pi, 0.0, "phase at x1 = 0 (rad)"))
    periodic = True

    def apply(self, plant, values):
        return dataclasses.replace(plant, effects=plant.effects + (
            (terms.TORQUE_RIPPLE, (values["amplitude"] * to_linear(plant), values["period"], values["phase"])),))

    def guess(self, plant, scale):
        return {"amplitude": 0.05 * scale.get("force", 1.0) / to_linear(plant),
                "period": (plant.pitch or 0.01) / 6, "phase": 0.0}

    synth_strength = {"amplitude": 0.6, "period": 0.005, "phase": 0.3}

    def evidence(self, ctx, values):
        return (f"{ctx.chan} residual periodic in position with period "
                f"{ctx.fmt_si(values.get('period', 0.0), ctx.unit('x_motor'), 3)}; ")

    def starts(self, ctx, guess):
        return ctx.periodic_starts(self, guess, None)
