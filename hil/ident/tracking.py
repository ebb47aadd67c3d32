"""An axis's tracked effects fitted on the night's plant (hil fleet: one record of an axis's history).

A healthy axis's masses, stiffnesses and dampings move by about a percent from night to night
(temperature, load). Beside most effects that is invisible, but not beside a lightly damped mode
or the moving mass: at the paper bench's tool tip (k2 over m3: 15 Hz, damping ratio 1.5 %) 1 % on
k2 shifts the ringing's phase within its decay and the tip's residual rules the cost; an effect
fitted on the config's plant then follows the plant's mismatch rather than its own strength. On
the independent fleet (tests/independent/test_fleet_ivp.py, 1 % scatter) a 4 um backlash fitted
alone read 0 to 7 um, a worn nut's 10 um 4 to 5; the cost against the gap, with the plant right,
has a basin about 10 % wide (a 12.4 um gap costs 13 times the true 11.3 um's).

So the tracked effects ``names`` are fitted in four stages:

1. each alone and then together from its global starts (hil.ident.fit.fit_effects), the effect that
   explains most alone first (fitted first on a record that another effect dominates, a friction
   that rose, an effect's global start sees that effect's residual);
2. for each tracked effect with a grid over a parameter in which the error is not convex
   (:meth:`~sim_plant.effects.base.Effect.grid`: a backlash's gaps, a delay), the profile of
   the cost over that grid and the stage before's value: each point screened by one simulation
   (those within :data:`SCREEN` times the cheapest, at least :data:`KEEP`, go on), then at each the
   night's plant refitted, the chain's masses by one common scale and the spring that sets each
   lightly damped mode (:func:`light_mode_keys`), within +-:data:`PROFILE_SPAN` and at most
   ``SEARCH`` (hil.ident.tolerance) times ``plant.tolerance`` (0: the config's plant held), with
   the other tracked parameters (:func:`_refit`), and between the best point and its neighbours
   :data:`FINE` more; the cheapest point is kept where it is cheaper than the stage before. One
   scale for the masses and one spring per mode are what a record fixes best (the moving mass in
   the torque, the tip's frequency); each mass and spring free, the refit wanders along the
   directions the record does not see (the tip's mass beside its stiffness) within its few
   evaluations;
3. the chain's masses, stiffnesses and dampings about stage 2's plant (its prior and search
   range set by ``plant.tolerance``), the tracked effects refitted with them
   (hil.ident.tolerance.within_tolerance, ``found``), kept where it costs less than its start;
4. the gridded parameter scanned by :data:`SCAN_STEP` steps about its value, all else held (one
   simulation a point, in one batch; a local fit does not cross the gap's non-smooth cost), and
   stage 3 again from the scan's point where it was cheaper.

The standard errors are stage 3's (its linearised joint fit), else stage 1's; where a later stage
moved the values, the linearised ones at the values reported, the plant held. A combination (``a+b``) is fitted by stage 1 alone. Measured on records
of the independent simulator with every mass, stiffness and damping scattered by 1.5 %
(``benchmarks/bench_tracked.py``; docs/benchmarks.md): the gap within 6 % and the Coulomb level
within 2.5 % of the truth, where the greedy fit alone is off by up to 106 %.

A lightly damped mode (damping ratio below :data:`LIGHT_ZETA`) is set by the link whose spring
holds most of the mode's strain energy: k_i (phi_i+1 - phi_i)^2 of the mass-normalised mode shape
phi of the chain the config's ``plant.m<i>``, ``plant.k<i>`` and ``plant.c<i>`` make
(sim_plant.chain).
"""
from __future__ import annotations

import logging
import math

import numpy as np

from hil.ident.starts import _cost as cost_of
from hil.ident.tolerance import tolerance_keys
from hil.plant_config import ParameterEffect, candidate, configure, effect_values, measurement_key
from sim_plant.effects import Combination

logger = logging.getLogger(__name__)

__all__ = ["light_mode_keys", "fit_tracked", "on_nights_plant", "with_effects", "LIGHT_ZETA"]

