"""``hil diagnose``: which physical effect is the model missing?"""
from __future__ import annotations

from hil.commands.record_inputs import add_common, check_candidates, load_records, make_records, make_replay
from hil.errors import UserError
from hil.io.jsonout import JsonKey, dumps

HELP = "rank the catalogue's effects by how much of the model error each explains"
DESCRIPTION = """\
For each candidate (every catalogue effect that fits the plant, and parameter:<key> for the chain's
masses, stiffnesses and dampings) adds it to the model, fits its parameters (scipy least squares on
every measured channel) and scores it by the fall of the BIC (on the effective sample count). A
candidate is significant when its score exceeds 6 and the error stands above the noise floor;
A richer effect that simpler ones can mimic (asymmetric_friction: coulomb_friction +
constant_force) is compared with them fitted jointly; when they explain most of its gain they are
named first (verdict, then "also_missing").

Then the chain: the verdict is added, everything found so far refitted together, and the record
diagnosed again, until the residual reaches the noise floor (standstill segments, encoder
quantization, or a figure given as noise.<channel> in the config or the file header) or no effect
pays for its parameters (at most --max-steps diagnoses). The verdict is "none" only when the model
already matches the record down to the noise floor; "unexplained" when the residual stays above it
and no candidate closes half of the gap (with the evidence of where the residual lives).

  hil diagnose data.csv --config config/paper_bench.toml --json
  hil diagnose data.csv --config config/paper_bench.toml --candidates coulomb_friction,parameter:plant.c2
  hil diagnose data.csv --config config/paper_bench.toml --out fitted.toml   (the config with the chain)
  hil diagnose data.csv --config config/paper_bench.toml --report out/diagnose.html   (one HTML file)

Several records of one axis (both directions, several speeds) are diagnosed and fitted together
(one objective over all of them, each record with its own noise floor); --validate RECORD...
replays records the chain did not use, and prints their errors (start -> the chain's model)
beside the estimation records' ("estimation" and "validation" in the JSON).

  hil diagnose up.csv down.csv --config axis.toml --validate mixed.csv --json
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
CHANNEL_UNIT = "the channel's (m, N*m, N, V)"
JSON_KEYS = {
    "verdict": JsonKey("", "the effect the model misses (a catalogue name or `parameter:<key>`), `none` (the "
                           "model matches down to the noise floor, or the chain found a drift of the config within "
                           "its tolerance and nothing beyond it: final.tolerance) or `unexplained` (above it, and no "
                           "candidate explains it); the chain's first finding still in the model where a later step "
                           "or the config's drift took the first diagnosis's verdict out of it"),
    "candidates": JsonKey("", "every candidate fitted, best score first (entries candidates[].*)"),
    "candidates[].effect": JsonKey("", "catalogue effect, `a+b` combination or `parameter:<key>`"),
    "candidates[].params": JsonKey("SI", "fitted parameters by name (units: reference/effects.md)"),
    "candidates[].stderr": JsonKey("SI", "standard error of each fitted parameter (null: none, e.g. at a bound)"),
    "candidates[].channel": JsonKey("", "the channel where the effect shows most (its RMS error falls the most)"),
    "candidates[].error_before": JsonKey(CHANNEL_UNIT, "RMS error of that channel before the fit"),
    "candidates[].error_after": JsonKey(CHANNEL_UNIT, "RMS error of that channel after the fit"),
    "candidates[].score": JsonKey("", "the fall of the BIC (significant above 6)"),
    "candidates[].evidence": JsonKey("", "where the effect shows in the residual, one sentence"),
    "candidates[].gain": JsonKey("1", "fraction of the weighted residual energy removed"),
    "candidates[].significant": JsonKey("", "score above 6 and the error above the noise floor"),
    "candidates[].confounded": JsonKey("", "pairs of fitted parameters correlated above 0.9 (the data tell only "
                                           "their combination): [name, name, r]"),
    "candidates[].worse_than_without": JsonKey("", "the fit left more error than the model without the effect: it "
                                                   "stopped in a wrong basin (said in its evidence; never significant)"),
    "candidates[].degenerate": JsonKey("", "why the fit names another effect, \"\" when it does not: a mode at the bound of "
                                       "its range (a rigid mass, a damper), a controller setting moved by under 1 %; such "
                                       "a fit is never significant and ranks after the others"),
    "shown_together": JsonKey("", "two effects that show only together: no single effect closed half the gap, the best "
                                  "fit with the next verdict on top of it did (the chain's first step adds both)",
                              when="the chain found such a pair"),
    "alternatives": JsonKey("", "the candidates this record cannot tell from the verdict (a mass on the table or on "
                                "the motor side): of (the verdict), effect, score, evidence, against_verdict and "
                                "verdict_against (each fit's BIC score with the other's residual as before; both at "
                                "most 6); none named beside the verdict or found by the chain; [] when none"),
    "not_tried": JsonKey("", "the catalogue effects this axis cannot have, each with the reason (a cable carrier on an "
                             "axis that turns without end, plant.endless; backlash without a transmission link): "
                             "`{effect: reason}`, never candidates; `{}` where --candidates names them"),
    "also_missing": JsonKey("", "effects missing beside the verdict (a preferred combination's other members): "
                                "effect, params (SI), score (the BIC fall when it is left out), significant, "
                                "evidence"),
    "combinations": JsonKey("", "simpler effects fitted jointly against a richer one they can mimic: effects, "
                                "explains, preferred, score, rich_against_combination, explained (fraction), "
                                "rich_score, params (SI), channel, error_before, error_after, evidence, members"),
    "joint_candidates": JsonKey("", "pairs of friction or force effects fitted together: effects, preferred, score, "
                                    "second_member_score, best_single, best_single_score, gain (fraction), params; "
                                    "and a preferred pair's leader fitted with one of the strongest single "
                                    "candidates: rival_of (the screened pair, + joined; screen_synergy null)"),
    "noise_floor": JsonKey(CHANNEL_UNIT, "per channel, the RMS noise floor of the record (units: units.noise_floor)"),
    "noise_floor_source": JsonKey("", "per channel, where the floor comes from: `given` (config or file header), "
                                      "`quantization`, `standstill (N samples)` or the third-difference fallback"),
    "error_before": JsonKey(CHANNEL_UNIT, "per channel, the RMS error of the start model"),
    "gap_closed": JsonKey("1", "fraction of the gap between the error and the noise floor the leading candidate "
                               "closes"),
    "units": JsonKey("", "the SI unit of each channel of noise_floor and error_before"),
    "residual": JsonKey("", "where the residual lives: channels, worst first (channel, unit, rms, noise_floor, "
                            "above_floor, spectral_peaks, correlation, along_travel, rms_moving, rms_standstill), "
                            "best_candidate, best_gap_closed",
                        when="the verdict is `unexplained`"),
    "estimation": JsonKey("", "per estimation record: record, samples, errors before (start model) and after "
                              "(the model found)", when="several records or --validate"),
    "validation": JsonKey("", "the same for each --validate record", when="several records or --validate"),
    "chain": JsonKey("", "one entry per step that added effects (entries chain[].*)",
                     when="the chain (not --no-chain or --max-steps 1)"),
    "chain[].step": JsonKey("", "step number, from 1"),
    "chain[].effect": JsonKey("", "the step's verdict"),
    "chain[].effects": JsonKey("", "the effects the step added"),
    "chain[].params": JsonKey("SI", "`{effect: {parameter: value}}` of everything found so far, after the step"),
    "chain[].error_before": JsonKey(CHANNEL_UNIT, "per channel, RMS error before the step"),
    "chain[].error_after": JsonKey(CHANNEL_UNIT, "per channel, RMS error after the step"),
    "chain[].gap_closed": JsonKey("1", "per channel, fraction of the gap to the noise floor the step closed"),
    "chain[].score": JsonKey("", "the step's BIC fall"),
    "chain[].evidence": JsonKey("", "the verdict's evidence, one sentence"),
    "chain[].refitted_together": JsonKey("", "everything found so far was refitted together at this step"),
    "chain[].recording_artefacts": JsonKey("", "the step's effects that are artefacts of the recording (a channel's "
                                               "skew, a sensor offset): written to the config's [measurement], "
                                               "never to the plant's [effects.*]"),
    "skill": JsonKey("", "the final error against two baselines that need no model (hil.ident.skill)"),
    "skill.error": JsonKey(CHANNEL_UNIT, "per channel, the final RMS error (the start model's without a chain)"),
    "skill.baseline": JsonKey(CHANNEL_UNIT, "start: the start model's error per channel; command: the following "
                                            "error x - x_cmd per position channel ('the axis is where it was told "
                                            "to be'; none for an open-loop record)"),
    "skill.fit_percent": JsonKey("%", "start and command: per channel 100 (1 - error / baseline); 0: no better "
                                      "than the baseline, negative: worse"),
    "skill.no_skill": JsonKey("", "the position channels whose error is no smaller than the following error"),
    "skill.has_skill": JsonKey("", "false where the model is no better than the command on every position channel"),
    "run_to_run": JsonKey("", "where the records repeat one test: spread (per channel, the repetitions' scatter "
                              "about their mean, the channel's unit), floor_parts (per channel: spread, sensor: the "
                              "records' own floor, quantization: q/sqrt(12)), error_over (the final error in "
                              "multiples of each part), within (every channel with a spread within it, the others at their own floor)",
                          when="several records of one command"),
    "chain[].dropped": JsonKey("SI", "effects of earlier steps that no longer pay for their parameters beside the "
                                     "step's effects, dropped from the model: effect, params (as it stood), score "
                                     "(its BIC score with the step's effects)",
                               when="a step made an earlier effect unnecessary"),
    "chain[].beyond_tolerance": JsonKey("", "the step's diagnosis named a drift of the config (verdict) that the "
                                            "config's tolerance does not explain, or an effect that the config's drift "
                                            "with the effects found refitted brings to the noise floor, and the fit of "
                                            "every key left one key alone beyond the tolerance: the step is that key's "
                                            "candidate (effect): verdict, "
                                            "effect, key, change (relative), tolerance, params (per key, the fit's "
                                            "relative change)",
                                        when="such a step"),
    "chain[].nights_plant": JsonKey("SI", "the step's effect whose error jumps with its parameter (a backlash's "
                                          "gap) refitted on the night's plant, or, where the model took a drift of "
                                          "the config at an earlier step, that drift fitted again beside the step's "
                                          "effects (final.tolerance.again_after), the config's masses, stiffnesses and "
                                          "dampings within plant.tolerance: effects, tolerance, params (per key: "
                                          "config, value, change, stderr, margin: the relative margin of the decision), stderr (effect.param), "
                                          "error_on_config_plant (the step's error before), estimation_error, "
                                          "held_out; the step's params and error_after are then the night's",
                                    when="a step with such an effect or after such a drift, refitted there, "
                                         "within the tolerance and earned on the held-out data"),
    "chain[].stderr": JsonKey("SI", "`{effect: {parameter: standard error}}` of the step's last fit (null: none)"),
    "chain[].confounded": JsonKey("", "pairs of that fit's parameters correlated above 0.9: [name, name, r]"),
    "chain[].aliases": JsonKey("SI", "`{effect: [{key, params, r, slope, confounded}]}`: the config's own "
                                     "parameters (the parameter: candidates) against the step's fitted ones: r, "
                                     "their correlation were both fitted (one fitted parameter; for several, the "
                                     "multiple correlation), slope, what a relative drift of the key, left out of "
                                     "the model, moves each fitted parameter by (per unit of relative drift), "
                                     "confounded, |r| above 0.9: the record cannot tell the two apart"),
    "chain[].swapped": JsonKey("", "the first step's verdict this step replaces (its runner-up, judged once the "
                                   "later steps' effects are in the model; the verdict under dropped)",
                               when="a swap"),
    "chain[].rival": JsonKey("", "the runner-up judged beside the verdict after the refit of everything found (a "
                                 "later step, when it removed at least 0.8 of the verdict's share): effect, score, "
                                 "verdict, verdict_score (BIC falls); the better is the step; null: none"),
    "chain[].estimation_error": JsonKey(CHANNEL_UNIT, "per channel, RMS error after the step on the data it was "
                                                      "fitted on (the record's estimation moves)",
                                        when="a held-out part (the record has moves both ways, or --validate)"),
    "chain[].held_out": JsonKey("", "the step on the held-out data: before and after (RMS per channel), fall "
                                    "(relative fall of the weighted error), uncertainty (two standard errors of "
                                    "it), earned (the fall beyond its uncertainty); for a step of several effects, "
                                    "members: per effect its own fall (the step without it against the step, "
                                    "both refitted on the estimation moves), uncertainty, model_refit_fall (the "
                                    "rest refitted on the held-out moves) and earned; an effect that does not earn "
                                    "its own is taken out of the step",
                                when="a held-out part (the record has moves both ways, or --validate)"),
    "final": JsonKey("", "the end of the chain (keys final.*)", when="the chain (not --no-chain or --max-steps 1)"),
    "final.error": JsonKey(CHANNEL_UNIT, "per channel, RMS error of the model with the chain"),
    "final.noise_floor": JsonKey(CHANNEL_UNIT, "per channel, the noise floor"),
    "final.above_floor": JsonKey("1", "per channel, ratio of the error to the noise floor"),
    "final.at_noise_floor": JsonKey("", "every channel at its noise floor"),
    "final.end": JsonKey("", "why the chain ended: `noise floor reached`, `noise floor reached within the config's "
                             "tolerance`, `no effect pays for its parameters`, `unexplained`, `no candidate left`, "
                             "`max steps (N)`"),
    "final.steps": JsonKey("", "number of steps that added effects"),
    "final.floor_parts": JsonKey(CHANNEL_UNIT, "per channel, the parts of the noise floor the records have: "
                                               "quantization (q/sqrt(12)), standstill (the standstill noise: the "
                                               "residual's, or a force channel's measured noise at rest), "
                                               "run_to_run (the spread of repeated records)"),
    "final.error_over": JsonKey("1", "per channel, the final error in multiples of each part of floor_parts"),
    "final.within_run_to_run": JsonKey("", "the final error within the run-to-run spread (every channel with a "
                                           "spread within it, the others at their own floor); null: no test "
                                           "was repeated"),
    "final.residual": JsonKey("", "where the residual lives (as residual)", when="the end is above the noise floor"),
    "final.held_out": JsonKey("", "what the steps were checked on: the record's moves, the validation records, or "
                                  "none and why", when="the chain"),
    "final.rejected": JsonKey("", "the last step the held-out data refused: effects, score, "
                                  "error_after, stderr, confounded, estimation_error, held_out (as chain[]); tolerance "
                                  "(plant.tolerance) where it was the fit of the config's drift within its tolerance; "
                                  "next_tried (true) where the next verdict was tried after it; confounded_with "
                                  "(why) where the step's parameters cannot be told apart from those found before",
                              when="a step did not earn its place"),
    "final.also_refused": JsonKey("", "the steps refused before it (each as final.rejected), after each of which the "
                                      "next verdict, without the refused effects, was tried",
                                  when="more than one step did not earn its place"),
    "final.tolerance": JsonKey("", "a step would have named a drift of the config's masses, stiffnesses or "
                                   "dampings (or, after a step, an effect that such a drift leaves nothing for), "
                                   "and all of them fitted within plant.tolerance: no finding, the model holds them; "
                                   "keys final.tolerance.*",
                               when="a drift within the config's tolerance"),
    "final.tolerance.tolerance": JsonKey("1", "plant.tolerance, relative"),
    "final.tolerance.step": JsonKey("", "the chain's diagnosis whose verdict was the drift (the steps after it "
                                        "name what is left, no drift of the config among the candidates)"),
    "final.tolerance.within": JsonKey("", "every change within the tolerance (less two of its standard errors): "
                                          "always true here"),
    "final.tolerance.at_noise_floor": JsonKey("", "every channel at its noise floor with the values so fitted"),
    "final.tolerance.error": JsonKey(CHANNEL_UNIT, "per channel, RMS error of the model so fitted"),
    "final.tolerance.params": JsonKey("SI", "per config key: config, value, change (relative), stderr (null: none); "
                                            "one key of a combination the record fixes (the tip's k2 / m3) has a "
                                            "large one"),
    "final.tolerance.nfev": JsonKey("", "evaluations of the fit"),
    "final.tolerance.refitted": JsonKey("SI", "`{effect: {param: value}}`: the effects the steps before had found, "
                                              "refitted with the drift (their values were fitted without it)",
                                        when="after a step"),
    "final.tolerance.again_after": JsonKey("", "the steps after which the drift was fitted again beside their "
                                               "effects, everything found refitted with it (chain[].nights_plant); "
                                               "params, error, at_noise_floor and refitted are then the last such "
                                               "fit's (estimation_error and held_out stay the first fit's: the later "
                                               "checks are the steps' nights_plant.held_out)",
                                           when="a step after the drift, refitted so within the tolerance and earned "
                                                "on the held-out data"),
    "final.tolerance.in_place_of": JsonKey("", "the effects a later step named that the drift within the tolerance "
                                               "stands in for: with the effects found before refitted, every channel "
                                               "at its noise floor", when="a later step's effect, not a drift"),
    "final.tolerance.dropped": JsonKey("", "effects found before that no longer pay beside the drift (as "
                                           "chain[].dropped: effect, params as it stood, score): out of the model",
                                       when="such an effect"),
    "final.tolerance.estimation_error": JsonKey(CHANNEL_UNIT, "per channel, RMS error on the data the held-out "
                                                              "check fitted it on (as chain[])",
                                                when="with a held-out part"),
    "final.tolerance.held_out": JsonKey("", "the fit's held-out check, as chain[].held_out: it earns its place as "
                                            "a step would", when="with a held-out part"),
    "report": JsonKey("", "path of the HTML report", when="with --report"),
    "torque_sampling": JsonKey("", "which torque (force) the record holds, where the config does not say "
                                   "(measurement.torque / measurement.force): keys torque_sampling.*",
                               when="the chain, on a record with a torque or force channel whose config does not "
                                    "say"),
    "torque_sampling.record": JsonKey("", "`command` (before the actuator's delay and current loop), `actual` "
                                          "(the current, after them) or `either` (the model has no delay or lag: "
                                          "they are the same at the sample)"),
    "torque_sampling.said": JsonKey("", "false: the config did not say, the diagnosis decided"),
    "torque_sampling.key": JsonKey("", "the config key that says it (`measurement.torque` or `measurement.force`)"),
    "torque_sampling.above_floor": JsonKey("1", "per sampling tried, how far its model ends from the noise floor: "
                                                "the sum over channels of (error / noise floor)^2"),
}


# the other candidates the text shows (the JSON and --all: every one)
SHOWN_CANDIDATES = 8


def add_arguments(parser) -> None:
    add_common(parser, records=True)
    parser.add_argument("--all", dest="all_candidates", action="store_true",
                        help=f"list every other candidate in the text (default: the first {SHOWN_CANDIDATES} by "
                             f"score; the JSON always has them all)")
    parser.add_argument("--candidates", metavar="EFFECTS", default=None, help="comma-separated candidates (default: the whole catalogue)")
    parser.add_argument("--jobs", metavar="N", type=int, default=None, help="worker processes (default: this process, the fits on the idle cores' threads)")
    parser.add_argument("--max-steps", "--steps", dest="max_steps", type=int, default=4, metavar="N",
                        help="at most N steps in the chain, each a diagnosis that adds its verdict (default 4; "
                             "1: the single diagnosis, as --no-chain)")
    parser.add_argument("--no-chain", action="store_true", help="the single diagnosis, nothing added")
    parser.add_argument("--out", default=None, metavar="FILE", help="write the config with the whole chain (TOML)")
    parser.add_argument("--report", default=None, metavar="FILE",
                        help="write an HTML report (one self-contained file): the verdict, the ranking, the chain, "
                             "and the residual analysis of the start model and of the model with the chain")


def candidates_json(d, unit=None):
    out = {"candidates": [c.as_json() for c in d["candidates"]], "verdict": d["verdict"],
           "also_missing": d.get("also_missing", []), "combinations": d.get("combinations", []),
           "joint_candidates": d.get("joint_candidates", []),
           "noise_floor": d["noise_floor"], "error_before": d["error_before"],
           "noise_floor_source": d.get("noise_floor_source", {}), "gap_closed": d.get("gap_closed")}
    # the convention of every command's JSON: SI, and a units map where a key does not carry its unit
    from hil.ident.replay import UNITS
    per_channel = {c: (unit(c) if unit is not None else UNITS.get(c, "")) for c in d["noise_floor"]}
    out["units"] = {"noise_floor": per_channel, "error_before": per_channel}
    if "residual" in d:
        out["residual"] = d["residual"]
    for k in ("shown_together", "estimation", "validation", "run_to_run", "skill", "not_tried", "alternatives"):
        if k in d:
            out[k] = d[k]
    if "chain" in d:
        from hil.ident.chain import chain_json
        out["chain"] = chain_json(d["chain"])
        out["final"] = d["final"]
    return out


def run(args) -> int:
    from hil.ident.diagnosis import diagnose, not_tried
    from hil.ident.unexplained import HALF_GAP, describe
    if args.out and (args.no_chain or args.max_steps <= 1):
        # the single diagnosis adds nothing to the model: there is no config to write (it wrote
        # nothing and said nothing)
        raise UserError(f"--out {args.out}: the single diagnosis ({'--no-chain' if args.no_chain else '--max-steps 1'}) "
                        f"adds nothing to the model, so there is no config to write; drop --out, or let the chain run")
    cfg, metas, vals = load_records(args)
    names = args.candidates.split(",") if args.candidates else None
    check_candidates(names, cfg, "--candidates")
    rp = make_records(args, cfg, metas)     # the floor: the estimation records' alone, never --validate's
    sampling = None
    from hil.commands.progress import bar
    from hil.commands.record_inputs import prompt_interrupt
    val_rps = None
    # Ctrl-C ends it at once, inside the compiled fits too
    with prompt_interrupt(), bar("diagnose", args) as prog:
        if args.no_chain or args.max_steps <= 1:
            d = diagnose(rp, names, progress=prog, jobs=args.jobs, min_gap=HALF_GAP)
        else:
            d, cfg, rp, sampling = _chain_both_samplings(args, cfg, metas, rp, names, prog, vals)
            val_rps = [make_replay(args, cfg, m) for m in vals] or None
    # what the catalogue holds but this axis cannot have, and why (asked for by name, it was refused above)
    d["not_tried"] = {} if names else not_tried(rp.plant)
    # the first diagnosis's look-alikes, while the chain kept its verdict and found none of them itself
    added = {e for s in d.get("chain") or [] for e in s.effects}
    d["alternatives"] = [a for a in d.get("alternatives", []) if a["of"] == d["verdict"] and a["effect"] not in added]
    rr = run_to_run(d, rp)
    if rr is not None:
        d["run_to_run"] = rr
    from hil.ident.skill import skill, skill_text
    d["skill"] = skill(rp, d["error_before"], d["final"]["error"] if "final" in d else d["error_before"])
    table = None
    if len(metas) > 1 or vals:
        from hil.ident.records import estimation_validation
        fitted = d.get("config")
        if fitted is None:        # the single diagnosis: its verdict's fit
            lead = next((c for c in d["candidates"] if c.effect == d["verdict"]), None)
            fitted = lead.cfg if lead is not None else cfg
        val_rps = val_rps if val_rps is not None else [make_replay(args, cfg, m) for m in vals]
        table = estimation_validation(getattr(rp, "parts", [rp]), val_rps, fitted)
        d.update(table)
    if args.out and "config" in d:
        from pathlib import Path
        _write_config(args, d, ", ".join(Path(str(m.source)).name for m in metas))
    if args.report:
        write_html_report(args.report, d, rp, cfg, args, ", ".join(str(m.source) for m in metas))
    if args.json:
        out = candidates_json(d, rp.unit)
        if sampling is not None:
            out["torque_sampling"] = sampling
        if args.report:
            out["report"] = str(args.report)
        print(dumps(out, indent=1))
        return 0
    from hil.units import fmt_si
    said = skill_text(d["skill"], lambda c, v: fmt_si(v, rp.unit(c), 3))
    if not d["skill"]["has_skill"]:      # the answer before the candidates
        print(said.pop(0))
    for line in ranking_text(d, None if args.all_candidates else SHOWN_CANDIDATES):
        print(line)
    if "chain" in d:
        for line in chain_text(d, rp):
            print(line)
        from hil.ident.sampling import sampling_text
        for line in sampling_text(sampling):
            print(line)
    elif "residual" in d:
        for line in describe(d["residual"]):
            print("  " + line)
    if rr is not None:
        for line in run_to_run_text(rr, rp):
            print(line)
    for line in said:
        print(line)
    if table is not None:
        from hil.ident.records import errors_text
        for line in errors_text(table, rp.unit):
            print(line)
    if args.out and "config" in d:
        print(f"wrote {args.out}")
    if args.report:
        print(f"report: {args.report}")
    return 0


def _chain_both_samplings(args, cfg, metas, rp, names, prog, vals=()):
    """The chain, where the config does not say which torque the record holds, on both samplings
    where the choice can matter (hil.ident.sampling): (diagnosis, config, replay, JSON entry)."""
    from hil.ident.chain import diagnose_chain
    from hil.ident.sampling import diagnose_both
    parts = getattr(rp, "parts", [rp])
    has_force = not getattr(args, "open_loop", False) and any(p.force_channel for p in parts)
    replays = {id(cfg): rp}

    def replay_of(c):
        if id(c) not in replays:
            replays[id(c)] = make_records(args, c, metas)
        return replays[id(c)]
    def chain(r):
        # every step earns its place on data it was not fitted on: the --validate records (replayed
        # through this sampling's config), else the record's moves in pairs
        holdout = [make_replay(args, r.cfg, m) for m in vals] or "moves"
        return diagnose_chain(r, names, max_steps=args.max_steps, progress=prog, jobs=args.jobs, holdout=holdout)
    d, used, entry = diagnose_both(chain, cfg, replay_of, has_force)
    return d, used, replay_of(used), entry


def ranking_text(d, limit: int | None = None) -> list[str]:
    """The diagnosis as a person reads it: the verdict first, with the score that decided it (a
    combination's when simpler effects fitted together were preferred to a richer one), the effects
    also missing beside it with their own (marginal) scores, then the other candidates by their
    score, best first, each listed once (the first ``limit``, and how many more; None: all); a
    richer effect that a combination mimics says so."""
    verdicts = {"none": "none (the model matches the record down to the noise floor)",
                "unexplained": "unexplained (above the noise floor, and no catalogue effect explains it)"}
    verdict = d["verdict"]
    cands = list(d["candidates"])
    by_name = {c.effect: c for c in cands}
    lead = next((cb for cb in d.get("combinations", []) if cb.get("preferred") and verdict in cb["effects"]), None)
    lines = []
    if verdict in by_name:
        c = by_name[verdict]
        if lead is not None:
            lines.append(f"verdict: {verdict} (with {' + '.join(e for e in lead['effects'] if e != verdict)}: "
                         f"combination score {lead['score']:.1f}, {100 * lead['explained']:.0f} % of the gain of "
                         f"{lead['explains']}; alone {c.score:.1f})")
        else:
            lines.append(f"verdict: {verdict} (score {c.score:.1f})")
        lines.append(f"    {c.evidence}")
    elif verdict == "none" and (d.get("final") or {}).get("tolerance"):
        t = d["final"]["tolerance"]
        lines.append(f"verdict: none (a drift of the config's masses, stiffnesses and dampings within their tolerance, "
                     f"plant.tolerance {100 * t['tolerance']:.3g} %: the config's own plant"
                     + ("" if d["final"]["at_noise_floor"] else "; the chain below says what stays above the floor")
                     + ")")
    else:
        lines.append(f"verdict: {verdicts.get(verdict, verdict)}")
    if d.get("shown_together"):
        lines.append(f"    {d['shown_together']}")
    shown = {verdict}
    from hil.ident.scores import MIN_SCORE
    for a in d.get("alternatives", []):
        lines.append(f"or {a['effect']} (score {a['score']:.1f}): this record cannot tell it from {verdict}, neither "
                     f"fit's residual beats the other's by a BIC of {MIN_SCORE:g}; a record that excites them "
                     f"differently would")
        lines.append(f"    {a['evidence']}")
        shown.add(a["effect"])
    for m in d.get("also_missing", []):
        lines.append(f"also missing: {m['effect']} (score {m['score']:.1f} in the joint fit beside {verdict}: "
                     f"the fall of the BIC when it is left out)")
        lines.append(f"    {m['evidence']}")
        shown.add(m["effect"])
    mimicked = {cb["explains"]: cb for cb in d.get("combinations", [])}
    rest = sorted((c for c in cands if c.effect not in shown), key=lambda c: -c.score)
    if rest:
        lines.append("other candidates, by score (BIC fall; * significant):")
    for i, c in enumerate(rest):
        if limit is not None and i >= limit:
            lines.append(f"     ... {len(rest) - limit} more, down to score {rest[-1].score:.1f} (--all lists them)")
            break
        mark = "*" if c.significant else " "
        note = ""
        cb = mimicked.get(c.effect)
        if cb is not None and cb.get("preferred"):
            note = (f" [mimicked by {' + '.join(cb['effects'])}: {100 * cb['explained']:.0f} % of its gain; "
                    f"against them it scores {cb['rich_against_combination']:.1f}]")
        lines.append(f"{i + 1:3d}{mark} {c.effect:26s} score {c.score:10.1f}  {c.evidence}{note}")
    for cb in d.get("combinations", []):
        if cb is lead:
            continue
        lines.append(f"combination {' + '.join(cb['effects'])} against {cb['explains']}: score {cb['score']:.1f}, "
                     f"{100 * cb['explained']:.0f} % of its gain, {cb['explains']} against it "
                     f"{cb['rich_against_combination']:.1f} -> "
                     f"{'named first' if cb['preferred'] else cb['explains'] + ' first'}")
    for j in d.get("joint_candidates", []):
        how = f"against {j['rival_of'].replace('+', ' + ')}" if j.get("rival_of") else "fitted together"
        lines.append(f"joint candidate {' + '.join(j['effects'])} ({how}): score {j['score']:.1f}, "
                     f"{100 * j['gain']:.0f} % of the weighted error removed, the second member "
                     f"{j['second_member_score']:.1f} on top -> {'named first' if j['preferred'] else 'not named'}")
    return lines + not_tried_text(d.get("not_tried"))


def not_tried_text(not_tried: dict | None) -> list[str]:
    """The catalogue effects this axis cannot have, one line per reason."""
    from hil.ident.diagnosis import by_reason
    return [f"not tried, cannot act on this axis: {', '.join(names)} ({why})"
            for why, names in by_reason(not_tried).items()]


def write_html_report(path, d, rp, cfg, args, record) -> None:
    """The diagnosis as one HTML file: the residual analysis of the start model and of the model with
    the chain (when the chain added something), the figures embedded (drawn in a temporary folder)."""
    import tempfile
    from pathlib import Path

    from hil.ident.residual_analysis import analyse
    from hil.io.safe_write import refuse_inputs
    from hil.plots.report import write_diagnosis_report
    from hil.plots.residual_figures import comparison_figures
    data = [args.data] if isinstance(args.data, str) else list(args.data)
    refuse_inputs(path, (*data, args.config, *(getattr(args, "validate", None) or [])))
    first = getattr(rp, "parts", [rp])[0]          # several records: the residual analysis of the first
    a = analyse(first)
    # the model the chain ends with: its steps, or the config's drift within its tolerance
    fitted = d.get("config") if d.get("chain") or (d.get("final") or {}).get("tolerance") else None
    b = analyse(first, fitted) if fitted is not None else None
    with tempfile.TemporaryDirectory(prefix="hil-diagnose-") as tmp:
        figs = comparison_figures(a, Path(tmp), after=b)
        write_diagnosis_report(Path(path), f"Diagnosis of {record} against {cfg.source}", candidates_json(d, rp.unit), a, figs,
                               after=b, record=record,
                               configs=[("model", cfg.source), ("model with the chain", args.out if b else None)],
                               cfg=cfg, validation=validation_tables(d, rp.unit))


def validation_tables(d, unit) -> list:
    """The estimation and validation records' errors (``estimation``/``validation`` of the
    diagnosis, hil.ident.records) as the report's table; none with one record and no --validate."""
    from hil.units import fmt_si
    rows = []
    for kind in ("estimation", "validation"):
        for r in d.get(kind, []):
            b, a = r["before"], r["after"]
            rows += [[kind, str(r["record"]), c, fmt_si(b["error"][c], unit(c)), fmt_si(a["error"][c], unit(c)),
                      f"{a['above_floor'][c]:.1f}", f"{a['relative_error'][c]:.3g}"] for c in a["error"]]
    if not rows:
        return []
    return [{"title": "Estimation and validation records",
             "note": "RMS error of the start model and of the model the diagnosis found; x floor: the ratio "
                     "to the record's own noise floor",
             "header": ["data", "record", "channel", "start", "found model", "x floor", "relative error %"],
             "rows": rows, "numeric": [3, 4, 5, 6]}]


