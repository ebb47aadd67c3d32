"""``hil fleet``: a fleet's records diagnosed, every axis judged against its own history."""
from __future__ import annotations

from hil.errors import HilError, UserError
from hil.io.jsonout import JsonKey, dumps

HELP = "many records of many axes: diagnose each, track the effects' strengths, flag the axes that drift"
DESCRIPTION = """\
A plant runs the same test move on every axis each night; hil fleet diagnoses every record (the
chain of hil diagnose) and fits the axis's tracked effects (fleet.track in the config, or --track)
on the night's plant (the masses, stiffnesses and dampings refitted with them near the config's
values, plant.tolerance setting how far), keeps the strengths with their standard errors, and judges each record against the axis's own
history: control limits from its baseline records (the first --baseline, or those the manifest
marks) that include the night-to-night scatter of a healthy axis, a CUSUM for slow drifts, and the
config's physical thresholds (fleet.thresholds, or --threshold "backlash.gap > 10um"). A parameter
that leaves its limits is flagged with the date it first moved; an effect the chain names on every
baseline record is the axis's normal, not a finding.

  hil fleet run records/ --config axis.toml --out out/fleet              (a folder, or manifest.csv / .toml)
  hil fleet run manifest.csv --config axis.toml --out out/fleet --scheduler tcp://127.0.0.1:8786
  hil fleet report out/fleet                 (report.html, values.csv, values.json)

Results are stored per record (out/fleet/results.jsonl, keyed by the record's content, the config,
the settings and the code version): a rerun diagnoses only new or changed records; Ctrl-C loses
nothing finished. A record that cannot be read is one line in the summary; the others go on.
"""

