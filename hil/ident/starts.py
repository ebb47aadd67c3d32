"""Starting values for the fit of one candidate effect, from the record and its residual before
the fit (SI units).

Each effect chooses its own (its hook :meth:`sim_plant.effects.base.Effect.starts`, called
with a :class:`StartContext`); the helpers here cost and refine them by simulation. What the
catalogue's effects ask for:

* The record's scales: speed, the 90th percentile of |v| of the command; force, the RMS of the
  force residual in load units, or without a force channel 5 % of the total mass times the RMS
  commanded acceleration; period, the sample period. The effect's own guess uses them.
* Friction and force effects (and a cable carrier's force, on 1 and x; the screw's elongation, the
  slope of x_motor - x_table in x): a linear regression of the force residual while moving
  (|v| > 2 % of max|v|), r = Fc sign(v) + c v + f0, or per direction
  r = Fc+ [v > 0] - Fc- [v < 0] + c+ v [v > 0] + c- v [v < 0], added to what the model has.
* Position-periodic effects (pitch_error, torque_ripple): every order per revolution (periods
  pitch / n, n = 1 .. :data:`MAX_ORDER`, as far as the record resolves them: at least
  :data:`MIN_RESOLVED` moving samples a quarter of the period or less apart), and the two
  strongest periods of the residual's Lomb-Scargle periodogram in position (any period, also a
  linear motor's). Each order is screened by the residual's own spectrum against the motor
  position (:func:`order_spectrum`: the weighted energy that sin and cos of 2 pi x_motor / period
  explain beside the slow regressors 1, v, a, sign(v)); the :data:`PERIODS_KEPT` strongest, the
  Lomb-Scargle periods and the effect's guess are then solved in closed form: the loop is nearly
  linear in the ripple's (lead error's) sine and cosine, so two simulations at one amplitude give
  the amplitude and phase that explain most of the weighted residual (least squares on the two
  responses); the cheapest two, by a third simulation each, are the starts.
* backlash: the gap the residual shows (x_motor - x_table moving in +x against moving in -x:
  the dead zone of +-gap/2 shifts it by the whole gap between the directions), and a coarse grid
  over the physical range (:data:`GAP_GRID`, log-spaced), refined along the one parameter as the
  delays' grids are (below).
* compliant_mode: for modal masses of 0.05 to 1.5 times the tip mass, the natural frequency that
  puts a mode of the coupled chain within 3 % of a peak of the residual spectrum; the cheapest
  two kept. The peaks are the residual's own, above the command's lines (:func:`mode_targets`):
  the inputs' spectra (the commanded acceleration, and ``u_add`` when the record has it) have
  lines, peaks :data:`LINE_ABOVE` times above their running median (:data:`LINE_BINS` bins); a
  residual peak within :data:`LINE_TOL` (or three bins) of a line is the command's forced
  response, not a mode, unless its ratio to the input there stands :data:`LINE_ABOVE` times above
  the median ratio over the input's lines (a mode amplifies the lines near it).
  Beside those, a coarse grid over the physical range, damping ratio :data:`MODE_DAMPING`: the
  modal mass first (:data:`MODE_MASSES` log-spaced over :data:`MODE_RATIOS` of the tip mass, the
  mode stiff at the grid's top frequency, where it acts as a mass on the tip), then at the two
  best masses the natural frequency (:data:`MODE_FREQS` log-spaced from :data:`MODE_FMIN` to the
  record's 0.45 / sample period); each line refined between its best point's neighbours as a
  delay's grid is; every start costed by one simulation; the local fit starts from the cheapest
  start of the residual's peaks and the cheapest of the grid (then the second of each). A coupled mode
  moves the chain's own resonance too, so the residual's peak alone has several basins (a light
  fast mode and a heavy slow one shift it alike): the grid tells them apart.
* Effects with a grid (:meth:`sim_plant.effects.Effect.grid`: the delays, the channel skews, the
  current loop's lag; the error is not convex in a delay): one simulation per grid point over the
  physically possible range, then, for a one-parameter grid, a finer scan between the best point's neighbours; the
  cheapest two are the starts of the local fit.

Where only the cheapest few of many starts are wanted (a grid, a prefilter), not every start is
simulated whole (:func:`_bounded_costs`): a start's weighted squared error on the record's first
:data:`HEAD_SHARE` is a lower bound of its whole error, and that head's simulation is the first
samples of the whole one to the bit (the loop is causal; Replay.head_costs gives it the few ticks
of command the feed-forward reads ahead). So the starts are simulated whole in the order of their
heads until a head exceeds the ``keep``-th cheapest whole error found: the starts kept, their order
and their costs are those of simulating every start whole. On the fleet benchmark's 6 s record
this simulates 673 of the 1220 starts whole (the eighth of a record is the share that costs least
there: a quarter 619, a sixteenth 729).
"""
from __future__ import annotations