def chain_text(d, rp) -> list[str]:
    """The error falling step by step: per step the effects added and the RMS error of each channel
    (before -> after, and its ratio to the noise floor), then the end."""
    from hil.ident.unexplained import describe
    from hil.plant_config import values_text
    from hil.units import fmt_si
    floor = {c: max(v, 1e-300) for c, v in d["noise_floor"].items()}
    chans = list(floor)
    lines = ["chain (RMS error per channel; x floor = ratio to the noise floor):",
             "  start: " + ", ".join(f"{c} {fmt_si(d['error_before'][c], rp.unit(c), 3)} "
                                     f"({d['error_before'][c] / floor[c]:.1f} x floor)" for c in chans)]
    tol = d["final"].get("tolerance")
    for s in d["chain"]:
        if tol is not None and s.step > tol["step"]:
            lines += [_tolerance_line(tol)] + _held_out_lines(tol, rp)
            tol = None
        added = " + ".join(s.effects)
        par = "; ".join(f"{n}: " + values_text(n, p) for n, p in s.params.items() if n in s.effects)
        lines.append(f"  step {s.step}: + {added}{' (all refitted together)' if s.refitted_together else ''}"
                     f" [{par}]")
        if s.recording_artefacts:
            lines.append(f"          {', '.join(s.recording_artefacts)}: a recording artefact, not physics "
                         f"(the config's [measurement]; the model of the axis unchanged)")
        if s.beyond_tolerance:
            b = s.beyond_tolerance
            lines.append(f"          the diagnosis named {b['verdict']}; the config's drift fitted within plant.tolerance "
                         f"{100 * b['tolerance']:.3g} % leaves {b['key'].split('.')[-1]} alone beyond it "
                         f"({100 * b['change']:+.1f} %)")
        if s.nights_plant:
            n = s.nights_plant
            # after a drift the model took at an earlier step, the drift fitted again beside the step
            again = s.step in ((d.get("final") or {}).get("tolerance") or {}).get("again_after", [])
            where, before = (("the drift fitted again beside it", "with the drift as it stood") if again else
                             ("on the night's plant", "on the config's plant"))
            lines.append(f"          {where} (within plant.tolerance {100 * n['tolerance']:.3g} %, no finding): "
                         + ", ".join(f"{k.split('.')[-1]} {100 * p['change']:+.2f} %" for k, p in n["params"].items())
                         + f"; {before} " + ", ".join(
                             f"{c} {fmt_si(n['error_on_config_plant'][c], rp.unit(c), 3)}" for c in chans))
            lines += [x.replace("          estimation", f"          {where.split(' beside')[0]}: estimation", 1)
                      for x in _held_out_lines(n, rp)]
        for e in s.dropped or []:
            par = values_text(e["effect"], e["params"])
            why = (f"replaced: {added} pays more in its place" if s.swapped == e["effect"] else
                   "no longer pays beside this step's effects")
            lines.append(f"          - {e['effect']} [{par}]: {why} (BIC score {e['score']:.1f}): dropped from the model")
        lines.append("          " + ", ".join(f"{c} {fmt_si(s.error_before[c], rp.unit(c), 3)} -> "
                                           f"{fmt_si(s.error_after[c], rp.unit(c), 3)} "
                                           f"({s.error_after[c] / floor[c]:.1f} x floor)" for c in chans))
        lines += _held_out_lines(s, rp)
    f = d["final"]
    if tol is not None:
        lines += [_tolerance_line(tol)] + _held_out_lines(tol, rp)
    for r in f.get("also_refused", []) + ([f["rejected"]] if "rejected" in f else []):
        what = (f"the config's drift within its tolerance ({', '.join(r['effects'])} and the other masses, stiffnesses "
                f"and dampings)" if "tolerance" in r else " + ".join(r["effects"]))
        then = "; the next verdict tried without it" if r.get("next_tried") else ""
        if r.get("confounded_with"):
            then = f"; confounded with what was found: {r['confounded_with']}" + then
        lines.append(f"  refused: + {what} (BIC score {r['score']:.1f} on the whole record{then})")
        lines += _held_out_lines(r, rp)
    lines.append(f"end: {f['end']}; " + ("every channel at its noise floor" if f["at_noise_floor"] else
                                         "the residual stays above the noise floor:"))
    if "residual" in f:
        lines += ["  " + x for x in describe(f["residual"])]
    if not f["at_noise_floor"]:
        # above the floor: how far above each part of it (the quantization, the standstill noise, the
        # spread of repeated records)
        from hil.ident.chain import floor_parts_text
        lines += floor_parts_text(f, rp.unit)
    return lines


