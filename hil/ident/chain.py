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
   the model, then together (hil.ident.fit.fit_effects). When the first diagnosis is
   ``unexplained``, two effects may show only together (a backlash under a force on the table,
   which leans the table on one flank): the best significant fit is taken into the model, the
   model diagnosed again and that verdict fitted on top, then both together; when the pair closes
   :data:`~hil.ident.unexplained.HALF_GAP` of the gap the first step adds both
   (``shown_together``), else the chain ends ``unexplained``;
   A later step's single verdict is judged beside the runner-up of the ranking when that removes
   at least :data:`RIVAL_GAIN` of the verdict's share (and is not the same fit by another name):
   both go through 3., and the better BIC is the step (``rival``);
3. every effect found so far refitted together from those values (one
   :class:`~sim_plant.effects.Combination`, bounded and scaled as any candidate's fit), kept when
   it lowers the weighted error; the step is kept when its BIC score on the record pays for the
   parameters it added.

The polishing fits weight each channel by the residual the step's first fit left (1 / max(RMS,
floor)), not by the residual before it: a channel the fit brought to its floor no longer drowns
the one still far above it.

With a held-out part (``holdout``: ``"moves"``, or the replays of records the chain does not fit,
as ``--validate``'s), every step must earn its place on data it was not fitted on:

* ``"moves"``: the record's moves (motion in one direction and the standstill after it, cut where
  the direction changes), taken in pairs (there and back), go pair by pair alternately to the
  estimation half and the held-out half (single moves where there are fewer than two pairs;
  :func:`split_moves`). The whole record is still simulated (the state where a held-out move
  starts is the record's, a backlash's side or an integrator's charge included); the step's
  effects are refitted on the estimation samples alone from the step's values
  (:data:`HOLDOUT_NFEV` evaluations: the held-out samples' errors never enter them);
  with validation records the step's fit on the record is the estimation fit;
* the held-out error before and after the step, per sample the weighted squared residual summed
  over the channels, e_n = sum_c (r_c[n] / s_c)^2 with s_c = max(RMS before, RMS after, noise
  floor): each channel's mean share is at most one, before and after, so a channel the step makes
  worse does not drown the others' falls by (after / before)^2 (a force and a backlash that bring
  the motor, table and torque from 13 to 88 x their floor to it uncover the tip's drifted mode, which
  the table's error had hidden: the tip 3 x worse); for a small change the weights are those of
  before. Its fall must stand above :data:`HOLDOUT_Z` standard errors of the held-out sample's noise
  (:func:`held_out_fall`) and above the fall the model as it stands reaches on the held-out moves
  when the effects already found are refitted on them (``model_refit_fall``): the uncertainty of
  what is already in the model. A record whose residual is chaotic after an effect (a table
  rattling in a backlash) changes with any small retuning; a step that does no better there
  than the model's own retuning is not earned. A step that does not earn its place is refused: its
  effects are no candidates any more and the next verdict is tried, as a drive engineer tries the
  next suspect (a friction that differs with the direction refused, the plain viscous friction
  beside it is the next); the chain stops when none earns its place: at its :data:`REFUSALS`-th
  refused step, or where the next verdict is nothing (``end`` "no step earns its place on the
  held-out data", the last refused step under ``final.rejected``, those before it under
  ``final.also_refused``);
* a step of several effects (the verdict and the effects ``also_missing`` beside it) is judged
  member by member first (:func:`_members_earned`, ``chain[].held_out.members``; a pair shown
  together as well, whose single member left is then the step): each member's
  own fall, the step without it against the step, both refitted on the estimation moves, must
  stand beyond its uncertainty and beyond what the rest reaches refitted on the held-out moves; the
  weakest member that does not earn its own is taken out, the rest refitted on the record and
  judged again. Where the record's plant differs from the model a little everywhere, a second
  member takes a sliver of it: a viscous friction of -6 uN m s/rad fitted beside the Coulomb
  friction of a record of the independent simulator that has none lowers the held-out error by
  0.13 %, beyond the noise's 0.09 %, not beyond the 0.15 % the Coulomb friction alone reaches
  refitted on those moves.

An effect found at an earlier step that no longer pays for its parameters once a step's effects
are in the model is dropped (``chain[].dropped``; stepwise selection's backward step): it is set
back to the start model's values alone, the rest kept as the step fitted them, and its BIC score
(the error with it against without it) compared with :data:`~hil.ident.scores.MIN_SCORE`; the
weakest goes first, and the others are judged again without it. Refitting the rest without it
could only lower the error without it, so an effect that does not pay so would pay less still.
A dropped effect is no candidate again. (On Coulomb friction with an actuator delay the first
step takes the friction with a mass change, the inverse model's pair, that stands in for the
delay's share of the torque; once the delay is found the mass is refitted to almost nothing and
dropped.)

The first step's single verdict keeps its look-alike (:func:`_look_alike`: a candidate of that
diagnosis that corrects the residual as the verdict does); where the chain ends above the noise
floor after more steps, the look-alike is fitted in the verdict's place with everything else
refitted, and kept as a step of its own when it scores better (``chain[].swapped``; stepwise
selection's swap): the first diagnosis ranked each candidate alone, beside effects still missing.

A step whose effects are all drifts of the config's masses, stiffnesses and dampings (``parameter:plant.m3``,
``mass_change``) is first put to the config's tolerance (hil.ident.tolerance, ``plant.tolerance``):
all of them fitted together, each held within the tolerance by a prior. Where every change lies
within it, the drift is no finding: the model takes the fitted values, no step is named, the
chain ends where that reaches the noise floor (``end`` "noise floor reached within the config's
tolerance") and else diagnoses the rest with no drift of the config among the candidates
(``final.tolerance``; the verdict is then what the chain names beyond it, else ``none``). A record
fixes combinations of those parameters (the tip's k2 / m3): a step that names one of them names it
off by the others' drifts. A later step (after an effect was found) that names another effect is
put to the same fit, the effects found refitted with the drift: where that brings every channel to
its noise floor, the step's effect is no finding either (``final.tolerance.in_place_of``; a torque
constant is every mass's drift in one parameter, a lightly damped mode a sliver of the tip's), and
an effect found before that no longer pays beside the drift is dropped
(``final.tolerance.dropped``, as a step's backward step): set back alone, or with the drift fitted
again without it (:func:`_unpaid_beside_drift`: a mode fitted far above the record's Nyquist
frequency is a rigid mass on the tip, the tip's drift by another name).

Where the step's drift does not fit within the tolerance and the fit of every key leaves one key
alone beyond it (its change, less two standard errors, above the tolerance; a key the model names
already not counted), the step is that key's (:func:`_beyond_tolerance`, ``chain[].beyond_tolerance``):
the best-ranked significant candidate that changes it. A tool-tip mode drifted by a percent rings
for seconds and outweighs in the record a transmission 18 % soft: the diagnosis named the tip's
mass, a tip mode beside it scored better as its rival, and the chain went on to name a mass, a
torque constant and the stiffness; the fit of every key put k1 alone beyond the tolerance, and
the chain now names k1 and ends at the floor within the tolerance. A later step's effect that is
no drift is judged so where the drift, the effects found refitted with it, brings every channel to
the floor with one key beyond (a table 49 kg heavier with k1 44 % soft: k1 found, the next verdict
a torque constant, its rival the motor's mass m1; the key beyond is the table's mass).

A drift within the tolerance that the model took at an earlier step was fitted beside the effects
still missing: after each later step that leaves the record above its floor it is fitted again
beside the step's effects, everything found refitted with it (:func:`_drift_again`; reported as a
refit on the night's plant is, below, and as that one only with ``nights_plant``:
``chain[].nights_plant``, ``final.tolerance.again_after``).
On a drifted bench with a ripple of 0.17 N m the drift fitted first split the moving mass wrongly
between motor and table (m1 4 % light, m2 3.5 % heavy), and the steps after the ripple named a
stiffness along the travel and a pitch error for slivers of what that left; fitted again beside
the ripple, the drift brings every channel to its floor (``tests/independent/test_tolerance.py``).

An effect whose error jumps with its parameter (:attr:`~sim_plant.effects.Effect.non_smooth`:
a backlash, whose table rattles in its gap) fitted on the config's plant follows the plant's drift
rather than its own strength: at the paper bench's tool tip (a mode at 15 Hz damped at 1.5 %) a
percent on k2 moves the ringing's phase, and a 34.7 um gap read 26.7 um. A step that adds one,
above the noise floor, refits it on the night's plant (``chain[].nights_plant``;
hil.ident.tracking.on_nights_plant: the profile over its grid with the masses' common scale and
the lightly damped modes' springs, then the tolerance's fit of every key and everything found, then
a scan of the gridded parameters found), kept where every change lies within ``plant.tolerance``,
it lowers the weighted error and, where the record has a held-out part, it earns its place there
(the tolerance's fit on the estimation moves from the refit's point, whose gap the whole record
chose) as a drift within the tolerance does: no finding; the step's values, standard errors, errors
and config are then those on the night's plant (its score and held-out check stay the step's own).
Later tolerance tests stay about the config's values (their fits start from the night's); a
backlash found after the model took a drift within the tolerance is not refitted so again. A first
diagnosis ``unexplained`` (``max_steps`` 1 included) tries its best such candidate so before
the pair shown together: a 31.1 um gap fitted as 7.1 um on the config's plant (x_motor 16 % less,
the tip no better), refitted on the night's plant, reads 31.1 um and brings the tip from 705 to 10
times its floor (``tests/independent/test_tracking.py``, seed 6).

