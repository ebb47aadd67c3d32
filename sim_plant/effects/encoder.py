"""Effects of the sensors: an encoder's interpolation error, the position error within one signal
period.

A sin/cos encoder (a rotary one on the motor, or a linear scale on the table) interpolates within
each signal period P, its grating pitch: a linear scale's 20 um, or for a rotary encoder of N
lines per revolution the pitch / N of travel (10 mm / 2048 = 4.88 um). Offsets, an amplitude
mismatch and a phase error of its two tracks make the reading periodic in the position, with 1
and 2 cycles per signal period (Heidenhain's "interpolation error" or "position error within one
signal period", typically +-1 % of P: +-0.2 um on a 20 um scale)::

    reading = x + a1 sin(2 pi x / P + phi1) + a2 sin(4 pi x / P + phi2)

(x the true position of the encoder's mass). The error is in the reading, not in the plant: the
kernel term ENCODER_ERROR (sim_plant.kernel.reading) is read by drivers.control's feedback stages,
so that the simulator, the replay and the real-time loop read the encoders alike. The recorded
channel shows it; an encoder in the feedback path feeds it to the loops. The motor encoder is the
velocity loop's too: the drive derives the motor's speed from it, and the measured speed carries the
error's change over one velocity period, (e(x) - e(x - v Tv)) / Tv (v e'(x) where a signal period
takes many velocity periods): a ripple of frequency v / P that the velocity loop turns into a
torque ripple, with its closed loop's gain there (with ``control.velocity_feedback =
"position_difference"`` the filtered readings carry it already). A table scale in the position
loop moves the axis by the position loop's response to it.

Quantisation is modelled already and not repeated here: ``sensors.motor_resolution`` and
``sensors.table_resolution`` quantize every reading (drivers.control.quantize), after this error (the
interpolator's quantum on the interpolated position). Its error is a sawtooth periodic with the
quantum; this one is periodic with the signal period.

Parameters: ``encoder`` (a setting: ``motor`` or ``table``), ``period`` (a setting: where the
config gives it, that one; else the starts choose it from the catalogue's signal periods,
:data:`LINES_PER_REVOLUTION` on a motor turning a screw, :data:`SCALE_PERIODS` on a scale; a fit
cannot move a period, whose phase drifts over thousands of periods of travel), the amplitudes
``amplitude1``, ``amplitude2`` (bounded by :data:`MAX_FRACTION` of the period: an encoder whose
error reaches 5 % of its period is broken or misadjusted, not interpolating) and their phases.

Closed forms (tests/test_encoder_error.py): at constant speed the recorded reading of an encoder
outside every feedback path differs from the true position by exactly e(x); a motor encoder in the
velocity loop makes the torque ripple of the sampled loop's transfer from a speed disturbance,
-C(z) (1 - 1/z) / (Tv (1 + C(z) G(z))) times the speed scale, at z = exp(j 2 pi v Tv / P).

Identification: the starts screen every (encoder, period) of the grid (periods of at least
:data:`RESOLVED_QUANTA` quanta of the recorded position) by the residual of that encoder's channel while moving regressed on the sine and cosine of 1 and 2 cycles per period of
its measured position (beside 1, v, a and sign(v) of the command), in closed form: the amplitudes and phases
of the strongest few, costed by simulation (``ctx.prefilter``). The evidence names the period and
the channel, says what the effect mimics (a torque ripple of the same order per revolution, a
lead error of that period) and which reading the channels support: an error in one encoder's
channel alone is its reading's; one that the other channels show too moves the axis.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from sim_plant import terms
from sim_plant.effects.base import Effect, Param, register

__all__ = ["EncoderError", "LINES_PER_REVOLUTION", "SCALE_PERIODS", "MAX_FRACTION", "CHANNELS", "harmonics",
           "record_quantum", "RESOLVED_QUANTA"]

MAX_FRACTION = 0.05        # the largest error per harmonic, as a fraction of the signal period
# signal periods per revolution of the motor's encoders: resolvers (1 to 8 speeds), magnetic and optical
# sin/cos encoders
LINES_PER_REVOLUTION = (1, 2, 3, 4, 5, 6, 8, 16, 32, 64, 128, 256, 500, 512, 1000, 1024, 2000, 2048, 2500, 4096,
                        5000, 8192, 10000, 16384)
# signal periods of linear scales, m: interferential (0.512, 2, 4 um), optical (8 to 40 um), magnetic (0.1 to 5 mm)
SCALE_PERIODS = (0.512e-6, 2e-6, 4e-6, 8e-6, 10e-6, 16e-6, 20e-6, 40e-6, 100e-6, 200e-6, 250e-6, 400e-6, 500e-6,
                 1e-3, 2e-3, 5e-3)
CHANNELS = ("x_motor", "x_table")     # the recorded channel of each encoder (terms.MOTOR_ENCODER, TABLE_ENCODER)
KEPT = 3                   # (encoder, period) pairs of the screen solved in closed form and costed
RESOLVED_QUANTA = 16       # the shortest period screened, in quanta of the recorded position (8 per cycle of its 2nd harmonic)
MIN_MOVING = 64            # moving samples the screen reads (else all of them)


def record_quantum(x) -> float:
    """The recorded position's quantum: the smallest step between the values it takes (0 where it
    takes one value)."""
    d = np.diff(np.unique(np.asarray(x, float)))
    d = d[d > 0]
    return float(np.min(d)) if d.size else 0.0


def harmonics(x, r, period: float, slow=None):
    """The part of ``r`` periodic in the position ``x`` with ``period``, by least squares on the sine
    and cosine of 1 and 2 cycles per period beside the columns ``slow`` (default: a constant):
    (energy it explains, a1, phi1, a2, phi2), r ~ a1 sin(2 pi x / P + phi1) + a2 sin(4 pi x / P + phi2)."""
    x = np.asarray(x, float)
    r = np.asarray(r, float)
    slow = np.ones((x.size, 1)) if slow is None else slow
    th = 2.0 * np.pi * x / period
    X = np.column_stack([slow, np.sin(th), np.cos(th), np.sin(2 * th), np.cos(2 * th)])
    coef, *_ = np.linalg.lstsq(X, r, rcond=None)
    c0, *_ = np.linalg.lstsq(slow, r, rcond=None)
    e_slow, e_all = r - slow @ c0, r - X @ coef
    s1, k1, s2, k2 = (float(c) for c in coef[-4:])
    # a sin(th + phi) = a cos(phi) sin(th) + a sin(phi) cos(th)
    return (max(float(e_slow @ e_slow - e_all @ e_all), 0.0), math.hypot(s1, k1), math.atan2(k1, s1),
            math.hypot(s2, k2), math.atan2(k2, s2))


@register
class EncoderError(Effect):
    name = "encoder_error"
    description = ("an encoder's interpolation error: the motor's or the table's encoder reads x + a1 sin(2 pi x/P "
                   "+ phi1) + a2 sin(4 pi x/P + phi2), periodic with its signal period P (a reading, not a motion)")
    params = (Param("encoder", "dimensionless", 0.0, 1.0, 0.0, "which encoder reads wrong: motor or table (a setting)",
                    fit=False, choices=("motor", "table")),
              Param("period", "length", 1e-7, 0.05, 20e-6,
                    "the encoder's signal period along the travel (pitch / lines per revolution on the motor; the "
                    "scale's grating period); a setting", fit=False),
              Param("amplitude1", "length", 0.0, 1e-4, 0.2e-6,
                    f"error of 1 cycle per signal period (at most {MAX_FRACTION:.0%} of the period)"),
              Param("phase1", "dimensionless", -4 * math.pi, 4 * math.pi, 0.0, "its phase at x = 0 (rad)"),
              Param("amplitude2", "length", 0.0, 1e-4, 0.0,
                    f"error of 2 cycles per signal period (at most {MAX_FRACTION:.0%} of the period)"),
              Param("phase2", "dimensionless", -4 * math.pi, 4 * math.pi, 0.0, "its phase at x = 0 (rad)"))
    periodic = True
    # the paper bench's linear scale: a 40 um grating (a steel tape scale) read 2 % off in its first harmonic
    synth_strength = {"encoder": 1.0, "period": 40e-6, "amplitude1": 0.8e-6, "phase1": 0.4, "amplitude2": 0.3e-6,
                      "phase2": -1.0}

    def apply(self, plant, values):
        enc, per = int(round(values["encoder"])), values["period"]
        if enc not in (terms.MOTOR_ENCODER, terms.TABLE_ENCODER):
            raise ValueError(f"{self.name}: encoder must be motor or table (got {values['encoder']!r})")
        if not per > 0:
            raise ValueError(f"{self.name}: period must be positive (got {per:g} m)")
        for a in ("amplitude1", "amplitude2"):
            if not 0.0 <= values[a] <= MAX_FRACTION * per:
                raise ValueError(f"{self.name}: {a} must lie within 0 .. {MAX_FRACTION:.0%} of the period "
                                 f"({MAX_FRACTION * per:.3g} m), got {values[a]:.3g} m")
        return dataclasses.replace(plant, effects=plant.effects + (
            (terms.ENCODER_ERROR, (float(enc), per, values["amplitude1"], values["phase1"], values["amplitude2"],
                                    values["phase2"])),))

    def guess(self, plant, scale):
        per = plant.pitch / 2048 if plant.pitch else 20e-6
        return {"encoder": 0.0, "period": per, "amplitude1": 0.01 * per, "phase1": 0.0, "amplitude2": 0.0,
                "phase2": 0.0}

    # --- the identification's hooks

    def _periods(self, plant, enc: int) -> list[float]:
        """The grid of signal periods of encoder ``enc``: a motor turning a screw, pitch / lines per
        revolution; a scale (or a linear motor's encoder), the scales' periods."""
        lo, hi = self.param("period").lower, self.param("period").upper
        if enc == terms.MOTOR_ENCODER and plant.pitch:
            return [plant.pitch / n for n in LINES_PER_REVOLUTION if lo <= plant.pitch / n <= hi]
        return [p for p in SCALE_PERIODS if lo <= p <= hi]

    @staticmethod
    def _channel(ctx, enc: int):
        """(channel name, its residual, the position it is periodic in) of encoder ``enc``: its own
        channel where recorded, else the primary residual against the command."""
        chan = CHANNELS[enc]
        if chan in ctx.res0 and chan in ctx.meas:
            return chan, np.asarray(ctx.res0[chan], float), np.asarray(ctx.meas[chan], float)
        main = ctx.chan if ctx.chan in ctx.res0 else next(iter(ctx.res0))
        return main, np.asarray(ctx.res0[main], float), np.asarray(ctx.meas["x_cmd"], float)

    @staticmethod
    def _slow(ctx):
        """The slow regressors beside the harmonics: 1, v, a and sign(v) of the command; and the
        samples they are read on: moving ones (at rest the samples crowd at a few positions, where a
        short period's sine and cosine fit any residual), all of them where fewer than
        :data:`MIN_MOVING` move."""
        v = np.asarray(ctx.v_cmd, float)
        a = np.gradient(v, ctx.meas.t)
        sel = np.asarray(ctx.moving, bool)
        if sel.sum() < MIN_MOVING:
            sel = np.ones_like(sel)
        return np.column_stack([np.ones_like(v), v, a, np.sign(v)])[sel], sel

    def starts(self, ctx, guess):
        given_enc = ctx.given(self.name, "encoder")
        given_per = ctx.given(self.name, "period")
        encs = [int(round(given_enc))] if given_enc is not None else [terms.MOTOR_ENCODER, terms.TABLE_ENCODER]
        slow, sel = self._slow(ctx)
        screened = []          # (encoder, period, energy, a1, phi1, a2, phi2)
        for enc in encs:
            _, r, x = self._channel(ctx, enc)
            r, x = r[sel], x[sel]
            # a record quantized to q cannot show a period of a few quanta: its own grid's sawtooth would
            # (its harmonics alias onto 1 and 2 cycles per period)
            shortest = RESOLVED_QUANTA * record_quantum(x)
            for per in ([given_per] if given_per else [p for p in self._periods(ctx.plant, enc) if p >= shortest]):
                screened.append((enc, per) + harmonics(x, r, per, slow))
        screened.sort(key=lambda s: -s[2])
        kept = []
        for s in screened:
            # twice a period with its energy in the second harmonic is that period's first: the shorter one
            if any(k[0] == s[0] and abs(k[1] - 0.5 * s[1]) < 1e-9 * s[1] for k in screened[:2 * KEPT]) \
                    and s[3] < 0.1 * s[5]:
                continue
            kept.append(s)
            if len(kept) == KEPT:
                break
        starts = []
        for enc, per, _, a1, p1, a2, p2 in kept:
            cap = MAX_FRACTION * per
            starts.append(dict(guess, encoder=float(enc), period=per, amplitude1=min(a1, cap), phase1=p1,
                               amplitude2=min(a2, cap), phase2=p2))
        return ctx.prefilter(self, starts) if len(starts) > 1 else starts or [guess]

    def evidence(self, ctx, values):
        enc = int(round(values.get("encoder", 0.0)))
        per = values.get("period", 0.0)
        if not per > 0:
            return ""
        a1, a2 = values.get("amplitude1", 0.0), values.get("amplitude2", 0.0)
        chan, r, x = self._channel(ctx, enc)
        slow, sel = self._slow(ctx)
        r, x = r[sel], x[sel]
        fmt = ctx.fmt_si
        seen = harmonics(x, r, per, slow)
        which = "motor" if enc == terms.MOTOR_ENCODER else "table"
        rotary_lines = ctx.plant.pitch / per if (enc == terms.MOTOR_ENCODER and ctx.plant.pitch) else None
        lines = (f", {rotary_lines:.6g} per revolution of the motor" if rotary_lines else "")
        text = (f"{chan} residual periodic in the measured position with {fmt(per, 'm', 3)} ({fmt(seen[1], 'm', 2)} "
                f"at 1, {fmt(seen[3], 'm', 2)} at 2 cycles per period): the {which} encoder's interpolation error, "
                f"{fmt(a1, 'm', 3)} and {fmt(a2, 'm', 3)} ({100 * a1 / per:.2g} % and {100 * a2 / per:.2g} % of its "
                f"signal period{lines}); ")
        # the other position channels at that period: the motion's share
        others = []
        for c in ("x_motor", "x_table", "x_tip"):
            if c != chan and c in ctx.res0 and c in ctx.meas:
                h = harmonics(x, np.asarray(ctx.res0[c], float)[sel], per, slow)
                others.append((c, math.hypot(h[1], h[3])))
        own = math.hypot(seen[1], seen[3])
        if others:
            listed = ", ".join(f"{c} {fmt(a, 'm', 2)}" for c, a in others)
            if own > 0 and max(a for _, a in others) < 0.5 * own:
                text += f"the other channels do not show it ({listed}): an error of the reading, not of the motion; "
            else:
                text += (f"the other channels show it too ({listed}): the axis moves with it, a lead error or a "
                         f"ripple that moves the axis is the likelier reading; ")
        n = round(rotary_lines) if rotary_lines else 0
        if n >= 1 and abs(rotary_lines - n) < 1e-6 * n:
            text += (f"it mimics a torque_ripple of order {n} per revolution (period {fmt(per, 'm', 3)}) and a "
                     f"pitch_error of that period, which move the axis; ")
        else:
            text += f"it mimics a pitch_error of period {fmt(per, 'm', 3)}, which moves the table; "
        return text
