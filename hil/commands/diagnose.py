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
otherwise the verdict is "none" (no significant missing effect). A richer effect that simpler ones
can mimic (asymmetric_friction: coulomb_friction + constant_force) is compared with them fitted
jointly; when they explain most of its gain they are named first (verdict, then "also_missing").

  hil diagnose data.csv --config config/paper_bench.toml --json
  hil diagnose data.csv --config config/paper_bench.toml --candidates coulomb_friction,parameter:plant.c2
"""


def add_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--candidates", default=None, help="comma-separated candidates (default: the whole catalogue)")
    parser.add_argument("--jobs", type=int, default=None, help="processes (default: the CPUs)")


def candidates_json(d):
    return {"candidates": [c.as_json() for c in d["candidates"]], "verdict": d["verdict"],
            "also_missing": d.get("also_missing", []), "combinations": d.get("combinations", []),
            "noise_floor": d["noise_floor"], "error_before": d["error_before"]}


def run(args) -> int:
    from hil.ident.diagnosis import diagnose
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
        d = diagnose(rp, names, progress=prog, jobs=args.jobs)
    if bar is not None:
        bar.close()
    if args.json:
        print(dumps(candidates_json(d), indent=1))
        return 0
    print(f"verdict: {d['verdict'] if d['verdict'] != 'none' else 'none (no significant missing effect)'}")
    for i, c in enumerate(d["candidates"]):
        mark = "*" if c.significant else " "
        print(f"{i + 1:2d}{mark} {c.effect:26s} score {c.score:10.1f}  {c.evidence}")
    for m in d.get("also_missing", []):
        print(f"also missing: {m['effect']} (score {m['score']:.1f} beside {d['verdict']}): {m['evidence']}")
    for cb in d.get("combinations", []):
        print(f"combination {' + '.join(cb['effects'])} against {cb['explains']}: score {cb['score']:.1f}, "
              f"{100 * cb['explained']:.0f} % of its gain, {cb['explains']} against it {cb['rich_against_combination']:.1f}"
              f" -> {'named first' if cb['preferred'] else cb['explains'] + ' first'}")
    return 0
