"""Delays in the loop: the torque (force) command reaching the motor late (a drive's computation
and transport), the position feedback arriving late (a scale read over a fieldbus).

The error is not convex in a delay: each gives a grid over the physically possible range
(:meth:`~sim_plant.effects.base.Effect.grid`), whole loop periods up to four, then about 1.4
times apart; the identification costs every point and refines between the best point's
neighbours. The evidence gives the delay in the loop's periods.
"""
from __future__ import annotations

import dataclasses

from sim_plant import terms
from sim_plant.effects.base import Effect, Param, register

__all__ = ["ActuatorDelay", "FeedbackDelay"]


def _delay_grid(lo: float, hi: float, step: float) -> list[float]:
    """Delays from ``lo`` to ``hi``: whole ``step``s up to 4, then about 1.4 times apart (the error
    is not convex in a delay: a grid finds its basin, a local fit refines it)."""
    out, d = [], lo
    while d < hi * (1 + 1e-9):
        out.append(d)
        d = d + step if d < 4 * step - 1e-15 else d * 1.4
    if out[-1] < hi * (1 - 1e-9):
        out.append(hi)
    return out


@register
class ActuatorDelay(Effect):
    """The drive's computation and transport: the torque (force) command reaches the motor late.
    Also known by its old name ``time_delay`` (config section ``[effects.time_delay]``)."""
    name = "actuator_delay"
    description = ("the torque (force) command reaches the motor late: a drive's computation and transport "
                   "delay, from one velocity-loop period upward")
    params = (Param("delay", "time", 0.0, 0.05, 5e-4, "delay of the command reaching the motor"),)
    MAX = 0.02           # the grid's upper end, s: a drive delays by a few velocity periods, a fieldbus by ms
    lags_the_torque = True

    def apply(self, plant, values):
        return dataclasses.replace(plant, effects=plant.effects + ((terms.TIME_DELAY, (values["delay"],)),))

    def guess(self, plant, scale):
        return {"delay": 0.25 * scale.get("period", 2e-3)}

    def grid(self, plant, ctrl, scale):
        tv = ctrl.velocity_period
        return [{"delay": d} for d in _delay_grid(tv, self.MAX, tv)]

    synth_strength = {"delay": 2e-3}

    def evidence(self, ctx, values):
        d, tv = values.get("delay", 0.0), ctx.velocity_period
        return (f"the {ctx.force_channel or 'force'} command reaches the motor {d * 1e3:.3g} ms late ({d / tv:.1f} "
                f"velocity periods of {tv * 1e6:.3g} us): a drive's computation and transport delay; ")


@register
class FeedbackDelay(Effect):
    """The position the position loop uses (table or motor, as the config says) is late: a linear
    scale read over a fieldbus. Only the loop's feedback: the recorded positions are the true ones."""
    name = "feedback_delay"
    description = ("the position the position loop uses is late (a scale read over a fieldbus): from a "
                   "fraction of a position period to several; the recorded positions are the true ones")
    params = (Param("delay", "time", 0.0, 0.05, 1e-3, "delay of the position loop's feedback"),)
    MAX_PERIODS = 5      # the grid's upper end, position periods

    def apply(self, plant, values):
        return dataclasses.replace(plant, effects=plant.effects + ((terms.FEEDBACK_DELAY, (values["delay"],)),))

    def guess(self, plant, scale):
        return {"delay": 0.25 * scale.get("period", 4e-3)}

    def grid(self, plant, ctrl, scale):
        tp = ctrl.position_period
        return [{"delay": d} for d in _delay_grid(tp / 8, min(self.MAX_PERIODS * tp, 0.05), tp / 8)]

    synth_strength = {"delay": 2e-3}

    def evidence(self, ctx, values):
        d, tp = values.get("delay", 0.0), ctx.position_period
        fb = "motor" if ctx.position_feedback == "motor" else "table"
        return (f"the {fb} position the position loop uses arrives {d * 1e3:.3g} ms late ({d / tp:.2f} position "
                f"periods of {tp * 1e3:.3g} ms; a scale read over a fieldbus); the recorded positions are the true "
                f"ones; ")
