"""The flexible transmission at the drive (issue 25): a 2-mass model, the motor and the load with
the screw's stiffness and damping between them, and the record's ringing after its edges that
its starts and evidence read (:func:`edges`, :func:`ringing`).

Conventions: SI; the link is given by its 2-mass resonance f = sqrt(k (1/m_motor + 1/m_load)) / 2 pi
and damping ratio, k = mu (2 pi f)^2, c = 2 zeta mu 2 pi f, mu = m_motor m_load / (m_motor + m_load).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from sim_plant import terms
from sim_plant.chain import Chain
from sim_plant.effects.base import Effect, Param, register
from sim_plant.plant import Plant

__all__ = ["FlexibleTransmission", "edges", "ringing", "RING_WINDOW"]

# link-indexed kernel terms: a link inserted at the drive moves them one link on
_LINK_TERMS = (terms.BACKLASH, terms.PITCH_ERROR, terms.STIFFNESS_ALONG_TRAVEL, terms.LOAD_FRICTION)
RING_WINDOW = 0.1        # s after each edge of the command in which the residual's ringing is looked for


def edges(t, x_cmd, window: float = RING_WINDOW) -> list[int]:
    """Sample indices where the commanded acceleration steps (the record's edges: a move starts,
    ends or changes its ramp), at least ``window`` apart: the jumps of the acceleration above a
    fifth of the largest."""
    t = np.asarray(t, float)
    a = np.gradient(np.gradient(np.asarray(x_cmd, float), t), t)
    da = np.abs(np.diff(a))
    if da.size == 0 or not np.max(da) > 0:
        return []
    out, last = [], -math.inf
    for i in np.flatnonzero(da > 0.2 * np.max(da)):
        if t[i] - last >= window:
            out.append(int(i))
            last = t[i]
    return out


def ringing(t, x_cmd, residual, window: float = RING_WINDOW, fmin: float = 2.0) -> tuple[float, float] | None:
    """(frequency Hz, share) of the residual's ringing after the record's edges: the peak of the
    power spectrum averaged over the ``window`` after each edge (mean-free, Hann-windowed, zero-padded
    to a 1/16 Hz grid), above ``fmin`` and below 0.45 / sample period; ``share``: the part of the
    residual's energy in those windows. None without edges or a window of 8 samples."""
    t = np.asarray(t, float)
    r = np.asarray(residual, float)
    dt = float(np.median(np.diff(t)))
    n = int(round(window / dt))
    idx = [i for i in edges(t, x_cmd, window) if i + n <= r.size]
    if n < 8 or not idx:
        return None
    nfft = max(int(2 ** math.ceil(math.log2(16.0 / dt))), 2 * n)
    w = np.hanning(n)
    power = np.zeros(nfft // 2 + 1)
    inside = np.zeros(r.size, bool)
    for i in idx:
        seg = r[i:i + n] - np.mean(r[i:i + n])
        power += np.abs(np.fft.rfft(seg * w, nfft)) ** 2
        inside[i:i + n] = True
    f = np.fft.rfftfreq(nfft, dt)
    band = (f >= max(fmin, 1.0 / window)) & (f <= 0.45 / dt)
    if not band.any() or not np.max(power[band]) > 0:
        return None
    fr = float(f[band][np.argmax(power[band])])
    rm = r - np.mean(r)
    total = float(np.sum(rm ** 2))
    return fr, (float(np.sum(rm[inside] ** 2)) / total if total > 0 else 0.0)


@register
class FlexibleTransmission(Effect):
    """The transmission's flexibility at the drive: a 2-mass model, the motor and the load with
    the screw's stiffness and damping between them (a ball screw's axial and torsional compliance
    with the coupling's). The first mass of the chain (a rigid axis's only mass) is split: the motor
    keeps (1 - ``load_share``) of it, the load side gets the rest, linked by k and c; the masses
    beyond follow the load side through the chain's own links, and the table and tool tip move
    one mass on (a rigid axis's table becomes the load). The link is given by its resonance, the
    2-mass closed form f = sqrt(k (1/m_motor + 1/m_load)) / 2 pi with m_load everything beyond the
    link (exact on a rigid axis, the motor against the whole load on a chain), and its damping
    ratio: k = mu (2 pi f)^2, c = 2 zeta mu 2 pi f, mu = m_motor m_load / (m_motor + m_load).
    Unlike ``compliant_mode``, which hangs a mass on the tool side, the drive itself rings.

    Its hooks (sim_plant.effects.base): :meth:`starts` from the ringing after the record's
    edges and the residual spectrum's peaks, :meth:`evidence` the ringing and the link."""
    name = "flexible_transmission"
    description = ("a flexible transmission at the drive (2-mass model): the motor and the load with the screw's "
                   "stiffness and damping between them, given by the load's share of the first mass, the resonance "
                   "and its damping ratio")
    synth_strength = {"load_share": 0.3, "frequency": 120.0, "damping_ratio": 0.1}
    params = (Param("load_share", "dimensionless", 0.02, 0.98, 0.5,
                    "the load's share of the first mass (the motor keeps the rest)"),
              Param("frequency", "frequency", 0.5, 1e3, 20.0,
                    "the 2-mass resonance sqrt(k (1/m_motor + 1/m_load)) / 2 pi (Hz)"),
              Param("damping_ratio", "dimensionless", 1e-4, 1.0, 0.05, "damping ratio of the resonance"))
    SHARES = (0.25, 0.5, 0.75)     # the load shares tried at each start frequency
    RING_FACTORS = (1.5, 2.0)      # link resonances tried above a ringing frequency (the loop lowers the ring)
    DAMPINGS = (0.03, 0.1, 0.3)    # damping ratios tried at each (the fit barely moves a damping from afar)
    FINE = (3, 0.3)                # the finer grid: 3 steps either way, over +-30 % of the resonance, +-0.075 share
    GRID_FREQS = 8                 # resonances of the log grid from RING_MIN to 0.45 / sample period
    RING_MIN = 2.0                 # Hz: a spectrum's peak below this is the moves' own rhythm, not a link
    PEAKS = 3                      # the strongest spectrum peaks above RING_MIN started from

    @property
    def cost_factor(self) -> int:
        return 3             # a coarse and a fine grid of starts, one simulation each

    @staticmethod
    def link(plant: Plant, values: dict) -> tuple[float, float, float, float]:
        """(m_motor, m_load, k, c) of the link the values give on this plant (SI, load side)."""
        s, f, z = values["load_share"], values["frequency"], values["damping_ratio"]
        if not (0.0 < s < 1.0 and f > 0.0 and z >= 0.0):
            raise ValueError(f"flexible_transmission: expected 0 < load_share < 1, frequency > 0 and "
                             f"damping_ratio >= 0 (got {s:g}, {f:g} Hz, {z:g})")
        m1 = plant.chain.m[0]
        m_motor, m_load = (1.0 - s) * m1, s * m1 + sum(plant.chain.m[1:])
        mu = m_motor * m_load / (m_motor + m_load)
        w = 2.0 * math.pi * f
        return m_motor, m_load, mu * w * w, 2.0 * z * mu * w

    def apply(self, plant, values):
        m_motor, _, k, c = self.link(plant, values)
        ch = plant.chain
        s = values["load_share"]
        chain = Chain((m_motor, s * ch.m[0]) + tuple(ch.m[1:]), (k,) + tuple(ch.k), (c,) + tuple(ch.c),
                      (ch.c_ground[0], 0.0) + tuple(ch.c_ground[1:]))
        terms = tuple((code, (q[0] + 1.0,) + tuple(q[1:])) if code in _LINK_TERMS else (code, q)
                      for code, q in plant.effects)
        return dataclasses.replace(plant, chain=chain, table=plant.table + 1, tip=plant.tip + 1, effects=terms)

    def starts(self, ctx, guess) -> list[dict]:
        """Global starts, cheapest first (``ctx.costs``: one simulation each). A coarse grid: the
        ringing after the record's edges (:func:`ringing` of the strongest weighted channel's
        residual) and the residual spectrum's peaks away from the command's lines
        (``ctx.mode_targets``, Hz; the :data:`PEAKS` strongest above :data:`RING_MIN`), each with the load
        shares :data:`SHARES` and the damping ratios :data:`DAMPINGS`. The loop moves the ring from
        the link's free resonance: a stiff velocity loop holds the motor, and the load rings on k
        alone, lower by sqrt(1 - share); a soft one leaves it free; in between the loop's own
        dynamics mix in. So each ringing frequency f_r gives the link f_r, f_r / sqrt(1 - share) and
        :data:`RING_FACTORS` f_r; beside those, :data:`GRID_FREQS` resonances log-spaced over what
        the record resolves (a stiff link whose ring the residual does not show). Then, around the cheapest point, a finer grid of share and
        frequency (:data:`FINE`): share and resonance trade along a valley that a local fit walks
        slowly. The cheapest three are kept."""
        p = self.param("frequency")
        chan = ctx.strongest_channel
        t, x_cmd = ctx.meas.t, ctx.meas["x_cmd"]
        found = ringing(t, x_cmd, ctx.res0[chan])
        rings = ([found[0]] if found else []) + [f for f in ctx.mode_targets(chan) if f >= self.RING_MIN][:self.PEAKS]
        rings = list(dict.fromkeys(round(f, 2) for f in rings)) or [guess["frequency"]]
        coarse = []
        for s in self.SHARES:
            for fr in rings:
                for f in dict.fromkeys((fr, fr / math.sqrt(1.0 - s)) + tuple(k * fr for k in self.RING_FACTORS)):
                    if p.lower <= f <= p.upper:
                        coarse += [{"load_share": s, "frequency": float(f), "damping_ratio": z} for z in self.DAMPINGS]
        # and a log grid over the resolvable range: a stiff link the residual's peaks do not show
        fmax = min(0.45 / float(np.median(np.diff(t))), p.upper)
        coarse += [{"load_share": s, "frequency": float(f), "damping_ratio": 0.1} for s in self.SHARES
                   for f in np.geomspace(self.RING_MIN, fmax, self.GRID_FREQS)]
        costs = ctx.costs(self, coarse, keep=3)
        best = coarse[min(range(len(coarse)), key=costs.__getitem__)]
        n, span = self.FINE
        sp = self.param("load_share")
        fine = [dict(best, load_share=min(max(best["load_share"] + 0.25 * span * i / n, sp.lower), sp.upper),
                     frequency=min(max(best["frequency"] * (1 + span * j / n), p.lower), p.upper))
                for i in range(-n, n + 1) for j in range(-n, n + 1) if i or j]
        pool = sorted(zip(costs + ctx.costs(self, fine, keep=3, known=costs), range(len(coarse) + len(fine))))
        allp = coarse + fine
        return [allp[k] for _, k in pool][:3]

    def degenerate(self, values, cfg=None, sample_period=None):
        # a link at a bound of its range is no resonance of the drive: a load of a few percent of the
        # mass, a link too stiff or too soft to ring, or damped past ringing
        at = [n for n in self._at_bound(values, ("load_share", "frequency", "damping_ratio"))
              if n != "damping_ratio" or values[n] > 0.5]
        f = values.get("frequency")
        if sample_period and f is not None and f > 0.5 / sample_period and "frequency" not in at:
            # as a tool-side mode: a link that cannot ring in the record moves its masses as one, and
            # what the fit took is a sliver of another effect's residual
            return (f"a 2-mass link at {f:.4g} Hz, above the record's Nyquist frequency ({0.5 / sample_period:.4g} Hz), "
                    f"cannot ring in it: its masses move as one; ")
        if not at:
            return ""
        return (f"a 2-mass link at the bound of its range ({', '.join(f'{n} {values[n]:.4g}' for n in at)}) is no "
                f"resonance of the drive; ")

    def evidence(self, ctx, values) -> str:
        """The ringing the residual shows after the record's edges, and the link the fit gives."""
        m_motor, m_load, k, c = self.link(ctx.plant, values)
        found = ringing(ctx.meas.t, ctx.meas["x_cmd"], ctx.res0[ctx.chan])
        head = (f"the {ctx.chan} residual rings at {found[0]:.1f} Hz after the record's edges ({100 * found[1]:.0f} % "
                f"of its energy in the {RING_WINDOW * 1e3:.0f} ms after them); " if found else "")
        return (head + f"a flexible transmission at the drive: the motor {m_motor:.4g} kg against the load {m_load:.4g} kg "
                f"through k {k:.4g} N/m, resonance {values['frequency']:.1f} Hz, damping ratio "
                f"{values['damping_ratio']:.3g}; ")