import math

import numpy as np

from hil.ident.context import EffectContext
from hil.ident.objective import batched
from hil.ident.replay import Replay, config_key
from hil.ident.residual import periodic_in_position, spectrum_peaks
from hil.plant_config import configure
from hil.simulate import batch_threads
from sim_plant.effects import Backlash, CompliantMode, Effect

__all__ = ["record_scales", "starting_values", "StartContext", "mode_targets", "command_lines", "order_spectrum", "LINE_ABOVE",
           "LINE_TOL", "LINE_BINS", "MAX_ORDER", "MIN_RESOLVED", "PERIODS_KEPT", "GAP_GRID", "MODE_FREQS",
           "MODE_FMIN", "MODE_RATIOS", "MODE_MASSES", "MODE_DAMPING"]

LINE_ABOVE = 10.0    # a line stands this many times above the spectrum's running median
LINE_TOL = 0.05      # a residual peak this close (relative) to an input's line is that line
LINE_BINS = 21       # bins of the running median
MAX_ORDER = 64       # orders per revolution screened (cogging of a motor reaches a few dozen)
MIN_RESOLVED = 64    # moving samples at most a quarter period apart that an order needs
PERIODS_KEPT = 3     # the strongest orders of the screen solved in closed form
HEAD_SHARE = 0.125   # the share of the record whose error bounds a start's (_bounded_costs)
HEAD_ROUNDING = 1e-9  # a head must exceed the bound by this (relative): the sums' rounding differs
# the grids of backlash and of an added mode are the effects' own (sim_plant.effects); their old names here
GAP_GRID = Backlash.GAP_GRID
MODE_FREQS = CompliantMode.GRID_FREQS
MODE_FMIN = CompliantMode.GRID_FMIN
MODE_RATIOS = CompliantMode.GRID_RATIOS
MODE_MASSES = CompliantMode.GRID_MASSES
MODE_DAMPING = CompliantMode.GRID_DAMPING


def record_scales(replay: Replay, res0: dict) -> dict:
    """Typical magnitudes of the record for starting guesses (SI)."""
    m = replay.meas
    v = np.gradient(m["x_cmd"], m.t)
    sc = {"speed": float(np.percentile(np.abs(v), 90)) or 1e-3, "period": replay.sample_period,
          "x_min": float(np.min(m["x_cmd"])), "x_max": float(np.max(m["x_cmd"]))}
    fch = replay.force_channel
    if fch is not None:
        sc["force"] = max(float(np.sqrt(np.mean(res0[fch] ** 2))) * replay.force_to_load, 1e-6)
    else:
        a = np.gradient(v, m.t)
        sc["force"] = 0.05 * replay.plant.total_mass * float(np.sqrt(np.mean(a * a))) + 1e-6
    return sc


def starting_values(eff: Effect, replay: Replay, res0: dict, scale: dict, cfg) -> list[dict]:
    """The starts of ``eff``'s fit, best first: its own hook (:meth:`Effect.starts`) from its guess,
    with a context of the replay and the helpers here (hil.ident.context)."""
    g = eff.guess(replay.plant, scale)
    g = {p.name: g.get(p.name, p.guess) for p in eff.params}
    return eff.starts(StartContext(replay, res0, cfg, scale), g)


