"""The diagnosis chain (``hil diagnose``, ``hil emps``): diagnose, add what the verdict names, refit
everything found so far together, diagnose again, until the residual reaches the noise floor or
no effect pays for its parameters (every figure SI, errors RMS per channel).

Each step:

1. the diagnosis (hil.ident.diagnosis.diagnose) of the model as it stands, the effects already
   added left out of the candidates; the first step's verdict must close at least
   :data:`~hil.ident.unexplained.HALF_GAP` of the gap between the error and the noise floor
   (else it is ``unexplained``); later steps add the verdict when its BIC score pays for its
   parameters (the score above :data:`~hil.ident.scores.MIN_SCORE`), reporting the share of the
   gap it closed;
2. the verdict and the effects ``also_missing`` beside it, fitted one after the other on top of
   the model, then together (hil.ident.fit.fit_effects);
3. every effect found so far refitted together from those values (one
   :class:`~hil.sim_plant.effects.Combination`, bounded and scaled as any candidate's fit), kept when
   it lowers the weighted error; the step is kept when its BIC score on the record pays for the
   parameters it added.

The polishing fits weight each channel by the residual the step's first fit left (1 / max(RMS,
floor)), not by the residual before it: a channel the fit brought to its floor no longer drowns
the one still far above it.

It stops when every channel is at its noise floor (``end`` "noise floor reached"), when the
diagnosis finds nothing that pays ("no effect pays for its parameters"; the remainder above the
floor comes with the evidence of where it lives), when the first verdict is ``none`` or
``unexplained``, when every candidate is in the model ("no candidate left"), or after
``max_steps``.
"""
from __future__ import annotations

import logging

import numpy as np

from hil.ident.diagnosis import candidate_names, diagnose
from hil.ident.fit import evaluate, fit_effects
from hil.ident.progress import expect
from hil.ident.scores import MIN_SCORE, bic_score
from hil.ident.unexplained import HALF_GAP, at_noise_floor, gap_closed, residual_evidence, rms
from hil.plant_config import candidate

logger = logging.getLogger(__name__)

__all__ = ["diagnose_chain", "chain_json", "MAX_STEPS", "effect_values"]

MAX_STEPS = 4


def effect_values(name: str, cfg) -> dict:
    """The fitted values of an effect in a config: {param: value} (SI)."""
    eff = candidate(name, cfg)
    if name.startswith("parameter:"):
        return {"value": float(cfg[eff.key])}
    # an alias (time_delay) configures its effect's own section
    out = {}
    for p in eff.params:
        v = cfg.get(f"effects.{eff.name}.{p.name}")
        out[p.name] = float(v if v is not None else cfg[f"effects.{name}.{p.name}"])
    return out


def _same(name: str, cfg) -> str:
    """What a candidate name stands for (an alias and its effect are one)."""
    try:
        return candidate(name, cfg).name
    except KeyError:
        return name


def _weighted(replay, res) -> float:
    return float(np.sum(replay.objective.vector(res) ** 2))


