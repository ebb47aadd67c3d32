"""``hil diagnose``: which physical effect is the model missing?"""
from __future__ import annotations

import sys

from hil.commands.compare import add_common, load_inputs, make_replay
from hil.errors import UserError
from hil.io.jsonout import dumps

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
"""


def add_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--candidates", default=None, help="comma-separated candidates (default: the whole catalogue)")
    parser.add_argument("--jobs", type=int, default=None, help="processes (default: the CPUs)")
    parser.add_argument("--max-steps", "--steps", dest="max_steps", type=int, default=4, metavar="N",
                        help="at most N steps in the chain, each a diagnosis that adds its verdict (default 4; "
                             "1: the single diagnosis, as --no-chain)")
    parser.add_argument("--no-chain", action="store_true", help="the single diagnosis, nothing added")
    parser.add_argument("--out", default=None, metavar="FILE", help="write the config with the whole chain (TOML)")
    parser.add_argument("--report", default=None, metavar="FILE",
                        help="write an HTML report (one self-contained file): the verdict, the ranking, the chain, "
                             "and the residual analysis of the start model and of the model with the chain")


def candidates_json(d):
    out = {"candidates": [c.as_json() for c in d["candidates"]], "verdict": d["verdict"],
           "also_missing": d.get("also_missing", []), "combinations": d.get("combinations", []),
           "noise_floor": d["noise_floor"], "error_before": d["error_before"],
           "noise_floor_source": d.get("noise_floor_source", {}), "gap_closed": d.get("gap_closed")}
    if "residual" in d:
        out["residual"] = d["residual"]
    if "chain" in d:
        from hil.ident.chain import chain_json
        out["chain"] = chain_json(d["chain"])
        out["final"] = d["final"]
    return out


def run(args) -> int:
    from hil.ident.chain import diagnose_chain
    from hil.ident.diagnosis import diagnose
    from hil.ident.unexplained import HALF_GAP, describe
    from hil.plant_config import candidate
    cfg, meas = load_inputs(args)
    rp = make_replay(args, cfg, meas)
    names = args.candidates.split(",") if args.candidates else None
    for n in names or []:
        try:
            candidate(n, cfg)
        except KeyError as exc:
            raise UserError(str(exc).strip("'\"")) from None
    try:
        from tqdm import tqdm
        bar = tqdm(desc="diagnose", unit="fit", file=sys.stderr, disable=None)
        prog = lambda n: (bar.update(1), bar.set_postfix_str(n))  # noqa: E731
    except ImportError:
        bar, prog = None, lambda n: print(f"  fitting {n}", file=sys.stderr)
    from hil.commands.compare import prompt_interrupt
    with prompt_interrupt():           # Ctrl-C ends it at once, inside the compiled fits too
        if args.no_chain or args.max_steps <= 1:
            d = diagnose(rp, names, progress=prog, jobs=args.jobs, min_gap=HALF_GAP)
        else:
            d = diagnose_chain(rp, names, max_steps=args.max_steps, progress=prog, jobs=args.jobs)
    if bar is not None:
        bar.close()
    if args.out and "config" in d:
        _write_config(args.out, d, meas.source)
    if args.report:
        write_html_report(args.report, d, rp, cfg, args, meas.source)
    if args.json:
        out = candidates_json(d)
        if args.report:
            out["report"] = str(args.report)
        print(dumps(out, indent=1))
        return 0
    verdicts = {"none": "none (the model matches the record down to the noise floor)",
                "unexplained": "unexplained (above the noise floor, and no catalogue effect explains it)"}
    print(f"verdict: {verdicts.get(d['verdict'], d['verdict'])}")
    for i, c in enumerate(d["candidates"]):
        mark = "*" if c.significant else " "
        print(f"{i + 1:2d}{mark} {c.effect:26s} score {c.score:10.1f}  {c.evidence}")
    for m in d.get("also_missing", []):
        print(f"also missing: {m['effect']} (score {m['score']:.1f} beside {d['verdict']}): {m['evidence']}")
    for cb in d.get("combinations", []):
        print(f"combination {' + '.join(cb['effects'])} against {cb['explains']}: score {cb['score']:.1f}, "
              f"{100 * cb['explained']:.0f} % of its gain, {cb['explains']} against it {cb['rich_against_combination']:.1f}"
              f" -> {'named first' if cb['preferred'] else cb['explains'] + ' first'}")
    if "chain" in d:
        for line in chain_text(d, rp):
            print(line)
    elif "residual" in d:
        for line in describe(d["residual"]):
            print("  " + line)
    if args.out and "config" in d:
        print(f"wrote {args.out}")
    if args.report:
        print(f"report: {args.report}")
    return 0


def write_html_report(path, d, rp, cfg, args, record) -> None:
    """The diagnosis as one HTML file: the residual analysis of the start model and of the model with
    the chain (when the chain added something), the figures embedded (drawn in a temporary folder)."""
    import tempfile
    from pathlib import Path

    from hil.ident.compare import analyse
    from hil.io.safe_write import refuse_inputs
    from hil.plots.compare import comparison_figures
    from hil.plots.report import write_diagnosis_report
    refuse_inputs(path, (args.data, args.config))
    a = analyse(rp)
    fitted = d.get("config") if d.get("chain") else None
    b = analyse(rp, fitted) if fitted is not None else None
    with tempfile.TemporaryDirectory(prefix="hil-diagnose-") as tmp:
        figs = comparison_figures(a, Path(tmp), after=b)
        write_diagnosis_report(Path(path), f"Diagnosis of {record} against {cfg.source}", candidates_json(d), a, figs,
                               after=b, record=record,
                               configs=[("model", cfg.source), ("model with the chain", args.out if b else None)],
                               cfg=cfg)


def chain_text(d, rp) -> list[str]:
    """The error falling step by step: per step the effects added and the RMS error of each channel
    (before -> after, and its ratio to the noise floor), then the end."""
    from hil.ident.unexplained import describe
    floor = {c: max(v, 1e-300) for c, v in d["noise_floor"].items()}
    chans = list(floor)
    lines = ["chain (RMS error per channel; x floor = ratio to the noise floor):",
             "  start: " + ", ".join(f"{c} {d['error_before'][c]:.3g} {rp.unit(c)} ({d['error_before'][c] / floor[c]:.1f} x floor)"
                                     for c in chans)]
    for s in d["chain"]:
        added = " + ".join(s["effects"])
        par = "; ".join(f"{n}: " + ", ".join(f"{k} {v:.4g}" for k, v in p.items()) for n, p in s["params"].items()
                        if n in s["effects"])
        lines.append(f"  step {s['step']}: + {added}{' (all refitted together)' if s['refitted_together'] else ''}"
                     f" [{par}]")
        lines.append("          " + ", ".join(f"{c} {s['error_before'][c]:.3g} -> {s['error_after'][c]:.3g} "
                                           f"({s['error_after'][c] / floor[c]:.1f} x floor)" for c in chans))
    f = d["final"]
    lines.append(f"end: {f['end']}; " + ("every channel at its noise floor" if f["at_noise_floor"] else
                                         "the residual stays above the noise floor:"))
    if "residual" in f:
        lines += ["  " + x for x in describe(f["residual"])]
    return lines


def _write_config(path, d, source) -> None:
    from pathlib import Path
    added = [" + ".join(s["effects"]) for s in d["chain"]]
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(f"# fitted by hil diagnose on {source}: chain {', '.join(added) or '(nothing added)'}\n"
                          + d["config"].to_toml(), encoding="utf-8")