class StartContext(EffectContext):
    """The context of an effect's :meth:`~sim_plant.effects.base.Effect.starts` hook: the
    replay's (hil.ident.context) and the helpers here that cost starts by simulation."""

    def grid_starts(self, eff, grid: list[dict], keep: int = 2, fine: int = 6) -> list[dict]:
        """The cheapest ``keep`` points of ``grid`` (one simulation each; a one-parameter grid refined
        between the best point's neighbours by ``fine`` points a side)."""
        return _grid_starts(eff, self.replay, grid, self.cfg, keep=keep, fine=fine)

    def prefilter(self, eff, starts: list[dict], keep: int = 2) -> list[dict]:
        """The ``keep`` cheapest of ``starts`` (one simulation each)."""
        return _prefilter(eff, self.replay, starts, self.cfg, keep=keep)

    def periodic_starts(self, eff, guess: dict, residual=None) -> list[dict]:
        """The starts of a position-periodic effect (hil.ident.starts): ``residual`` the signal its
        periods are read from (default: the record's primary channel's residual)."""
        return _periodic_starts(eff, self.replay, self.res0, guess, self.cfg, residual)

    def mode_targets(self, chan: str | None = None) -> list[float]:
        """The residual's spectral peaks that are not the command's lines, Hz, strongest first
        (``chan``: the residual channel; default the strongest weighted)."""
        return mode_targets(self.replay, self.res0, chan)

    @property
    def strongest_channel(self) -> str:
        """The channel whose weighted residual is the largest."""
        w = self.replay.objective.weights
        return max((c for c in self.res0 if c in w), key=lambda c: float(np.mean(self.res0[c] ** 2)) * w[c] ** 2)

    def costs(self, eff, starts: list[dict], keep: int | None = None, known=()) -> list[float]:
        """The weighted squared error of each of ``starts`` (one simulation each; inf: not simulable).
        With ``keep``: only of those that can be among the ``keep`` cheapest of ``known`` (the costs
        of other points) and ``starts`` together, inf for the others (:func:`_bounded_costs`)."""
        if keep is None:
            return _costs(eff, self.replay, starts, self.cfg)
        return _bounded_costs(eff, self.replay, starts, self.cfg, keep, known)


def _motor_position(replay) -> np.ndarray:
    """The position a periodic effect follows: the motor's (load units) where recorded, else the
    command."""
    m = replay.meas
    return np.asarray(m["x_motor"] if "x_motor" in m else m["x_cmd"], float)


def order_spectrum(replay, res0: dict, periods, chans=None) -> list[float]:
    """The residual's spectrum against the motor position at the given ``periods`` (m): per period
    the weighted residual energy that sin and cos of 2 pi x / period explain by least squares beside
    the slow regressors 1, v, a and sign(v) (velocity and acceleration of the command), summed over
    the channels (``chans``: the objective's), on the moving samples that resolve the period (at most
    a quarter period apart); 0 where fewer than :data:`MIN_RESOLVED` samples do."""
    m = replay.meas
    w = replay.objective.weights
    chans = [c for c in (chans or w) if c in res0]
    x = _motor_position(replay)
    v = np.gradient(np.asarray(m["x_cmd"], float), m.t)
    a = np.gradient(v, m.t)
    step = np.abs(np.gradient(x))
    moving = np.abs(v) > 0.02 * max(float(np.max(np.abs(v))), 1e-12)
    out = []
    for per in periods:
        sel = moving & (step <= 0.25 * per)
        if sel.sum() < MIN_RESOLVED:
            out.append(0.0)
            continue
        ph = 2 * np.pi * x[sel] / per
        slow = np.column_stack([np.ones(sel.sum()), v[sel], a[sel], np.sign(v[sel])])
        X = np.column_stack([slow, np.sin(ph), np.cos(ph)])
        energy = 0.0
        for c in chans:
            r = np.asarray(res0[c], float)[sel] * w[c]
            ssr_slow = _ssr(slow, r)
            energy += max(ssr_slow - _ssr(X, r), 0.0)
        out.append(energy)
    return out