LIGHT_ZETA = 0.05       # a mode damped below this rings through the record's moves
SCREEN, KEEP = 4.0, 8   # the profile refits the grid's points within SCREEN times the cheapest, at least KEEP
PROFILE_NFEV = 12       # evaluations of each profile point's refit
PROFILE_SPAN = 0.1      # the profile's plant moves within +-10 % of the config
FINE = 4                # profile points between the best and each neighbour
SCAN, SCAN_STEP = 25, 0.01      # the scan about the fitted value: +-25 steps of 1 %


def _number(cfg, key) -> float | None:
    v = cfg.get(key)
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def light_mode_keys(cfg, zeta_max: float = LIGHT_ZETA) -> list[str]:
    """The config keys (``plant.k<i>``) of the springs that set the lightly damped modes (damping
    ratio below ``zeta_max``) of the chain the config's ``plant.m<i>``, ``plant.k<i>`` and
    ``plant.c<i>`` make (its effects aside: one that adds a mass would shift the links' numbers):
    per such mode, the link holding most of its strain energy. [] where the config does not give
    the chain by those keys."""
    from sim_plant.chain import Chain
    m = []
    while (x := _number(cfg, f"plant.m{len(m) + 1}")) is not None:
        m.append(x)
    k = [_number(cfg, f"plant.k{i}") for i in range(1, len(m))]
    c = [_number(cfg, f"plant.c{i}") or 0.0 for i in range(1, len(m))]
    if len(m) < 2 or any(x is None or not x > 0 for x in k) or not all(x > 0 for x in m):
        return []
    ch = Chain(tuple(m), tuple(k), tuple(c))
    w, phi = ch.modes()
    zeta = ch.modal_damping_ratios()
    keys = []
    for j in range(1, ch.n):
        if w[j] > 0 and zeta[j - 1] < zeta_max:
            energy = [ch.k[i] * (phi[i + 1, j] - phi[i, j]) ** 2 for i in range(ch.n - 1)]
            key = f"plant.k{int(np.argmax(energy)) + 1}"
            if key not in keys:
                keys.append(key)
    return keys


def _param_keys(name: str, cfg) -> dict[str, str]:
    """{param: config key} of the fitted numeric parameters of the effect ``name`` as
    hil.plant_config.configure writes them; {} for a combination (no profile of its own)."""
    eff = candidate(name, cfg)
    if isinstance(eff, Combination):
        return {}
    if isinstance(eff, ParameterEffect):
        return {"value": eff.key}
    key = measurement_key(eff)
    if key is not None:
        return {eff.params[0].name: key}
    return {p.name: f"effects.{eff.name}.{p.name}" for p in eff.fitted_params if not p.choices}


def with_effects(cfg, values: dict):
    """``cfg`` with the effects of ``values`` ({effect.param: value}) switched on."""
    by: dict[str, dict] = {}
    for k, v in values.items():
        name, param = k.rsplit(".", 1)
        by.setdefault(name, {})[param] = v
    for name, vals in by.items():
        cfg = configure(candidate(name, cfg), cfg, vals)
    return cfg


def _values(cfg, names, like: dict) -> dict:
    """The values of ``cfg`` under the keys of ``like`` ({effect.param: value})."""
    out = {}
    for name in names:
        vals = effect_values(name, cfg)
        out.update({f"{name}.{p}": float(v) for p, v in vals.items() if f"{name}.{p}" in like})
    return out


def _greedy(replay, names, max_nfev):
    """Stage 1: ({effect.param: value}, {effect.param: standard error})."""
    from hil.ident.fit import evaluate, fit_effects
    from hil.ident.parallel import in_threads
    order = list(names)
    if len(order) > 1:
        gains = dict(zip(order, (c.gain for c in in_threads(lambda e: evaluate(replay, e, max_nfev=max_nfev), order))))
        order.sort(key=lambda e: -gains[e])
    _, steps = fit_effects(replay, order, max_nfev=max_nfev)
    last = steps[-1]
    if "+" in last.effect:          # the joint fit: its parameters are named effect.param already
        return dict(last.params), dict(last.stderr)
    vals, ses = {}, {}
    for s in steps:
        vals.update({f"{s.effect}.{k}": v for k, v in s.params.items()})
        ses.update({f"{s.effect}.{k}": v for k, v in s.stderr.items()})
    return vals, ses


