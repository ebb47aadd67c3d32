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

from hil.fleet.manifest import Entry
from hil.fleet.run import Settings, Task, executor, record_key
from hil.sweep.store import ResultStore

__all__ = ["FleetRun", "run_fleet", "confirm_findings", "STORE_NAME", "load_configs"]

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
                     out_dir, n_baseline: int, scheduler=None, jobs: int | None = None, progress=None) -> dict:
    """The strength of every effect the chain named after an axis's baseline outside its normal,
    fitted on every record of that axis (as ``--track`` fits it: on the night's plant, no chain),
    so that a weak effect present all along, which the chain names on some nights and not on
    others, is told from one that appeared or grew. Record id -> figures (``values``,
    ``stderr``); stored and reused like the first pass (its own key: the settings differ)."""
    from dataclasses import replace

    from hil.fleet.spc import new_effects, normal_effects
    from hil.fleet.summary import _baseline
    axes: dict[str, list[Entry]] = {}
    for e in entries:
        axes.setdefault(e.axis, []).append(e)
    out: dict = {}
    for axis, es in sorted(axes.items()):
        good = [e for e in es if "error" not in first.figures.get(e.id, {"error": ""})]
        if not good:
            continue
        base = _baseline(good, n_baseline)
        named = [set(first.figures[e.id].get("named", [])) for e in good]
        found = new_effects(named, base, normal_effects(named, base))
        if not found:
            continue
        confirm = replace(settings, track=tuple(sorted(found)), candidates=None, max_steps=0)
        res = run_fleet(good, configs, default, confirm, out_dir, scheduler=scheduler, jobs=jobs, progress=progress)
        out.update(res.figures)
    return out