def _ssr(X, y) -> float:
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    e = y - X @ coef
    return float(e @ e)


def _periodic_starts(eff, replay, res0, g, cfg, residual=None) -> list[dict]:
    """The starts of a position-periodic effect (the module's definition): the orders per revolution
    screened by :func:`order_spectrum`, the strongest with the Lomb-Scargle periods (of ``residual``,
    default the primary channel's) and the guess solved in closed form for amplitude and phase, the
    cheapest two kept."""
    lo, hi = eff.param("period").lower, eff.param("period").upper
    pitch = replay.plant.pitch
    r = residual if residual is not None else res0[replay.primary_channel(res0)]
    found = [p for p, _, _ in periodic_in_position(replay.meas["x_cmd"], r, replay.meas.t, n=2)]
    periods = []
    if pitch:
        orders = [pitch / n for n in range(1, MAX_ORDER + 1) if lo <= pitch / n <= hi]
        energy = order_spectrum(replay, res0, orders)
        ranked = [orders[i] for i in np.argsort(energy)[::-1] if energy[i] > 0]
        periods += ranked[:PERIODS_KEPT]
    periods += [p for p in found + [g["period"]] if lo <= p <= hi]
    periods = list(dict.fromkeys(float(p) for p in periods))
    starts = []
    for per in periods:
        s = _solve_amplitude_phase(eff, replay, res0, cfg, dict(g, period=per))
        starts += [s] if s else [dict(g, period=per, phase=ph) for ph in (0.0, math.pi / 2, math.pi, -math.pi / 2)]
    return _prefilter(eff, replay, starts, cfg)


def _solve_amplitude_phase(eff, replay, res0, cfg, g) -> dict | None:
    """Amplitude and phase at one period in closed form: the weighted residual vector falls by D_s
    with the effect at amplitude A0 and phase 0 (A0 sin), by D_c at phase pi/2 (A0 cos); the loop
    being nearly linear in them, a sin + b cos with (a, b) = A0 argmin ||e0 - a' D_s - b' D_c||
    explains the most: amplitude hypot(a, b), phase atan2(b, a). None when a simulation fails."""
    obj = replay.objective
    amp0 = float(g["amplitude"])
    try:
        e0 = obj.vector(res0)
        es = obj.vector(obj.residuals(configure(eff, cfg, dict(g, phase=0.0))))
        ec = obj.vector(obj.residuals(configure(eff, cfg, dict(g, phase=math.pi / 2))))
    except ValueError:
        return None
    D = np.column_stack([e0 - es, e0 - ec])
    coef, *_ = np.linalg.lstsq(D, e0, rcond=None)
    if not np.all(np.isfinite(coef)):
        return None
    a, b = (amp0 * float(c) for c in coef)
    amp = float(np.clip(math.hypot(a, b), eff.param("amplitude").lower, eff.param("amplitude").upper))
    return dict(g, amplitude=amp if amp > 0 else amp0, phase=math.atan2(b, a))


def _spectrum(y, dt):
    """Hann-windowed amplitude spectrum of the mean-free ``y`` (as hil.ident.residual) and its
    frequencies."""
    y = np.asarray(y, float) - np.mean(y)
    w = np.hanning(y.size)
    return np.abs(np.fft.rfft(y * w)) * 2 / w.sum(), np.fft.rfftfreq(y.size, dt)


def command_lines(replay) -> list[tuple[str, np.ndarray, list[int]]]:
    """The lines of the record's inputs: per input (the commanded acceleration; ``u_add`` when
    measured) its name, its amplitude spectrum and the bins of its lines (peaks :data:`LINE_ABOVE`
    times above the running median over :data:`LINE_BINS` bins)."""
    from scipy.ndimage import median_filter
    from scipy.signal import find_peaks
    m = replay.meas
    inputs = [("x_cmd", np.gradient(np.gradient(m["x_cmd"], m.t), m.t))]
    if "u_add" in m:
        inputs.append(("u_add", m["u_add"]))
    out = []
    for name, y in inputs:
        spec, _ = _spectrum(y, replay.sample_period)
        med = median_filter(spec, size=LINE_BINS, mode="nearest")
        idx, _ = find_peaks(spec)
        lines = [int(i) for i in idx if i > 0 and spec[i] > LINE_ABOVE * max(med[i], 1e-300)]
        out.append((name, spec, lines))
    return out


