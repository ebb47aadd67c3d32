"""Which effect is the model missing? Every candidate fitted to a replayed record, scored and ranked
(``hil diagnose``; the fits in hil.ident.fit, the scores in hil.ident.scores).

Every candidate (each catalogue effect that applies to the plant, and ``parameter:<key>`` for the
chain's masses, stiffnesses and dampings) is first fitted briefly, then the few best are fitted
fully. Its score is BIC(before) - BIC(after) on the effective samples; it is significant above
:data:`~hil.ident.scores.MIN_SCORE` (6) when the channel's error stands above its noise floor
(hil.ident.noise). The verdict is ``"none"`` only when the model matches the record down to the
noise floor in every channel; above it, when no candidate is significant or the leading one closes
less than half of the gap between the error and the floor (hil.ident.unexplained), the verdict is
``"unexplained"``, with the evidence of where the residual lives, unless another significant
candidate closes the half (two effects at once: the best score can go to the one that closes
less of the gap); that one is then the verdict.

Ranking: best score first; a catalogue effect before a ``parameter:`` that is the same fit by
another name; a simpler catalogue effect nested in a richer one (coulomb_friction inside
asymmetric_friction) first, unless the richer one's score is higher by more than MIN_SCORE (the
same criterion: its extra parameters must pay for themselves). A richer effect that a
combination of simpler ones can mimic (``Effect.mimicked_by``: asymmetric_friction by
coulomb_friction + constant_force) is compared with them fitted jointly (:class:`Combo`); the
combination is named first (verdict, then ``also_missing``) when the richer effect's extra
parameters do not pay against it, or when it explains at least :data:`EXPLAINED` of the richer
effect's fall of the log weighted error.

Joint candidates (hil.ident.joint): the pairs of friction and force effects that are linear in
their parameters through the inverse model are screened together by least squares on the force
residual; the :data:`~hil.ident.joint.JOINT_REFINE` pairs whose screen pays against their better
member alone are fitted by simulation (:class:`Joint`). A pair leads the ranking, named as its
members (verdict, then ``also_missing``), when it is significant, its score beats every single
candidate's, and its second member pays on top of the better one (:func:`pair_score` above
MIN_SCORE): effects that only help together are found.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from hil.ident.evidence import evidence
from hil.ident.fit import Candidate, evaluate
from hil.ident.joint import JOINT_REFINE, screen_pairs
from hil.ident.parallel import evaluate_many
from hil.ident.replay import Replay
from hil.ident.scores import MIN_SCORE, bic_score
from hil.ident.unexplained import at_noise_floor, gap_closed, residual_evidence
from hil.plant_config import candidate, default_parameters
from sim_plant.blas_threads import one_blas_thread
from sim_plant.effects import CATALOGUE

logger = logging.getLogger(__name__)

__all__ = ["diagnose", "candidate_names", "not_tried", "by_reason", "look_alikes", "is_open_loop", "Combo", "Joint", "pair_score", "EXPLAINED"]

EXPLAINED = 0.8          # a combination of simpler effects explaining this share of a richer one's gain goes first


def candidate_names(cfg, plant, include_parameters: bool = True, open_loop: bool = False) -> list[str]:
    """The default candidates: the catalogue effects that apply to the plant, and the
    ``parameter:<key>`` candidates of the config (hil.plant_config.default_parameters: the
    controller's settings among them unless the record is ``open_loop``)."""
    names = [n for n, e in CATALOGUE.items() if e.applicable(plant)]
    if include_parameters:
        names += default_parameters(cfg, closed_loop=not open_loop)
    return names


def not_tried(plant) -> dict[str, str]:
    """The catalogue effects that cannot act on ``plant``, each with the reason (Effect.unsuited):
    a cable carrier on an axis that turns without end is not a candidate, never a finding."""
    return {n: why for n, e in CATALOGUE.items() if (why := e.unsuited(plant))}


def by_reason(not_tried: dict[str, str] | None) -> dict[str, list[str]]:
    """{reason: [effects]} of :func:`not_tried`'s answer, the reasons in catalogue order."""
    out: dict[str, list[str]] = {}
    for name, why in (not_tried or {}).items():
        out.setdefault(why, []).append(name)
    return out


def is_open_loop(replay) -> bool:
    """Whether the record (or every record of several, hil.ident.records.Records) is replayed open
    loop: the loops never run."""
    return all(getattr(p, "open_loop", False) for p in getattr(replay, "parts", [replay]))


@one_blas_thread()
def diagnose(replay: Replay, names: list[str] | None = None, progress=None, max_nfev: int = 30,
             jobs: int | None = None, screen_nfev: int = 6, refine: int = 3, min_gap: float = 0.0) -> dict:
    """Try every candidate; returns {"candidates": [...ranked Candidate], "verdict": name | "none" |
    "unexplained", "noise_floor": {...}, "error_before": {...}, "gap_closed": share, ...}.

    Every candidate is first fitted briefly (``screen_nfev`` evaluations), then the ``refine``
    best are fitted fully (``max_nfev``); ``jobs`` processes share the work (default: this process,
    the candidates fitted on the idle cores' threads, hil.ident.parallel.in_threads).
    The verdict is ``"none"`` when every channel is at its noise floor (hil.ident.unexplained);
    ``"unexplained"`` when it is not and no candidate is significant or the leading one closes
    less than ``min_gap`` of the gap between the error and the floor (then ``residual`` holds the
    evidence of where the residual lives). The chain (hil.ident.chain) asks ``min_gap`` =
    :data:`~hil.ident.unexplained.HALF_GAP` of a record's first verdict; later steps, on a model
    that already holds the effects found, add what pays for its parameters."""
    cfg = replay.cfg
    res0 = replay.residuals(cfg)
    names = names or candidate_names(cfg, replay.plant, open_loop=is_open_loop(replay))
    jobs = jobs or 1
    # the costly candidates first, so that the processes finish together
    names = sorted(names, key=lambda n: -_cost_hint(n, cfg))
    # an added mode starts from the residual's peaks and from a grid, two basins apart: both screened
    out = [c for c in evaluate_many(replay, [(n, screen_nfev, None, _screen_starts(n, cfg)) for n in names],
                                    res0, jobs, progress) if c is not None]
    ranked = sorted(out, key=lambda c: -c.score)
    top = [c.effect for c in ranked[:refine]]
    # and the simpler effects nested in those, so that the ranking compares refined fits
    for c in list(top):
        top += [n for n in getattr(CATALOGUE.get(c), "nests", ()) if n in names and n not in top]
    by_name = {c.effect: c for c in out}
    if top and max_nfev > screen_nfev:
        work = [(n, max_nfev, by_name[n].params, 1) for n in top]
        better = {c.effect: c for c in evaluate_many(replay, work, res0, jobs, progress) if c is not None}
        out = [better.get(c.effect, c) if better.get(c.effect, c).score >= c.score else c for c in out]
    combos = _combinations(replay, out, res0, jobs, progress, max_nfev, refine)
    joints = _joint_pairs(replay, out, res0, jobs, progress, max_nfev, combos, names, min_gap)
    ranked, lead = _rank(out, combos + joints, replay.noise)
    also = []
    if lead is not None:
        verdict = lead.leader if lead.significant else "none"
        also = [m for m in lead.members if m["effect"] != lead.leader and m["significant"]] if lead.significant else []
        best = lead.cand
    else:
        verdict = ranked[0].effect if ranked and ranked[0].significant else "none"
        best = ranked[0] if ranked else None
    err0 = {c: float(np.sqrt(np.mean(res0[c] ** 2))) for c in replay.objective.weights}
    # an honest end: "none" only down to the noise floor; above it, a verdict must close half the gap
    closed = gap_closed(best.error_before, best.error_after, replay.noise.get(best.channel, 0.0)) if best else 0.0
    if verdict not in ("none",) and closed < min_gap and lead is None:
        # two effects at once: the best score may go to the one that closes less of the gap (a
        # ripple fitted in its basin beside a larger mass change); a significant candidate that
        # closes the half is the verdict, the chain adds the other next
        wide = max((c for c in ranked if c.significant and not isinstance(c, Combo)),
                   key=lambda c: gap_closed(c.error_before, c.error_after, replay.noise.get(c.channel, 0.0)),
                   default=None)
        if wide is not None:
            share = gap_closed(wide.error_before, wide.error_after, replay.noise.get(wide.channel, 0.0))
            if share >= min_gap:
                verdict, best, closed = wide.effect, wide, share
    if at_noise_floor(err0, replay.noise):
        verdict, also = "none", []
    elif verdict == "none" or closed < min_gap:
        verdict, also = "unexplained", []
    d = {"candidates": ranked, "verdict": verdict, "also_missing": also,
         "combinations": [c.as_json() for c in combos], "joint_candidates": [j.as_json() for j in joints],
         "noise_floor": dict(replay.noise),
         "error_before": err0, "gap_closed": closed,
         "noise_floor_source": {c: replay.noise_sources[c]["source"] for c in replay.noise}}
    if verdict == "unexplained":
        d["residual"] = residual_evidence(replay, res0, best)
    beside = {m["effect"] for m in also}         # named beside the verdict: no alternative to it
    d["alternatives"] = [a for a in look_alikes(next((c for c in ranked if c.effect == verdict), None), ranked,
                                                list(replay.objective.weights), replay.noise, replay.plant)
                         if a["effect"] not in beside]
    for c in ranked:
        logger.debug("candidate %s: score %.1f, params %s", c.effect, c.score, c.params)
    logger.info("diagnosis: verdict %s (%d candidates; gap closed %.2f)", verdict, len(ranked), closed)
    return d


def look_alikes(lead: Candidate | None, ranked: list, chans, floor=None, plant=None) -> list[dict]:
    """The candidates this record cannot tell from the verdict ``lead``: significant, neither nested
    in the other nor the config key the other changes, and neither fit's residual beating the other's by :data:`MIN_SCORE` (the same BIC
    as a score, each fit's residual as the other's "before", the richer paying for its extra
    parameters). A mass on the table and one on the
    motor side, on a record that barely excites the mode between them: one finding, two places.
    Each: of (the verdict), effect, score, evidence, and the two pair scores (the alternative against the verdict,
    the verdict against it)."""
    if lead is None or lead.res is None:
        return []
    out = []
    for c in ranked:
        if c is lead or isinstance(c, Combo) or not c.significant or c.res is None or getattr(c, "degenerate", ""):
            continue
        if _same_physics(lead.effect, c.effect, plant) or _same_physics(c.effect, lead.effect, plant):
            continue
        # the richer one pays for its extra fitted parameters (a setting, where it acts, is no freedom)
        k = len(candidate(c.effect).fitted_params) - len(candidate(lead.effect).fitted_params)
        ahead = bic_score(lead.res, c.res, chans, max(k, 0), floor)
        behind = bic_score(c.res, lead.res, chans, max(-k, 0), floor)
        if max(ahead, behind) <= MIN_SCORE:
            out.append({"of": lead.effect, "effect": c.effect, "score": float(c.score), "evidence": c.evidence,
                        "against_verdict": float(ahead), "verdict_against": float(behind)})
    return out


def _same_physics(a: str, b: str, plant) -> bool:
    """``b`` is nested in effect ``a`` (Coulomb friction in Stribeck's), or is the config key that
    ``a`` is a change of (mass_change is parameter:plant.m<table>)."""
    eff = CATALOGUE.get(a)
    return eff is not None and (b in getattr(eff, "nests", ())
                                or (plant is not None and b == f"parameter:{eff.drifted_key(plant)}"))


def _cost_hint(name, cfg) -> float:
    try:
        eff = candidate(name, cfg)
    except KeyError:
        return 0.0
    return (1 + len(eff.params)) * eff.cost_factor


def _screen_starts(name, cfg) -> int:
    """Starts of a candidate's brief screening fit: the effect's own (``Effect.screen_starts``)."""
    try:
        return candidate(name, cfg).screen_starts
    except KeyError:
        return 1


@dataclass
class Combo:
    """A combination of simpler catalogue effects fitted jointly against the richer effect it can
    mimic (``Effect.mimicked_by``): its candidate (scored like any other), the richer one, and per
    member its marginal score (the BIC score of the joint fit against the fit without that member)."""
    cand: Candidate
    rich: Candidate
    members: list            # [{"effect", "params", "score" (marginal), "significant", "evidence"}]
    leader: str = ""
    preferred: bool = False
    pair: float = math.nan   # BIC score of the richer effect against the combination
    explained: float = math.nan   # the combination's share of the richer effect's fall of the log error

    @property
    def score(self):
        return self.cand.score

    @property
    def effect(self):
        return self.cand.effect

    @property
    def significant(self):
        return self.cand.significant

    def as_json(self) -> dict:
        return {"effects": [m["effect"] for m in self.members], "explains": self.rich.effect,
                "preferred": bool(self.preferred), "score": float(self.cand.score),
                "rich_against_combination": float(self.pair), "explained": float(self.explained),
                "rich_score": float(self.rich.score), "params": {k: float(v) for k, v in self.cand.params.items()},
                "channel": self.cand.channel, "error_before": float(self.cand.error_before),
                "error_after": float(self.cand.error_after), "evidence": self.cand.evidence,
                "members": [{k: (float(v) if isinstance(v, float) else v) for k, v in m.items()} for m in self.members]}


def _combinations(replay, out, res0, jobs, progress, max_nfev, refine) -> list[Combo]:
    """Fit jointly the combinations of simpler effects that can mimic a significant richer effect
    among the best ``refine``, when every member was a candidate; their members' single fits give the
    starting values and the fits without each member (for the marginal scores)."""
    by_name = {c.effect: c for c in out}
    work, rich_of = [], {}
    for c in sorted(out, key=lambda c: -c.score)[:max(refine, 1)]:
        if not c.significant:
            continue
        for combo in getattr(CATALOGUE.get(c.effect), "mimicked_by", ()):
            if not all(m in by_name for m in combo):
                continue
            name = "+".join(combo)
            if name in rich_of:
                continue
            start = {f"{m}.{k}": v for m in combo for k, v in by_name[m].params.items()}
            rich_of[name] = c
            work.append((name, max_nfev, start, 1))
    if not work:
        return []
    fits = [c for c in evaluate_many(replay, work, res0, jobs, progress) if c is not None]
    combos = []
    for fc in fits:
        members = _members(replay, fc, by_name, res0, max_nfev)
        lead = max(members, key=lambda d: d["score"])["effect"]
        combos.append(Combo(fc, rich_of[fc.effect], members, lead))
    return combos


def _members(replay, fc, by_name, res0, max_nfev) -> list:
    """Each member of a jointly fitted combination with its marginal score: the BIC score of the
    joint fit against the fit without that member."""
    chans = list(replay.objective.weights)
    eff = candidate(fc.effect, replay.cfg)
    res1 = replay.residuals(fc.cfg)
    members = []
    for m, vals in zip(eff.members, eff.split(fc.params)):
        others = [o.name for o in eff.members if o is not m]
        if len(others) == 1:
            without = by_name[others[0]]
        else:
            without = evaluate(replay, "+".join(others), res0, max_nfev,
                               start={k: v for k, v in fc.params.items() if not k.startswith(m.name + ".")})
        sc = bic_score(replay.residuals(without.cfg), res1, chans, len(m.fitted_params), replay.noise)
        members.append({"effect": m.name, "params": vals, "score": float(sc), "significant": sc > MIN_SCORE,
                        "evidence": evidence(m.name, vals, replay, res0, fc.channel, fc.error_before,
                                              fc.error_after, [])})
    return members


class Joint(Combo):
    """A pair of friction or force effects fitted together because the inverse model's screen
    (hil.ident.joint) says the pair explains more than its better member alone: its candidate, no
    richer effect, its members with their marginal scores, the screen's figures, and the best
    single candidate it is ranked against (``single``)."""

    def __init__(self, cand, members, leader, screen, single):
        super().__init__(cand, None, members, leader)
        self.screen = screen
        self.single = single

    def prefer(self, floor=None) -> bool:
        """Named first: significant, a higher score than the best single candidate, and its
        second member pays on top of the better one (its marginal score above MIN_SCORE)."""
        best = self.single
        self.pair = min(m["score"] for m in self.members)
        self.explained = 1.0
        self.preferred = bool(self.significant and (best is None or self.score > best.score)
                              and self.pair > MIN_SCORE)
        return self.preferred

    def as_json(self) -> dict:
        out = {"effects": [m["effect"] for m in self.members], "preferred": bool(self.preferred),
               "score": float(self.cand.score), "second_member_score": float(self.pair),
               "best_single": self.single.effect if self.single is not None else None,
               "best_single_score": float(self.single.score) if self.single is not None else None,
               "screen_synergy": float(self.screen["synergy"]) if "synergy" in self.screen else None,
               "params": {k: float(v) for k, v in self.cand.params.items()},
               "channel": self.cand.channel, "error_before": float(self.cand.error_before),
               "error_after": float(self.cand.error_after), "gain": float(self.cand.gain),
               "evidence": self.cand.evidence,
               "members": [{k: (float(v) if isinstance(v, float) else v) for k, v in m.items()} for m in self.members]}
        if "rival_of" in self.screen:
            out["rival_of"] = self.screen["rival_of"]
        return out


def _joint_pairs(replay, out, res0, jobs, progress, max_nfev, combos, names, min_gap=0.0) -> list[Joint]:
    """The pairs of friction and force effects screened by the inverse model (hil.ident.joint),
    the best few whose screen pays against their better member refined by simulation; pairs
    already fitted as a combination against a richer effect are left out; and the rivals of the
    pair that would be named (:func:`_rival_pairs`)."""
    by_name = {c.effect: c for c in out}
    taken = {frozenset(m["effect"] for m in c.members) for c in combos}
    pool = [n for n in names if n in by_name]
    screened = [s for s in screen_pairs(replay, res0, pool)
                if frozenset(s["effects"]) not in taken and s["synergy"] > MIN_SCORE][:JOINT_REFINE]
    if not screened:
        return []
    work = [("+".join(s["effects"]), max_nfev, s["start"], 1) for s in screened]
    fits = evaluate_many(replay, work, res0, jobs, progress)
    best = max(out, key=lambda c: c.score) if out else None
    joints = []
    for s, fc in zip(screened, fits):
        if fc is None:
            continue
        members = _members(replay, fc, by_name, res0, max_nfev)
        lead = max(members, key=lambda d: by_name[d["effect"]].score)["effect"]
        joints.append(Joint(fc, members, lead, s, best))
    return joints + _rival_pairs(replay, out, res0, jobs, progress, max_nfev, joints, best, min_gap)


def _rival_pairs(replay, out, res0, jobs, progress, max_nfev, joints, best, min_gap=0.0) -> list["Joint"]:
    """The leader of a preferred screened pair fitted together with each of the :data:`JOINT_REFINE`
    strongest significant single candidates outside the pair: the screen sees friction and forces
    only, and its second member may stand in for an effect it cannot see (a mass change taking a
    feedback delay's share of the torque beside Coulomb friction). Left out: a member by another
    name (``parameter:plant.m<table>`` is mass_change), an effect that nests the leader or that it
    nests (asymmetric_friction and coulomb_friction), a degenerate fit, a pair already screened.
    Each such pair is a joint candidate like the screened ones (``screen``: ``{"rival_of": the
    screened pair}``); the ranking then names the best pair. Only where the screened pair would be
    the verdict: it closes at least ``min_gap`` of the gap to the floor (else the diagnosis is
    ``unexplained`` and the chain looks for two effects that show only together from the strongest
    single one)."""
    lead = max((j for j in joints if j.prefer(replay.noise)), key=lambda j: j.score, default=None)
    if lead is None or gap_closed(lead.cand.error_before, lead.cand.error_after,
                                  replay.noise.get(lead.cand.channel, 0.0)) < min_gap:
        return []

    def name(n: str) -> str:       # the catalogue's name of an alias (time_delay is actuator_delay)
        return n if n.startswith("parameter:") else candidate(n, replay.cfg).name
    # by the names a combination's members carry, and by those the candidates were given
    by_name = {**{name(c.effect): c for c in out}, **{c.effect: c for c in out}}
    members = [by_name[m["effect"]] for m in lead.members]
    taken = {frozenset(name(m["effect"]) for m in j.members) for j in joints}

    def kin(a, b) -> bool:
        return a in getattr(CATALOGUE.get(b), "nests", ()) or b in getattr(CATALOGUE.get(a), "nests", ())

    def same(c, m) -> bool:         # the same fit by another name (parameter:plant.m<table> is mass_change)
        return name(c.effect) == name(m.effect) or (_close(c, m, 0.02) and _close(m, c, 0.02))
    singles = [c for c in sorted(out, key=lambda c: -c.score)
               if c.significant and "+" not in c.effect and not any(same(c, m) for m in members)
               and not kin(name(c.effect), lead.leader) and not getattr(c, "degenerate", "")
               and frozenset((lead.leader, name(c.effect))) not in taken][:JOINT_REFINE]
    if not singles:
        return []
    work = []
    for c in singles:
        pair = [lead.leader, name(c.effect)]
        start = {f"{n}.{k}": v for n in pair for k, v in by_name[n].params.items()}
        work.append(("+".join(pair), max_nfev, start, 1))
    rivals = []
    for fc in evaluate_many(replay, work, res0, jobs, progress):
        if fc is None:
            continue
        ms = _members(replay, fc, by_name, res0, max_nfev)
        leader = max(ms, key=lambda d: by_name[d["effect"]].score)["effect"]
        rivals.append(Joint(fc, ms, leader, {"rival_of": lead.effect}, best))
    return rivals


def _rank(cands: list[Candidate], combos: list | None = None, floor=None):
    """The candidates best first, and the combination that leads the ranking (or None).

    A combination of simpler effects is preferred over the richer effect it mimics when its score is
    not lower by more than :data:`MIN_SCORE` (the richer effect's extra parameters do not pay for
    themselves) or it leaves no more error (:func:`_close`); a preferred combination takes the
    richer effect's place if that is higher, and stands in the ranking for its leading member (the
    one whose removal costs the most)."""
    entries = _rank_single(list(cands) + [c for c in combos or ()
                                          if (c.prefer(floor) if isinstance(c, Joint) else _prefer(c, floor=floor))])
    out, lead = [], None
    for e in entries:
        if isinstance(e, Combo):
            if lead is None and not out:
                lead = e
            single = next((c for c in cands if c.effect == e.leader), None)
            if single is not None and single not in out:
                rest = [m["effect"] for m in e.members if m["effect"] != e.leader]
                if isinstance(e, Joint):
                    single.evidence += (f"; fitted together with {' and '.join(rest)} (a joint candidate: score "
                                        f"{e.score:.1f}, {100 * e.cand.gain:.0f} % of the weighted error removed, "
                                        f"{' and '.join(rest)} scoring {e.pair:.1f} on top)")
                else:
                    single.evidence += (f"; with {' and '.join(rest)} it explains {100 * e.explained:.0f} % of the gain "
                                        f"of {e.rich.effect} (whose remainder scores {e.pair:.1f}: judged once these "
                                        f"are fitted)")
                out.append(single)
        elif e not in out:
            out.append(e)
    return out, lead


def _rank_single(cands: list) -> list:
    # best score first; the same fit twice (mass_change is parameter:plant.m<table> by another name)
    # puts the catalogue effect, which names the physics, before the parameter: the same fit when
    # the scores agree to 1e-4, or when both leave the same error in every channel (to 2 %: the
    # fits' convergence differs, the model does not) and the scores lie within MIN_SCORE
    # a fit that names another effect (Effect.degenerate: a mode at its bound is a rigid mass) ranks
    # after every one that does not: its score belongs to what it turned into
    cands = sorted(cands, key=lambda c: (bool(getattr(c, "degenerate", "")), -c.score))
    for i in range(len(cands) - 1):
        a, b = cands[i], cands[i + 1]
        if a.effect.startswith("parameter:") and not b.effect.startswith("parameter:") and not isinstance(b, Combo) \
                and (abs(a.score - b.score) <= 1e-4 * abs(a.score) + 0.05
                     or (a.score - b.score <= MIN_SCORE and _close(b, a, 0.02))):
            cands[i], cands[i + 1] = b, a
    # a candidate that leaves less error in every channel with no more parameters goes first: the
    # scores count the effective samples of each one's own residual, and a smoother residual after
    # the better fit can score lower (comparing scores rewards a whiter residual twice)
    _move_first(cands, lambda b, a: b.significant and _dominates(b, a))
    # a preferred combination before the richer effect it mimics
    for c in [c for c in cands if isinstance(c, Combo) and c.rich is not None]:
        i, j = cands.index(c.rich), cands.index(c)
        if j > i:
            cands.insert(i, cands.pop(j))
    # a simpler nested effect first when it explains most of the richer one's gain
    def nested_simpler(simple, rich) -> bool:
        eff = CATALOGUE.get(rich.effect)
        return bool(eff) and simple.effect in getattr(eff, "nests", ()) and simple.significant \
            and (rich.score - simple.score < MIN_SCORE or _close(simple, rich))
    _move_first(cands, nested_simpler)
    return cands


def _move_first(cands: list, goes_before) -> None:
    """Reorder ``cands`` in place until no single effect ``b`` listed after ``a`` has
    ``goes_before(b, a)``: the first such pair found, scanning from the top, moves ``b`` just
    before ``a``, and the scan starts again (combinations keep their places)."""
    changed = True
    while changed:
        changed = False
        for i in range(len(cands)):
            for j in range(i + 1, len(cands)):
                a, b = cands[i], cands[j]
                if not isinstance(a, Combo) and not isinstance(b, Combo) and goes_before(b, a):
                    cands.insert(i, cands.pop(j))
                    changed = True
                    break
            if changed:
                break


def _dominates(b: Candidate, a: Candidate) -> bool:
    """``b`` leaves less RMS error than ``a`` in every channel (by more than 5 % in one) with no more
    parameters."""
    if not a.errors_after or set(a.errors_after) != set(b.errors_after) or len(b.params) > len(a.params):
        return False
    return all(b.errors_after[c] <= a.errors_after[c] for c in a.errors_after) and \
        any(b.errors_after[c] < 0.95 * a.errors_after[c] for c in a.errors_after)


def _prefer(combo, chans=None, floor=None) -> bool:
    """Whether the combination of simpler effects is named before the richer effect it mimics.

    Marginality (lower-order terms first, as in hierarchical regression): asymmetric friction is
    Coulomb friction and an offset plus a direction-dependent remainder; the remainder is only judged
    once the lower-order terms are in the model. So a significant combination is named first when
    the richer effect's extra parameters do not pay against it (their BIC score against the
    combination, :func:`pair_score`, at most :data:`MIN_SCORE`), or when it accounts for at least
    :data:`EXPLAINED` of the richer effect's fall of the log weighted error; the richer effect's
    score against the combination is reported, and the next diagnosis (with the combination fitted)
    judges the remainder by the same criterion."""
    combo.explained = _log_fall(combo.cand) / _log_fall(combo.rich) if _log_fall(combo.rich) > 0 else 1.0
    if combo.cand.res is not None and combo.rich.res is not None:
        combo.pair = pair_score(combo.cand, combo.rich, chans or list(combo.cand.res), floor)
        pays = combo.pair > MIN_SCORE
    else:
        pays = combo.rich.score - combo.score > MIN_SCORE
    combo.preferred = bool(combo.significant and (not pays or combo.explained >= EXPLAINED
                                                  or _close(combo.cand, combo.rich)))
    return combo.preferred


def pair_score(simple: Candidate, rich: Candidate, chans, floor=None) -> float:
    """The same BIC score between two fits: the richer model against the simpler one (its residual
    as "before", the extra parameters as the penalty). Each candidate's own score counts the
    effective samples of its own residual; comparing two scores would reward a whiter residual
    twice."""
    k = len(candidate(rich.effect).fitted_params) - len(candidate(simple.effect).fitted_params)
    return bic_score(simple.res, rich.res, chans, max(k, 0), floor)


def _log_fall(c: Candidate) -> float:
    """ln(weighted error before / after) of a fit."""
    return math.log(max(1.0 / max(1.0 - c.gain, 1e-300), 1.0))


def _close(simple: Candidate, rich: Candidate, tol: float = 0.05) -> bool:
    """The simpler fit leaves no more than ``tol`` more RMS error than the richer one in every
    channel: the richer one's BIC lead is then the fits' convergence (stick-slip makes the cost
    rough), not the data."""
    return bool(simple.errors_after) and all(
        simple.errors_after[c] <= (1 + tol) * rich.errors_after.get(c, 0.0) for c in simple.errors_after)