def _profile_points(grid: list[dict]):
    """The points of ``grid`` (a one-parameter grid sorted) and a function of the best one giving
    :data:`FINE` points between it and each neighbour; a grid of several parameters: none finer."""
    params = {k for pt in grid for k in pt}
    if len(params) != 1:
        return grid, lambda best: []
    (p,) = params
    xs = sorted({float(pt[p]) for pt in grid})

    def fine(best):
        i = xs.index(best[p])
        out = []
        for j in (i - 1, i + 1):
            if 0 <= j < len(xs):
                out += np.linspace(best[p], xs[j], FINE + 2)[1:-1].tolist()
        return [{p: x} for x in out]
    return [{p: x} for x in xs], fine


def _grid(replay, name: str, cfg) -> list[dict]:
    """The effect's grid over its parameters in which the error is not convex (Effect.grid)."""
    from drivers.control import controller_from_config
    from hil.ident.starts import record_scales
    return candidate(name, cfg).grid(replay.plant, controller_from_config(replay.cfg, replay.plant),
                                     record_scales(replay, replay.base_residuals))


def _refit(replay, cfg, plant: bool, modes: list[str], keys: list[str], span: float, max_nfev: int):
    """The night's plant at a profile point: least squares of the chain's masses' common scale and
    the springs ``modes`` (``plant``: else neither), each as a ratio of its value in ``cfg`` within
    +-``span``, and the config ``keys`` (the other tracked parameters) within 0 to twice their value:
    (the config at the fit's end, its weighted squared error)."""
    from scipy.optimize import least_squares

    from hil.ident.fit import _with_jacobian
    masses = [k for k in tolerance_keys(cfg) if k.startswith("plant.m")] if plant else []
    modes = modes if plant else []
    keys = [k for k in keys if k not in masses and k not in modes]     # a tracked parameter:plant.k2 is a mode's
    x0 = {k: float(cfg[k]) for k in masses + modes + keys}
    n = int(bool(masses)) + len(modes)
    if not n + len(keys):
        return cfg, _cost(replay, cfg)
    lo = np.r_[np.full(n, 1.0 - span), np.zeros(len(keys))]
    hi = np.r_[np.full(n, 1.0 + span), np.full(len(keys), 2.0)]

    def config(z):
        vals = {k: x0[k] * z[0] for k in masses}
        vals.update({k: x0[k] * r for k, r in zip(modes + keys, z[int(bool(masses)):])})
        return cfg.with_values(vals)
    obj = replay.objective

    def fun(z):
        try:
            return obj.vector(obj.residuals(config(z)))
        except (ValueError, ArithmeticError):
            return np.full(obj.n, 1e3)
    fun, jac = _with_jacobian(obj, fun, config, lo, hi, 1e-2, failed=(ValueError, ArithmeticError))
    sol = least_squares(fun, np.ones(n + len(keys)), jac=jac, bounds=(lo, hi), diff_step=1e-2, max_nfev=max_nfev,
                        x_scale=1.0)
    return config(sol.x), float(2.0 * sol.cost)


def _profile(replay, cfg, name: str, names, values: dict, modes: list[str], span: float):
    """Stage 2 for the tracked effect ``name`` from ``cfg`` (the model with the tracked effects at
    ``values``; the plant refitted within +-``span``, not at all where it is 0): the config at the
    profile's cheapest point, None where ``name`` has no grid or no point is cheaper than ``cfg``."""
    grid = _grid(replay, name, cfg)
    if not grid or not _param_keys(name, cfg):
        return None
    gridded = {k for pt in grid for k in pt}
    # refitted at each point besides the plant: every other tracked parameter that is not 0
    keys = [key for n in names for p, key in _param_keys(n, cfg).items()
            if f"{n}.{p}" in values and not (n == name and p in gridded) and values[f"{n}.{p}"]]
    eff, obj = candidate(name, cfg), replay.objective
    now = effect_values(name, cfg)

    def point(pt):
        try:
            return (*_refit(replay, configure(eff, cfg, dict(now, **pt)), span > 0, modes, keys, span, PROFILE_NFEV),
                    pt)
        except (ValueError, ArithmeticError):
            return None, np.inf, pt

    # the grid and the stage before's value, screened by one simulation each (the plant as it
    # stands): the points that may hold the basin (within SCREEN times the cheapest, at least KEEP),
    # each then refitted
    points, fine = _profile_points(grid + [{p: now[p] for p in gridded if p in now}])
    screen = np.array(_costs(obj, [configure(eff, cfg, dict(now, **pt)) for pt in points]))
    order = np.argsort(screen, kind="stable")
    keep = sorted({int(i) for i in order if screen[i] <= SCREEN * screen[order[0]]} | set(order[:KEEP].tolist()))
    tried = [point(points[i]) for i in keep]
    tried += [point(pt) for pt in fine(min(tried, key=lambda r: r[1])[2])]
    best, cost, pt = min(tried, key=lambda r: r[1])
    if best is None or not cost < _cost(replay, cfg):
        return None
    logger.info("profile of %s: %s, cost %.4g; %s", name, pt, cost,
                ", ".join(f"{k} {best[k] / replay.cfg[k] - 1:+.2%}" for k in modes if k in best.values))
    return best