def mode_targets(replay, res0: dict, chan: str | None = None, n: int = 6) -> list[float]:
    """The frequencies (Hz) of the residual's spectral peaks that are not the command's own lines
    (see the module's definitions), strongest first; ``chan``: the residual channel (default: the
    strongest weighted)."""
    if chan is None:
        w = replay.objective.weights
        chan = max((c for c in res0 if c in w), key=lambda c: float(np.mean(res0[c] ** 2)) * w[c] ** 2)
    dt = replay.sample_period
    fmax = 0.45 / dt
    spec_r, f = _spectrum(res0[chan], dt)
    df = float(f[1] - f[0]) if f.size > 1 else 1.0
    inputs = []
    for _, spec_u, lines in command_lines(replay):
        if lines:
            ratio = [spec_r[i] / max(spec_u[i], 1e-300) for i in lines]
            inputs.append((spec_u, lines, float(np.median(ratio))))
    out = []
    for fp, amp in spectrum_peaks(res0[chan], dt, n=4 * n):
        if not 0.5 < fp < fmax:
            continue
        own = False
        for spec_u, lines, med in inputs:
            for i in lines:
                if abs(fp - f[i]) <= max(LINE_TOL * f[i], 3 * df) and amp / max(spec_u[i], 1e-300) <= LINE_ABOVE * med:
                    own = True
        if not own:
            out.append(round(fp, 2))
    return list(dict.fromkeys(out))[:n]


def _costs(eff, replay, starts, cfg) -> list[float]:
    """The weighted squared error of each start (one simulation each; inf where its model cannot be
    configured or fails); those the objective knows already (Objective.known_costs) are not
    simulated again."""
    obj = replay.objective
    known = getattr(obj, "known_costs", None)
    if known is None:
        return _simulated_costs(eff, obj, starts, cfg)
    cfgs = _configured(eff, cfg, starts)
    keys = [None if c is None else config_key(c) for c in cfgs]
    todo = [i for i, k in enumerate(keys) if k is None or k not in known]
    fresh = dict(zip(todo, _simulated_costs(eff, obj, [starts[i] for i in todo], cfg, [cfgs[i] for i in todo])))
    known.update((keys[i], c) for i, c in fresh.items() if keys[i] is not None)
    return [fresh[i] if i in fresh else known[k] for i, k in enumerate(keys)]


def _simulated_costs(eff, obj, starts, cfg, cfgs=None) -> list[float]:
    """:func:`_costs` without what the objective knows; ``cfgs``: the starts' configs, where made."""
    if batched():       # the starts' loops in one compiled call (hil.ident.objective), the same numbers
        return _costs_batched(eff, obj, starts, cfg, cfgs)
    costs = []
    for s in starts:
        try:
            costs.append(_cost(obj, obj.residuals(configure(eff, cfg, s))))
        except ValueError:
            costs.append(math.inf)
    return costs


def _cost(obj, res) -> float:
    """The weighted squared error of residuals ``res``; inf where it is not a number (a loop that ran
    away): such a start is never among the cheapest."""
    c = float(np.sum(obj.vector(res) ** 2))
    return math.inf if math.isnan(c) else c


def _costs_batched(eff, obj, starts, cfg, cfgs=None) -> list[float]:
    """:func:`_costs` with the simulations in one batched call: a start whose model raises a
    ValueError costs infinity (any other error is raised, as one by one)."""
    cfgs = _configured(eff, cfg, starts) if cfgs is None else cfgs
    got = iter(obj.residuals_many([c for c in cfgs if c is not None]))
    costs = []
    for c in cfgs:
        r = next(got) if c is not None else None
        if isinstance(r, Exception) and not isinstance(r, ValueError):
            raise r
        costs.append(math.inf if r is None or isinstance(r, Exception) else _cost(obj, r))
    return costs