def diagnose_chain(replay, names: list[str] | None = None, max_steps: int = MAX_STEPS, progress=None,
                   jobs: int | None = None, max_nfev: int = 30, fit_nfev: int = 40, **kw) -> dict:
    """The chain on a record (see the module's definition).

    Parameters
    ----------
    replay : Replay
        The record replayed through the start model.
    names : list of str, optional
        The candidates (default: the catalogue and the config's parameters).
    max_steps : int
        At most this many diagnoses (1: today's single diagnosis).
    progress : callable, optional
        Called with the name of each fit as it starts.
    jobs, max_nfev, **kw
        Passed on to :func:`~hil.ident.diagnosis.diagnose`.
    fit_nfev : int
        Evaluations of the fits that add the verdicts and of the joint refit.

    Returns
    -------
    dict
        The first diagnosis's keys (``verdict``, ``candidates``, ``also_missing``, ...), and
        ``chain`` (one entry per added step: ``step``, ``effect`` (its verdict), ``effects`` (what
        it added), ``params`` ({effect: {param: value}} of everything found so far, after the
        step's refit), ``error_before`` and ``error_after`` (RMS per channel), ``gap_closed`` (per
        channel), ``score`` (the step's BIC score), ``evidence``, ``refitted_together``; and,
        with a leading underscore, the fits and the config, left out of the JSON), ``final`` (the
        residual against the noise floor and why it ended), ``diagnoses`` (every step's diagnosis)
        and ``config`` (the model with the whole chain).
    """
    floor = replay.noise
    cur = replay
    found: list[str] = []
    steps, diags = [], []
    first = None
    end = f"max steps ({max_steps})"
    for i in range(max(1, max_steps)):
        err0 = rms(cur.base_residuals)
        if at_noise_floor(err0, floor):
            end = "noise floor reached"
            if first is None:
                first = diagnose(cur, names, progress=progress, jobs=jobs, max_nfev=max_nfev, **kw)
                diags.append(first)
            break
        pool = names or candidate_names(cur.cfg, cur.plant)
        have = {_same(n, cur.cfg) for n in found}
        cands = [n for n in pool if _same(n, cur.cfg) not in have]
        if not cands:
            end = "no candidate left"
            break
        d = diagnose(cur, cands, progress=progress, jobs=jobs, max_nfev=max_nfev,
                     min_gap=HALF_GAP if i == 0 else 0.0, **kw)
        diags.append(d)
        if first is None:
            first = d
        verdict = d["verdict"]
        if verdict in ("none", "unexplained"):
            end = ("noise floor reached" if verdict == "none" else
                   "unexplained" if i == 0 else "no effect pays for its parameters")
            break
        add = [verdict] + [m["effect"] for m in d["also_missing"] if _same(m["effect"], cur.cfg) not in have]
        if len(add) > 1:
            # a combination: one after the other on top of the model, then together (hil fit --add ...)
            cfg1, fits = fit_effects(cur, add, max_nfev=fit_nfev, progress=progress)
        else:
            # the diagnosis's fit, polished from where it stopped
            lead = next(c for c in d["candidates"] if c.effect == verdict)
            if progress:
                expect(progress, 1)
                progress(verdict)
            # (weighted by the residual the fit left: the channel still far from its floor leads)
            at = cur.with_config(lead.cfg)
            c1 = evaluate(at, verdict, max_nfev=fit_nfev, start=lead.params)
            c1 = c1 if _weighted(at, c1.res) <= _weighted(at, at.base_residuals) else lead
            cfg1, fits = c1.cfg, [c1]
        res1 = cur.residuals(cfg1)
        joint = None
        if found:
            # everything found so far refitted together, from the values it has now
            name = "+".join(found + add)
            start = {f"{n}.{k}": v for n in found + add for k, v in effect_values(n, cfg1).items()}
            if progress:
                expect(progress, 1)
                progress(name)
            try:
                at = replay.with_config(cfg1)
                joint = evaluate(at, name, max_nfev=fit_nfev, start=start)
            except ValueError:
                joint = None
            if joint is not None and _weighted(at, joint.res) < _weighted(at, res1):
                cfg1, res1 = joint.cfg, joint.res
            else:
                joint = None
        # the step must pay for its parameters on the record (BIC, as every candidate's score)
        k = sum(len(candidate(n, cur.cfg).params) for n in add)
        paid = bic_score(cur.base_residuals, res1, list(floor), k, floor)
        if i > 0 and paid <= MIN_SCORE:
            end = "no effect pays for its parameters"
            break
        found += add
        lead = next((c for c in d["candidates"] if c.effect == verdict), None)
        err1 = rms(res1)
        steps.append({"step": i + 1, "effect": verdict, "effects": list(add),
                      "params": {n: effect_values(n, cfg1) for n in found},
                      "error_before": err0, "error_after": err1,
                      "gap_closed": {c: gap_closed(err0[c], err1[c], floor[c]) for c in err0},
                      "score": float(paid), "evidence": lead.evidence if lead is not None else "",
                      "refitted_together": joint is not None, "_fits": fits, "_joint": joint, "_config": cfg1})
        logger.info("chain step %d: + %s (score %.1f)", i + 1, " + ".join(add), paid)
        cur = cur.with_config(cfg1)
    errf = rms(cur.base_residuals)
    final = {"error": errf, "noise_floor": dict(floor),
             "above_floor": {c: errf[c] / max(floor[c], 1e-300) for c in errf},
             "at_noise_floor": at_noise_floor(errf, floor), "end": end, "steps": len(steps)}
    if not final["at_noise_floor"]:
        last = diags[-1] if diags else None
        best = last["candidates"][0] if last and last["candidates"] else None
        final["residual"] = residual_evidence(cur, cur.base_residuals, best)
    out = dict(first)
    out.update(chain=steps, final=final, diagnoses=diags, config=cur.cfg)
    return out


def chain_json(steps: list) -> list:
    """The chain's entries without their internal fits and configs."""
    return [{k: v for k, v in s.items() if not k.startswith("_")} for s in steps]