def _cost(replay, cfg) -> float:
    """The weighted squared error of ``cfg`` (hil.ident.starts: inf where it is not a number)."""
    return cost_of(replay.objective, replay.objective.residuals(cfg))


def _costs(obj, cfgs) -> list[float]:
    """The weighted squared errors of ``cfgs`` in one batch; inf for one that cannot be simulated."""
    return [math.inf if isinstance(r, Exception) else cost_of(obj, r) for r in obj.residuals_many(cfgs)]


def _scan(replay, cfg, names):
    """Stage 4: each tracked effect's one gridded parameter (a gap) on a dense scan about its value
    (:data:`SCAN` steps of :data:`SCAN_STEP` either way), everything else held (one simulation per
    point, in one batch): (cost, config) at the cheapest point."""
    obj = replay.objective
    best = (_cost(replay, cfg), cfg)
    for name in names:
        eff = candidate(name, cfg)
        params = {k for pt in _grid(replay, name, cfg) for k in pt}
        if len(params) != 1:
            continue
        (p,) = params
        vals = effect_values(name, best[1])
        v = float(vals[p])
        if not v:
            continue
        pts = [v * (1.0 + SCAN_STEP * k) for k in range(-SCAN, SCAN + 1) if k]
        cfgs = [configure(eff, best[1], dict(vals, **{p: x})) for x in pts]
        costs = _costs(obj, cfgs)
        i = int(np.argmin(costs))
        if costs[i] < best[0]:
            best = (costs[i], cfgs[i])
    return best


def _stderr_at(replay, cfg, names, like: dict) -> dict:
    """The linearised standard errors (hil.ident.fit.standard_errors) of the tracked parameters
    under the keys of ``like`` at ``cfg``, the plant held: one Jacobian, in one batch."""
    from types import SimpleNamespace

    from hil.ident.fit import _with_jacobian, standard_errors
    from hil.ident.tolerance import approx_fprime
    items = []      # (effect.param, config key, scale)
    for n in names:
        eff, vals = candidate(n, cfg), effect_values(n, cfg)
        bounds = {p.name: p for p in eff.params}
        for p, key in _param_keys(n, cfg).items():
            if f"{n}.{p}" in like and isinstance(vals.get(p), (int, float)):
                v = float(vals[p])
                prm = bounds.get(p)
                items.append((f"{n}.{p}", key, abs(v) if v else max(abs(prm.lower), abs(prm.upper), 1e-12) if prm
                              else 1.0))
    if not items:
        return {}
    obj = replay.objective
    scale = np.array([x[2] for x in items])
    z0 = np.array([float(cfg[x[1]]) for x in items]) / scale

    def config(z):
        return cfg.with_values({x[1]: float(v) for x, v in zip(items, z * scale)})

    def fun(z):
        try:
            return obj.vector(obj.residuals(config(z)))
        except (ValueError, ArithmeticError):
            return np.full(obj.n, 1e3)
    f, jac = _with_jacobian(obj, fun, config, -np.inf, np.inf, 1e-3, failed=(ValueError, ArithmeticError))
    f0 = f(z0)
    J = jac(z0) if callable(jac) else approx_fprime(z0, f, -np.inf, np.inf)
    se = standard_errors(SimpleNamespace(jac=J, cost=0.5 * float(f0 @ f0)), scale)
    return {x[0]: float(e) for x, e in zip(items, se)}