def _tolerance_line(t) -> str:
    from hil.plant_config import values_text
    line = (f"  step {t['step']}: a drift within the config's tolerance (plant.tolerance {100 * t['tolerance']:.3g} %), "
            f"no finding; the config's values fitted within it: " +
            ", ".join(f"{k.split('.')[-1]} {100 * p['change']:+.2f} %" for k, p in t["params"].items()))
    if t.get("in_place_of"):
        line += " (in place of " + ", ".join(t["in_place_of"]) + ": it leaves nothing for them)"
    if t.get("dropped"):
        line += "; no longer pays beside it, dropped from the model: " + ", ".join(e["effect"] for e in t["dropped"])
    if t.get("again_after"):
        line += " (fitted again after step " + ", ".join(str(n) for n in t["again_after"]) + ")"
    if t.get("refitted"):
        line += ("; refitted with them: " + "; ".join(
            f"{n}: " + values_text(n, p) for n, p in t["refitted"].items()))
    return line


def run_to_run(d, rp) -> dict | None:
    """The error of the final model against each part of the noise floor, where the records hold
    repetitions of one test (hil.ident.noise.run_to_run_spread); None where they do not."""
    from hil.ident.unexplained import AT_FLOOR
    spread = {c: v for c, v in getattr(rp, "spread", {}).items() if v > 0}    # a copied channel has none
    if not spread:
        return None
    err = d["final"]["error"] if "final" in d else d["error_before"]
    others = [c for c in err if c not in spread]
    src = getattr(rp, "noise_sources", {})
    parts = {}
    for c in spread:
        sensor, q = src.get(c, {}).get("sensor"), src.get(c, {}).get("quantization", 0.0) / 12 ** 0.5
        parts[c] = {"spread": spread[c], "sensor": sensor}
        if q and (sensor is None or abs(q - sensor) > 1e-9 * q):       # said once where the floor is the grid
            parts[c]["quantization"] = q
    over = {c: {k: (err[c] / v if v else None) for k, v in parts[c].items()} for c in spread}
    return {"spread": dict(spread), "floor_parts": parts, "error_over": over,
            "within": (all(err[c] <= AT_FLOOR * spread[c] for c in spread)
                       and all(err[c] <= AT_FLOOR * d["noise_floor"][c] for c in others))}


