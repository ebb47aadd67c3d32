"""Effects of the structure: a mode the model lacks at the tool tip, a change of the moving mass.

An added mode hangs on the chain's last body, and its mass is new or split off that body
(``origin`` "new" or "lumped": a 2-dof model of a column lumps the column's mass into the
table's, and the mode found splits it off, the moving mass kept; a setting, not a share, which
the record could not tell from the mass beside a heavy body). The tool tip is measured on the new
mass (``tip`` "mode") or where the model measured it, the mode lying past it (``tip`` "kept": a
tool or a fixture that the tip's sensor does not see, which loads the tip at its own frequency).

Its starts (:meth:`CompliantMode.starts`): coupled to the chain, the new mode does not show at its
own frequency (the measured resonances move), so for modal masses of 0.05 to 1.5 times the tip
mass (and, split off the table, 0.01 to 0.5 of it) the natural frequency that puts a mode of the
coupled chain within 3 % of a peak of the residual spectrum (``ctx.mode_targets()``: the
residual's own peaks, not the command's lines); beside those, a coarse grid over the physical
range at damping ratio :attr:`CompliantMode.GRID_DAMPING`: the modal mass first
(:attr:`CompliantMode.GRID_MASSES` log-spaced over :attr:`CompliantMode.GRID_RATIOS` of the tip
mass, the mode stiff at the grid's top frequency, where it acts as a mass on the tip), then at the
two best masses the natural frequency (:attr:`CompliantMode.GRID_FREQS` log-spaced from
:attr:`CompliantMode.GRID_FMIN` to the record's 0.45 / sample period); each line refined between
its best point's neighbours (``ctx.grid_starts``). The fits start from the cheapest of each: the
peaks, the grid (a light fast mode and a heavy slow one shift the chain's own resonance alike, the
grid tells them apart), the grid's frequencies again with the tip kept (a mode past the tip puts
no peak of its own in the tip's residual: the independent simulator's 0.5 kg at 60 Hz showed only as
the tip mode's shift, and was named a heavier tip) and, where the mode hangs on the table
(:meth:`CompliantMode.may_split`), the peaks with the mass split off.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from sim_plant.chain import Chain
from sim_plant.effects.base import Effect, Param, register

__all__ = ["CompliantMode", "MassChange"]

@register
class CompliantMode(Effect):
    name = "compliant_mode"
    description = ("an extra mass-spring-damper at the tool tip (a structural mode the model lacks), new or "
                   "split off the mass the model held rigidly there; the new mass becomes the tool tip, or the mode "
                   "lies past the measured tip")
    params = (Param("mass", "mass", 1e-3, 1e4, 5.0, "modal mass of the extra mode"),
              Param("frequency", "frequency", 0.5, 1e3, 20.0, "natural frequency of the extra mode (Hz)"),
              Param("damping_ratio", "dimensionless", 1e-4, 1.0, 0.02, "its damping ratio"),
              Param("origin", "dimensionless", 0.0, 1.0, 0.0,
                    "where the modal mass comes from: new on the axis, or lumped (the model held it rigidly in "
                    "the body the mode hangs on; split off it, the moving mass is kept) (a setting)",
                    fit=False, choices=("new", "lumped")),
              Param("tip", "dimensionless", 0.0, 1.0, 0.0,
                    "where the tool tip is measured: on the mode's mass, or kept where the model measures it, the "
                    "mode lying beyond (a tool or a fixture that the tip's sensor does not see) (a setting)",
                    fit=False, choices=("mode", "kept")))

    def apply(self, plant, values):
        m, f, z = values["mass"], values["frequency"], values["damping_ratio"]
        w = 2 * math.pi * f
        k, c = m * w * w, 2 * z * m * w
        ch = plant.chain
        # a model that lumps the structure rigidly holds the mode's mass in its last body already
        host = ch.m[-1] - m * self._lumped(values)
        if host <= 0:
            raise ValueError(f"compliant_mode: {m:g} kg split off the {ch.m[-1]:g} kg it hangs on leaves {host:g} kg")
        chain = Chain(ch.m[:-1] + (host, m), ch.k + (k,), ch.c + (c,), ch.c_ground + (0.0,))
        return dataclasses.replace(plant, chain=chain, tip=plant.tip if self._kept(values) else ch.n)

    def _lumped(self, values) -> bool:
        return self.param("origin").written(values.get("origin", 0.0)) == "lumped"

    def _kept(self, values) -> bool:
        return self.param("tip").written(values.get("tip", 0.0)) == "kept"

    synth_strength = {"mass": 2.0, "frequency": 25.0, "damping_ratio": 0.02}
    screen_starts = 4          # the residual's peaks, the grid, the grid past the tip, the peaks split off: basins apart
    GRID_FREQS = 12            # natural frequencies of the grid
    GRID_FMIN = 2.0            # Hz, the grid's lower end
    GRID_RATIOS = (0.02, 2.0)  # the grid's modal masses, relative to the tip mass: lowest, highest
    GRID_MASSES = 7            # modal masses of the grid
    GRID_DAMPING = 0.02        # damping ratio of the grid's points
    PEAK_RATIOS = (0.05, 0.15, 0.5, 1.5)     # modal masses of the peaks' starts, relative to the tip mass
    LUMPED_RATIOS = (0.01, 0.05, 0.15, 0.5)  # the same split off the table, relative to it

    @property
    def cost_factor(self) -> int:
        return 3

    def degenerate(self, values, cfg=None, sample_period=None):
        # stiff to the frequency's bound, or damped past ringing, the "mode" is a rigid mass on the
        # tip (parameter:plant.m3) or a damper: not a mode; above the record's Nyquist frequency it
        # cannot ring in the record at all, and what the fit took is the mass
        at = [n for n in self._at_bound(values, ("frequency", "damping_ratio"))
              if values[n] > 0.5 * (self.param(n).upper + self.param(n).lower)]
        f = values.get("frequency")
        if sample_period and f is not None and f > 0.5 / sample_period and "frequency" not in at:
            return (f"a mode at {f:.4g} Hz, above the record's Nyquist frequency ({0.5 / sample_period:.4g} Hz), "
                    f"cannot ring in it: a rigid {values.get('mass', 0.0):.3g} kg on the tip; ")
        if not at:
            return ""
        return (f"a mode at its bound ({', '.join(f'{n} {values[n]:.4g}' for n in at)}) is no mode: a rigid "
                f"{values.get('mass', 0.0):.3g} kg on the tip or a damper; ")

    def evidence(self, ctx, values):
        f = values.get("frequency", 0.0)
        near = [fm for fm in ctx.base_modes if abs(fm - f) < 0.1 * f]
        tail = "not a mode of the model" if not near else f"near the model's {near[0]:.1f} Hz mode"
        m, host = values.get("mass", 0.0), ctx.plant.chain.m[-1]
        split = (f"; its {m:.3g} kg split off the {host:.4g} kg body it hangs on, which held it rigidly (now "
                 f"{host - m:.4g} kg)" if self._lumped(values) else "")
        past = "; past the measured tip, which its sensor does not see" if self._kept(values) else ""
        return f"residual peak at {f:.1f} Hz in {ctx.chan}, {tail}{split}{past}; "

    def starts(self, ctx, guess):
        # the cheapest start from the residual's peaks, of the grid, of the grid with the tip kept and,
        # where the mode may be split off, of the peaks with the mass split off: the cheapest start is
        # not always in the deepest basin, and a split start cheaper than a new mass's must not take
        # its place
        lines = [self.peak_starts(ctx, guess), *self.grid_starts(ctx)]
        if self.may_split(ctx.plant):
            lines.append(self.peak_starts(ctx, guess, lumped=True))
        return [s for line in lines for s in ctx.prefilter(self, line, keep=1)]

    @staticmethod
    def may_split(plant) -> bool:
        """Whether a mode's mass may be split off the body it would hang on: only where that body is
        the table (a rigid axis's one mass, a 2-dof model's table), which a model that lumps the
        structure holds it in. A tip body the model already hangs on a spring of its own has its
        mode; split, it stood for a softer spring (a 2 kg tool-side mode at 98 Hz was fitted as the
        tip's whole mass, 4.227 of 4.228 kg, on a 22 Hz spring)."""
        return plant.table == plant.chain.n - 1

    def peak_starts(self, ctx, guess, lumped: bool = False) -> list[dict]:
        """For each modal mass (relative to the tip mass; split off the last body, :attr:`LUMPED_RATIOS`
        of it, where ``lumped``) the natural frequency that puts one of the coupled chain's modes on a peak of the
        residual spectrum, with a low damping."""
        fmax = 0.45 / ctx.sample_period
        targets = ctx.mode_targets()[:2] or [guess["frequency"]]
        plant = ctx.plant
        # split off, relative to the body the mode hangs on
        m_ref = plant.chain.m[-1] if lumped else plant.chain.m[plant.tip]
        f_grid = np.geomspace(0.5, fmax, 240)
        origin = self.param("origin").number("lumped" if lumped else "new")
        starts = []
        for ratio in (self.LUMPED_RATIOS if lumped else self.PEAK_RATIOS):
            m = ratio * m_ref
            for ft in targets:
                best = None
                for fn in f_grid:
                    ch = self.apply(plant, {"mass": m, "frequency": fn, "damping_ratio": 0.0, "origin": origin}).chain
                    ev = np.linalg.eigvals(np.linalg.solve(ch.M, ch.K)).real
                    fm = np.sqrt(np.maximum(ev, 0.0)) / (2 * np.pi)
                    d = float(np.min(np.abs(fm - ft))) / ft
                    if best is None or d < best[0]:
                        best = (d, fn)
                if best[0] < 0.03:
                    starts.append({"mass": m, "frequency": float(best[1]), "damping_ratio": 0.01, "origin": origin,
                                   "tip": 0.0})
            starts.append({"mass": m, "frequency": targets[0], "damping_ratio": 0.01, "origin": origin, "tip": 0.0})
        return starts

    def grid_starts(self, ctx) -> tuple[list[dict], list[dict]]:
        """The coarse grid (the module's definition): the modal mass with the mode stiff, then the
        natural frequency at the best masses, the tip measured on the mode's mass and, a second
        line on the same masses, where the model measures it (``tip`` kept); the cheapest two of
        each line."""
        m_tip = ctx.plant.chain.m[ctx.plant.tip]
        p = self.param("frequency")
        fmax = min(0.45 / ctx.sample_period, p.upper)
        freqs = np.geomspace(max(self.GRID_FMIN, p.lower), fmax, self.GRID_FREQS)
        masses = [{"mass": float(r * m_tip), "frequency": float(fmax), "damping_ratio": self.GRID_DAMPING, "origin": 0.0,
                   "tip": 0.0}
                  for r in np.geomspace(self.GRID_RATIOS[0], self.GRID_RATIOS[1], self.GRID_MASSES)]
        stiff = ctx.grid_starts(self, masses, keep=2, fine=3)
        lines = []
        for tip in (self.param("tip").number(t) for t in ("mode", "kept")):
            line = list(stiff)
            for best in stiff:
                line += ctx.grid_starts(self, [dict(best, frequency=float(f), tip=tip) for f in freqs], keep=2, fine=3)
            lines.append(line)
        return lines[0], lines[1]


@register
class MassChange(Effect):
    name = "mass_change"
    description = "a change of the moving mass (payload, workpiece) on the table"
    params = (Param("mass", "mass", -1e4, 1e5, 0.0, "mass added to the table (negative: removed)"),)

    def apply(self, plant, values):
        ch = plant.chain
        m = list(ch.m)
        m[plant.table] += values["mass"]
        if m[plant.table] <= 0:
            raise ValueError(f"mass_change: the table mass would be {m[plant.table]:g} kg")
        return dataclasses.replace(plant, chain=dataclasses.replace(ch, m=tuple(m)))

    def guess(self, plant, scale):
        return {"mass": 0.05 * plant.chain.m[plant.table]}

    synth_strength = {"mass": 80.0}
    linear_param = "mass"

    def drifted_key(self, plant):
        return f"plant.m{plant.table + 1}"

    def evidence(self, ctx, values):
        return f"{ctx.chan} residual follows the acceleration: {values.get('mass', 0):+.3g} kg on the table; "

    def linear_column(self, ctx):
        return ctx.a / ctx.force_to_load, ctx.configured(self.name, "mass")
