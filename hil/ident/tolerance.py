"""Whether the record is the config's own plant, its parameters moved within their tolerance.

A config's masses, stiffnesses and dampings are known to a tolerance (``plant.tolerance``, relative;
the CAD's masses, the stiffnesses of a finite-element model or a test, the dampings of a fit), and
they move night to night by about a percent with temperature and load. A record of a healthy axis
differs from the config by such drifts, all at once, and a one-parameter step cannot name them:
the record fixes combinations (the tool-tip mode's sqrt(k2 / m3) and c2 / m3, the moving mass
m1 + m2 + m3 in the torque, the table's lag m2 / k1), so a step that names m3 names it off by k2's
drift (hil.ident.fit.config_aliases says so), and the next step names c2 off by m3's. That is no
missing effect.

So before the chain names a drift of the config (a step whose effects are all changes of the
plant's masses, stiffnesses and dampings: ``parameter:plant.m3``, ``mass_change``, the table mass
by another name; :meth:`~sim_plant.effects.Effect.drifted_key`) it asks whether all of them
together, each near its config value, fit the record within the tolerance: least squares of every
such key of the config as z_k = value_k / config_k, searched within :data:`SEARCH` tolerances of 1
with a prior residual (z_k - 1) / tol per key (small beside the record's thousands of samples: it
decides only the directions the record does not see, the tip's mass beside its stiffness), on the
model as it stands, from z = 1, the effects already found refitted with it (their values were
fitted before the drift was in the model and hold part of it: a weak friction's level 1.5 % high
put the drift's fit beyond the tolerance); weighted as every fit
(hil.ident.objective), and refitted up to :data:`ROUNDS` times weighted by the residual the last
fit left (a channel the fit brought near its floor no longer drowns the one still far above it:
the tool tip's ringing is thousands of times its floor before and a few times after). Where every
change lies within the tolerance (less :data:`Z_WITHIN` of its standard errors) the drift is no
finding (``within``): the chain (hil.ident.chain) then holds out part of the record as for a step,
takes the values where the fit earns its place, names nothing, and ends at the noise floor or
diagnoses what is left (``final.tolerance``). Else nothing changes: the chain goes on as without
the test.

The fitted values come with the linearised standard errors of the joint fit (hil.ident.fit); those
the record cannot tell apart (the tip's mass and stiffness) have large ones or none (at a bound).
``plant.tolerance = 0`` switches the test off.
"""
from __future__ import annotations

import logging
import re
from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares

from hil.ident.fit import _with_jacobian, standard_errors
from hil.ident.objective import MaskedObjective
from hil.ident.unexplained import at_noise_floor, rms
from hil.plant_config import candidate, configure, effect_values

logger = logging.getLogger(__name__)

__all__ = ["tolerance_keys", "is_drift", "within_tolerance", "ROUNDS", "MAX_NFEV", "TOLERANCE"]

TOLERANCE = 0.05    # plant.tolerance where the config does not say (its schema's default)
ROUNDS = 3          # fits, each weighted by the residual the one before left
MAX_NFEV = 40       # evaluations of each
Z_WITHIN = 2.0      # a change is within the tolerance where it lies within this many standard errors of it
SEARCH = 4          # the fit searches within this many tolerances of the config (the prior holds it near)


def tolerance_keys(cfg) -> list[str]:
    """The config's keys a tolerance applies to: the chain's masses, stiffnesses and dampings that
    are set and not 0 (a damping of 0 is a statement, not a measured value)."""
    return [k for k in cfg.keys() if re.fullmatch(r"plant\.[mkc][0-9]+", k) and isinstance(cfg.get(k), (int, float))
            and cfg.get(k)]


def is_drift(effects: list, plant, cfg) -> bool:
    """Whether every effect of a step is a change of one of :func:`tolerance_keys` (the effect's
    :meth:`~sim_plant.effects.Effect.drifted_key`)."""
    keys = set(tolerance_keys(cfg))
    return bool(effects) and all(getattr(e, "drifted_key", lambda p: None)(plant) in keys for e in effects)


