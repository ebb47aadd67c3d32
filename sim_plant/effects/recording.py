"""Artefacts of the recording, not of the plant: a channel logged out of step (the force channel,
the tool tip's instrument), a sensor's constant offset (the force channel, the tool tip).

Each acts on the recorded channels alone (:meth:`~sim_plant.effects.base.RecordEffect.apply_record`);
its evidence says it is a logging artefact or a sensor offset, not physics, and the model of the
axis needs no change.
"""
from __future__ import annotations

import numpy as np

from sim_plant.effects.base import Param, RecordEffect, motor_force_kind, no_tip, register, to_linear

__all__ = ["ChannelSkew", "TipSkew", "ForceOffset", "PositionOffset"]


def _skewed(t, y, skew):
    """``y`` recorded ``skew`` seconds late: y(t - skew), linear between samples, held at the ends."""
    return np.interp(t - skew, t, y)


@register
class ChannelSkew(RecordEffect):
    """The force channel (torque, force or command) is logged out of step with the positions."""
    name = "channel_skew"
    description = ("a logging artefact, not physics: the force (torque) channel is recorded out of step with "
                   "the positions, by a signed skew (+: recorded late)")
    params = (Param("skew", "time", -0.2, 0.2, 0.0, "time skew of the force channel against the positions"),)
    channels = ("torque", "force", "command")
    MAX_SAMPLES = 12     # the grid's range, samples either way

    def apply_record(self, t, channels, values):
        out = dict(channels)
        for c in self.channels:
            if c in out:
                out[c] = _skewed(t, out[c], values["skew"])
        return out

    def guess(self, plant, scale):
        return {"skew": 0.0}

    def grid(self, plant, ctrl, scale):
        ts = scale.get("period", ctrl.position_period)
        n = self.MAX_SAMPLES
        return [{"skew": 0.5 * i * ts} for i in range(-2 * n, 2 * n + 1)]

    synth_strength = {"skew": 8e-3}

    def evidence(self, ctx, values):
        sk = values.get("skew", 0.0)
        which = "x_tip" if "x_tip" in self.channels else (ctx.force_channel or "force")
        return (f"a logging artefact, not physics: the {which} channel is recorded {abs(sk) * 1e3:.3g} ms "
                f"({abs(sk) / ctx.sample_period:.2f} samples) {'late' if sk >= 0 else 'early'} against the "
                f"others; the model of the axis needs no change; ")


@register
class TipSkew(ChannelSkew):
    """The tool-tip channel is logged by another instrument (an interferometer with its own clock)."""
    name = "tip_skew"
    description = ("a logging artefact, not physics: the tool-tip channel (another instrument) is recorded out "
                   "of step with the drive's channels, by a signed skew (+: recorded late)")
    params = (Param("skew", "time", -0.2, 0.2, 0.0, "time skew of the x_tip channel against the others"),)
    channels = ("x_tip",)
    synth_strength = {"skew": 8e-3}

    def unsuited(self, plant):
        return no_tip(plant)


@register
class ForceOffset(RecordEffect):
    """A constant offset of the force sensor (a current or torque reading, a load cell): the
    recorded torque (rotary) or force (linear) reads ``offset`` more than the actuator delivered.
    A sensor offset, not a load: it changes the recorded channel alone, the same at standstill
    and in motion, and never the positions; a constant load force (``constant_force``) moves the
    axis, and on a P-I loop the torque shows it only as the integrator takes it up (not while dry
    friction holds the axis at rest)."""
    name = "force_offset"
    description = ("a sensor offset, not a load: the force (torque, current) channel reads a constant offset, the "
                   "same at rest and in motion, and the positions are unchanged")
    params = (Param("offset", motor_force_kind, -1e5, 1e5, 0.0, "offset of the recorded torque (force) channel"),)
    channels = ("torque", "force")

    def apply_record(self, t, channels, values):
        out = dict(channels)
        for c in self.channels:
            if c in out:
                out[c] = out[c] + values["offset"]
        return out

    def guess(self, plant, scale):
        # (linear in the offset: any start of the residual's size converges; 0 gives no scale)
        return {"offset": 0.1 * scale.get("force", 1.0) / to_linear(plant)}

    synth_strength = {"offset": 0.4}        # N m on the motor: a current sensor's offset

    def evidence(self, ctx, values):
        off = values.get("offset", 0.0)
        rf, fch, fu, moving = ctx.force_residual, ctx.force_channel, ctx.force_unit, ctx.moving
        rotary = ctx.rotary
        still = ~moving
        parts = [f"{float(np.mean(rf[sel])):+.3g} {fu} {what}" for sel, what in ((still, "at rest"), (moving, "moving"))
                 if rf is not None and sel.sum() >= 8]
        # an open-loop record compares no force channel: the offset is in the actuator's unit
        ou = fu or ("N*m" if rotary else "N")
        sign = "+" if off >= 0 else "-"
        return (f"a sensor offset, not a load: the {fch or ('torque' if rotary else 'force')} channel "
                f"reads {sign}{ctx.fmt_si(abs(off), ou, 3)} more than the "
                f"actuator delivers" + (f" (residual mean {' and '.join(parts)})" if parts else "") +
                "; a load would move the axis and show in the positions, this changes the recorded channel alone; ")


@register
class PositionOffset(RecordEffect):
    """A constant offset of the tool-tip channel (another instrument: a laser interferometer or
    a probe whose zero is not the scale's): a sensor offset, not a motion of the tip."""
    name = "position_offset"
    description = ("a sensor offset, not a motion: the tool-tip position channel (another instrument) reads a "
                   "constant offset from the drive's positions")
    params = (Param("offset", "length", -1.0, 1.0, 0.0, "offset of the recorded x_tip channel"),)
    channels = ("x_tip",)

    def unsuited(self, plant):
        return no_tip(plant)

    def apply_record(self, t, channels, values):
        out = dict(channels)
        if "x_tip" in out:
            out["x_tip"] = out["x_tip"] + values["offset"]
        return out

    def guess(self, plant, scale):
        return {"offset": 1e-6}

    synth_strength = {"offset": 5e-6}

    def evidence(self, ctx, values):
        return (f"a sensor offset, not a motion: the x_tip channel reads {values.get('offset', 0.0) * 1e6:+.3g} um "
                f"from the drive's positions, at rest and in motion alike; ")
