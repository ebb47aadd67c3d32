"""A fleet's records diagnosed, resumably: the store, the tasks not yet done, the executor.

``results.jsonl`` in the fleet's output folder holds one line per finished record
(hil.sweep.store.ResultStore: appended and flushed as each finishes, a line cut by Ctrl-C
skipped on the next run). A record is diagnosed again only when its key (its content, its
config, the settings, the code version; :func:`hil.fleet.run.record_key`) is not in the store.
A record whose file cannot be read at all is an error of its own line; the others go on.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hil.errors import HilError
from hil.fleet.manifest import Entry
from hil.fleet.run import Settings, Task, executor, record_key
from hil.sweep.store import ResultStore

__all__ = ["FleetRun", "run_fleet", "confirm_findings", "contribution", "STORE_NAME", "load_configs"]

STORE_NAME = "results.jsonl"


@dataclass
class FleetRun:
    """What :func:`run_fleet` did: the figures of every entry (by record id; an error's figures
    are ``{"error": line}``), how many were computed now and how many reused."""
    figures: dict = field(default_factory=dict)
    keys: dict = field(default_factory=dict)
    computed: int = 0
    reused: int = 0


def load_configs(entries: list[Entry], default: str | None, overrides: dict | None = None) -> dict:
    """config path -> Config of every entry (the manifest's config, else ``default``)."""
    from hil.config import load
    from hil.errors import ConfigError
    out = {}
    for e in entries:
        path = e.config or default
        if path is None:
            raise ConfigError(f"{e.record}: no config (give --config, or a config column in the manifest)")
        if path not in out:
            out[path] = load(path, overrides or {})
    return out


def run_fleet(entries: list[Entry], configs: dict, default: str | None, settings: Settings, out_dir,
              scheduler=None, jobs: int | None = None, progress=None) -> FleetRun:
    """Diagnose every entry not yet in ``out_dir``'s store; ``progress(done, total, id)`` after each."""
    store = ResultStore(Path(out_dir) / STORE_NAME)
    result = FleetRun()
    todo = []
    for e in entries:
        cfg_path = e.config or default
        try:
            data = Path(e.record).read_bytes()
        except OSError as exc:
            result.figures[e.id] = {"error": f"{e.record}: cannot be read ({exc.strerror or exc})"}
            continue
        key = record_key(data, configs[cfg_path], settings)
        result.keys[e.id] = key
        if key in store.done:
            result.figures[e.id] = store.done[key]
            result.reused += 1
            continue
        todo.append((key, Task(e.record, e.axis, e.timestamp, cfg_path), data, configs[cfg_path], settings))
    by_key = {}
    for it in todo:
        by_key.setdefault(it[0], []).append(it[1])
    unique = list({it[0]: it for it in todo}.values())   # two entries of one content: one run
    ex = executor(scheduler, jobs)
    done = 0
    try:
        for key, fig in ex.map(unique):
            store.add(key, fig, by_key[key][0])
            for task in by_key[key]:
                result.figures[f"{task.axis}@{task.timestamp}"] = fig
            result.computed += 1
            done += 1
            if progress is not None:
                progress(done, len(unique), by_key[key][0].record)
    finally:
        ex.close()
    return result


def confirm_findings(entries: list[Entry], configs: dict, default: str | None, settings: Settings, first: FleetRun,
                     out_dir, n_baseline: int, scheduler=None, jobs: int | None = None, progress=None,
                     thresholds: dict | None = None, scatter: float | None = None) -> dict:
    """Before an axis is flagged, its strengths fitted with one model on every night (as ``--track``
    fits them: on the night's plant, no chain). The chain's own values come from whatever it named
    that night: a friction fitted on a night without the backlash took the backlash up, and a weak
    effect present all along is named on some nights and not on others. For each axis with a
    finding (an effect named after its baseline outside its normal) or a flag on the chain's values:

    * its usual model (hil.fleet.spc.usual_effects, the normal and the tracked effects) together:
      the strengths of its effects judged instead of the chain's;
    * each finding with that model beside it, one finding a fit: findings fitted together
      take up each other's share (a table mass beside the plant's mass scale), and one spurious
      finding must not move another;
    * where a parameter's move is judged (hil.fleet.summary.judge_axis), what its effect does to
      each record (:func:`contribution`);
    * where several findings of an axis moved, each again beside the others that moved: a torque
      ripple that appeared is taken up by a friction fitted without it, whose levels then move too.

    Record id -> figures: ``values`` and ``stderr`` ({effect.param: SI}, the usual model's and each
    finding's own parameters), ``models`` (each fit's values, standard errors and night's plant),
    ``contribution`` ({effect: {channel: SI}}) and ``failed`` ({effect or "normal": error line})
    for a fit that ended in an error. Stored and reused like the first pass (each track set its own
    key)."""
    from hil.fleet.spc import SCATTER, new_effects, normal_effects, usual_effects
    from hil.fleet.summary import _baseline, judge_axis
    scatter = SCATTER if scatter is None else scatter
    thresholds = thresholds or {}
    axes: dict[str, list[Entry]] = {}
    for e in entries:
        if "error" not in first.figures.get(e.id, {"error": ""}):
            axes.setdefault(e.axis, []).append(e)
    plans: dict[tuple, list[tuple[Entry, str]]] = {}     # track set -> [(entry, model)]
    usual: dict[str, set] = {}
    for axis, good in sorted(axes.items()):
        base = _baseline(good, n_baseline)
        named = [set(first.figures[e.id].get("named", [])) for e in good]
        normal = normal_effects(named, base)
        found = new_effects(named, base, normal)
        if not found and not judge_axis(axis, good, first.figures, thresholds, n_baseline, scatter)["flags"]:
            continue
        # the axis's usual model: the effects named on most baseline nights, and the tracked ones
        # (the user's model of the axis); no fit of its own where all of it is tracked
        own = usual[axis] = normal | usual_effects(named, base) | set(settings.track)
        models = ([("normal", tuple(sorted(own)))] if not own <= set(settings.track) else []) + \
                 [(f, tuple(sorted(own | {f}))) for f in sorted(found)]
        for model, track in models:
            plans.setdefault(track, []).extend((e, model) for e in good)
    out: dict = {}
    fit = (lambda plans: _fit_plans(plans, configs, default, settings, out_dir, out, scheduler, jobs, progress))
    fit(plans)
    replays: dict = {}          # each record read and replayed once for the figures below
    replay = (lambda e: _replay(e, configs[e.config or default], settings.mapping, replays))
    for axis in usual:
        _unexplained(axes[axis], replay, out)
        _contributions(axes[axis], replay, first, out, n_baseline, thresholds, scatter)
    again: dict[tuple, list[tuple[Entry, str]]] = {}
    for axis, own in usual.items():
        good = axes[axis]
        judged = judge_axis(axis, good, first.figures, thresholds, n_baseline, scatter, out)
        moved = [f["effect"] for f in judged["findings"] if f.get("strength") == "moved"]
        if len(moved) < 2:
            continue
        for e in good:
            for f in moved:                 # judged afresh on the joint fit's figures
                out[e.id].get("contribution", {}).pop(f, None)
        again.setdefault(tuple(sorted(own | set(moved))), []).extend((e, f) for e in good for f in moved)
    if again:
        fit(again)
        for axis in {e.axis for items in again.values() for e, _ in items}:
            _contributions(axes[axis], replay, first, out, n_baseline, thresholds, scatter)
    return out


def _fit_plans(plans: dict, configs: dict, default, settings: Settings, out_dir, out: dict, scheduler, jobs,
               progress) -> None:
    """Each track set's fit on its records (:func:`run_fleet`, no chain), merged into ``out`` under
    the model each record's entry names."""
    from dataclasses import replace
    total, before = sum(len({e.id for e, _ in items}) for items in plans.values()), 0
    for track, items in plans.items():
        run = replace(settings, track=track, candidates=None, max_steps=0)
        uniq = list({e.id: e for e, _ in items}.values())
        # counted over the pass, not per track set ("3/5", then "2/10"); records the store already
        # holds are counted when their set is done
        step = None if progress is None else (lambda done, _n, rid, at=before: progress(at + done, total, rid))
        res = run_fleet(uniq, configs, default, run, out_dir, scheduler=scheduler, jobs=jobs, progress=step)
        before += len(uniq)
        if progress is not None and res.computed < len(uniq):
            progress(before, total, f"{len(uniq) - res.computed} from the store")
        for e, model in items:
            _merge(out.setdefault(e.id, {"values": {}, "stderr": {}}), res.figures.get(e.id, {"error": "not run"}),
                   model)


def _replay(entry: Entry, cfg, mapping, cache: dict):
    """The record of ``entry`` replayed through ``cfg`` (hil.ident.replay.Replay), kept in ``cache``;
    None where it cannot be read."""
    if entry.id not in cache:
        from hil.fleet.run import _read
        from hil.ident.replay import Replay
        try:
            cache[entry.id] = Replay(_read(Path(entry.record).read_bytes(), entry.record, cfg, mapping), cfg)
        except (HilError, OSError, ValueError, ArithmeticError):
            cache[entry.id] = None
    return cache[entry.id]


def _contributions(good: list[Entry], replay, first: FleetRun, confirm: dict, n_baseline: int, thresholds: dict,
                   scatter: float) -> None:
    """For every effect whose confirmed parameters left their limits on the axis of the records
    ``good``, its :func:`contribution` on every night (``replay(entry)``: the night's replay), into
    each record's ``contribution`` ({effect: {channel: SI}}) and its noise floor into ``floor``:
    the judgement (hil.fleet.summary.judge_axis) keeps the flag only where what the effect does
    moved too. A linearised standard error does not see a fit that wandered along a direction the
    record hardly sees (the period of a pitch error of 5 nm, a viscous share traded against a
    level); what the effect does to the record does. (Not real-time: two simulations a record.)"""
    from hil.fleet.summary import judge_axis, usual_model
    if not good or not all(e.id in confirm for e in good):
        return
    judged = judge_axis(good[0].axis, good, first.figures, thresholds, n_baseline, scatter, confirm)
    flagged = sorted({n.rsplit(".", 1)[0] for n, p in judged["params"].items()
                      if p["source"] == "confirmed" and p["flagged"]})
    usual = usual_model(judged["findings"])
    for effect in flagged:
        for e in good:
            models = confirm[e.id].get("models", {})
            # a finding's own fit, else the one its strengths were judged from (hil.fleet.summary)
            fit = models.get(effect) or models.get(usual) or models.get("normal")
            rp = replay(e) if fit is not None else None
            confirm[e.id].setdefault("contribution", {})[effect] = {} if rp is None else contribution(rp, fit, effect)
            if rp is not None:
                confirm[e.id]["floor"] = {c: float(v) for c, v in rp.noise.items()}


def _unexplained(good: list[Entry], replay, confirm: dict) -> None:
    """Each record's residual under the axis's usual model as fitted that night (the ``normal``
    fit): its RMS over the record's noise floor per channel, into ``unexplained`` (1: explained
    down to the noise); and under each finding's model (the usual model with the finding beside
    it), into ``unexplained_with`` ({finding: {channel: ratio}}): a finding is the cause of a rise
    of the first only where it takes part of it away (hil.fleet.summary). Not real-time: a
    simulation a record and model."""
    for e in good:
        models = confirm.get(e.id, {}).get("models", {})
        rp = replay(e) if "normal" in models else None
        if rp is None:
            continue
        for model, fit in models.items():
            try:
                res = rp.residuals(_night_model(rp.cfg, fit, fit["values"]))
            except (HilError, ValueError, ArithmeticError):     # a value the config cannot hold
                continue
            ratios = {c: float(np.sqrt(np.mean(r * r)) / rp.noise[c]) for c, r in res.items()
                      if r.size and rp.noise.get(c, 0.0) > 0}
            if model == "normal":
                confirm[e.id]["unexplained"] = ratios
            else:
                confirm[e.id].setdefault("unexplained_with", {})[model] = ratios


def _night_model(cfg, fit: dict, values: dict):
    """``cfg`` on the night's plant of ``fit`` with the effects of ``values`` ({effect.param: SI})."""
    from hil.ident.tracking import with_effects
    return with_effects(cfg.with_values(fit.get("plant") or {}), values)


def contribution(rp, fit: dict, effect: str) -> dict:
    """What the effect ``effect`` does to the record of the replay ``rp`` in the night's model of
    ``fit`` (``values`` {effect.param: SI} on its ``plant`` {key: SI}): per measured channel, the RMS
    of the change of the simulated channel when the effect is taken out, every other effect kept
    ({channel: SI}; a figure per night whatever the effect's parametrisation); {} where the model
    cannot be simulated."""
    others = {k: v for k, v in fit["values"].items() if not k.startswith(effect + ".")}
    try:
        with_it = rp.residuals(_night_model(rp.cfg, fit, fit["values"]))
        without = rp.residuals(_night_model(rp.cfg, fit, others))
    except (HilError, ValueError, ArithmeticError):     # a value the config cannot hold
        return {}
    return {c: float(np.sqrt(np.mean((with_it[c] - without[c]) ** 2))) for c in with_it if with_it[c].size}


def _merge(into: dict, fig: dict, model: str) -> None:
    """One fit's figures into a record's confirmed ones: a finding's own parameters, or every
    parameter of the normal fit, and the fit itself under ``models`` (values, standard errors, the
    night's plant); a fit in error under ``failed``."""
    if "error" in fig:
        into.setdefault("failed", {})[model] = fig["error"]
        return
    into.setdefault("models", {})[model] = {k: fig[k] for k in ("values", "stderr", "plant") if k in fig}
    keep = (lambda k: True) if model == "normal" else (lambda k: k.startswith(model + "."))
    for part in ("values", "stderr"):
        into[part].update({k: v for k, v in fig.get(part, {}).items() if keep(k)})
