"""``hil fit``: add effects with fitted parameters and write the new config."""
from __future__ import annotations

import math
import sys
from pathlib import Path

from hil.commands.record_inputs import add_common, check_candidates, load_records, make_records, make_replay
from hil.errors import UserError
from hil.io.jsonout import JsonKey, dumps

HELP = "fit one or more effects (or parameter:<key>) to a measurement and write the new config"
DESCRIPTION = """\
Adds each --add effect in turn, fitting its parameters on top of the ones before, and writes the
config with the effects' sections ([effects.<name>]) or the re-identified parameters to --out.
--out is an edit of --config: only the fitted keys change (comments, layout and the units each
value was written in are kept), each value rounded to its standard error (from the fit's
Jacobian), which a comment beside it gives.
Then `hil compare DATA --config OLD --after NEW` shows the error fall. DATA may also be the
frf.json that `hil frf` writes: the effects are then fitted to the measured frequency responses
(all --add fitted together, weighted by the measured uncertainty).

  hil fit data.csv --config config/paper_bench.toml --add parameter:plant.c2 --out fitted.toml
  hil fit out/frf/frf.json --config config/paper_bench.toml --add parameter:plant.c2 --out fitted.toml
  hil fit DATA_EMPS.mat --config config/emps.toml --map ... --add coulomb_friction --add constant_force --out emps_fit.toml

Several records of one axis (both directions, several speeds) are fitted together: one objective
sums each record's residuals, weighted by its own error and noise floor. --validate RECORD...
replays records the fit did not use: their errors (start -> fitted) are printed beside the
estimation records' (System Identification practice: estimation and validation data).

  hil fit up.csv down.csv --config axis.toml --add asymmetric_friction --validate mixed.csv --out fitted.toml

--refit KEYS refits config keys at the end (a gain the drive was set to, a mass), jointly with
the added effects' parameters, which were fitted with the keys at their old values:

  hil fit data.csv --config config/paper_bench.toml --add coulomb_friction --refit control.kv,control.kp --out fitted.toml

An effect that makes the (weighted) error worse is refused: nothing is written, one line says
which and by how much, and the exit status is 2 (with --json the object says "written": false).
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
CHANNEL_UNIT = "the channel's (m, N*m, N, V)"
_RECORD = "records (not an frf.json)"
_FRF = "an frf.json of hil frf"
JSON_KEYS = {
    "config": JsonKey("", "path of the new config (--out)"),
    "error_before": JsonKey(CHANNEL_UNIT, "per channel, RMS error of the start model (frf.json: a number, the RMS "
                                          "weighted log error, dimensionless)"),
    "error_after": JsonKey(CHANNEL_UNIT, "the same for the config as written (its values rounded to their standard "
                                         "errors)"),
    "written": JsonKey("", "the config was written (false: an effect made the error worse, exit 2)", when=_RECORD),
    "steps": JsonKey("", "each --add fit in turn, then the joint refit: effect, params (SI), stderr (SI), channel, "
                         "error_before, error_after, score, evidence, gain, significant, worse_than_without, confounded, degenerate (as diagnose's "
                         "candidates[])", when=_RECORD),
    "misfit": JsonKey("", "null where the fitted model reaches the estimation records' noise floor; else where it "
                          "misses most: record, channel, above_floor (its ratio to the floor). The fitted values then "
                          "take up what the model lacks, which their standard errors do not count",
                      when=_RECORD + ", written"),
    "fitted": JsonKey("SI", "per written config key: value, stderr (standard error, counting the residual's serial "
                            "correlation; null: at its bound or not identifiable alone) and unit (its SI unit)",
                      when=_RECORD),
    "unchanged": JsonKey("SI", "per fitted config key that the fit left at the config's value (so not written): "
                               "value, stderr and unit", when=_RECORD),
    "records": JsonKey("", "the estimation records", when=_RECORD),
    "units": JsonKey("", "the SI unit of each channel of error_before and error_after", when=_RECORD),
    "estimation": JsonKey("", "per estimation record: record, samples, errors before and after (as diagnose's)",
                          when=_RECORD),
    "validation": JsonKey("", "the same for each --validate record (empty without)", when=_RECORD),
    "refused": JsonKey("", "the effects that made the error worse: effects, weighted_error_ratio, message",
                       when="the fit was refused (written false)"),
    "domain": JsonKey("", "`frequency`", when=_FRF),
    "effect": JsonKey("", "the effects fitted together", when=_FRF),
    "params": JsonKey("SI", "fitted parameters by name", when=_FRF),
    "per_response": JsonKey("1", "per response, the RMS log error before and after", when=_FRF),
}


def add_arguments(parser) -> None:
    add_common(parser, records=True)
    parser.add_argument("--add", action="append", required=True, metavar="EFFECT",
                        help="catalogue effect or parameter:<dotted key> (repeatable)")
    parser.add_argument("--refit", metavar="KEYS", default=None,
                        help="comma-separated config keys to refit at the end, jointly with the added effects' parameters")
    parser.add_argument("--out", required=True, metavar="FILE", help="the new config (TOML)")


def _check_out(args) -> None:
    """--out: never the input config or data (checked before the fit's minutes, and again when
    writing), never a folder."""
    from hil.io.safe_write import refuse_inputs
    refuse_inputs(args.out, (args.config, *_paths(args.data), *(getattr(args, "validate", None) or [])))
    if Path(args.out).is_dir():
        raise UserError(f"--out {args.out}: is a folder, expected the new config's file name")


def _paths(data) -> list:
    return [data] if isinstance(data, str) else list(data)


def _refit_keys(text: str | None) -> list[str]:
    """The --refit keys, each a parameter the schema knows (checked before fitting)."""
    from hil.config import field_for
    if not text:
        return []
    keys = [k.strip() for k in text.split(",") if k.strip()]
    for k in keys:
        f = field_for(k)
        if f is None or f.kind_for({}) in ("str", "bool", "floats", "int"):
            raise UserError(f"--refit {k}: not a numeric parameter of the configuration schema")
    return keys


def run(args) -> int:
    from hil.ident.frf_fit import is_frf_file
    paths = _paths(args.data)
    if any(is_frf_file(p) for p in paths):
        if len(paths) > 1 or getattr(args, "validate", None):
            raise UserError(f"{paths[0]}: frequency responses are fitted one file at a time, without --validate")
        args.data = paths[0]
        return _run_frequency(args)
    from hil.ident.fit import fit_effects, joint_refit
    from hil.ident.records import errors_text, estimation_validation
    cfg, metas, vals = load_records(args)
    _check_out(args)
    check_candidates(args.add, cfg, "--add")
    refit = _refit_keys(args.refit)
    refit_se: dict = {}
    rp = make_records(args, cfg, metas)
    before = {c: float((rp.base_residuals[c] ** 2).mean() ** 0.5) for c in rp.channels}
    from hil.commands.progress import bar
    with bar("fit", args) as prog:          # fit_effects tells it the total (hil.ident.progress.expect)
        new, steps = fit_effects(rp, args.add, progress=prog)
    if refit:
        missing = [k for k in refit if not isinstance(new.get(k), float)]
        if missing:
            raise UserError(f"--refit {missing[0]}: not a number of the fitted config (the keys it has: "
                            f"the config's and the added effects')")
        # the added effects were fitted with the refit keys at their old values: held there, their
        # values keep that error and the refit's standard errors ignore them (kv 60 and 2 N m of
        # friction: kv 56.7 +- 1.1, kp 4.4 and the level 8.7 standard errors off)
        # (not one the step left at a bound or could not see: the joint refit has no bounds)
        refit += [k for k, se in _step_keys(cfg, steps)
                  if k not in refit and isinstance(new.get(k), float) and math.isfinite(se)]
        new = joint_refit(rp, new, refit, stderr=refit_se)
    res = rp.residuals(new)
    after = {c: float((res[c] ** 2).mean() ** 0.5) for c in rp.channels}
    stderr = fitted_stderr(cfg, steps)
    stderr.update(refit_se)
    parts = getattr(rp, "parts", [rp])
    checks = [make_replay(args, cfg, m) for m in vals]
    units = {c: rp.unit(c) for c in rp.channels}
    out = {"config": args.out, "written": True, "steps": [s.as_json() for s in steps], "fitted": {},
           "error_before": before, "error_after": after, "records": [m.source for m in metas],
           "units": {"error_before": units, "error_after": units}}
    refused = worse_effects(rp, steps, new)
    if refused:
        out.update(estimation_validation(parts, checks, new), written=False, refused=refused)
        line = f"not written: {refused['message']} (drop it from --add; `hil diagnose` says what the record lacks)"
        if args.json:
            print(dumps(out, indent=1))
            print(f"hil fit: refused: {line}", file=sys.stderr)
            return 2
        raise UserError(line)
    names = ", ".join(Path(str(m.source)).name for m in metas)
    written = _write(args, new, stderr, f"hil fit on {names}",
                     inputs=(args.config, *paths, *(getattr(args, "validate", None) or [])))
    out["fitted"] = {k: {"value": new.get(k), "stderr": stderr.get(k), "unit": _si_unit(k, new)} for k in written}
    # every --add is accounted for: a fitted key the fit left at the config's value is named, not dropped
    kept = [k for k in stderr if k not in written]
    out["unchanged"] = {k: {"value": new.get(k), "stderr": stderr.get(k), "unit": _si_unit(k, new)} for k in kept}
    # the errors of the config as written (its values rounded to their standard errors)
    from hil.config import load
    saved = load(args.out)
    res = rp.residuals(saved)
    after = out["error_after"] = {c: float((res[c] ** 2).mean() ** 0.5) for c in rp.channels}
    table = estimation_validation(parts, checks, saved)
    out.update(table)
    out["misfit"] = misfit(table, rp.channels)
    if args.json:
        print(dumps(out, indent=1))
    else:
        from hil.units import fmt_si
        for line in fitted_text(written, new, stderr):
            print(line)
        for c in rp.channels:
            print(f"  {c}: RMS {fmt_si(before[c], rp.unit(c))} -> {fmt_si(after[c], rp.unit(c))}")
        if len(metas) > 1 or vals:
            for line in errors_text(table, rp.unit):
                print(line)
        for k in written:
            if stderr.get(k) is None and k in stderr:
                print(f"{k}: no standard error: at its bound, or the record sees it only together with another "
                      f"parameter (a near-singular fit); the value is not a measurement of it alone")
        if out["misfit"]:
            m = out["misfit"]
            print(f"note: the fitted model leaves {m['channel']} {m['above_floor']:.1f} x above its noise floor on "
                  f"{m['record']}: the values take up what the model still lacks, which their standard errors do "
                  f"not count (hil diagnose names what is missing)")
        for k in kept:
            print(f"{k}: the fit left it at the config's value {fitted_text([k], new, {})[0].split(' = ', 1)[1]} "
                  f"(the record does not move it; not written)")
        print(f"wrote {args.out} (changed: {', '.join(written) or 'nothing'}"
              f"{'; unchanged: ' + ', '.join(kept) if kept else ''})")
    return 0


def misfit(table: dict, channels) -> dict | None:
    """Where the fitted model still misses the estimation records: the channel furthest above its
    noise floor, where that is beyond :data:`hil.ident.unexplained.MISFIT` times it ({"record",
    "channel", "above_floor"}); None where every channel is within it."""
    from hil.ident.unexplained import MISFIT
    worst = None
    for r in table.get("estimation", []):
        for c in channels:
            x = r["after"]["above_floor"].get(c)
            if x is not None and x == x and (worst is None or x > worst["above_floor"]):
                worst = {"record": r["record"], "channel": c, "above_floor": float(x)}
    return worst if worst is not None and worst["above_floor"] > MISFIT else None


def _si_unit(key: str, cfg) -> str:
    from hil.config import field_for
    from hil.units import SI_UNIT
    f = field_for(key)
    return SI_UNIT.get(f.kind_for(cfg.values), "") if f is not None else ""


def fitted_stderr(cfg, steps) -> dict:
    """Standard error (SI) per config key of the fitted parameters: each step's parameters mapped
    to the keys they set (a later step, the joint fit, wins)."""
    return {key: se if math.isfinite(se) else None for key, se in _step_keys(cfg, steps)}


def _step_keys(cfg, steps):
    """(config key, standard error) of each fitted parameter of each step that sets one key alone
    (the key found by bumping the parameter)."""
    from hil.plant_config import candidate, configure
    for s in steps:
        try:
            eff = candidate(s.effect, cfg)
        except KeyError:
            continue
        vals = dict(s.params)
        try:
            ref = configure(eff, cfg, vals)
        except ValueError:
            continue
        for name, se in s.stderr.items():
            bumped = dict(vals, **{name: vals[name] * (1 + 1e-3) + 1e-9})
            try:
                other = configure(eff, cfg, bumped)
            except ValueError:
                continue
            keys = [k for k, v in other.values.items() if v != ref.values.get(k)]
            if len(keys) == 1:
                yield keys[0], se


def fitted_text(keys, new, stderr) -> list[str]:
    """One line per written key: its value rounded to its standard error, in an engineering unit."""
    from hil.config import field_for
    from hil.units import DIMENSIONS, fmt, fmt_uncertain
    lines = []
    for k in keys:
        v = new.get(k)
        f = field_for(k)
        kind = f.kind_for(new.values) if f is not None else "dimensionless"
        if not isinstance(v, float) or kind not in DIMENSIONS:
            lines.append(f"{k} = {v}")
        elif stderr.get(k) is not None:
            lines.append(f"{k} = {fmt_uncertain(v, stderr[k], kind)}  (standard error)")
        else:
            lines.append(f"{k} = {fmt(v, kind, digits=6)}")
    return lines


def _write(args, new, stderr, note, inputs) -> list[str]:
    """--out as an edit of --config: the changed keys only (hil.io.config_write)."""
    from hil.io.config_write import write_config
    from hil.plant_config import without_replaced
    return write_config(args.out, args.config, without_replaced(new), stderr=stderr, note=note, inputs=inputs)


def worse_effects(rp, steps, new) -> dict | None:
    """The effects that made the weighted error of the estimation records worse (each greedy step
    against the model before it, and the whole fit against the start), or None when none did."""
    import numpy as np
    obj = rp.objective
    e0 = float(np.sum(obj.vector(rp.base_residuals) ** 2))
    e1 = float(np.sum(obj.vector(rp.residuals(new)) ** 2))
    bad = [s for s in steps if "+" not in s.effect and s.gain < 0]
    if not bad and e1 <= e0:
        return None
    names = [s.effect for s in bad] or [s.effect for s in steps if "+" not in s.effect]
    if bad:
        s = bad[0]
        chans = ", ".join(f"{c} RMS {s.errors_after[c]:.3g}" for c in s.errors_after)
        msg = (f"{' and '.join(names)} make{'s' if len(names) == 1 else ''} the error worse (weighted error "
               f"x{1 - s.gain:.3g} when {s.effect} is added; after it: {chans})")
    else:
        msg = f"{' and '.join(names)} make the error worse (weighted error x{e1 / max(e0, 1e-300):.3g})"
    return {"effects": names, "weighted_error_ratio": e1 / max(e0, 1e-300), "message": msg}


def _run_frequency(args) -> int:
    """``hil fit frf.json``: the same effects fitted to measured frequency responses."""
    from hil.config import load, parse_assignment
    from hil.ident.frf_fit import FrfDataError, fit_frf, load_frf
    cfg = load(args.config, dict(parse_assignment(s) for s in args.set))
    _check_out(args)
    try:
        data = load_frf(args.data)
        fit = fit_frf(cfg, data, args.add)
    except (FrfDataError, KeyError) as exc:
        raise UserError(str(exc).strip("'\"")) from None
    written = _write(args, fit.config, {}, f"hil fit on {Path(args.data).name} (frequency responses)",
                     inputs=(args.config, args.data))
    out = {"config": args.out, "domain": "frequency", "effect": fit.effect, "params": fit.params,
           "error_before": fit.error_before, "error_after": fit.error_after, "per_response": fit.per_response}
    if args.json:
        print(dumps(out, indent=1))
    else:
        for line in fitted_text(written, fit.config, {}):
            print(line)
        for name, e in fit.per_response.items():
            print(f"  {name}: rms log error {e['before']:.4g} -> {e['after']:.4g}")
        print(f"wrote {args.out}")
    return 0