JSON_KEYS = {
    "records": JsonKey("", "number of records in the manifest"),
    "computed": JsonKey("", "records diagnosed in this run", when="hil fleet run"),
    "reused": JsonKey("", "records whose stored results were reused", when="hil fleet run"),
    "store": JsonKey("", "path of the per-record store (results.jsonl)", when="hil fleet run"),
    "summary": JsonKey("", "path of fleet.json, the judged fleet that hil fleet report reads", when="hil fleet run"),
    "errors": JsonKey("", "records that could not be diagnosed: record (AXIS@DATE), error (one line)"),
    "axes": JsonKey("", "one entry per axis (entries axes[].*)"),
    "axes[].axis": JsonKey("", "the axis id"),
    "axes[].verdict": JsonKey("", "`ok`, or `drift: ` and what moved since when"),
    "axes[].flags": JsonKey("SI", "what left its limits: parameter, since (the date it first moved), reason, from "
                                  "(the baseline's centre), to (the latest value)"),
    "axes[].worst": JsonKey("SI", "the tracked parameter furthest from its centre: parameter, sigma (in units of the "
                                  "baseline's spread), from, to"),
    "axes[].normal": JsonKey("", "effects the chain names on every baseline record (the axis's normal)"),
    "axes[].findings": JsonKey("", "effects named after the baseline and not in the normal: effect, since, strength "
                                   "(`moved`: fitted on every night, beyond the baseline's limits: a flag; `as in the "
                                   "baseline`: there all along, too weak to be named every night: no flag; `not "
                                   "fitted`: a flag)"),
    "axes[].params": JsonKey("SI", "per tracked parameter: centre, sigma, values, stderr, lower, upper, status per "
                                   "record, flagged, first_moved, reasons, threshold, drift_sigma"),
    "axes[].records": JsonKey("", "the axis's readable records (AXIS@DATE), in time order"),
    "axes[].dates": JsonKey("", "their dates"),
    "axes[].errors": JsonKey("", "the axis's records that could not be diagnosed"),
    "report": JsonKey("", "path of report.html", when="hil fleet report"),
    "csv": JsonKey("", "path of values.csv: every (axis, date, effect, value, stderr)", when="hil fleet report"),
    "json": JsonKey("", "path of values.json: the same rows as JSON", when="hil fleet report"),
    "pages": JsonKey("", "paths of each record's own page", when="hil fleet report"),
}


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="fleet_command", metavar="SUBCOMMAND", required=True)
    r = sub.add_parser("run", help="diagnose the records not yet stored and judge every axis",
                       description="Diagnose every record of a manifest or folder not yet in --out's store, then "
                                   "judge each axis against its own history and print the summary.")
    r.add_argument("manifest", metavar="MANIFEST|FOLDER",
                   help="manifest.csv or manifest.toml (record, axis, timestamp[, config, baseline]), or a folder of "
                        "records AXIS_DATE.csv (or AXIS/DATE.csv)")
    r.add_argument("--config", default=None, metavar="FILE",
                   help="the axes' config (TOML), where the manifest names none; its fleet.track and "
                        "fleet.thresholds are the defaults of --track and --threshold")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config parameter")
    r.add_argument("--out", default="out/fleet", metavar="DIR", help="the fleet's folder: the store and fleet.json")
    r.add_argument("--track", default=None, metavar="EFFECTS",
                   help="comma-separated effects to fit on every record and track (default: the config's fleet.track)")
    r.add_argument("--threshold", action="append", default=[], metavar="LIMIT",
                   help="a physical limit, e.g. \"backlash.gap > 10um\" (repeatable; added to fleet.thresholds)")
    r.add_argument("--candidates", default=None, metavar="EFFECTS",
                   help="the chain's candidates, comma-separated (default: the whole catalogue)")
    r.add_argument("--max-steps", type=int, default=4, metavar="N",
                   help="at most N steps of the diagnosis chain per record (0: no chain, the tracked fit only)")
    r.add_argument("--baseline", type=int, default=3, metavar="N",
                   help="the first N records of each axis set its limits, unless the manifest marks some (default 3)")
    r.add_argument("--scatter", default="1%", metavar="FRACTION",
                   help="the least night-to-night scatter of a healthy axis, relative (default 1%%)")
    r.add_argument("--map", action="append", default=[], metavar="SOURCE=CHANNEL[unit]",
                   help="column -> channel, as hil diagnose's --map (every record)")
    r.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on an existing dask.distributed cluster (tcp://127.0.0.1:8786); default: local "
                        "processes. Another machine's only over tls:// or with --allow-remote-scheduler")
    r.add_argument("--allow-remote-scheduler", action="store_true",
                   help="accept a --scheduler on another machine without encryption: Dask unpickles what it "
                        "receives, so the scheduler and the network can run code here; only where you trust both")
    r.add_argument("--jobs", type=int, default=None, metavar="N", help="local processes (default: the CPUs)")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    p = sub.add_parser("report", help="the fleet's HTML report, CSV and JSON from a run's folder",
                       description="Write report.html (one row per axis; per axis a trend plot of each tracked "
                                   "strength with its band and the flagged dates; links to each record's page), "
                                   "values.csv and values.json into the fleet's folder.")
    p.add_argument("folder", metavar="DIR", help="the folder of hil fleet run (its fleet.json)")
    p.add_argument("--out", default=None, metavar="DIR", help="where to write (default: DIR)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _scatter(text: str) -> float:
    import math
    t = text.strip()
    try:
        v = float(t[:-1]) / 100 if t.endswith("%") else float(t)
    except ValueError:
        raise UserError(f"--scatter {text}: expected a fraction or a percentage, e.g. 1% or 0.01") from None
    if not (math.isfinite(v) and 0 <= v < 0.5):
        raise UserError(f"--scatter {text}: expected 0 to 50 %")
    return v


def _split(text) -> list[str]:
    return [s.strip() for s in str(text or "").split(",") if s.strip()]


def run(args) -> int:
    if args.fleet_command == "report":
        return _report(args)
    return _run(args)


def _run(args) -> int:
    import sys
    from pathlib import Path

    from hil.config import parse_assignment
    from hil.fleet.batch import confirm_findings, load_configs, run_fleet
    from hil.fleet.manifest import read_manifest
    from hil.fleet.run import Settings, tracked_kinds
    from hil.fleet.spc import parse_threshold
    from hil.fleet.summary import judge_fleet
    if args.baseline < 1:
        raise UserError(f"--baseline {args.baseline}: expected at least 1 record")
    if args.max_steps < 0:
        raise UserError(f"--max-steps {args.max_steps}: expected 0 or more")
    scatter = _scatter(args.scatter)
    if args.scheduler:
        from hil.sweep.executors import check_scheduler_address
        check_scheduler_address(args.scheduler, args.allow_remote_scheduler)
    entries = read_manifest(args.manifest)
    configs = load_configs(entries, args.config, dict(parse_assignment(s) for s in args.set))
    first = configs[args.config] if args.config in configs else next(iter(configs.values()))
    track = tuple(_split(args.track) if args.track is not None else _split(first.get("fleet.track", "")))
    kinds = tracked_kinds(first, track)
    where_cfg = f"{args.config or entries[0].config}: fleet.thresholds"
    thresholds = {}
    for text, where in [(t, where_cfg) for t in _split(first.get("fleet.thresholds", ""))] + \
                       [(t, "--threshold") for t in args.threshold]:
        th = parse_threshold(text, kinds, where)
        thresholds[th.name] = th
    cands = tuple(_split(args.candidates)) if args.candidates else None
    if cands:
        from hil.commands.record_inputs import check_candidates
        for cfg in configs.values():
            check_candidates(cands, cfg, "--candidates")
    settings = Settings(track=track, candidates=cands, max_steps=args.max_steps, mapping=tuple(args.map))

    def progress(done, total, record):
        print(f"fleet: {done}/{total} diagnosed: {Path(record).name}", file=sys.stderr, flush=True)

    def progress_confirm(done, total, record):
        print(f"fleet: {done}/{total} strengths fitted with one model every night: {Path(record).name}",
              file=sys.stderr, flush=True)

    from hil.commands.record_inputs import prompt_interrupt
    with prompt_interrupt():
        res = run_fleet(entries, configs, args.config, settings, args.out, scheduler=args.scheduler, jobs=args.jobs,
                        progress=progress)
        # an axis with a finding or a flag: its strengths fitted with one model every night, before it is flagged
        confirm = confirm_findings(entries, configs, args.config, settings, res, args.out, args.baseline,
                                   scheduler=args.scheduler, jobs=args.jobs, progress=progress_confirm,
                                   thresholds=thresholds, scatter=scatter)
    axes = judge_fleet(entries, res.figures, thresholds, args.baseline, scatter, confirm)
    # the units of the normal effects' strengths, judged beside the tracked ones
    normal = sorted({n for a in axes for n in a["normal"]} | {f["effect"] for a in axes for f in a["findings"]})
    try:
        kinds = {**tracked_kinds(first, normal), **kinds}
    except HilError:
        pass                    # a normal effect of a name this config does not know: printed without a unit
    errors = [er for a in axes for er in a["errors"]]
    state = {"entries": [e.__dict__ for e in entries], "figures": res.figures, "confirm": confirm, "axes": axes,
             "kinds": kinds,
             "settings": {"track": list(track), "candidates": list(cands or []), "max_steps": args.max_steps,
                          "baseline": args.baseline, "scatter": scatter,
                          "thresholds": {k: t.text for k, t in thresholds.items()}}}
    from hil.io.safe_write import write_atomic
    summary = Path(args.out) / "fleet.json"
    write_atomic(summary, dumps(state, indent=1) + "\n")
    # a fleet of which no record could be diagnosed has answered nothing: not a success
    none_diagnosed = bool(entries) and all("error" in (res.figures.get(e.id) or {"error": ""}) for e in entries)
    if args.json:
        print(dumps({"records": len(entries), "computed": res.computed, "reused": res.reused,
                     "store": str(Path(args.out) / "results.jsonl"), "summary": str(summary),
                     "errors": errors, "axes": axes}, indent=1))
    else:
        for line in summary_text(entries, res, axes, kinds):
            print(line)
    if none_diagnosed:
        print(f"hil fleet run: error: none of the {len(entries)} records could be diagnosed (their errors above, "
              f"and in {summary})", file=sys.stderr)
        return 2
    return 0


def summary_text(entries, res, axes, kinds) -> list[str]:
    """The fleet as a person reads it: counts, then one line per axis, then its flags and errors."""
    from hil.units import DIMENSIONS, fmt
    n_axes = len(axes)
    lines = [f"{len(entries)} records of {n_axes} axes: {res.computed} diagnosed now, {res.reused} reused"]

    def q(v, name):
        k = kinds.get(name, "")
        return fmt(v, k) if k in DIMENSIONS and k != "dimensionless" else f"{v:.4g}"
    for a in axes:
        lines.append(f"{a['axis']}: {a['verdict']}" + (f" (normal: {', '.join(a['normal'])})" if a["normal"] else ""))
        for f in a["flags"]:
            if f["from"] is not None:
                lines.append(f"    {f['parameter']}: {q(f['from'], f['parameter'])} -> {q(f['to'], f['parameter'])} "
                             f"({f['reason']}, first moved {f['since']})")
            else:
                lines.append(f"    {f['parameter']}: {f['reason']}, since {f['since']}")
        for name, p in a.get("params", {}).items():
            if p.get("source") == "chain":      # a normal effect's strength, night by night (issue 53)
                vals = ", ".join("-" if v != v else q(v, name) for v in p["values"][-8:])
                lines.append(f"    {name} (the chain's, per night{', last 8' if len(p['values']) > 8 else ''}): "
                             f"{vals}")
        for er in a["errors"]:
            lines.append(f"    error: {er['error']}")
    return lines


# what hil fleet report reads of a fleet.json: key -> (type, the keys each item must have)
_STATE_KEYS = {"entries": (list, ("axis", "timestamp", "record")), "figures": (dict, ()),
               "axes": (list, ("axis", "verdict", "flags", "worst", "normal", "params", "dates", "errors"))}


def check_state(state, src) -> None:
    """One line naming the file and the key for a fleet.json that hil fleet run did not write as
    hil fleet report reads it ({}, [], a key missing, an item of the wrong type)."""
    if not isinstance(state, dict):
        raise UserError(f"{src}: expected a JSON object (hil fleet run's fleet.json), got {type(state).__name__}")
    for key, (kind, item_keys) in _STATE_KEYS.items():
        if not isinstance(state.get(key), kind):
            raise UserError(f"{src}: key {key!r}: missing or not a {'list' if kind is list else 'JSON object'} "
                            f"(not a fleet.json of hil fleet run?)")
        for i, item in enumerate(state[key] if kind is list else ()):
            missing = [k for k in item_keys if not isinstance(item, dict) or k not in item]
            if missing:
                raise UserError(f"{src}: {key}[{i}]: key {missing[0]!r} missing (not a fleet.json of hil fleet run?)")
            if key == "entries" and not all(isinstance(item[k], str) for k in item_keys):
                raise UserError(f"{src}: {key}[{i}]: axis, timestamp and record must be strings")
    if not isinstance(state.get("kinds", {}), dict):
        raise UserError(f"{src}: key 'kinds': expected a JSON object")


def _report(args) -> int:
    import json
    from pathlib import Path

    from hil.fleet.report import write_report
    src = Path(args.folder) / "fleet.json"
    try:
        state = json.loads(src.read_text(encoding="utf-8"))
    except OSError:
        raise UserError(f"{src}: no fleet here (run hil fleet run ... --out {args.folder} first)") from None
    except ValueError:
        raise UserError(f"{src}: not a fleet summary (JSON) of hil fleet run") from None
    check_state(state, src)
    out = write_report(state, Path(args.out or args.folder))
    if args.json:
        print(dumps({"records": len(state["entries"]), "axes": [{k: a[k] for k in ("axis", "verdict", "flags", "worst")}
                                                                   for a in state["axes"]],
                     "errors": [er for a in state["axes"] for er in a["errors"]], **out}, indent=1))
        return 0
    print(f"report: {out['report']}")
    print(f"values: {out['csv']}, {out['json']}")
    return 0
