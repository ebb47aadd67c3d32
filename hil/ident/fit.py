"""Fitting candidate effects to a replayed record (output error: the model simulated in the loop).

A candidate (a catalogue effect, a combination ``a+b`` or ``parameter:<key>``) is added to the
model and its parameters are fitted by :func:`scipy.optimize.least_squares` on the weighted
residual vector of every measured channel (hil.ident.objective): each parameter scaled by its
start, bounded by its range, relative difference step 1e-3; a config that cannot be simulated
costs a vector of 1e3. The best of the starts (hil.ident.starts) wins. The candidate is then
scored (hil.ident.scores.bic_score) and described (hil.ident.evidence); its gain is
1 - ||w r_after||^2 / ||w r_before||^2, and the channel where it shows is the one whose RMS error
falls the most, relatively. A fitted effect that leaves more weighted error than the model without
it has stopped in a wrong basin (the effect-free model is one of its values, or the limit of them):
the candidate says so (``worse_than_without``, and in its evidence), and its negative score keeps
it from any verdict. A fit that ends where its effect turns into another (``Effect.degenerate``: a
mode at the bound of its frequency or damping is a rigid mass or a damper; a controller setting moved
by under 1 % is another effect's shadow) says so in ``degenerate`` and its evidence, and is never
significant.

:func:`fit_effects` adds effects one after the other (greedy), then refits them all together
from the greedy values; :func:`joint_refit` refits config keys together from their values.

The standard error of each fitted parameter is the linearised one of the least-squares fit
(:func:`standard_errors`): with the Jacobian J of the weighted residual vector at the solution
(scipy's, in the scaled parameters), s^2 = ||r||^2 / (n - p) and Cov = s^2 (J^T J)^-1, counting
n / tau independent samples where the residual is serially correlated (tau its integrated
autocorrelation time, :func:`correlation_time`: a residual of what the model lacks rings for
hundreds of samples, and taking its samples as independent made the errors ten to a few hundred
times too small). A parameter at its bound, without influence, or in a near-singular direction
(J^T J's condition beyond :data:`SINGULAR`) has none: NaN, and the commands say why. It is the
uncertainty under the model: where the fit leaves the record far above its noise floor, the
value also takes up what the model lacks, which no standard error counts (``hil fit`` says so).
The correlation matrix of the same covariance,
Cov_ij / sqrt(Cov_ii Cov_jj), says what a parameter is confounded with: the pairs with |r| above
:data:`CONFOUNDED` are named (``confounded``: [name, name, r]); the data cannot tell them apart, only
their combination.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from hil.ident.evidence import evidence, model_modes
from hil.ident.objective import Objective, batched
from hil.ident.replay import Replay
from hil.ident.scores import MIN_SCORE, SIGNIFICANT_ABOVE_NOISE, bic_score
from hil.ident.starts import record_scales, starting_values
from hil.plant_config import candidate, configure
from sim_plant.effects import Effect

logger = logging.getLogger(__name__)

EDGE = 1e-3         # share of a parameter's range within which a fitted value is at its bound
CONFOUNDED = 0.9     # |correlation| of two fitted parameters above which they are named as confounded
SINGULAR = 1e12      # condition number of J^T J (scaled parameters) beyond which no standard error is claimed
TAU_WINDOW = 5.0     # Sokal's window: the autocorrelation summed to the first lag M >= TAU_WINDOW * tau(M)
WORSE_TOL = 1e-6     # relative: a fit leaving more weighted error than this above the effect-free model's is wrong

__all__ = ["Candidate", "evaluate", "fd_steps", "fit_effects", "joint_refit", "standard_errors", "correlation_time",
           "confounded_pairs",
           "config_aliases", "CONFOUNDED"]


@dataclass
class Candidate:
    """One fitted candidate: its parameters (SI), the channel where it shows with its RMS error before
    and after, its BIC score, evidence and gain; the fitted config and residuals."""
    effect: str
    params: dict
    channel: str
    error_before: float
    error_after: float
    score: float
    evidence: str
    gain: float = 0.0            # fraction of the weighted residual energy removed
    significant: bool = False
    cfg: object = None
    errors_after: dict = field(default_factory=dict)
    nfev: int = 0
    res: dict = field(default=None, repr=False)     # residuals after the fit (for pairwise comparisons)
    stderr: dict = field(default_factory=dict)      # standard error of each fitted parameter (SI; NaN: none)
    worse_than_without: bool = False    # the fit left more error than the model without the effect: a wrong basin
    confounded: list = field(default_factory=list)   # [name, name, r]: fitted parameters correlated above CONFOUNDED
    degenerate: str = ""         # why the fit names another effect (Effect.degenerate): never significant

    def as_json(self) -> dict:
        return {"effect": self.effect, "params": {k: float(v) for k, v in self.params.items()},
                "stderr": {k: float(v) for k, v in self.stderr.items()},
                "channel": self.channel, "error_before": float(self.error_before),
                "error_after": float(self.error_after), "score": float(self.score), "evidence": self.evidence,
                "gain": float(self.gain), "significant": bool(self.significant),
                "worse_than_without": bool(self.worse_than_without),
                "confounded": [[a, b, float(r)] for a, b, r in self.confounded], "degenerate": self.degenerate}


def correlation_time(r) -> float:
    """The integrated autocorrelation time of a residual vector, tau = 1 + 2 sum_k rho_k, summed
    to Sokal's window (the first lag M with M >= :data:`TAU_WINDOW` tau(M)): the number of samples
    per independent one (1 for white noise). Bounded to [1, n / 2]."""
    r = np.asarray(r, dtype=float)
    n = r.size
    if n < 4 or not np.all(np.isfinite(r)):
        return 1.0
    r = r - r.mean()
    spec = np.fft.rfft(r, 2 * n)
    ac = np.fft.irfft(spec * np.conj(spec))[:n]
    if ac[0] <= 0:
        return 1.0
    partial = 1.0 + 2.0 * np.cumsum(ac[1:] / ac[0])
    lags = np.arange(1, n)
    done = np.nonzero(lags >= TAU_WINDOW * partial)[0]
    tau = float(partial[done[0]] if done.size else partial[-1])
    return float(min(max(tau, 1.0), n / 2))


def _covariance(sol, correlated: bool = True, refuse_singular: bool = True):
    """The linearised covariance s^2 tau (J^T J)^-1 of the scaled parameters ``sol.x`` (the module's
    definition; ``correlated=False``: tau = 1) and a mask of the directions without a finite one;
    None when it cannot be formed, or is near-singular (``refuse_singular``)."""
    J = np.asarray(sol.jac, dtype=float)
    n, p = J.shape
    if n <= p or not np.all(np.isfinite(J)):
        return None
    s2 = 2.0 * float(sol.cost) / (n - p)
    if correlated and getattr(sol, "fun", None) is not None:
        s2 *= correlation_time(sol.fun)
    jtj = J.T @ J
    d = np.sqrt(np.maximum(np.diag(jtj), 1e-300))
    if refuse_singular and p > 1 and np.linalg.cond(jtj / np.outer(d, d)) > SINGULAR:
        return None                # the data see only a combination: no parameter has an error alone
    try:
        cov = s2 * np.linalg.inv(jtj)
    except np.linalg.LinAlgError:
        return None
    # a direction the residual does not see: no finite standard error
    bad = (np.diag(jtj) <= 1e-12 * max(float(np.max(np.diag(jtj))), 1e-300)) | ~(np.diag(cov) >= 0)
    at_bound = np.asarray(getattr(sol, "active_mask", np.zeros(p)), dtype=int) != 0
    return cov, bad | at_bound


def standard_errors(sol, scale, correlated: bool = True) -> np.ndarray:
    """Standard errors of the parameters ``sol.x * scale`` of a :func:`least_squares` result:
    sqrt(diag(s^2 tau (J^T J)^-1)) * scale, s^2 = 2 cost / (n - p), tau the residual's correlation
    time (:func:`correlation_time`; ``correlated=False`` or a result without ``fun``: 1); NaN where
    J^T J is singular in that direction (a parameter at its bound, or one the residual does not
    see), and for every parameter where it is near-singular (:data:`SINGULAR`)."""
    p = np.asarray(sol.jac).shape[1]
    scale = np.broadcast_to(np.asarray(scale, dtype=float), (p,))
    got = _covariance(sol, correlated)
    if got is None:
        return np.full(p, np.nan)
    cov, bad = got
    return np.sqrt(np.where(bad, np.nan, np.diag(cov))) * np.abs(scale)


def confounded_pairs(sol, names) -> list:
    """The pairs of fitted parameters whose correlation (of the linearised covariance) exceeds
    :data:`CONFOUNDED` in magnitude: [name, name, r], strongest first."""
    # the scale and tau cancel in a correlation; a near-singular fit is where the pair matters most
    got = _covariance(sol, correlated=False, refuse_singular=False)
    if got is None:
        return []
    cov, bad = got
    d = np.sqrt(np.abs(np.diag(cov)))
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if bad[i] or bad[j] or d[i] == 0 or d[j] == 0:
                continue
            r = float(cov[i, j] / (d[i] * d[j]))
            if abs(r) > CONFOUNDED:
                out.append([names[i], names[j], r])
    return sorted(out, key=lambda x: -abs(x[2]))


def config_aliases(replay: Replay, name: str, values: dict, keys: list[str]) -> list[dict]:
    """The aliases of the config's own parameters in a fit (the alias matrix of a design of
    experiments, (J_p^T J_p)^-1 J_p^T J_q): what the fitted parameters of the effect ``name`` (at ``values``, in the replay's config) are
    confounded with among the config's own parameters ``keys`` (a mass, a stiffness, a gain), which
    the fit held: a one-parameter fit has no correlation matrix of its own, yet the data may see
    its parameter only together with one the config holds (a tip mode's frequency is sqrt(k2 / m3):
    a fit of m3 alone, on a record where k2 moved, finds the ratio, not the mass).

    With the columns J_p of the weighted residual vector's derivative by each fitted parameter
    (forward differences, the fit's steps) and J_q by the relative change of each key (a step of
    1e-3):

    * ``slope``: the change of the fitted parameters that a relative change of the key shows as
      (least squares of J_q on the J_p): a relative drift d of q that the model does not have
      moves the fit by slope * d, to first order;
    * ``r``: for one fitted parameter the correlation the two would have if fitted together,
      -J_p.J_q / (|J_p| |J_q|) (near +1: the data fix their ratio p / q; near -1: their product);
      for several, the multiple correlation of J_q with the J_p (how much of the key's drift the
      effect's parameters together can take up).

    Returns one entry per key the record sees: {"key", "params" (the fitted parameters' names),
    "r", "slope" (one per parameter, in its SI unit), "confounded" (|r| above
    :data:`CONFOUNDED`: the record cannot tell the two apart)}, strongest first; [] when the columns
    cannot be formed (a config that cannot be simulated)."""
    eff = candidate(name, replay.cfg)
    fitted = eff.fitted_params
    cfg = replay.cfg

    def number(k):
        v = cfg.get(k)
        return isinstance(v, (int, float)) and not isinstance(v, bool) and v != 0 and math.isfinite(v)
    keys = [k for k in keys if number(k) and k != getattr(eff, "key", None)]
    if not fitted or not keys:
        return []
    x0 = np.array([float(values[p.name]) for p in fitted])
    h = fd_steps(x0, [p.lower for p in fitted], [p.upper for p in fitted], 1e-3)
    base = configure(eff, cfg, values)
    cfgs = [base] + [configure(eff, cfg, dict(values, **{p.name: float(x0[i] + h[i])})) for i, p in enumerate(fitted)]
    cfgs += [base.with_values({k: float(base[k]) * (1.0 + 1e-3)}) for k in keys]
    got = replay.objective.residuals_many(cfgs)
    if any(isinstance(r, Exception) for r in got):
        return []
    vec = [replay.objective.vector(r) for r in got]
    jp = np.column_stack([(vec[1 + i] - vec[0]) / h[i] for i in range(len(fitted))])
    jq = np.column_stack([(vec[1 + len(fitted) + j] - vec[0]) / 1e-3 for j in range(len(keys))])
    if not np.all(np.isfinite(jp)) or not np.all(np.isfinite(jq)) or not np.any(jp):
        return []
    slope = np.linalg.lstsq(jp, jq, rcond=None)[0]          # (fitted, keys)
    out = []
    for j, k in enumerate(keys):
        nq = float(np.linalg.norm(jq[:, j]))
        if nq == 0:
            continue
        if len(fitted) == 1:
            r = -float(jp[:, 0] @ jq[:, j]) / (float(np.linalg.norm(jp[:, 0])) * nq)
        else:
            r = float(np.linalg.norm(jp @ slope[:, j])) / nq
        out.append({"key": k, "params": [p.name for p in fitted], "r": r, "slope": slope[:, j].tolist(),
                    "confounded": bool(abs(r) > CONFOUNDED)})
    return sorted(out, key=lambda e: -abs(e["r"]))


_FAILED = (ValueError, ZeroDivisionError, FloatingPointError)   # a config that cannot be simulated


def _with_jacobian(obj: Objective, fun, config, lower, upper, rel_step: float, failed=_FAILED):
    """``fun`` and a Jacobian for :func:`least_squares` that evaluates its columns in one batched
    call (:meth:`Objective.residuals_many`), with exactly the steps and arithmetic of scipy's
    '2-point' scheme (:func:`fd_steps`), so that the fit takes the same path as with
    ``jac='2-point'``; ``config(z)`` is the config of the scaled parameters ``z``, ``failed`` the
    errors that cost a vector of 1e3 (as ``fun``'s). With ``HIL_BATCH=0`` (hil.ident.objective.batched)
    ``fun`` and scipy's own scheme: the peer."""
    if not batched():
        return fun, "2-point"
    last: dict = {}

    def fun_kept(z):
        f = fun(z)
        last["z"], last["f"] = np.array(z, float), f
        return f

    def vectors(zs):
        cfgs, out = [], []
        for z in zs:
            try:
                cfgs.append(config(z))
            except failed:
                cfgs.append(None)
        got = iter(obj.residuals_many([c for c in cfgs if c is not None]))
        for c in cfgs:
            r = next(got) if c is not None else None
            if isinstance(r, Exception) and not isinstance(r, failed):
                raise r
            out.append(np.full(obj.n, 1e3) if r is None or isinstance(r, Exception) else obj.vector(r))
        return out

    def jac(z):
        x0 = np.asarray(z, float)
        h = fd_steps(x0, lower, upper, rel_step)
        probes = []
        for i in range(x0.size):
            x1 = x0.copy()
            x1[i] = x0[i] + h[i]
            probes.append(x1)
        have_f0 = "z" in last and np.array_equal(last["z"], x0)
        fs = vectors(probes if have_f0 else probes + [x0])
        f0 = last["f"] if have_f0 else fs[-1]
        jt = np.empty((x0.size, f0.size))          # laid out as scipy's (its transpose's rows)
        for i in range(x0.size):
            jt[i] = (fs[i] - f0) / ((x0[i] + h[i]) - x0[i])
        return jt.T
    return fun_kept, jac


def fd_steps(x0, lower, upper, rel_step: float) -> np.ndarray:
    """The forward steps of scipy's '2-point' finite differences with a relative step (as
    scipy.optimize's approx_derivative takes them): h = rel_step sign(x) |x| (sign(0) = 1), or
    sqrt(eps) sign(x) max(1, |x|) where that step vanishes in x + h; a step that leaves the bounds
    is reversed where the reversed one fits, else it goes to the farther bound."""
    x0 = np.asarray(x0, float)
    lb, ub = (np.broadcast_to(np.asarray(b, float), x0.shape) for b in (lower, upper))
    sign = (x0 >= 0).astype(float) * 2 - 1
    h = rel_step * sign * np.abs(x0)
    h = np.where(((x0 + h) - x0) == 0, np.finfo(float).eps ** 0.5 * sign * np.maximum(1.0, np.abs(x0)), h)
    if np.all((lb == -np.inf) & (ub == np.inf)):
        return h
    lower_dist, upper_dist = x0 - lb, ub - x0
    x = x0 + h
    violated = (x < lb) | (x > ub)
    fitting = np.abs(h) <= np.maximum(lower_dist, upper_dist)
    h = h.copy()
    h[violated & fitting] *= -1
    forward = (upper_dist >= lower_dist) & ~fitting
    h[forward] = upper_dist[forward]
    backward = (upper_dist < lower_dist) & ~fitting
    h[backward] = -lower_dist[backward]
    return h


def _param_scale(p, g):
    if g != 0.0 and math.isfinite(g):
        return abs(g)
    span = p.upper - p.lower
    return max(abs(p.upper), abs(p.lower), 1e-12) * 1e-3 if not math.isfinite(span) else span * 1e-3


def _fit_one(obj: Objective, base_cfg, eff: Effect, starts: list[dict], max_nfev: int = 40, stderr=None):
    """Least squares from each start; returns (values, cfg, residuals, nfev) of the best, and fills
    ``stderr`` (a dict, when given) with the standard error of each fitted parameter."""
    best = None
    total = 0
    fitted = eff.fitted_params
    names = [p.name for p in fitted]
    for start in starts:
        # settings, not fitted; one a start does not give (a pair screened on its linear parameters)
        # keeps the value the config has
        held = {p.name: start[p.name] for p in eff.params if not p.fit and p.name in start}
        scale = np.array([_param_scale(p, start[p.name]) for p in fitted])
        lo = np.array([p.lower for p in fitted]) / scale
        hi = np.array([p.upper for p in fitted]) / scale
        z0 = np.clip(np.array([start[n] for n in names]) / scale, lo + 1e-12 * abs(lo), hi - 1e-12 * abs(hi))

        def config(z, held=held):
            return configure(eff, base_cfg, dict(held, **dict(zip(names, z * scale))))

        def fun(z):
            try:
                return obj.vector(obj.residuals(config(z)))
            except _FAILED:
                return np.full(obj.n, 1e3)
        fun, jac = _with_jacobian(obj, fun, config, lo, hi, 1e-3)
        try:
            sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), diff_step=1e-3, max_nfev=max_nfev, x_scale=1.0,
                                xtol=1e-5, ftol=1e-5)
        except ValueError:
            continue
        total += sol.nfev * (1 + len(names))
        cost = float(sol.cost)
        if best is None or cost < best[0]:
            best = (cost, dict(held, **dict(zip(names, (sol.x * scale).tolist()))), sol, scale)
    if best is None:
        raise ValueError(f"{eff.name}: no start could be fitted")
    vals = best[1]
    logger.debug("%s fitted: %s (cost %.4g, %d evaluations)", eff.name, vals, best[0], total)
    if stderr is not None:
        stderr.update(zip(names, standard_errors(best[2], best[3]).tolist()))
        stderr["_confounded"] = confounded_pairs(best[2], names)
    cfg = configure(eff, base_cfg, vals)
    return vals, cfg, obj.residuals(cfg), total


def evaluate(replay: Replay, name: str, res0: dict | None = None, max_nfev: int = 40,
             start: dict | None = None, n_starts: int = 2) -> Candidate:
    """Fit one candidate (catalogue name or parameter:<key>) and score it: from ``start`` when
    given (a screened fit to refine), else from the ``n_starts`` best of its starting guesses."""
    cfg = replay.cfg
    res0 = res0 if res0 is not None else replay.residuals(cfg)
    eff = candidate(name, cfg)
    if why := eff.unsuited(replay.plant):
        raise ValueError(f"{name}: cannot act on this axis: {why}")
    obj = replay.objective
    scale = record_scales(replay, res0)
    starts = [dict(start)] if start else starting_values(eff, replay, res0, scale, cfg)[:max(1, n_starts)]
    se: dict = {}
    vals, cfg1, res1, nfev = _fit_one(obj, cfg, eff, starts, max_nfev=max_nfev, stderr=se)
    confounded = se.pop("_confounded", [])
    chans = list(obj.weights)
    score = bic_score(res0, res1, chans, len(eff.fitted_params), replay.noise)
    e0 = float(np.sum(obj.vector(res0) ** 2))
    e1 = float(np.sum(obj.vector(res1) ** 2))
    gain = 1.0 - e1 / e0 if e0 > 0 else 0.0
    # the channel where it shows: the largest relative fall
    rel = {c: 1 - math.sqrt(np.mean(res1[c] ** 2) / max(np.mean(res0[c] ** 2), 1e-300)) for c in chans}
    chan = max(rel, key=rel.get)
    before = float(np.sqrt(np.mean(res0[chan] ** 2)))
    after = float(np.sqrt(np.mean(res1[chan] ** 2)))
    floor = replay.noise[chan]
    significant = score > MIN_SCORE and before > SIGNIFICANT_ABOVE_NOISE * floor
    ev = evidence(name, vals, replay, res0, chan, before, after, model_modes(cfg))
    worse = e1 > e0 * (1 + WORSE_TOL)
    why = eff.degenerate(vals, cfg, replay.sample_period) or at_range_edge(eff, vals)
    if why:          # it fits, but as another effect (a mode at its bound) or a sliver of a setting
        ev = why + ev
        significant = False
    if worse:
        ev = (f"the fit is wrong: it leaves {100 * (e1 / e0 - 1):.2g} % more weighted error than the model without "
              f"{name} (a wrong basin); " + ev)
    return Candidate(name, vals, chan, before, after, float(score), ev, gain, significant and not worse, cfg1,
                     {c: float(np.sqrt(np.mean(res1[c] ** 2))) for c in chans}, nfev, res1, se, worse, confounded,
                     why)


def at_range_edge(eff, vals: dict) -> str:
    """Why a fit that ends at a bound of a parameter's range is no finding ("" where none does):
    no value the effect can take explains the record, only the edge of what it may, so it stands
    for something else (HSM150: a torque constant at its lower bound 0.5). A bound at zero is left
    alone: there the effect, or that part of it, is absent."""
    edges = []
    for p in getattr(eff, "fitted_params", ()):
        v = vals.get(p.name)
        if v is None or not (math.isfinite(p.lower) and math.isfinite(p.upper)) or p.upper <= p.lower:
            continue
        # close to the bound on its own scale too: a range over decades (a stiffness from 1000 N/m)
        # puts a tenth of a percent of its span far above the lower bound
        edges += [(p.name, v, b) for b in (p.lower, p.upper)
                  if b != 0 and abs(v - b) <= EDGE * min(abs(b), p.upper - p.lower)]
    if not edges:
        return ""
    return ("; ".join(f"{n} ended at the bound of its range ({v:.4g}, bound {b:.4g})" for n, v, b in edges)
            + ": no value within the range explains the record, so it stands for another effect; ")


def fit_effects(replay: Replay, names: list[str], max_nfev: int = 60, progress=None):
    """Add the effects one after the other, each fitted on top of the previous ones (greedy), then
    all of them together. Returns the final config and the fitted :class:`Candidate` of each step
    (the joint fit last, when it lowered the error)."""
    from hil.ident.progress import expect
    expect(progress, len(names) + (len(names) > 1 and len(set(names)) == len(names)))
    steps = []
    cur = replay
    for name in names:
        if progress:
            progress(name)
        c = evaluate(cur, name, max_nfev=max_nfev)
        steps.append(c)
        cur = cur.with_config(c.cfg)
    if len(names) > 1 and len(set(names)) == len(names):
        # then all of them together from the greedy values: the greedy fit of a later effect cannot
        # move the earlier ones (an offset is correlated with the friction levels)
        name = "+".join(names)
        if progress:
            progress(name)
        start = {f"{s.effect}.{k}": v for s in steps for k, v in s.params.items()}
        joint = evaluate(replay, name, max_nfev=max_nfev, start=start)
        obj = replay.objective
        if np.sum(obj.vector(joint.res) ** 2) < np.sum(obj.vector(cur.base_residuals) ** 2):
            steps.append(joint)
            return joint.cfg, steps
    return cur.cfg, steps


def joint_refit(replay: Replay, cfg, keys: list[str], max_nfev: int = 60, stderr: dict | None = None):
    """Refit several config keys together (after greedy additions), from their current values;
    ``stderr`` (a dict, when given) receives the standard error of each key (SI)."""
    obj = replay.objective
    x0 = np.array([float(cfg[k]) for k in keys])
    # steps large enough to see through the stick-slip's non-smoothness
    scale = np.maximum(np.abs(x0), 0.05 * np.max(np.abs(x0)) + 1e-12)

    def config(z):
        return cfg.with_values(dict(zip(keys, (z * scale).tolist())))

    def fun(z):
        try:
            return obj.vector(obj.residuals(config(z)))
        except ValueError:
            return np.full(obj.n, 1e3)
    fun, jac = _with_jacobian(obj, fun, config, -np.inf, np.inf, 1e-2, failed=(ValueError,))
    sol = least_squares(fun, x0 / scale, jac=jac, diff_step=1e-2, max_nfev=max_nfev, xtol=1e-8, ftol=1e-8)
    if stderr is not None:
        stderr.update(zip(keys, standard_errors(sol, scale).tolist()))
    return cfg.with_values(dict(zip(keys, (sol.x * scale).tolist())))
