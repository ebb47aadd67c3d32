"""Joint candidates: pairs of friction and force effects screened together by the inverse model
(effects that only help together are found: Coulomb friction plus a lower viscous slope, where
each alone barely moves the error).

The effects with a ``linear_param`` (:func:`linear_effects`) are linear in it through the inverse
model of a rigid axis (hil.ident.inverse): the force residual r (measured - simulated, in the force
channel's units: motor torque on a rotary axis) that each asks for is its parameter times a
regressor of the measured motion (``Effect.linear_column``), in the catalogue:

* coulomb_friction (level, motor units): sign(v);
* viscous_friction (coefficient, motor units): s v, s = speed_scale (rad/m; 1 on a linear axis);
* constant_force (force, N on the load, + in +x): -1 / k, k = force_to_load (2 pi / pitch);
* mass_change (mass, kg on the table): a / k;

v and a from the measured position (the motor's, else the table's, else the command) of each
record, filtered forward and backward and differentiated (:func:`hil.ident.inverse.motion`); the samples where the
axis moves (|v| > 2 % of max|v|). Each pair's parameters are the least squares of r on its two
regressors; its synergy is the BIC score (hil.ident.scores) of the pair against the better of its
members alone, on the force channel: N_eff ln(SSR_member / SSR_pair) - ln N_eff, N_eff the
effective samples of the pair's residual. The pairs whose synergy exceeds
:data:`~hil.ident.scores.MIN_SCORE` are refined by simulation (the ``refine`` best, from the
regression's values plus what the model has) and ranked beside the single candidates
(hil.ident.diagnosis).
"""
from __future__ import annotations

import math
from functools import partial
from types import SimpleNamespace

import numpy as np

from hil.ident.context import configured_value
from hil.ident.inverse import motion
from hil.ident.scores import effective_samples
from sim_plant.effects import CATALOGUE

__all__ = ["LINEAR", "linear_effects", "regressors", "screen_pairs", "JOINT_REFINE"]

JOINT_REFINE = 2        # pairs refined by simulation at most, per diagnosis



def linear_effects() -> dict[str, str]:
    """The catalogue's effects linear through the inverse model: effect -> its fitted parameter
    (``Effect.linear_param``; the regressor per unit of it is the effect's ``linear_column``)."""
    return {n: e.linear_param for n, e in CATALOGUE.items() if e.linear_param}


# effect -> its fitted parameter, as the catalogue had it at import (:func:`linear_effects` for the current one)
LINEAR = linear_effects()


def _position(meas):
    for c in ("x_motor", "x_table", "x_cmd"):
        if c in meas:
            return meas[c]


def regressors(replay) -> tuple[dict, np.ndarray]:
    """({effect: (regressor per unit of its parameter, the value the model has now)}, moving mask)
    of the replay's record (see the module's definitions)."""
    dt = replay.sample_period
    cutoff = min(100.0, 0.2 / dt)        # 100 Hz as the EMPS recipe, at most 0.4 of the Nyquist rate
    # record by record (hil.ident.records.Records: several records fitted together)
    va = [motion(p.meas.t, _position(p.meas), cutoff=cutoff) for p in getattr(replay, "parts", [replay])]
    v, a = np.concatenate([x[0] for x in va]), np.concatenate([x[1] for x in va])
    moving = np.abs(v) > 0.02 * max(float(np.max(np.abs(v))), 1e-12)
    # each effect's own column (Effect.linear_column) on the inverse model's motion
    ctx = SimpleNamespace(v=v, a=a, plant=replay.plant, force_to_load=replay.force_to_load,
                          configured=partial(configured_value, replay.cfg))
    return {n: CATALOGUE[n].linear_column(ctx) for n in linear_effects()}, moving


def _ssr(X, y):
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    e = y - X @ theta
    return theta, float(e @ e), e


def screen_pairs(replay, res0: dict, names) -> list[dict]:
    """The pairs of :data:`LINEAR` effects among ``names``, screened by the inverse model on the
    force residual: [{"effects": (a, b), "start": {"a.p": value, ...}, "synergy": score,
    "ssr_ratio": SSR_pair / SSR_best_member}], best synergy first (empty without a force channel
    or motion)."""
    fch = replay.force_channel
    linear = linear_effects()
    lin = [n for n in names if n in linear]
    if fch is None or len(lin) < 2:
        return []
    cols, moving = regressors(replay)
    if moving.sum() < 32:
        return []
    y = np.asarray(res0[fch], float)[moving]
    single = {n: _ssr(cols[n][0][moving, None], y)[1] for n in lin}
    out = []
    for i, a in enumerate(lin):
        for b in lin[i + 1:]:
            X = np.column_stack([cols[a][0][moving], cols[b][0][moving]])
            if np.linalg.matrix_rank(X) < 2:
                continue
            theta, ssr, e = _ssr(X, y)
            best = min(single[a], single[b])
            ne = effective_samples(e)
            syn = ne * math.log(max(best, 1e-300) / max(ssr, 1e-300)) - math.log(max(ne, 2.0))
            start = {f"{n}.{linear[n]}": cols[n][1] + float(th) for n, th in zip((a, b), theta)}
            if "coulomb_friction.level" in start:
                start["coulomb_friction.level"] = max(start["coulomb_friction.level"], 0.0)
            out.append({"effects": (a, b), "start": start, "synergy": float(syn),
                        "ssr_ratio": ssr / max(best, 1e-300)})
    return sorted(out, key=lambda d: -d["synergy"])