def run_to_run_text(r, rp) -> list[str]:
    from hil.units import fmt_si
    lines = []
    for c, over in r["error_over"].items():
        bits = [f"{over[k]:.3g} x the {name} ({fmt_si(r['floor_parts'][c][k], rp.unit(c), 3)})"
                for k, name in (("spread", "run-to-run spread"), ("sensor", "record's own floor"),
                                ("quantization", "quantization")) if over.get(k) is not None]
        lines.append(f"  {c}: the error is " + ", ".join(bits))
    head = ("within the run-to-run spread: the model is as close to each record as repetitions of the same "
            "command are to each other" if r["within"] else
            "above the run-to-run spread of the repeated records")
    return [f"run-to-run: {head}"] + lines


def _held_out_lines(s, rp) -> list[str]:
    """A chain step on its estimation and held-out data, and its confounded parameters (``s`` a
    :class:`~hil.ident.result.ChainStep`, or the refused step's or the tolerance's mapping)."""
    from hil.units import fmt_si
    lines = []
    if "held_out" in s:
        h = s["held_out"]
        lines.append("          estimation " + ", ".join(f"{c} {fmt_si(v, rp.unit(c), 3)}"
                                                       for c, v in s["estimation_error"].items()) +
                     "; held out " + ", ".join(f"{c} {fmt_si(h['before'][c], rp.unit(c), 3)} -> "
                                               f"{fmt_si(h['after'][c], rp.unit(c), 3)}" for c in h["before"]) +
                     f"; weighted error {100 * h['fall']:.1f} % less (+- {100 * h['uncertainty']:.1f} %): "
                     f"{'earned' if h['earned'] else 'not earned'}")
        kept = s["effects"] if "effects" in s else []
        for m, f in (h.get("members") or {}).items():
            lines.append(f"          {m} on its own: {100 * f['fall']:.1f} % less than the step without it "
                         f"(+- {100 * f['uncertainty']:.1f} %, the rest refitted on the held-out moves "
                         f"{100 * f.get('model_refit_fall', 0.0):.1f} %): " +
                         ("earned" if f["earned"] else "not earned, taken out of the step" if m not in kept
                          else "not earned"))
    if s.get("confounded"):
        lines.append("          confounded: " + ", ".join(f"{a} and {b} (r = {r:+.3f})" for a, b, r in s["confounded"]))
    for eff, al in (s.get("aliases") or {}).items():
        # one fitted parameter standing for a config's (m3 for k2 / m3): the finding may be the other
        # one; an effect of several takes up a related drift by construction (a second mode's mass and
        # frequency, m3's) and its fit is its own: JSON only
        conf = [a for a in al if a["confounded"] and len(a["params"]) == 1]
        if conf:
            lines.append(f"          {eff} is confounded with the config's " + ", ".join(_alias_text(a) for a in conf))
    return lines


def _alias_text(a) -> str:
    """One alias in words: the key, the correlation and what 1 % of drift in it shows as."""
    what = "their ratio is what the record fixes" if a["r"] > 0 else "their product is what the record fixes"
    moves = ", ".join(f"{p} {0.01 * v:+.4g}" for p, v in zip(a["params"], a["slope"]))
    return f"{a['key']} (r = {a['r']:+.3f}: {what}; 1 % more {a['key']} shows here as {moves})"


def _write_config(args, d, source) -> None:
    """--out: the config with the chain, as an edit of --config (hil.io.config_write: only the keys
    the chain changed, the file's comments, layout and units kept)."""
    from pathlib import Path

    from hil.io.config_write import write_config
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    data = [args.data] if isinstance(args.data, str) else list(args.data)
    write_config(args.out, args.config, d["config"], note=f"hil diagnose on {source}",
                 inputs=(args.config, *data, *(getattr(args, "validate", None) or [])))