def within_tolerance(replay, tol: float, rounds: int = ROUNDS, max_nfev: int = MAX_NFEV, mask=None,
                     found=(), start=None) -> dict | None:
    """The test of the module's definition on ``replay`` (the model as it stands): None where the
    config has no such key or ``tol`` is not above 0; else {"tolerance", "within" (every change within
    ``tol``, less :data:`Z_WITHIN` of its standard errors), "at_noise_floor" (every channel), "error"
    (RMS per channel after the fit), "params" {key: {"config", "value", "change" (relative), "stderr"
    (NaN: none)}}, "nfev"} and, with a leading underscore, the fitted config (``_config``). With
    ``mask`` (a boolean array of the record's samples) the fit sees those samples alone (the whole
    record simulated: the estimation half of hil.ident.chain's held-out check); the errors are the
    whole record's. ``found``: the effects the model holds (the chain's steps before), their fitted
    parameters refitted with the drift, free within their catalogue bounds (they were fitted before
    the drift was in the model and hold part of it): ``refitted`` {effect: {param: value}} and
    ``_refitted_stderr`` {effect.param: standard error (NaN: none)}. ``start``: a config the fit starts
    from (its masses, stiffnesses, dampings and the found effects' values, within the search's
    range), the prior and the changes still about ``replay``'s config (a basin a local fit from the
    config does not reach: hil.ident.tracking's profile)."""
    cfg = replay.cfg
    keys = tolerance_keys(cfg)
    if not keys or not tol > 0:
        return None
    x0 = np.array([float(cfg[k]) for k in keys])
    # where the search may go (a mass stays a mass); the prior keeps it near the config
    lo, hi = np.full(len(keys), max(0.1, 1.0 - SEARCH * tol)), np.full(len(keys), 1.0 + SEARCH * tol)
    free = _free_params(found, cfg, keys)
    n = len(keys)
    if free:
        # the found effects' values as ratios of their scale, free within their bounds (no prior)
        lo = np.concatenate([lo, [f.param.lower / f.scale for f in free]])
        hi = np.concatenate([hi, [f.param.upper / f.scale for f in free]])
    prior = np.hstack([np.eye(n), np.zeros((n, len(free)))]) / tol

    def config(z):
        c = cfg.with_values(dict(zip(keys, (z[:n] * x0).tolist())))
        for name, eff, vals in _effect_values(free, z[n:], cfg):
            c = configure(eff, c, vals)
        return c

    state = {"nfev": 0, "sol": None}

    def fit(at, z, lo, hi):
        """One bounded fit of z from ``z``, weighted by ``at``'s residuals: (z, its replay)."""
        obj = at.objective if mask is None else MaskedObjective(at.objective, mask)

        def data(z):
            try:
                return obj.vector(obj.residuals(config(z)))
            except (ValueError, ZeroDivisionError, FloatingPointError):
                return np.full(obj.n, 1e3)
        f_data, j_data = _with_jacobian(obj, data, config, lo, hi, 1e-3)
        state["objective"] = obj

        def fun(z):
            return np.concatenate([f_data(z), (z[:n] - 1.0) / tol])

        def jac(z):
            jd = j_data(z) if callable(j_data) else approx_fprime(z, f_data, lo, hi)
            return np.vstack([jd, prior])
        sol = least_squares(fun, np.clip(z, lo, hi), jac=jac, bounds=(lo, hi), diff_step=1e-3, max_nfev=max_nfev,
                            x_scale=1.0, xtol=1e-6, ftol=1e-6)
        state["nfev"] += sol.nfev
        state["sol"] = sol
        return sol.x, replay.with_config(config(sol.x))

    floor = replay.noise
    z, at = np.ones(n + len(free)), replay
    if free:
        z[n:] = [f.value / f.scale for f in free]
    if start is not None:
        z[:n] = [float(start[k]) / x for k, x in zip(keys, x0)]
        if free:
            z[n:] = [float(effect_values(f.name, start)[f.param.name]) / f.scale for f in free]
        z = np.clip(z, lo, hi)
        at = replay.with_config(config(z))
    for _ in range(max(1, rounds)):
        z, at = fit(at, z, lo, hi)
        if at_noise_floor(rms(at.base_residuals), floor):
            break
    sol, nfev = state["sol"], state["nfev"]
    err = rms(at.base_residuals)
    scales = np.concatenate([x0, [f.scale for f in free]])
    white = standard_errors(sol, scales, correlated=False)[:n]
    # the errors published (hil fit, the fleet's limits) count the residual's correlation time, as
    # every fit's do (hil.ident.fit): white ones understate them by its square root
    se_all = standard_errors(_same_steps(sol, state["objective"], config, _changes_of_keys(free, keys, replay.plant),
                                         x0, free), scales)
    # within the tolerance: each change, less Z_WITHIN of its white standard errors (a drift at the
    # edge that the fit puts a little beyond it), at most the tolerance; white: the margin is a
    # statistic of this decision (Z_WITHIN was set on them over the drifted matrix), not a claim
    margin = Z_WITHIN * np.nan_to_num(white / x0, nan=0.0)
    params = {k: {"config": float(x0[i]), "value": float(z[i] * x0[i]), "change": float(z[i] - 1.0),
                  "stderr": float(se_all[i]), "margin": float(margin[i])} for i, k in enumerate(keys)}
    ok = bool(np.all(np.abs(z[:n] - 1.0) - margin <= tol * (1.0 + 1e-9)))
    logger.info("tolerance %.3g: %s, %s (%s)", tol, "within" if ok else "beyond",
                "at the noise floor" if at_noise_floor(err, floor) else "above the noise floor",
                ", ".join(f"{k} {100 * p['change']:+.2f} %" for k, p in params.items()))
    out = {"tolerance": float(tol), "within": ok, "at_noise_floor": bool(at_noise_floor(err, floor)), "error": err,
           "params": params, "nfev": int(nfev), "_config": at.cfg}
    if free:
        out["refitted"] = {name: effect_values(name, at.cfg) for name in dict.fromkeys(f.name for f in free)}
        out["_refitted_stderr"] = {f"{f.name}.{f.param.name}": float(x) for f, x in zip(free, se_all[n:])}
    return out