def on_nights_plant(replay, cfg, names, profiled=None, anchored: bool = False, values: dict | None = None):
    """Stages 2 to 4 of the module's definition from ``cfg`` (the model with the tracked effects
    ``names`` at their stage-1 values), the profile for the effects ``profiled`` (default: all of
    ``names``): (the config, its weighted squared error, the last tolerance test kept or None).
    ``anchored``: ``replay``'s config holds the effects (the model as it stands) and the tolerance
    tests start from the stage before's config, their prior and changes about ``replay``'s config
    (hil.ident.chain: within the config's tolerance or not); else each test is about the stage
    before's config itself (the fleet's fit: a fit, not a test). ``values``: the tracked parameters
    ({effect.param: value}) the profile refits beside the plant where not 0 (default: ``cfg``'s)."""
    from hil.ident.tolerance import SEARCH, TOLERANCE, within_tolerance
    tol = float(replay.cfg.get("plant.tolerance", TOLERANCE))
    modes = light_mode_keys(replay.cfg)
    if values is None:
        values = {f"{n}.{p}": float(v) for n in names for p, v in effect_values(n, cfg).items()
                  if isinstance(v, (int, float)) and not isinstance(v, bool)}
    for name in names if profiled is None else profiled:
        best = _profile(replay, cfg, name, names, values, modes, min(PROFILE_SPAN, SEARCH * max(tol, 0.0)))
        if best is not None:
            cfg = best
    cost, kept = _cost(replay, cfg), None
    for rnd in range(2):
        if rnd:
            scanned, cfg_s = _scan(replay, cfg, names)
            if not scanned < cost:
                break
            cost, cfg = scanned, cfg_s
        test = (within_tolerance(replay, tol, found=names, start=cfg) if anchored
                else within_tolerance(replay.with_config(cfg), tol, found=names))
        # the joint fit from where the profile (the scan) left; kept where it costs less than its start
        if test is not None and (c := _cost(replay, test["_config"])) <= cost:
            cost, cfg, kept = c, test["_config"], test
    return cfg, cost, kept


def fit_tracked(replay, names, max_nfev: int = 40, plant: dict | None = None) -> tuple[dict, dict]:
    """The tracked effects ``names`` fitted on the night's plant (the module's stages):
    ({effect.param: value}, {effect.param: standard error}), SI. A standard error is NaN where the
    fit gives none; where a later stage moved the values and the joint fit was not kept, it is the
    linearised one at the values reported, the plant held. A combination (``a+b``) is fitted by
    stage 1 alone. ``plant`` (a dict, when given) receives the night's plant the values were
    fitted on ({config key: value} of hil.ident.tolerance.tolerance_keys), so that the night's
    model can be rebuilt from the config."""
    names = list(names)
    if not names:
        return {}, {}
    values, stderr = _greedy(replay, names, max_nfev)
    if any(isinstance(candidate(n, replay.cfg), Combination) for n in names):
        if plant is not None:
            plant.update({k: float(replay.cfg[k]) for k in tolerance_keys(replay.cfg)})
        return values, stderr
    start = with_effects(replay.cfg, values)
    cfg, _, test = on_nights_plant(replay, start, names, values=values)
    if test is not None:
        start = test["_config"]
        se = dict(test.get("_refitted_stderr", {}))
        # a tracked parameter:<plant key> is among the test's own keys
        se.update({f"{n}.value": test["params"][k]["stderr"] for n in names
                   for k in [getattr(candidate(n, cfg), "key", None)] if k in test["params"]})
        stderr = {k: se.get(k, float("nan")) for k in values}
    got = dict(values, **_values(cfg, names, values))
    if cfg is not start:        # moved after the standard errors were had: those at the values reported
        stderr = dict(stderr, **_stderr_at(replay, cfg, names, got))
    if plant is not None:
        plant.update({k: float(cfg[k]) for k in tolerance_keys(cfg)})
    return got, stderr
