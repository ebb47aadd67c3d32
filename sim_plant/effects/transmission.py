"""Effects of the transmission between motor and table (link 1): backlash, the stiffness k1 along
the travel (a screw held at one end or at both), the screw's periodic lead error.

Evidence: backlash, the gap x_motor - x_table jumps by at reversals; the stiffness, k1 and the
transmission mode's frequency (sim_plant.modal) at both ends of the stretch, and whether the
record can see the variation at all (a constant k1, the best of the two end values and their
mean, scored against the fit: ``ctx.pays``; when it does as well, the variation cannot be seen
over the stroke the record covers); a lead error, its period in x_motor - x_table.
Starts: backlash, the gap the residual shows (x_motor - x_table moving in +x against moving in
-x: the dead zone of +-gap/2 shifts it by the whole gap between the directions) and a coarse grid
over the physical range (:attr:`Backlash.GAP_GRID`, log-spaced), costed and refined along the one
parameter (``ctx.grid_starts``); a lead error, the periodic starts (``ctx.periodic_starts``) on
x_motor - x_table where both are recorded.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from sim_plant import terms
from sim_plant.effects.base import Effect, Param, no_link, no_travel, register
from sim_plant.modal import transmission_mode

__all__ = ["Backlash", "StiffnessAlongTravel", "StiffnessFixedFixed", "PitchError"]


@register
class Backlash(Effect):
    name = "backlash"
    description = "backlash: a dead zone of +-gap/2 in the transmission between motor and table (link 1)"
    params = (Param("gap", "length", 0.0, 2e-3, 5e-6, "total play of the transmission"),)

    def unsuited(self, plant):
        return no_link(plant)

    def apply(self, plant, values):
        self._need_link(plant)
        return dataclasses.replace(plant, effects=plant.effects + (
            (terms.BACKLASH, (0.0, 0.5 * values["gap"], plant.chain.k[0], plant.chain.c[0])),))

    synth_strength = {"gap": 20e-6}
    # a table that rattles in its gap: 0.25 % of a 35 um gap moves the tip's ringing by its residual
    non_smooth = True
    # gaps of the grid, m (total play): over the whole range, and densely (10 % apart) where a ball
    # screw's play lies: a table that rattles in its gap makes the error against the gap rough, its
    # basin a few micrometres wide at 20 um
    GAP_GRID = tuple(sorted(set(float(g) for g in np.geomspace(0.5e-6, 1e-3, 12))
                            | set(float(g) for g in np.geomspace(2e-6, 200e-6, 49))))

    def evidence(self, ctx, values):
        return f"x_motor - x_table jumps by about {values.get('gap', 0) * 1e6:.3g} um at reversals; "

    def grid(self, plant, ctrl, scale):
        return [{"gap": g} for g in self.GAP_GRID]

    def starts(self, ctx, guess):
        gaps = sorted(set(self.GAP_GRID) | {self.gap_from_residual(ctx, self.param("gap").upper)} - {None})
        return ctx.grid_starts(self, [dict(guess, gap=gp) for gp in gaps])

    @staticmethod
    def gap_from_residual(ctx, upper: float) -> float | None:
        """The backlash the residual shows: the median of x_motor - x_table moving in +x less the
        median moving in -x (the model's own elastic part is not in the residual). None without
        both channels, both directions, or a gap within (0, ``upper``)."""
        res0 = ctx.res0
        if "x_motor" not in res0 or "x_table" not in res0:
            return None
        v = ctx.v_cmd
        lim = 0.02 * max(float(np.max(np.abs(v))), 1e-12)
        d = np.asarray(res0["x_motor"]) - np.asarray(res0["x_table"])
        up, down = d[v > lim], d[v < -lim]
        if up.size < 8 or down.size < 8:
            return None
        gap = float(np.median(up) - np.median(down))
        return gap if 0.0 < gap < upper else None


@register
class StiffnessAlongTravel(Effect):
    """The transmission stiffness k1 changes with the nut position: the screw's axial compliance
    grows with the length of screw between the fixed bearing and the nut (EA/L, Eq. 20, for a
    screw held at one end), in series with the compliances that do not move (motor shaft,
    coupling, bearings, nut, nut-table link; Eq. 21). Its compliance 1/k1 is then linear in the
    nut position: the effect is fitted as k1 at the two ends of a stretch of travel
    (``x_start``, ``x_end``: settings, by default the stroke the record covers), and the kernel
    evaluates k1(x_nut) = 1 / (1/k_start + (x - x_start)/(x_end - x_start) (1/k_end - 1/k_start))
    every step (sim_plant.components.k1_along_travel)."""
    name = "stiffness_along_travel"
    description = ("the transmission stiffness k1 changes with the nut position (screw held at one end: EA/L "
                   "in series with the fixed compliances), given at both ends of the travel")
    params = (Param("k_start", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut at x_start"),
              Param("k_end", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut at x_end"),
              Param("x_start", "length", -1e3, 1e3, 0.0, "one end of the travel (a setting, not fitted)", fit=False),
              Param("x_end", "length", -1e3, 1e3, 0.1, "the other end of the travel (a setting, not fitted)",
                    fit=False))
    # a constant k1 is the special case k_start = k_end: named first when the record cannot see the
    # variation (a uniform drift of k1 is not a stiffness along the travel)
    nests = ("parameter:plant.k1",)

    def unsuited(self, plant):
        return no_travel(plant) or no_link(plant)

    def apply(self, plant, values):
        self._need_link(plant)
        x0, x1 = values["x_start"], values["x_end"]
        if not x1 > x0:
            raise ValueError(f"{self.name}: x_end must lie beyond x_start (got {x0:g} .. {x1:g} m)")
        c0, c1 = 1.0 / values["k_start"], 1.0 / values["k_end"]
        return dataclasses.replace(plant, effects=plant.effects + (
            (terms.STIFFNESS_ALONG_TRAVEL, (0.0, plant.chain.k[0], x0, x1, c0, 0.5 * (c0 + c1), c1)),))

    def guess(self, plant, scale):
        k = plant.chain.k[0] if plant.n >= 2 else 5e7
        lo, hi = scale.get("x_min", 0.0), scale.get("x_max", 0.1)
        if not hi > lo:
            hi = lo + 1e-3
        return {"k_start": k, "k_end": k, "x_start": lo, "x_end": hi}

    synth_strength = {"k_start": 1.2 * 5.362e7, "k_end": 0.8 * 5.362e7, "x_start": 0.0, "x_end": 0.08}

    def evidence(self, ctx, values):
        return _stiffness_evidence(self, ctx, values)


@register
class StiffnessFixedFixed(StiffnessAlongTravel):
    """k1 along the travel of a screw held axially at both ends (fixed-fixed): the nut at ``a`` from
    one bearing of ``L`` sees the two screw lengths in parallel, E A L / (a (L - a)) (Eq. 13 with
    rigid bearings, sim_plant.components.k_screw_fixed_fixed), least in the middle. Its compliance
    a (L - a) / (E A L), in series with the fixed ones, is quadratic in the nut position: fitted as
    k1 at both ends of the stretch and midway, wherever the bearings sit. A screw held at one end
    is the special case of a compliance linear along the travel (``stiffness_along_travel``)."""
    name = "stiffness_along_travel_fixed_fixed"
    description = ("the transmission stiffness k1 changes with the nut position as for a screw held at both ends "
                   "(softest between the bearings), given at both ends of the travel and midway")
    params = (Param("k_start", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut at x_start"),
              Param("k_middle", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut midway between x_start and x_end"),
              Param("k_end", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut at x_end"),
              Param("x_start", "length", -1e3, 1e3, 0.0, "one end of the travel (a setting, not fitted)", fit=False),
              Param("x_end", "length", -1e3, 1e3, 0.1, "the other end of the travel (a setting, not fitted)",
                    fit=False))
    nests = ("stiffness_along_travel", "parameter:plant.k1")

    def apply(self, plant, values):
        self._need_link(plant)
        x0, x1 = values["x_start"], values["x_end"]
        if not x1 > x0:
            raise ValueError(f"{self.name}: x_end must lie beyond x_start (got {x0:g} .. {x1:g} m)")
        return dataclasses.replace(plant, effects=plant.effects + (
            (terms.STIFFNESS_ALONG_TRAVEL, (0.0, plant.chain.k[0], x0, x1, 1.0 / values["k_start"],
                                             1.0 / values["k_middle"], 1.0 / values["k_end"])),))

    def guess(self, plant, scale):
        g = super().guess(plant, scale)
        return dict(g, k_middle=g["k_start"])

    # a screw held at both ends: k1 30 % lower with the nut midway than at both ends of the travel
    synth_strength = {"k_start": 5.362e7, "k_middle": 0.7 * 5.362e7, "k_end": 5.362e7, "x_start": 0.0, "x_end": 0.08}


@register
class PitchError(Effect):
    name = "pitch_error"
    description = ("periodic lead error of the screw: the nut sits at x1 + a sin(2 pi x1 / period + phase), "
                   "seen as x_motor - x_table periodic in position")
    params = (Param("amplitude", "length", 0.0, 1e-3, 1e-6, "amplitude of the lead error"),
              Param("period", "length", 1e-4, 1.0, 0.01, "period of the error along the travel (often the pitch)"),
              Param("phase", "dimensionless", -4 * math.pi, 4 * math.pi, 0.0, "phase at x1 = 0 (rad)"))
    periodic = True

    def unsuited(self, plant):
        return no_link(plant)

    def apply(self, plant, values):
        self._need_link(plant)
        return dataclasses.replace(plant, effects=plant.effects + (
            (terms.PITCH_ERROR, (0.0, values["amplitude"], values["period"], values["phase"], plant.chain.k[0])),))

    def guess(self, plant, scale):
        return {"amplitude": 1e-6, "period": plant.pitch or 0.01, "phase": 0.0}

    synth_strength = {"amplitude": 4e-6, "period": 0.01, "phase": 0.5}

    def evidence(self, ctx, values):
        what = "x_motor - x_table" if "x_table" in ctx.res0 else ctx.chan
        return (f"{what} residual periodic in position with period "
                f"{ctx.fmt_si(values.get('period', 0.0), ctx.unit('x_motor'), 3)}; ")

    def starts(self, ctx, guess):
        res0 = ctx.res0
        both = "x_table" in res0 and "x_motor" in res0
        return ctx.periodic_starts(self, guess, (res0["x_motor"] - res0["x_table"]) if both else None)




def _stiffness_evidence(eff, ctx, vals) -> str:
    """k1 and the transmission mode at both ends of the stretch (and midway, for a screw held at
    both ends); whether the record sees the change at all."""
    x0, x1, k0, k1 = vals["x_start"], vals["x_end"], vals["k_start"], vals["k_end"]
    chain = ctx.plant.chain

    def mode(k):
        return transmission_mode(type(chain)(chain.m, (k,) + tuple(chain.k[1:]), chain.c, chain.c_ground))
    kmean = 2.0 / (1.0 / k0 + 1.0 / k1)
    change = 100.0 * (k1 - k0) / kmean
    text = (f"k1 {k0:.4g} N/m with the nut at {x0 * 1e3:.4g} mm, {k1:.4g} N/m at {x1 * 1e3:.4g} mm ({change:+.0f} % "
            f"along the travel); the transmission mode at {mode(k0):.1f} Hz and {mode(k1):.1f} Hz there; ")
    if "k_middle" in vals:
        km = vals["k_middle"]
        # the compliance c(s) = c0 (2s-1)(s-1) + 4 cm s(1-s) + c1 s(2s-1) on s in [0, 1]: its vertex
        c0, cm, c1 = 1 / k0, 1 / km, 1 / k1
        curv = 2 * (c0 + c1) - 4 * cm           # c(s) = curv s^2 + ..., softest inside where curv < 0
        slope = 4 * cm - 3 * c0 - c1
        s_v = -slope / (2 * curv) if curv != 0 else math.nan
        text += f"{km:.4g} N/m midway ({mode(km):.1f} Hz); "
        if curv < 0 and 0.0 < s_v < 1.0:
            text += (f"softest with the nut at {(x0 + s_v * (x1 - x0)) * 1e3:.4g} mm, between the bearings of a "
                     f"screw held at both ends (EA L/(a (L - a)) in series with the fixed compliances); ")
        else:
            text += "no softest point inside the travel: a screw held at one end does as well; "
    else:
        text += ("the compliance 1/k1 linear in the nut position, as EA/L of a screw held at one end in series "
                 "with the fixed compliances; ")
    xs = ctx.meas["x_cmd"]
    lo, hi = float(np.min(xs)), float(np.max(xs))
    if hi - lo < 0.5 * (x1 - x0):
        text += f"the record covers {lo * 1e3:.4g} .. {hi * 1e3:.4g} mm only; "
    # can the record see the change? a constant k1 (the best of the ends' values and their mean) against the fit
    ks = [k for n, k in vals.items() if n.startswith("k_")]
    try:
        res1 = ctx.residuals_with(eff, vals)
        best = None
        for k in (k0, kmean, k1):
            r = ctx.residuals_with(eff, dict(vals, **{n: k for n in vals if n.startswith("k_")}))
            cost = ctx.cost(r)
            if best is None or cost < best[0]:
                best = (cost, r)
        seen = ctx.pays(best[1], res1, len(ks) - 1)
    except ValueError:
        seen = True
    if not seen or not math.isfinite(change):
        text += (f"the variation cannot be seen over the stroke this record covers ({lo * 1e3:.4g} .. {hi * 1e3:.4g} "
                 f"mm): a constant k1 fits as well; ")
    return text