Each step reports its estimation error (the record's, or the estimation half's) and held-out
error per channel, and the standard errors of everything found so far with the pairs of fitted
parameters confounded in the step's last fit (hil.ident.fit: |correlation| above
:data:`~hil.ident.fit.CONFOUNDED`); and the aliases of the config's own parameters in the step's
effects (:func:`~hil.ident.fit.config_aliases`): a one-parameter step has no correlation of its
own, yet on a record where k2 drifted a step that names m3 has found the tip mode's frequency,
sqrt(k2 / m3), not the mass; the alias says so (m3 confounded with k2, r = +1.00) and how much a
drift of k2 moves it.

It stops when every channel is at its noise floor (``end`` "noise floor reached"), when the
diagnosis finds nothing that pays ("no effect pays for its parameters"; the remainder above the
floor comes with the evidence of where it lives), when the first verdict is ``none`` or
``unexplained``, when every candidate is in the model ("no candidate left"), or after
``max_steps``.
"""
from __future__ import annotations

import logging
import math
from enum import Enum

import numpy as np

from hil.ident.diagnosis import _close, candidate_names, diagnose, is_open_loop
from hil.ident.fit import CONFOUNDED, _fit_one, config_aliases, evaluate, fit_effects
from hil.ident.objective import MaskedObjective
from hil.ident.progress import expect
from hil.ident.result import ChainStep
from hil.ident.scores import MIN_SCORE, bic_score
from hil.ident.tolerance import TOLERANCE, is_drift, tolerance_keys, within_tolerance
from hil.ident.unexplained import AT_FLOOR, HALF_GAP, at_noise_floor, gap_closed, residual_evidence, rms
from hil.plant_config import candidate, default_parameters, effect_values, measurement_key, without_replaced
from sim_plant.blas_threads import one_blas_thread

logger = logging.getLogger(__name__)

__all__ = ["diagnose_chain", "chain_json", "chain_verdict", "End", "floor_parts", "floor_parts_text", "MAX_STEPS",
           "effect_values", "split_moves", "held_out_fall", "HOLDOUT_MIN", "HOLDOUT_Z", "HOLDOUT_NFEV", "REFUSALS"]

MAX_STEPS = 4


class End(Enum):
    """Why the chain ended; ``final["end"]`` is its text (:meth:`text`)."""
    NOISE_FLOOR = "noise floor reached"
    WITHIN_TOLERANCE = "noise floor reached within the config's tolerance"
    NO_CANDIDATE = "no candidate left"
    UNEXPLAINED = "unexplained"
    UNPAID = "no effect pays for its parameters"
    NOT_EARNED = "no step earns its place on the held-out data"
    TANGLED = "no step left that the record tells apart from the effects found"
    MAX_STEPS = "max steps"

    def text(self, max_steps: int) -> str:
        return f"max steps ({max_steps})" if self is End.MAX_STEPS else self.value

    @property
    def at_floor(self) -> bool:
        return self in (End.NOISE_FLOOR, End.WITHIN_TOLERANCE)

REFUSALS = 2            # a chain ends at its second refused step (the next candidate tried after the first)
HOLDOUT_MIN = 64        # samples each half needs at least
HOLDOUT_Z = 2.0         # the held-out fall must stand this many standard errors above zero
HOLDOUT_NFEV = 15       # evaluations of a step's refit on the estimation half


def _same(name: str, cfg) -> str:
    """What a candidate name stands for (an alias and its effect are one)."""
    try:
        return candidate(name, cfg).name
    except KeyError:
        return name


def _moves(t, x_cmd) -> list[tuple[int, int]]:
    """(start, end) sample ranges of the record's moves: a stretch of motion in one direction with
    the standstill after it (standstill: |v| of the command below 1 % of its maximum); the record
    is cut where the direction of motion changes, or, where it never changes, where the motion
    starts after a standstill."""
    v = np.gradient(np.asarray(x_cmd, float), t)
    sign = np.where(np.abs(v) < 0.01 * max(float(np.max(np.abs(v))), 1e-12), 0.0, np.sign(v))
    nz = np.flatnonzero(sign)
    if nz.size == 0:
        return [(0, sign.size)]
    # a standstill belongs to the move before it (the first one to the first move)
    filled = sign[nz[np.clip(np.searchsorted(nz, np.arange(sign.size), side="right") - 1, 0, None)]]
    cuts = list(np.flatnonzero(np.diff(filled)) + 1)
    if not cuts:
        # every motion in one direction: the moves are cut where the motion starts after a
        # standstill (without, a record of moves one after the other would have no halves)
        starts = np.flatnonzero((sign[1:] != 0) & (sign[:-1] == 0)) + 1
        cuts = [int(c) for c in starts[starts > nz[0]]]
    ends = [0] + [int(c) for c in cuts] + [sign.size]
    return [(a, b) for a, b in zip(ends[:-1], ends[1:]) if b > a]


def _half_of_travel(x, a: int, b: int) -> int:
    """The sample where the move ``a:b`` has covered half of its travel (its acceleration before,
    its deceleration and the standstill after it from there); ``a`` for a move without travel."""
    seg = np.abs(x[a:b] - x[a])
    half = 0.5 * float(seg[-1])
    return a + int(np.argmax(seg >= half)) if half > 0 else a


def split_moves(replay, min_samples: int = HOLDOUT_MIN):
    """The record's moves (the module's definition) in pairs, the pairs alternately in an
    estimation half and a held-out half; single moves when there are fewer than two pairs.
    Where single moves would leave a direction of motion to one half alone (there and back, or
    there, back and there again: an effect that differs with the direction, a friction, would be
    fitted on one direction and judged on the other), and where the record is one move, each move
    is cut at the middle of its travel (:func:`_half_of_travel`) and its halves go to the two
    halves in turn, the next move's the other way round: the first move's acceleration estimates
    and its deceleration is held out, the second's deceleration estimates, and so on.

    Returns (estimation, held_out), boolean masks of the record's samples (of the records joined,
    for several); None for an open-loop record, or when either half has fewer than ``min_samples``."""
    out = _split(replay, min_samples)
    return out[:2] if out is not None else None


def _split(replay, min_samples: int = HOLDOUT_MIN):
    """:func:`split_moves`'s (estimation, held_out) and whether the moves were cut at the middle of
    their travel; None as there."""
    if any(getattr(p, "open_loop", False) for p in getattr(replay, "parts", [replay])):
        return None
    m = replay.meas
    x = np.asarray(m["x_cmd"], float)
    moves = _moves(m.t, x)
    per = 2 if len(moves) >= 4 else 1
    sign = [float(np.sign(x[b - 1] - x[a])) for a, b in moves]
    halved = per == 1 and (len(moves) == 1 or set(sign[0::2]) != set(sign[1::2]))
    est = np.zeros(m.t.size, bool)
    for i, (a, b) in enumerate(moves):
        first = (i // per) % 2 == 0
        if halved:
            c = _half_of_travel(x, a, b)
            est[a:c], est[c:b] = first, not first
        else:
            est[a:b] = first
    held = ~est
    if est.sum() < min_samples or held.sum() < min_samples:
        return None
    return est, held, halved


def held_out_fall(before: dict, after: dict, floor: dict) -> dict:
    """The held-out error before and after a step (the module's definition), from the held-out
    residuals ``before`` and ``after`` (per channel) and the noise floor: ``before`` and ``after``
    (RMS per channel), ``fall`` (the relative fall of the weighted error), ``uncertainty``
    (:data:`HOLDOUT_Z` standard errors of it) and ``earned`` (the fall beyond its uncertainty).

    Each channel weighs by s_c = max(RMS before, RMS after, its floor) (the module's definition).
    The uncertainty is the held-out sample's: with r = m + n (the model error and white noise at the
    floor f_c) and the step's change delta = r_before - r_after, the fall's noise part is
    2 sum delta n / N, of standard error 2 sqrt(sum_c sum_n (delta_cn / s_c)^2 (f_c / s_c)^2) / N."""
    n = next(iter(before.values())).size
    eb = np.zeros(n)
    ea = np.zeros_like(eb)
    var = 0.0
    for c in before:
        sc = max(float(np.sqrt(np.mean(before[c] ** 2))), float(np.sqrt(np.mean(after[c] ** 2))),
                 float(floor.get(c, 0.0)), 1e-300)
        eb += (before[c] / sc) ** 2
        ea += (after[c] / sc) ** 2
        var += 4.0 * float(np.sum(((before[c] - after[c]) / sc) ** 2)) * (float(floor.get(c, 0.0)) / sc) ** 2
    mean_b = max(float(np.mean(eb)), 1e-300)
    fall = float(np.mean(eb - ea))
    se = math.sqrt(var) / max(n, 1)
    return {"before": rms(before), "after": rms(after), "fall": fall / mean_b, "uncertainty": HOLDOUT_Z * se / mean_b,
            "earned": bool(fall > HOLDOUT_Z * se)}


def _holdout_parts(replay, holdout):
    """What the steps are checked on: ("moves", (estimation mask, held-out mask)) for ``"moves"``
    (None where the record cannot be split), ("records", Records of the validation replays), or None."""
    if holdout is None:
        return None
    if isinstance(holdout, str):
        if holdout != "moves":
            raise ValueError(f"holdout {holdout!r}: 'moves' or the validation records")
        masks = split_moves(replay)
        return ("moves", masks) if masks is not None else None
    from hil.ident.records import Records
    parts = list(holdout)
    # the validation records' floor is their own (sensor, standstill, their own repetitions): the
    # fitted records never raise it (a difference between the two is what the model must predict)
    return ("records", Records(parts)) if parts else None


def _earned(cur, split, add, found, cfg1, fit_nfev, refit=None) -> dict:
    """The step on the held-out data. With the record's moves: the step's effects refitted on the
    estimation moves alone from their values in ``cfg1`` (the whole record simulated, the held-out
    samples out of the objective), the held-out samples' residuals before (the model as it stands)
    and after (:func:`held_out_fall`); and what the model as it stands reaches on the held-out moves
    when the effects already ``found`` are refitted on them (``model_refit_fall``): the step earns
    its place when its fall stands beyond both. With validation records, ``cfg1`` on them. With
    ``estimation``: the RMS error per channel after the step on the data it was fitted on. ``refit``
    (a mask -> residuals callable): the step's own refit on the estimation moves, in place of its
    effects' (the config's tolerance, hil.ident.tolerance)."""
    kind, what = split
    if kind != "moves":
        out = held_out_fall(what.residuals(cur.cfg), what.residuals(cfg1), what.noise)
        out["estimation"] = rms(cur.residuals(cfg1))
        return out
    est, held = what
    res_b = cur.base_residuals
    res_a = refit(est) if refit is not None else _refit_on(cur, est, add, cfg1, fit_nfev)
    out = held_out_fall({c: r[held] for c, r in res_b.items()}, {c: r[held] for c, r in res_a.items()}, cur.noise)
    model = 0.0
    if found:
        res_o = _refit_on(cur, held, found, cur.cfg, fit_nfev)
        model = max(held_out_fall({c: r[held] for c, r in res_b.items()}, {c: r[held] for c, r in res_o.items()},
                                  cur.noise)["fall"], 0.0)
    out.update(model_refit_fall=model, earned=bool(out["fall"] > out["uncertainty"] + model),
               estimation=rms({c: r[est] for c, r in res_a.items()}))
    return out


def _start(names, cfg) -> dict:
    """The values of the effects ``names`` in ``cfg`` as a fit's start: the effect's own {param:
    value}, or {"effect.param": value} for several (a Combination's names)."""
    if len(names) == 1:
        return effect_values(names[0], cfg)
    return {f"{n}.{k}": v for n in names for k, v in effect_values(n, cfg).items()}


def _members_earned(cur, split, add, cfg1, fits, fit_nfev, progress):
    """A step of several effects member by member on the held-out data: each member's fall there,
    the rest refitted on the estimation data without it (``before``) against the whole step
    refitted so (``after``), by :func:`held_out_fall`. The step as a whole may earn its place on
    one member's fall; each member must also stand beyond what the rest reaches refitted on the
    held-out moves (as the step's ``model_refit_fall``). The weakest member that does not earn its
    own is taken out, the rest refitted on the record, and the rest judged again. Returns (effects,
    config, fits, {member: its fall}); the members taken out are those of the last not in
    effects."""
    members = {}
    while len(add) > 1:
        kind, what = split
        cfgs = {m: _without(m, cfg1, cur.cfg) for m in add}
        if kind == "moves":
            est, held = what
            res_a = _refit_on(cur, est, add, cfg1, fit_nfev)
            after = {c: r[held] for c, r in res_a.items()}
            falls = {}
            for m in add:
                rest = [a for a in add if a != m]
                before = {c: r[held] for c, r in _refit_on(cur, est, rest, cfgs[m], fit_nfev).items()}
                f = held_out_fall(before, after, cur.noise)
                # and beyond what the rest reaches refitted on the held-out moves themselves (a model
                # that differs from the record's plant a little everywhere lets any small parameter
                # take a sliver of it)
                retuned = {c: r[held] for c, r in _refit_on(cur, held, rest, cfgs[m], fit_nfev).items()}
                f["model_refit_fall"] = max(held_out_fall(before, retuned, cur.noise)["fall"], 0.0)
                f["earned"] = bool(f["fall"] > f["uncertainty"] + f["model_refit_fall"])
                falls[m] = f
        else:
            res_a = what.residuals(cfg1)
            falls = {m: held_out_fall(what.residuals(cfgs[m]), res_a, what.noise) for m in add}
        for m, f in falls.items():
            members[m] = {k: f[k] for k in ("fall", "uncertainty", "model_refit_fall", "earned") if k in f}
        weakest = min(add, key=lambda m: falls[m]["fall"] - falls[m]["uncertainty"] - falls[m].get("model_refit_fall", 0))
        if falls[weakest]["earned"]:
            break
        logger.info("chain: %s does not earn its place beside %s on the held-out data (fall %.3g, uncertainty "
                    "%.3g): taken out of the step", weakest, ", ".join(a for a in add if a != weakest),
                    falls[weakest]["fall"], falls[weakest]["uncertainty"])
        add = [a for a in add if a != weakest]
        cfg1 = cfgs[weakest]
        if progress:
            expect(progress, 1)
            progress("+".join(add))
        start = _start(add, cfg1)
        try:
            at = cur.with_config(cfg1)
            c = evaluate(at, "+".join(add), max_nfev=fit_nfev, start=start)
        except ValueError:
            c = None
        if c is not None and _weighted(at, c.res) < _weighted(at, at.base_residuals):
            cfg1, fits = c.cfg, fits + [c]
    return add, cfg1, fits, members


def _refit_on(cur, mask, names, cfg, fit_nfev) -> dict:
    """The residuals of the whole record with the effects ``names`` refitted on the ``mask``
    samples alone, from their values in ``cfg``, on top of ``cur``'s model."""
    eff = candidate("+".join(names), cur.cfg)
    vals = _start(names, cfg)
    try:
        return _fit_one(MaskedObjective(cur.objective, mask), cur.cfg, eff, [vals],
                        max_nfev=min(fit_nfev, HOLDOUT_NFEV))[2]
    except ValueError:
        return cur.residuals(cfg)


def _nested(stderr: dict) -> dict:
    """{effect.param: value} as {effect: {param: value}} (a step's ``stderr``); NaN as None."""
    out: dict = {}
    for k, v in stderr.items():
        name, param = k.rsplit(".", 1)
        out.setdefault(name, {})[param] = float(v) if math.isfinite(v) else None
    return out


def _stderr_of(fit, names) -> tuple[dict, list]:
    """A step's last fit's standard errors as {effect: {param: value}} and its confounded pairs."""
    if fit is None:
        return {}, []
    out = {}
    for k, v in fit.stderr.items():
        n = next((n for n in names if k.startswith(n + ".")), None) if "+" in fit.effect else fit.effect
        if n is not None:
            out.setdefault(n, {})[k[len(n) + 1:] if "+" in fit.effect else k] = float(v)
    return out, [list(p) for p in fit.confounded]


TANGLED = 0.95     # |r| between a step's parameter and a found one's beyond which the step is refused


def confounded_with_found(conf, aliases, add, found) -> str:
    """Why a step's effects ``add`` cannot be told apart from the effects ``found`` before it, ""
    where they can: a parameter of the step correlated with a found one's beyond :data:`TANGLED`
    in the step's joint fit (``conf``: [name, name, r]), or a step's parameter that aliases a
    config key found as ``parameter:<key>`` (``aliases``: :func:`_aliases`; LinA: a torque
    constant of 1.075 beside kp +25 %, r = -1.000)."""
    def owner(name):
        return next((n for n in add + found if name == n or name.startswith(n + ".")), None)
    for a, b, r in conf:
        ea, eb = owner(a), owner(b)
        if abs(r) >= TANGLED and ea != eb and {ea, eb} & set(add) and {ea, eb} & set(found):
            return f"{a} and {b} (r = {r:+.3f}): this record cannot tell them apart"
    for n, al in (aliases or {}).items():
        for x in al:
            if abs(x["r"]) >= TANGLED and f"parameter:{x['key']}" in found:
                return (f"{n} and parameter:{x['key']}, found before (r = {x['r']:+.3f}): this record cannot tell "
                        f"them apart")
    return ""


def _aliases(replay, cfg1, add) -> dict:
    """{effect: :func:`~hil.ident.fit.config_aliases`} of a step's effects at the step's config
    against the config's own parameters (the diagnosis's ``parameter:`` candidates): what a drift
    of each, left out of the model, shows as in the step's fitted values."""
    keys = [k.split(":", 1)[1] for k in default_parameters(cfg1, closed_loop=not is_open_loop(replay))]
    at = replay.with_config(cfg1)
    return {n: config_aliases(at, n, effect_values(n, cfg1), keys) for n in add}


def _add_verdict(cur, d, verdict, add, fit_nfev, progress):
    """(config, fits) of a step's effects added on top of the model: a combination one after the
    other, then together (hil fit --add ...); a single verdict the diagnosis's fit, polished from
    where it stopped (weighted by the residual the fit left: the channel still far from its floor
    leads)."""
    if len(add) > 1:
        return fit_effects(cur, add, max_nfev=fit_nfev, progress=progress)
    lead = next(c for c in d["candidates"] if c.effect == verdict)
    if progress:
        expect(progress, 1)
        progress(verdict)
    at = cur.with_config(lead.cfg)
    c1 = evaluate(at, verdict, max_nfev=fit_nfev, start=lead.params)
    c1 = c1 if _weighted(at, c1.res) <= _weighted(at, at.base_residuals) else lead
    return c1.cfg, [c1]


def _shown_together(cur, d, cands, progress, jobs, max_nfev, fit_nfev, **kw) -> dict | None:
    """The first step when no single effect closes :data:`HALF_GAP` (the verdict ``unexplained``):
    the best significant fit (its own: not degenerate, not worse than without) taken into the model,
    the model diagnosed again, and its verdict fitted on top; then both refitted together. Kept when
    the pair closes half the gap on the channel where it shows most; else None (the chain ends
    ``unexplained``, as before). Returns the step's ``verdict``, ``effects``, ``text`` (what it
    says), and its fits and config (``_fits``, ``_config``)."""
    lead = next((c for c in d["candidates"] if c.significant and "+" not in c.effect), None)
    if lead is None:
        return None
    at = cur.with_config(lead.cfg)
    rest = [n for n in cands if _same(n, cur.cfg) != _same(lead.effect, cur.cfg)]
    d2 = diagnose(at, rest, progress=progress, jobs=jobs, max_nfev=max_nfev, min_gap=0.0, **kw)
    second = d2["verdict"]
    if second in ("none", "unexplained"):
        return None
    c2 = next(c for c in d2["candidates"] if c.effect == second)
    pair = [lead.effect, second]
    name = "+".join(pair)
    start = _start(pair, c2.cfg)
    if progress:
        expect(progress, 1)
        progress(name)
    try:
        joint = evaluate(cur.with_config(c2.cfg), name, max_nfev=fit_nfev, start=start)
    except ValueError:
        return None
    res0 = cur.base_residuals
    cfg1, res1 = (joint.cfg, joint.res) if _weighted(cur, joint.res) < _weighted(cur, c2.res) else (c2.cfg, c2.res)
    floor = cur.noise
    e0, e1 = rms(res0), rms(res1)
    closed = {c: gap_closed(e0[c], e1[c], floor[c]) for c in e0}
    chan = max(closed, key=closed.get)
    alone = gap_closed(lead.error_before, lead.error_after, floor.get(lead.channel, 0.0))
    logger.info("shown together: %s closes %.2f of the gap in %s (%s alone %.2f)", name, closed[chan], chan,
                lead.effect, alone)
    if closed[chan] < HALF_GAP:
        return None
    text = (f"{lead.effect} and {second} show only together: {lead.effect} alone closed {100 * alone:.0f} % of the gap "
            f"in {lead.channel}, with {second} fitted on top and both refitted together {100 * closed[chan]:.0f} % in "
            f"{chan}; {second}: {c2.evidence}")
    return {"verdict": lead.effect, "effects": pair, "text": text, "_fits": [lead, c2, joint], "_config": cfg1}


# a runner-up whose gain is at least this share of the verdict's is judged beside it (:func:`_rival`)
RIVAL_GAIN = 0.8


def _refit_found(replay, cur, found, add, cfg1, fit_nfev, progress):
    """(config, residuals, joint fit or None, BIC score) of a step: everything found so far refitted
    together with ``add`` from the values it has now (kept when it lowers the weighted error), and
    the step's score on the record (BIC, as every candidate's)."""
    floor = replay.noise
    res1 = cur.residuals(cfg1)
    joint = None
    if found:
        name = "+".join(found + add)
        start = _start(found + add, cfg1)
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
    k = sum(len(candidate(n, cur.cfg).fitted_params) for n in add)
    return cfg1, res1, joint, bic_score(cur.base_residuals, res1, list(floor), k, floor)


def _without(name: str, cfg, base):
    """``cfg`` with the effect ``name`` as the start model ``base`` has it: a parameter at base's
    value, a recording artefact's key and an effect's section as base holds them (absent: removed)."""
    eff = candidate(name, base)
    key = getattr(eff, "key", None) or measurement_key(eff)
    if key is not None:
        return cfg.with_values({key: base.get(key)})
    prefix = f"effects.{eff.name}."
    return cfg.with_values({k: base.get(k) for k in cfg.values if k.startswith(prefix)})


def _unpaid(replay, found, add, cfg1, res1) -> list[dict]:
    """The effects of earlier steps that no longer pay for their parameters once a step's effects
    ``add`` are in the model (the module's definition): each effect found before the step set back
    to the start model's values alone, the rest as the step fitted them, and its BIC score (the
    error with it against without it); the weakest at most :data:`~hil.ident.scores.MIN_SCORE` is
    dropped, and the rest judged again without it. Returns the config and residuals after the
    drops and one entry per dropped effect (``effect``, ``params`` as it stood, ``score``)."""
    floor = replay.noise
    dropped = []
    while True:
        earlier = [n for n in found if n not in add and "+" not in n]
        if not earlier:
            return cfg1, res1, dropped
        cfgs = [_without(n, cfg1, replay.cfg) for n in earlier]
        scores = []
        for n, r in zip(earlier, replay.residuals_many(cfgs)):
            k = len(candidate(n, replay.cfg).fitted_params)
            scores.append(math.inf if isinstance(r, Exception) else bic_score(r, res1, list(floor), k, floor))
        i = int(np.argmin(scores))
        if not scores[i] <= MIN_SCORE:
            return cfg1, res1, dropped
        name = earlier[i]
        logger.info("chain: %s no longer pays (BIC score %.1f with the step's effects): dropped", name, scores[i])
        dropped.append({"effect": name, "params": effect_values(name, cfg1), "score": float(scores[i])})
        cfg1 = cfgs[i]
        res1 = replay.residuals(cfg1)
        found = [n for n in found if n != name]


def _unpaid_beside_drift(replay, cur, found, tol, cfg_t, ref=None) -> tuple[dict | None, list[dict]]:
    """The effects of earlier steps that a drift within the tolerance holds in their place: each
    set back to the start model's values alone and the drift fitted again without it, the others
    refitted with it (:func:`~hil.ident.tolerance.within_tolerance` from ``cur``, the model before the
    drift). An effect and the drift can be one fit by two names, which setting the effect back
    alone (:func:`_unpaid`) does not see: a mode fitted above the record's bandwidth is a rigid
    mass on its side, a torque constant every mass's drift in one parameter. The weakest whose
    drift so refitted stays within the tolerance and whose BIC score against the drift with it
    (``cfg_t``) is at most :data:`~hil.ident.scores.MIN_SCORE` is dropped, the others judged again
    without it. Returns the last such tolerance test (None: nothing dropped) and one entry per
    dropped effect, as :func:`_unpaid`."""
    floor = replay.noise
    res_t = replay.residuals(cfg_t)
    dropped, last = [], None
    while True:
        earlier = [n for n in found if "+" not in n]
        best = None
        for name in earlier:
            rest = [n for n in found if n != name]
            test = _tolerance_test(cur.with_config(_without(name, cur.cfg, replay.cfg)), tol, rest, ref)
            if test is None or not test["within"]:
                continue
            k = len(candidate(name, replay.cfg).fitted_params)
            score = bic_score(replay.residuals(test["_config"]), res_t, list(floor), k, floor)
            if score <= MIN_SCORE and (best is None or score < best[1]):
                best = (name, score, test)
        if best is None:
            return last, dropped
        name, score, last = best
        logger.info("chain: %s no longer pays beside the config's drift refitted without it (BIC score %.1f): "
                    "dropped", name, score)
        dropped.append({"effect": name, "params": effect_values(name, cfg_t), "score": float(score)})
        found = [n for n in found if n != name]
        cfg_t = last["_config"]
        res_t = replay.residuals(cfg_t)
        cur = cur.with_config(_without(name, cur.cfg, replay.cfg))


def _rival(d, verdict, add, have, cur):
    """The runner-up of a later step's single verdict: the next significant single candidate of the
    ranking (its own fit, not one already in the model) whose gain is at least :data:`RIVAL_GAIN`
    of the verdict's; None when there is none."""
    if len(add) != 1:
        return None
    ranked = [c for c in d["candidates"] if "+" not in c.effect]
    lead = next((c for c in ranked if c.effect == verdict), None)
    if lead is None:
        return None
    for c in ranked[ranked.index(lead) + 1:]:
        if c.significant and _same(c.effect, cur.cfg) not in have:
            # the same fit by another name (mass_change is parameter:plant.m<table>: the ranking put
            # the one that names the physics first) is no rival
            same = _close(c, lead, 0.02) and _close(lead, c, 0.02)
            return c if c.gain >= RIVAL_GAIN * lead.gain and not same else None
    return None


def _tolerance_test(cur, tol, found, ref, mask=None, **kw) -> dict | None:
    """hil.ident.tolerance.within_tolerance on the model as it stands (``cur``) about the config's
    plant: ``ref`` ({key: the start model's value}) holds the keys a refit on the night's plant
    moved (:func:`_on_nights_plant`), set back for the test's prior and changes, its fit starting
    from ``cur``'s values; empty or None: about ``cur``'s own."""
    base = _config_plant(cur, found, ref)
    if base is cur:
        return within_tolerance(cur, tol, mask=mask, found=found, **kw)
    return within_tolerance(base, tol, mask=mask, found=found, start=cur.cfg, **kw)


def _config_plant(cur, found, ref):
    """``cur`` with the keys of ``ref`` ({key: the start model's value}) set back, but for those the
    effects ``found`` name (a parameter:plant.k2 beyond the tolerance is the model's own); ``cur``
    itself where none is left."""
    named = {getattr(candidate(n, cur.cfg), "key", None) for n in found}
    ref = {k: v for k, v in (ref or {}).items() if k not in named}
    return cur.with_config(cur.cfg.with_values(ref)) if ref else cur


def _within_tolerance(cur, add, found, progress, ref=None) -> dict | None:
    """hil.ident.tolerance's test, the effects ``found`` refitted with the drift (about the config's
    plant: :func:`_tolerance_test`): where every
    effect of the step ``add`` is a drift of the config's masses, stiffnesses or dampings; and where
    a later step (``found`` not empty) names another effect, kept only where the drift within the
    tolerance brings every channel to its noise floor (``in_place_of`` the step's effects: the
    effects found, refitted with the config's drift, leave nothing for it), or where it does so with
    keys beyond the tolerance (``within`` false: :func:`_beyond_tolerance` judges whether one key
    alone is the step). Else None."""
    drift = is_drift([candidate(n, cur.cfg) for n in add], cur.plant, cur.cfg)
    if not drift and not found:
        return None
    if progress:
        expect(progress, 1)
        progress("plant.tolerance")
    test = _tolerance_test(cur, float(cur.cfg.get("plant.tolerance", TOLERANCE)), found, ref)
    if drift or test is None:
        return test
    if not test["at_noise_floor"]:
        return None
    # within: no finding, in place of the step's effects; beyond: one key alone beyond it may be the
    # step (:func:`_beyond_tolerance`)
    return dict(test, in_place_of=list(add)) if test["within"] else test


def _beyond_tolerance(cur, d, test, add, have, found=()) -> dict | None:
    """Where a step's diagnosis names a drift of the config (``add``), or a later step's an effect that
    the config's drift with the effects found refitted brings to the noise floor, and the drift does
    not fit within its tolerance (``test``, :func:`_within_tolerance`'s), the key the fit leaves alone
    beyond it (its change, less :data:`~hil.ident.tolerance.Z_WITHIN` of its standard errors,
    above the tolerance; every other key within): the best-ranked significant candidate of the
    diagnosis that is a change of that key, not one of the step's, not in the model. A tip mode
    drifted by a percent rings for seconds and outweighs in the record a transmission 18 % soft;
    the diagnosis names the tip's mass, whose drift is within the tolerance, and the fit of every
    key puts the stiffness alone beyond it. Returns {"verdict" (the diagnosis's), "effect", "key",
    "change", "tolerance", "params" (the fit's relative changes)}, or None."""
    def key_of(name):
        return getattr(candidate(name, cur.cfg), "drifted_key", lambda p: None)(cur.plant)
    tol = test["tolerance"]
    # (a key the model names already, beyond the tolerance before, is free in the fit: not counted)
    named = {key_of(n) for n in found}
    beyond = [k for k, p in test["params"].items() if k not in named and abs(p["change"]) - p["margin"]
              > tol * (1.0 + 1e-9)]
    if len(beyond) != 1:
        return None
    key = beyond[0]
    if key in {key_of(n) for n in add}:
        return None
    lead = next((c for c in d["candidates"] if "+" not in c.effect and c.significant and key_of(c.effect) == key
                 and _same(c.effect, cur.cfg) not in have), None)
    if lead is None or _tangled_with_key(cur, d, add[0], key):
        return None
    return {"verdict": add[0], "effect": lead.effect, "key": key, "change": test["params"][key]["change"],
            "tolerance": tol, "params": {k: p["change"] for k, p in test["params"].items()}}


def _tangled_with_key(cur, d, verdict: str, key: str) -> bool:
    """Whether the record cannot tell the diagnosis's ``verdict`` from a drift of the config's
    ``key`` (|r| >= :data:`TANGLED` between its fitted parameters and the key, at its fit): then the
    key the tolerance's fit leaves beyond it is the same finding put elsewhere, and the diagnosis's
    verdict, ranked first on the record, stands (h12 of the independent records: +30 kg on the table
    named as the motor's mass, m1 and m2 at r = -0.96)."""
    c = next((c for c in d["candidates"] if c.effect == verdict), None)
    if getattr(c, "cfg", None) is None:
        return False
    aliases = config_aliases(cur.with_config(c.cfg), verdict, effect_values(verdict, c.cfg), [key])
    return any(abs(a["r"]) >= TANGLED for a in aliases)


def _non_smooth(cur, name: str) -> bool:
    """Whether the effect ``name`` (not a combination) is refitted on the night's plant: its error
    jumps with its one gridded parameter (:attr:`~sim_plant.effects.Effect.non_smooth`)."""
    from hil.ident.tracking import _grid
    return "+" not in name and candidate(name, cur.cfg).non_smooth and bool(_grid(cur, name, cur.cfg))


def _on_nights_plant(replay, cur, found, add, split, fit_nfev, progress, ref=None) -> dict | None:
    """The step's effects whose error jumps with their gridded parameter (``non_smooth``: a
    backlash's gap) refitted on the night's plant (the module's definition;
    hil.ident.tracking.on_nights_plant from the model as it stands, ``cur``, which holds the step,
    about the config's plant as :func:`_tolerance_test`): ``effects``, ``tolerance``, the plant's
    ``params`` and the effects' ``stderr`` there, and with a held-out part its check there; where
    the drift lies within the tolerance, lowers the weighted error and earns its place. Else None."""
    from hil.ident.tracking import _cost, on_nights_plant
    tol = float(cur.cfg.get("plant.tolerance", TOLERANCE))
    gridded = [n for n in add if _non_smooth(cur, n)]
    if not tol > 0 or not gridded or not tolerance_keys(cur.cfg):
        return None
    names = [n for n in found if "+" not in n]
    if progress:
        expect(progress, 1)
        progress("plant.tolerance")
    base = _config_plant(cur, names, ref)
    cfg_p, cost, test = on_nights_plant(base, cur.cfg, names, profiled=gridded, anchored=True)
    if test is None or not test["within"] or not cost < _cost(base, cur.cfg):
        return None
    # the plant's keys it moved pay for themselves, as any step's parameters
    res_p = cur.residuals(cfg_p)
    if not bic_score(cur.base_residuals, res_p, list(cur.noise), len(test["params"]), cur.noise) > MIN_SCORE:
        return None
    held = _earned(cur, split, [], names, cfg_p, fit_nfev, refit=lambda m: cur.residuals(
        within_tolerance(base, tol, mask=m, found=names, start=cfg_p)["_config"])) if split else None
    if held is not None and not held["earned"]:
        logger.info("chain: %s on the night's plant refused by the held-out data", " + ".join(gridded))
        return None
    logger.info("chain: %s on the night's plant (%s)", ", ".join(f"{n} {effect_values(n, cfg_p)}" for n in gridded),
                ", ".join(f"{k} {100 * p['change']:+.2f} %" for k, p in test["params"].items()))
    out = {"effects": gridded, "tolerance": tol, "params": test["params"],
           "stderr": dict(test.get("_refitted_stderr", {})), "_config": cfg_p, "_error": rms(res_p)}
    if held is not None:
        out.update(estimation_error=held.pop("estimation"), held_out=held)
    return out


def _drift_again(replay, cur, found, add, within, split, fit_nfev, progress, ref=None) -> dict | None:
    """The config's drift within its tolerance, taken at an earlier step, fitted again once a later
    step's effects ``add`` are in the model (``cur``), with everything ``found`` refitted beside it
    (:func:`_tolerance_test` about the config's plant, from ``cur``'s values): the drift was fitted
    beside the effects still missing, and where one of them moves the tip (a ripple's torque rings
    the tool's mode) the drift took a share of it, the tip's k2 and m3 off in the same ratio, which
    the next step's effect then closes a sliver of. Kept where every change lies within the
    tolerance, it lowers the weighted error and, with a held-out part, it earns its place there (no
    BIC score: the drift's parameters paid at its own step); the same keys as
    :func:`_on_nights_plant`'s (``effects`` the step's), and ``_refitted``, the effects found as
    refitted with it. As the refit on the night's plant, only where the chain's ``nights_plant``."""
    tol = within["tolerance"]
    names = [n for n in found if "+" not in n]
    about = {k: float(replay.cfg[k]) for k in tolerance_keys(replay.cfg)} | dict(ref or {})
    if progress:
        expect(progress, 1)
        progress("plant.tolerance")
    test = _tolerance_test(cur, tol, names, about)
    if test is None or not test["within"]:
        return None
    cfg_p = test["_config"]
    res_p = cur.residuals(cfg_p)
    if not _weighted(cur, res_p) < _weighted(cur, cur.base_residuals):
        return None
    held = _earned(cur, split, [], names, cfg_p, fit_nfev, refit=lambda m: cur.residuals(
        _tolerance_test(cur, tol, names, about, mask=m)["_config"])) if split else None
    if held is not None and not held["earned"]:
        logger.info("chain: the config's drift refitted beside %s refused by the held-out data", " + ".join(add))
        return None
    logger.info("chain: the config's drift refitted beside %s (%s)", " + ".join(add),
                ", ".join(f"{k} {100 * p['change']:+.2f} %" for k, p in test["params"].items()))
    out = {"effects": list(add), "tolerance": tol, "params": test["params"],
           "stderr": dict(test.get("_refitted_stderr", {})), "_config": cfg_p, "_error": rms(res_p),
           "_refitted": test.get("refitted")}
    if held is not None:
        out.update(estimation_error=held.pop("estimation"), held_out=held)
    return out


def _unexplained_on_nights_plant(cur, d, split, fit_nfev, progress) -> dict | None:
    """The first diagnosis ``unexplained``: its best candidate whose error jumps with its parameter
    (a backlash: its fit on the config's plant follows the plant's drift and may close little)
    refitted on the night's plant (hil.ident.tracking.on_nights_plant, about the config's plant),
    kept as the first step where the plant's changes lie within the tolerance, it closes
    :data:`~hil.ident.unexplained.HALF_GAP` of the gap on some channel and earns its place on the
    held-out data (refitted there with the plant). Returns the step's ``effect``, ``fit`` (the
    candidate), ``text``, ``nights_plant`` (as :func:`_on_nights_plant`'s, without its own held-out
    check: the step's is that check), ``held`` and ``_config``; else None."""
    from hil.ident.tracking import on_nights_plant
    tol = float(cur.cfg.get("plant.tolerance", TOLERANCE))
    if not tol > 0 or not tolerance_keys(cur.cfg):
        return None
    lead = next((c for c in d["candidates"] if c.res is not None and _non_smooth(cur, c.effect)), None)
    if lead is None:
        return None
    if progress:
        expect(progress, 1)
        progress("plant.tolerance")
    at = cur.with_config(lead.cfg)
    cfg_p, _, test = on_nights_plant(at, lead.cfg, [lead.effect], anchored=True)
    if test is None or not test["within"]:
        return None
    floor = cur.noise
    e0, e1, e_lead = rms(cur.base_residuals), rms(cur.residuals(cfg_p)), rms(lead.res)
    # on the channels above their floor (one below it has no gap to close)
    closed = {c: gap_closed(e0[c], e1[c], floor[c]) for c in e0 if e0[c] > AT_FLOOR * floor[c]}
    if not closed:
        return None
    chan = max(closed, key=closed.get)
    logger.info("chain: %s on the night's plant closes %.2f of the gap in %s", lead.effect, closed[chan], chan)
    if closed[chan] < HALF_GAP:
        return None
    held = _earned(cur, split, [lead.effect], [], cfg_p, fit_nfev, refit=lambda m: cur.residuals(
        within_tolerance(at, tol, mask=m, found=[lead.effect], start=cfg_p)["_config"])) if split else None
    if held is not None and not held["earned"]:
        return None
    alone = gap_closed(e0[chan], e_lead[chan], floor[chan])
    text = (f"{lead.effect} on the night's plant (the config's masses, stiffnesses and dampings within their "
            f"tolerance) closes {100 * closed[chan]:.0f} % of the gap in {chan}, on the config's plant "
            f"{100 * alone:.0f} %; there: {lead.evidence}")
    nights = {"effects": [lead.effect], "tolerance": tol, "params": test["params"],
              "stderr": dict(test.get("_refitted_stderr", {})), "error_on_config_plant": e_lead}
    return {"effect": lead.effect, "fit": lead, "text": text, "nights_plant": nights, "held": held, "_config": cfg_p}


def _look_alike(d, verdict, add, have, cur):
    """The candidate of a step's diagnosis that does what its single verdict does: a significant
    single candidate, not in the model, whose gain is at least :data:`RIVAL_GAIN` of the verdict's
    and whose correction of the weighted residual (before - after its fit) is the verdict's to a
    cosine of :data:`~hil.ident.fit.CONFOUNDED` (the record tells the two apart no better than two
    confounded parameters: a current loop's lag and an actuator delay both shift the torque's
    phase), with no more fitted parameters than the verdict (a richer effect that holds the
    verdict, a stiffness along the travel for k1, is a step of its own, not a look-alike); the
    closest, or None."""
    if len(add) != 1:
        return None
    lead = next((c for c in d["candidates"] if c.effect == verdict), None)
    if lead is None or lead.res is None:
        return None
    k_lead = len(candidate(verdict, cur.cfg).fitted_params)
    obj = cur.objective
    base = obj.vector(cur.base_residuals)
    v = base - obj.vector(lead.res)
    nv = float(np.linalg.norm(v))
    best, best_cos = None, CONFOUNDED
    for c in d["candidates"]:
        if (c is lead or "+" in c.effect or not c.significant or c.res is None or c.gain < RIVAL_GAIN * lead.gain
                or _same(c.effect, cur.cfg) in have | {_same(verdict, cur.cfg)}
                or (_close(c, lead, 0.02) and _close(lead, c, 0.02))
                or len(candidate(c.effect, cur.cfg).fitted_params) > k_lead):
            continue
        w = base - obj.vector(c.res)
        cos = float(v @ w) / max(nv * float(np.linalg.norm(w)), 1e-300)
        if cos > best_cos:
            best, best_cos = c, cos
    return best


def _swap(replay, cur, steps, found, gone, split, fit_nfev, progress) -> ChainStep | None:
    """The first step's runner-up in place of its verdict, once the later steps' effects are in the
    model (stepwise selection's swap): the first step judged each candidate alone, beside effects
    still missing (a current loop's lag scored above an actuator delay beside a torque ripple not
    yet found). The verdict is set back (:func:`_without`), the runner-up fitted on top of the rest
    and everything refitted together; kept as a step of its own (``swapped``, the verdict under
    ``dropped``) when its BIC score beats the verdict's own in the model by :data:`MIN_SCORE` and it
    earns its place on the held-out data. None: no swap."""
    first = steps[0]
    r = first.runner_up
    if r is None or len(first.effects) != 1:
        return None
    name, verdict = r.effect, first.effects[0]
    have = {_same(n, cur.cfg) for n in found + gone}
    if verdict not in found or _same(name, cur.cfg) in have:
        return None
    floor = replay.noise
    rest = [n for n in found if n != verdict]
    base = replay.with_config(_without(verdict, cur.cfg, replay.cfg))
    k_v = len(candidate(verdict, cur.cfg).fitted_params)
    own = bic_score(base.base_residuals, cur.base_residuals, list(floor), k_v, floor)   # the verdict's, in the model
    if progress:
        expect(progress, 1)
        progress(name)
    try:
        c = evaluate(base, name, max_nfev=fit_nfev)
    except ValueError:
        return None
    cfg1, res1, joint, paid = _refit_found(replay, base, rest, [name], c.cfg, fit_nfev, progress)
    logger.info("chain: %s in place of %s scores %.1f against %.1f", name, verdict, paid, own)
    if not paid > own + MIN_SCORE:
        return None
    held = _earned(base, split, [name], rest, cfg1, fit_nfev) if split else None
    if held is not None and not held["earned"]:
        return None
    err0, err1 = rms(cur.base_residuals), rms(res1)
    se, conf = _stderr_of(joint if joint is not None else c, rest + [name])
    out = ChainStep(
        step=steps[-1].step + 1, effect=name, effects=[name], params={n: effect_values(n, cfg1) for n in rest + [name]},
        error_before=err0, error_after=err1, gap_closed={ch: gap_closed(err0[ch], err1[ch], floor[ch]) for ch in err0},
        score=float(paid), evidence=f"in place of {verdict} (its score in the model {own:.1f}): {r.evidence}",
        refitted_together=joint is not None, stderr=se, confounded=conf, aliases=_aliases(replay, cfg1, [name]),
        rival=None, recording_artefacts=[name] if measurement_key(candidate(name, cur.cfg)) is not None else [],
        swapped=verdict, dropped=[{"effect": verdict, "params": effect_values(verdict, cur.cfg), "score": float(own)}],
        fits=[c], joint=joint, config=cfg1)
    if held is not None:
        out.estimation_error, out.held_out = held.pop("estimation"), held
    return out


def _weighted(replay, res) -> float:
    return float(np.sum(replay.objective.vector(res) ** 2))


@one_blas_thread()
def diagnose_chain(replay, names: list[str] | None = None, max_steps: int = MAX_STEPS, progress=None,
                   jobs: int | None = None, max_nfev: int = 30, fit_nfev: int = 40, holdout=None,
                   nights_plant: bool = True, refusals: int = REFUSALS, **kw) -> dict:
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
    holdout : "moves", list of Replay, or None
        What every step must earn its place on (the module's definition): the record's moves split
        into estimation and held-out halves, the replays of validation records, or nothing (None:
        the BIC score on the record alone).
    nights_plant : bool
        Whether a backlash is refitted on the night's plant (the module's definition; False: the
        config's plant only, as ``hil fleet``, which fits its tracked effects so on its own,
        hil.ident.tracking).
    refusals : int
        The chain ends at this many steps refused by the held-out data; before, a refused step's
        effects are no candidates any more and the next verdict is tried (1: the first refusal
        ends it).

    Returns
    -------
    dict
        The first diagnosis's keys (``verdict``, ``candidates``, ``also_missing``, ...; the verdict
        the chain's first finding still in the model where a later step, the config's drift or a
        refusal took the first diagnosis's out of it), and
        ``chain`` (one :class:`~hil.ident.result.ChainStep` per kept step: what it added, the values
        of everything found so far after its refit, its errors, score, standard errors, what they
        are confounded with, its aliases, and with a held-out part its check on it
        (:func:`held_out_fall`); the fits and the config stay on the object, out of its JSON);
        ``final`` (the residual against the noise floor and why it ended; ``rejected``: the last step
        the held-out data refused; ``also_refused``: those refused before it, after each of which the
        next verdict was tried; ``tolerance``: a drift of the config within its tolerance),
        ``diagnoses`` (every step's diagnosis) and ``config`` (the model with the whole chain).
    """
    floor = replay.noise
    cur = replay
    found: list[str] = []
    steps, diags = [], []
    first = None
    end = End.MAX_STEPS
    split = _holdout_parts(replay, holdout)
    rejected = within = None
    gone: list[str] = []        # effects dropped by a later step (no candidates again)
    ref: dict = {}              # the plant's keys a refit on the night's plant moved: their start values
    refused: list[dict] = []    # the steps the held-out data refused (their effects no candidates again)
    barred: set[str] = set()
    no_drift = False            # a drift within the config's tolerance refused: no drift a candidate again
    i = 0                       # the steps kept so far (a drift within the tolerance counts as one)
    while i < max(1, max_steps):
        retry = rejected is not None
        if retry:
            # the step before was refused: the next verdict without its effects, while refusals are
            # left; where it ends the chain with nothing kept, the refusal stays why it ended
            if len(refused) >= max(1, refusals) or max_steps <= 1:
                break
            refused[-1]["next_tried"], rejected = True, None
        err0 = rms(cur.base_residuals)
        if at_noise_floor(err0, floor):
            end = End.NOISE_FLOOR
            if first is None:
                first = diagnose(cur, names, progress=progress, jobs=jobs, max_nfev=max_nfev, **kw)
                diags.append(first)
            break
        pool = names or candidate_names(cur.cfg, cur.plant, open_loop=is_open_loop(cur))
        have = {_same(n, cur.cfg) for n in found + gone} | barred
        cands = [n for n in pool if _same(n, cur.cfg) not in have]
        if within is not None or no_drift:      # the config's drifts are in the model, or were refused
            cands = [n for n in cands if not is_drift([candidate(n, cur.cfg)], cur.plant, cur.cfg)]
        if not cands:
            end = end if retry else End.NO_CANDIDATE
            break
        d = diagnose(cur, cands, progress=progress, jobs=jobs, max_nfev=max_nfev,
                     min_gap=HALF_GAP if i == 0 else 0.0, **kw)
        diags.append(d)
        if first is None:
            first = d
        verdict = d["verdict"]
        together, members, alone, first_nights, beyond, beyond_first = None, {}, False, None, None, False
        if verdict == "unexplained" and i == 0 and not retry and nights_plant:
            # a backlash fitted on the config's plant may close little where the night's plant differs
            first_nights = _unexplained_on_nights_plant(cur, d, split, fit_nfev, progress)
        if first_nights is not None:
            verdict, alone = first_nights["effect"], True
            add, cfg1, fits = [verdict], first_nights["_config"], [first_nights["fit"]]
        elif verdict == "unexplained" and i == 0 and not retry and max_steps > 1:
            # two effects that show only together (a table leaning on one flank of a backlash only
            # under a force on it): the best fit on top of the model, the next verdict on top of that
            together = _shown_together(cur, d, cands, progress, jobs, max_nfev, fit_nfev, **kw)
        if first_nights is not None:
            pass                            # the step is the night's plant's (its held-out check done)
        elif together is not None:
            verdict, add, cfg1, fits = together["verdict"], together["effects"], together["_config"], together["_fits"]
            if split:
                # each member of the pair earns its own place too: a drift of the config (c2) taken
                # first beside a mode whose first fit missed its basin is no member once the mode
                # is refitted
                add, cfg1, fits, members = _members_earned(cur, split, add, cfg1, fits, fit_nfev, progress)
                if len(add) == 1:
                    # one member left: the step is that effect's, as a single verdict's would be
                    verdict, together, alone = add[0], None, True
        elif verdict in ("none", "unexplained"):
            end = (end if retry else End.NOISE_FLOOR if verdict == "none" else
                   End.UNEXPLAINED if i == 0 else End.UNPAID)
            break
        else:
            add = [verdict] + [m["effect"] for m in d["also_missing"] if _same(m["effect"], cur.cfg) not in have]
            test = _within_tolerance(cur, add, found, progress, ref) if within is None and not no_drift else None
            if test is not None and test["within"]:
                # the step would name a drift of the config, and the config's masses, stiffnesses and
                # dampings fit within their tolerance: no finding; where it earns its place as a step
                # would, the model takes them, and what is left is diagnosed again (no drift of the
                # config a candidate any more)
                tol = test["tolerance"]
                held = _earned(cur, split, [], found, test["_config"], fit_nfev, refit=lambda m: cur.residuals(
                    _tolerance_test(cur, tol, found, ref, mask=m)["_config"])) if split else None
                if held is not None and not held["earned"] and "in_place_of" in test:
                    test = None             # the step's own effect is judged as any step is
                elif held is not None and not held["earned"]:
                    end = End.NOT_EARNED
                    res_t = cur.residuals(test["_config"])
                    rejected = {"effects": list(add), "tolerance": tol,
                                "score": float(bic_score(cur.base_residuals, res_t, list(floor), len(test["params"]),
                                                         floor)),
                                "error_after": rms(res_t), "stderr": {}, "confounded": [],
                                "estimation_error": held.pop("estimation"), "held_out": held}
                    logger.info("chain step %d: the config's tolerance refused by the held-out data", i + 1)
                    refused.append(rejected)
                    barred |= {_same(n, cur.cfg) for n in add}
                    no_drift = True
                    continue
            if test is not None and test["within"]:
                within = dict(test, step=i + 1)
                if held is not None:
                    within.update(estimation_error=held.pop("estimation"), held_out=held)
                if found:
                    # an effect found before the drift was in the model may have held a part of it
                    # alone: one that no longer pays beside the drift is dropped, as after a step
                    cfg_t = within["_config"]
                    cfg_t, _, dropped = _unpaid(replay, found, [], cfg_t, replay.residuals(cfg_t))
                    rest = [n for n in found if n not in {e["effect"] for e in dropped}]
                    before = cur
                    for e in dropped:
                        before = before.with_config(_without(e["effect"], before.cfg, replay.cfg))
                    refit, more = _unpaid_beside_drift(replay, before, rest, tol, cfg_t, ref) if rest else (None, [])
                    if refit is not None:
                        # the drift as fitted without the dropped effects
                        cfg_t = refit["_config"]
                        within.update({k: refit[k] for k in ("within", "at_noise_floor", "error", "params")},
                                      nfev=within["nfev"] + refit["nfev"], refitted=refit.get("refitted", {}))
                        dropped += more
                    if dropped:
                        unpaid = {e["effect"] for e in dropped}
                        found = [n for n in found if n not in unpaid]
                        gone += list(unpaid)
                        within.update(_config=cfg_t, dropped=dropped,
                                      refitted={n: v for n, v in within.get("refitted", {}).items() if n not in unpaid})
                cur = cur.with_config(within["_config"])
                logger.info("chain step %d: %s is a drift within the config's tolerance", i + 1, " + ".join(add))
                i, end = i + 1, End.MAX_STEPS
                if at_noise_floor(rms(cur.base_residuals), floor):
                    end = End.WITHIN_TOLERANCE
                    break
                continue
            beyond = _beyond_tolerance(cur, d, test, add, have, found) if test is not None and not test["within"] else None
            if beyond is not None:
                # the config's drift leaves one key alone beyond its tolerance: the step is that key's
                logger.info("chain step %d: %s is no drift within the config's tolerance, %s alone beyond it "
                            "(%+.1f %%): the step is %s", i + 1, " + ".join(add), beyond["key"],
                            100 * beyond["change"], beyond["effect"])
                verdict, add = beyond["effect"], [beyond["effect"]]
                beyond_first = d is first
            cfg1, fits = _add_verdict(cur, d, verdict, add, fit_nfev, progress)
            if split and len(add) > 1:
                add, cfg1, fits, members = _members_earned(cur, split, add, cfg1, fits, fit_nfev, progress)
                verdict = verdict if verdict in add else add[0]
                if d is first and len(add) < 1 + len(d["also_missing"]):
                    # the first diagnosis names what the step kept
                    first = dict(first, verdict=verdict,
                                 also_missing=[m for m in d["also_missing"] if m["effect"] in add and m["effect"] != verdict])
        cfg1, res1, joint, paid = _refit_found(replay, cur, found, add, cfg1, fit_nfev, progress)
        rival = _rival(d, verdict, add, have, cur) if found and together is None else None
        # the first step's look-alike: judged in its place once the later steps' effects are in the
        # model (:func:`_swap`)
        runner_up = (_look_alike(d, verdict, add, have, cur) if not found and together is None and first_nights is None
                     else None)
        if rival is not None:
            # a runner-up that removes about as much: the effects found before were fitted without
            # it and may hold part of it (a friction fitted before a delay takes part of its phase),
            # so both are judged after the refit of everything found (the better BIC is the step)
            rcfg, rfits = _add_verdict(cur, d, rival.effect, [rival.effect], fit_nfev, progress)
            r = _refit_found(replay, cur, found, [rival.effect], rcfg, fit_nfev, progress)
            logger.info("chain step %d: %s scores %.1f, its rival %s %.1f after the refit of what was found", i + 1,
                        verdict, paid, rival.effect, r[3])
            rival = {"effect": rival.effect, "score": float(r[3]), "verdict": verdict, "verdict_score": float(paid)}
            if r[3] > paid + MIN_SCORE:     # it pays beyond the scores' own noise
                verdict, add, fits, members = rival["effect"], [rival["effect"]], rfits, {}
                cfg1, res1, joint, paid = r
        if (i > 0 or retry) and paid <= MIN_SCORE:
            end = end if retry else End.UNPAID
            break
        err1 = rms(res1)
        se, conf = _stderr_of(joint if joint is not None else fits[-1], found + add)
        if first_nights is not None:        # the fit on the config's plant is not the step's values
            se, conf = _nested(first_nights["nights_plant"]["stderr"]), []
        aliases = _aliases(replay, cfg1, add)
        tangled = confounded_with_found(conf, aliases, add, found)
        if tangled:
            # the record cannot tell the step from what was found: adding both only splits one finding
            end = End.TANGLED
            rejected = {"effects": list(add), "score": float(paid), "error_after": err1, "stderr": se,
                        "confounded": conf, "confounded_with": tangled}
            refused.append(rejected)
            logger.info("chain step %d: %s refused, confounded with the effects found: %s", i + 1, " + ".join(add),
                        tangled)
            barred |= {_same(n, cur.cfg) for n in add}
            continue
        held = (first_nights["held"] if first_nights is not None else
                _earned(cur, split, add, found, cfg1, fit_nfev) if split else None)
        if held is not None and members:
            held["members"] = members
        lead = next((c for c in d["candidates"] if c.effect == verdict), None)
        if together is not None:
            lead = None
        if held is not None and not held["earned"]:
            end = End.NOT_EARNED
            rejected = {"effects": list(add), "score": float(paid), "error_after": err1, "stderr": se,
                        "confounded": conf, "estimation_error": held.pop("estimation"), "held_out": held}
            logger.info("chain step %d: %s refused by the held-out data (fall %.3g, uncertainty %.3g)", i + 1,
                        " + ".join(add), held["fall"], held["uncertainty"])
            refused.append(rejected)
            barred |= {_same(n, cur.cfg) for n in add}
            continue
        found += add
        cfg1, res1, dropped = _unpaid(replay, found, add, cfg1, res1)
        if dropped:
            found = [n for n in found if n not in {e["effect"] for e in dropped}]
            gone += [e["effect"] for e in dropped]
            err1 = rms(res1)
        steps.append(ChainStep(
            step=i + 1, effect=verdict, effects=list(add), params={n: effect_values(n, cfg1) for n in found},
            error_before=err0, error_after=err1,
            gap_closed={c: gap_closed(err0[c], err1[c], floor[c]) for c in err0}, score=float(paid),
            evidence=(together["text"] if together is not None else first_nights["text"] if first_nights is not None
                      else lead.evidence if lead is not None else ""),
            refitted_together=joint is not None, stderr=se, confounded=conf, aliases=aliases,
            rival=rival, recording_artefacts=[n for n in add if measurement_key(candidate(n, cur.cfg)) is not None],
            dropped=dropped or None, fits=fits, joint=joint, config=cfg1, runner_up=runner_up,
            beyond_tolerance=beyond if beyond is not None and beyond["effect"] in add else None))
        if held is not None:
            steps[-1].estimation_error, steps[-1].held_out = held.pop("estimation"), held
        if together is not None:
            # the first diagnosis names the pair once the step is kept (refused, it stays unexplained)
            first = dict(first, verdict=verdict, shown_together=together["text"])
        elif alone:
            first = dict(first, verdict=verdict)
        elif beyond_first and steps[-1].beyond_tolerance:
            # the first diagnosis names the key beyond the tolerance once its step is kept
            first = dict(first, verdict=verdict, also_missing=[])
        logger.info("chain step %d: + %s (score %.1f)", i + 1, " + ".join(add), paid)
        i, end = i + 1, End.MAX_STEPS
        cur = cur.with_config(cfg1)
        if first_nights is not None:
            steps[-1].nights_plant = first_nights["nights_plant"]
            ref = {k: float(replay.cfg[k]) for k in first_nights["nights_plant"]["params"]}
            if at_noise_floor(err1, floor):
                end = End.WITHIN_TOLERANCE
                break
        elif nights_plant and not at_noise_floor(err1, floor):
            # an effect whose error jumps with its parameter, fitted on the config's plant, follows the plant's
            # own drift (a lightly damped mode's phase) rather than its strength; a drift the model took
            # before the step was fitted beside the step's effect still missing
            nights = (_on_nights_plant(replay, cur, found, add, split, fit_nfev, progress, ref) if within is None else
                      _drift_again(replay, cur, found, add, within, split, fit_nfev, progress, ref))
            if nights is not None:
                cfg_n, err_n = nights.pop("_config"), nights.pop("_error")
                st = steps[-1]
                refitted = nights.pop("_refitted", None)
                if within is not None:
                    # final.tolerance: the drift the model holds, and the effects refitted with it
                    within.update(params=nights["params"], error=err_n, at_noise_floor=at_noise_floor(err_n, floor),
                                  again_after=within.get("again_after", []) + [st.step])
                    if refitted:
                        within["refitted"] = refitted
                st.nights_plant = dict(nights, error_on_config_plant=st.error_after)
                st.params, st.error_after, st.config = {n: effect_values(n, cfg_n) for n in found}, err_n, cfg_n
                # (the first step's look-alike is fitted afresh in its place: kept after a drift fitted again)
                st.stderr, st.confounded = _nested(nights["stderr"]), []
                st.runner_up = st.runner_up if within is not None else None
                st.gap_closed = {c: gap_closed(err0[c], err_n[c], floor[c]) for c in err0}
                # the plant's keys it moved, their start values: later tolerance tests are about those
                ref = {k: float(replay.cfg[k]) for k in nights["params"]}
                cur = cur.with_config(cfg_n)
                if at_noise_floor(err_n, floor):
                    end = End.WITHIN_TOLERANCE
                    break
    if len(steps) > 1 and not end.at_floor:
        swap = _swap(replay, cur, steps, found, gone, split, fit_nfev, progress)
        if swap is not None:
            steps.append(swap)
            found = list(swap.params)
            cur = cur.with_config(swap.config)
            if at_noise_floor(rms(cur.base_residuals), floor):
                end = End.NOISE_FLOOR
    errf = rms(cur.base_residuals)
    final = {"error": errf, "noise_floor": dict(floor),
             "above_floor": {c: errf[c] / max(floor[c], 1e-300) for c in errf},
             "at_noise_floor": at_noise_floor(errf, floor), "end": end.text(max_steps), "steps": len(steps)}
    if split is not None:
        final["held_out"] = ("the validation records" if split[0] != "moves" else
                             "the record's moves cut at the middle of their travel, the halves alternately estimation "
                             "and held out" if _split(replay)[2] else
                             "the record's moves in pairs, alternately estimation and held out")
    elif holdout is not None:
        final["held_out"] = (f"none (the record has fewer than {HOLDOUT_MIN} samples in its estimation or held-out "
                             f"moves, or is open-loop)")
    if refused:
        final["rejected"] = refused[-1]
        if len(refused) > 1:
            final["also_refused"] = refused[:-1]
    if within is not None:
        final["tolerance"] = {k: v for k, v in within.items() if not k.startswith("_")}
    final.update(floor_parts(replay, errf))
    if not final["at_noise_floor"]:
        last = diags[-1] if diags else None
        best = last["candidates"][0] if last and last["candidates"] else None
        final["residual"] = residual_evidence(cur, cur.base_residuals, best)
    out = dict(first, **chain_verdict(first, steps, refused, within, found, gone, barred, replay.cfg))
    # the config as written: an effect a later one sets anew leaves (the same plant, no dead value)
    out.update(chain=steps, final=final, diagnoses=diags, config=without_replaced(cur.cfg))
    return out


def chain_verdict(first: dict, steps: list, refused: list, within: dict | None, found: list, gone: list,
                  barred: set, cfg) -> dict:
    """The chain's answer, ``verdict`` and ``also_missing``: the first diagnosis's, set right by
    what the chain did (a pure function of the first diagnosis and the chain's outcome).

    Parameters
    ----------
    first : dict
        The first diagnosis (its verdict as the steps that kept it named it: a pair shown together,
        the key beyond the tolerance, the night's plant's backlash).
    steps : list of ChainStep
        The steps kept, the look-alike swap (``swapped``) last.
    refused : list of dict
        The steps the held-out data or a confounding refused.
    within : dict or None
        The drift of the config within its tolerance the model took (its ``step``), or None.
    found, gone : list of str
        The effects in the final model, and those a later step dropped.
    barred : set of str
        The refused steps' effects.
    cfg : Config
        The start model's config.
    """
    out = {"verdict": first.get("verdict"), "also_missing": first.get("also_missing", [])}
    swap = next((x for x in steps if x.swapped), None)
    if swap is not None and out["verdict"] == swap.swapped:
        out["verdict"] = swap.effect            # the first diagnosis's look-alike, set right

    def chain_first(named):
        # the chain's first finding, as the look-alike swap set it right
        return swap.effect if swap is not None and swap.swapped == named else named

    if within is not None and (not steps or steps[0].step > within["step"]):
        # the first diagnosis named a drift of the config that its tolerance explains: the verdict is
        # what the chain named beyond it, else nothing
        out["verdict"] = chain_first(steps[0].effect if steps else "none")
    elif steps and any(out.get("verdict") in r["effects"] for r in refused):
        # the first diagnosis's verdict was refused and the next one kept: the verdict is the chain's first
        out["verdict"] = chain_first(steps[0].effect)
        out["also_missing"] = [m for m in out.get("also_missing", [])
                               if _same(m["effect"], cfg) not in barred and m["effect"] != out["verdict"]]
    refined = any(out.get("verdict") in getattr(candidate(n, cfg), "replaces", ()) for n in found)
    if steps and out.get("verdict") in gone and out["verdict"] not in found and not refined:
        # the verdict left the model at a later step (a drift within the tolerance took its place, or
        # it no longer paid beside a later step's effects): the verdict is the chain's first finding
        # still in the model; not where an effect found sets it anew (EMPS's Coulomb friction under
        # the asymmetric friction named after it: the same friction, its levels told apart)
        kept = next((e for s in steps for e in s.effects if e in found), None)
        if kept is not None:
            out["verdict"] = kept
            out["also_missing"] = [m for m in out.get("also_missing", []) if m["effect"] in found and m["effect"] != kept]
        elif within is not None:
            # the drift within the tolerance left nothing of what was found: no finding
            out["verdict"], out["also_missing"] = "none", []
    return out


def floor_parts(replay, err: dict) -> dict:
    """The parts of each channel's noise floor (hil.ident.noise, hil.ident.records) and the error
    ``err`` in multiples of each: ``floor_parts`` {channel: {"quantization": q / sqrt(12),
    "standstill": the standstill noise, "run_to_run": the spread of repeated records}} (the parts
    the record has), ``error_over`` {channel: {part: error / part}}, and ``within_run_to_run``
    (where some channel has a spread: every such channel's error within :data:`AT_FLOOR` times
    it, the others at their own floor; None where no test was repeated)."""
    src = getattr(replay, "noise_sources", {})
    spread = {c: v for c, v in (getattr(replay, "spread", None) or {}).items() if v > 0}
    parts = {}
    for c in err:
        ns = src.get(c, {})
        p = {"quantization": ns.get("quantization", 0.0) / math.sqrt(12.0), "standstill": ns.get("standstill"),
             "run_to_run": spread.get(c)}
        parts[c] = {k: float(v) for k, v in p.items() if v}
    over = {c: {k: err[c] / v for k, v in p.items()} for c, p in parts.items()}
    within = None
    if spread:
        within = bool(all(err[c] <= AT_FLOOR * spread[c] for c in spread if c in err)
                      and all(err[c] <= AT_FLOOR * replay.noise[c] for c in err if c not in spread))
    return {"floor_parts": parts, "error_over": over, "within_run_to_run": within}


def floor_parts_text(final: dict, unit) -> list[str]:
    """The error in multiples of each part of the floor, and whether it lies within the run-to-run
    spread, in words (``unit``: the SI unit of a channel)."""
    from hil.units import fmt_si
    names = {"quantization": "the quantization", "standstill": "the standstill noise",
             "run_to_run": "the run-to-run spread"}
    lines = []
    for c, over in final.get("error_over", {}).items():
        if over:
            lines.append(f"  {c}: the error is " + ", ".join(
                f"{v:.3g} x {names[k]} ({fmt_si(final['floor_parts'][c][k], unit(c), 3)})" for k, v in over.items()))
    w = final.get("within_run_to_run")
    if w is not None:
        lines.insert(0, "floor: " + ("within the run-to-run spread" if w else "above the run-to-run spread"))
    elif lines:
        lines.insert(0, "floor (no repeated records: no run-to-run spread):")
    return lines


def chain_json(steps: list) -> list:
    """The chain's entries without their internal fits and configs (:meth:`ChainStep.as_json`)."""
    return [s.as_json() for s in steps]