def _changes_of_keys(free, keys, plant) -> list[tuple[int, int]]:
    """(the key's column, the free parameter's column) for each found effect that is a change of
    one of the test's ``keys`` (a mass on the table is plant.m2: sim_plant's drifted_key)."""
    out = []
    for i, f in enumerate(free):
        key = f.effect.drifted_key(plant)
        if key in keys:
            out.append((keys.index(key), len(keys) + i))
    return out


def _same_steps(sol, obj, config, pairs, x0, free):
    """``sol`` with the data's columns of each pair of :func:`_changes_of_keys` taken again with one
    physical step (a thousandth of the key's value) at the fit's end. The fit's own steps are
    relative to each value: 0.39 kg for the table's mass, 3.4 g for a change of 3.4 kg on it; through
    a model that is not smooth (a backlash) the two columns of one physical change then differ
    (r = 0.93 measured), and the data seem to tell apart what they cannot, a change of -5.4 kg
    claimed to +-0.004 kg where the truth was +1.9 kg. With one step the columns agree, and the
    split between the two is the prior's, as it is in the fit (the standard error says so)."""
    if not pairs:
        return sol
    from types import SimpleNamespace
    z = np.asarray(sol.x, float)
    probes, steps = [z], []
    for k, i in pairs:
        d = 1e-3 * x0[k]
        for col, h in ((k, d / x0[k]), (i, d / free[i - len(x0)].scale)):
            zp = z.copy()
            zp[col] += h
            probes.append(zp)
            steps.append((col, h))
    try:
        got = obj.residuals_many([config(zp) for zp in probes])
    except (ValueError, ZeroDivisionError, FloatingPointError):
        return sol
    if any(isinstance(r, Exception) for r in got):
        return sol
    vec = [obj.vector(r) for r in got]
    jac = np.array(sol.jac, float)
    for (col, h), v in zip(steps, vec[1:]):
        jac[:obj.n, col] = (v - vec[0]) / h
    return SimpleNamespace(**{k: getattr(sol, k) for k in ("x", "cost", "fun", "active_mask") if hasattr(sol, k)},
                           jac=jac)


class FreeParam(NamedTuple):
    """A fitted parameter of an effect found before the drift, refitted with it."""
    name: str           # the effect's name in the chain
    effect: object      # its catalogue effect
    param: object       # the parameter (its bounds)
    scale: float        # the fit's unit for it (its value, else its widest bound)
    value: float        # its value as found


def _free_params(found, cfg, keys) -> list[FreeParam]:
    """The fitted parameters of the effects ``found`` (not a drift key itself: a mass the chain
    named beyond the tolerance is among ``keys``)."""
    out = []
    for name in found:
        eff = candidate(name, cfg)
        if getattr(eff, "key", None) in keys:
            continue
        vals = effect_values(name, cfg)
        for p in eff.params:
            if p.fit and isinstance(vals.get(p.name), (int, float)):
                v = float(vals[p.name])
                scale = abs(v) if v else max(abs(p.lower), abs(p.upper), 1e-12)
                out.append(FreeParam(name, eff, p, scale, v))
    return out


def _effect_values(free, r, cfg):
    """Per effect of ``free``: (name, effect, {param: value}) with its fitted parameters at ``r``
    times their scale, the others as ``cfg`` holds them."""
    by = {}
    for f, x in zip(free, r):
        if f.name not in by:
            by[f.name] = (f.effect, dict(effect_values(f.name, cfg)))
        by[f.name][1][f.param.name] = float(x * f.scale)
    return [(name, eff, vals) for name, (eff, vals) in by.items()]


def approx_fprime(z, f, lo, hi):
    """scipy's '2-point' Jacobian of ``f`` (the one-by-one path, HIL_BATCH=0)."""
    from scipy.optimize._numdiff import approx_derivative
    return approx_derivative(f, z, method="2-point", rel_step=1e-3, bounds=(lo, hi))