def _configured(eff, cfg, starts) -> list:
    """Per start the config with ``eff`` at its values, or None where they are refused (ValueError)."""
    out = []
    for s in starts:
        try:
            out.append(configure(eff, cfg, s))
        except ValueError:
            out.append(None)
    return out


def _bounded_costs(eff, replay, starts, cfg, keep: int, known=()) -> list[float]:
    """:func:`_costs` of the ``starts`` that can be among the ``keep`` cheapest of ``known`` (costs
    of other points) and ``starts`` together, math.inf for the others: a start's error on the
    record's first :data:`HEAD_SHARE` (a short simulation, Replay.head_costs) is a lower bound of
    its whole error, so the starts are simulated whole in the order of those heads, and once a head
    exceeds the ``keep``-th cheapest whole error, that start and every one after it cannot be among
    the cheapest. The cheapest ``keep`` and their costs are :func:`_costs`'s, in the same order."""
    heads = None
    if len(starts) + len(known) > keep > 0 and hasattr(replay, "head_costs"):
        cfgs = _configured(eff, cfg, starts)
        got = replay.head_costs([c for c in cfgs if c is not None], HEAD_SHARE)
        if got is not None:
            it = iter(got)
            # a start whose model fails, or that cannot be configured, is simulated whole (_costs
            # says what it costs), as is one whose head is not a number
            heads = [-math.inf if c is None else next(it) for c in cfgs]
            heads = [-math.inf if h is None or math.isnan(h) else h for h in heads]
    if heads is None:
        return _costs(eff, replay, starts, cfg)
    costs = [math.inf] * len(starts)
    done = sorted(c for c in known if not math.isnan(c))
    order = sorted(range(len(starts)), key=heads.__getitem__)
    chunk = max(1, batch_threads()) if batched() else 1
    for i in range(0, len(order), chunk):
        # the float sums of a head and of the whole differ in their rounding only
        if len(done) >= keep and heads[order[i]] > done[keep - 1] * (1.0 + HEAD_ROUNDING):
            break
        part = order[i:i + chunk]
        for j, c in zip(part, _costs(eff, replay, [starts[j] for j in part], cfg)):
            costs[j] = c
        done = sorted(done + [costs[j] for j in part if not math.isnan(costs[j])])
    return costs


def _prefilter(eff, replay, starts, cfg, keep=2):
    """Keep the few starts with the lowest cost (one simulation each, :func:`_bounded_costs`)."""
    costs = _bounded_costs(eff, replay, starts, cfg, keep)
    order = np.argsort(costs)[:keep]
    return [starts[i] for i in order]


def _grid_starts(eff, replay, grid, cfg, keep=2, fine=6) -> list[dict]:
    """The cheapest ``keep`` points of the grid; along a one-parameter grid, first a finer scan
    (``fine`` points) on each side of the best point, up to its neighbours (one simulation each,
    :func:`_bounded_costs`)."""
    costs = _bounded_costs(eff, replay, grid, cfg, max(keep, 1))
    moved = [n for n in grid[0] if len({pt[n] for pt in grid}) > 1]
    if len(moved) == 1 and len(grid) > 2:
        name = moved[0]
        order = sorted(range(len(grid)), key=lambda i: grid[i][name])
        pos = order.index(int(np.argmin(costs)))
        best = grid[order[pos]]
        extra = []
        for nb in (order[pos - 1] if pos > 0 else None, order[pos + 1] if pos + 1 < len(order) else None):
            if nb is None:
                continue
            a, b = best[name], grid[nb][name]
            extra += [dict(best, **{name: a + (b - a) * j / (fine + 1)}) for j in range(1, fine + 1)]
        grid = grid + extra
        costs = costs + _bounded_costs(eff, replay, extra, cfg, max(keep, 1), known=costs)
    order = np.argsort(costs)[:keep]
    return [grid[i] for i in order]
