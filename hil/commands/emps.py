"""``hil emps``: the EMPS benchmark end to end, against its published reference model (the chain
itself is hil.ident.emps)."""
from __future__ import annotations

import shutil
from pathlib import Path

from hil.errors import UserError
from hil.io.jsonout import JsonKey, dumps
from hil.io.safe_write import write_atomic

HELP = "EMPS record: effects added one by one, fitted parameters and errors beside the published reference"
DESCRIPTION = """\
Reads DATA_EMPS.mat (mapping t, qg -> x_cmd, qm -> x_motor, vir*gtau -> force), starts from
config/emps.toml (published M and Fv, no Coulomb friction, no offset), runs the diagnosis chain of
hil diagnose (coulomb_friction and constant_force, then asymmetric_friction), and beside it the
published inverse model refitted by output error (M, Fv, Fc and the offset jointly, simulation in
the loop), then asymmetric_friction from its inverse model. Errors are relative 2-norm errors in %, 100 ||y - y_sim|| / ||y||,
of the position qm, of the velocity the controller sees (backward difference of the two-tap
filtered position) and of the force gtau*vir.

  hil emps --data ../shared/data/emps/DATA_EMPS.mat --out out/emps

--validate DATA_EMPS_PULSES.mat (the benchmark's validation record, when you have it) replays it
through the models fitted on --data (the chain's model among them), its pulses entering as the
u_add input, and sets its errors beside the published validation figures (position 0.0080 %,
force 8.94 %). Every step of the chain earns its place on the validation record (without it, on
the record's own held-out moves); the table gives each step's estimation and held-out errors.

  hil emps --data DATA_EMPS.mat --validate DATA_EMPS_PULSES.mat --out out/emps
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints). The errors are the benchmark's: relative 2-norm errors in %.
_PARAMS = ("M (kg), Fv (N*s/m), Fc (N), offset (N); with asymmetric friction M, offset, level_pos, level_neg (N), "
           "viscous_pos, viscous_neg (N*s/m) (it sets the dry and viscous friction anew: no Fv, Fc)")
JSON_KEYS = {
    "rows": JsonKey("", "the table: one row per model, from the published reference to the fitted ones "
                        "(entries rows[].*)"),
    "rows[].step": JsonKey("", "the model, in words"),
    "rows[].short": JsonKey("", "a short label (figures)", when="every row but the published reference"),
    "rows[].params": JsonKey("kg, N*s/m, N", "the rigid model's parameters in the benchmark's names: " + _PARAMS),
    "rows[].position": JsonKey("%", "relative error of the position qm"),
    "rows[].velocity": JsonKey("%", "relative error of the velocity the controller sees"),
    "rows[].force": JsonKey("%", "relative error of the force gtau*vir"),
    "rows[].inverse_force": JsonKey("%", "relative error of the inverse model on the force",
                                    when="the inverse-model rows (IDIM-LS, + asymmetric_friction)"),
    "rows[].inverse_params": JsonKey("kg, N*s/m, N", "the asymmetric inverse model's M, Fv+, Fv-, Fc+, Fc-",
                                     when="the + asymmetric_friction row"),
    "published": JsonKey("kg, N*s/m, N, %", "the published IDIM-LS model (Janot et al. 2019): M, Fv, Fc, offset, "
                                            "and its errors (position, velocity, force, %)"),
    "check": JsonKey("%, N", "the output-error fit against the published: deviation (M, Fv, Fc in %, offset_N in N), "
                             "within_5_percent_and_0.5_N, errors_match_or_beat_published"),
    "diagnosis": JsonKey("", "each diagnosis of the chain: on (the model), verdict, ranking (effect, score, "
                             "significant, evidence), also_missing, combinations; empty with --no-diagnose"),
    "out": JsonKey("", "the output folder (--out)"),
    "validation": JsonKey("%", "per fitted model on each --validate record: model, record, position, velocity, "
                               "force; empty without --validate"),
    "published_validation": JsonKey("%", "the published validation errors: position, force"),
    "chain": JsonKey("", "the diagnosis chain's steps as `hil diagnose --json`'s chain[] (effects, params, errors "
                         "in SI), each with estimation_error and held_out (before, after, fall, uncertainty, "
                         "earned): on the --validate records, else on the record's held-out moves",
                     when="the diagnosis runs (not --no-diagnose)"),
    "chain_final": JsonKey("", "the end of the chain as `hil diagnose --json`'s final (error, noise_floor, end, "
                               "held_out, rejected)", when="the diagnosis runs (not --no-diagnose)"),
}

# the validation rows' label of the chain's model (hil.ident.chain), beside the output-error refits
CHAIN_MODEL = "the diagnosis chain's model"


# the record in the project's shared folder, beside a clone (not shipped with the package)
DEFAULT_DATA = "../shared/data/emps/DATA_EMPS.mat"


def add_arguments(parser) -> None:
    parser.add_argument("--data", metavar="FILE", default=DEFAULT_DATA,
                        help="the EMPS .mat record, DATA_EMPS.mat (default: the shared folder beside a clone, "
                             f"{DEFAULT_DATA})")
    # by name: the clone's config/emps.toml, else the shipped example (an installed package has no
    # config/ beside it: the path of this file's grandparent was site-packages/config/emps.toml)
    parser.add_argument("--config", default="config/emps.toml", metavar="FILE",
                        help="the EMPS axis (default config/emps.toml, shipped)")
    parser.add_argument("--out", default="out/emps", metavar="DIR")
    parser.add_argument("--quick", action="store_true", help="fewer iterations (tests)")
    parser.add_argument("--no-diagnose", action="store_true", help="skip the diagnosis rankings (faster)")
    parser.add_argument("--docs", metavar="DIR", default=None,
                        help="also copy the figures as emps_*.png into DIR (e.g. docs)")
    parser.add_argument("--validate", action="extend", nargs="+", default=[], metavar="RECORD",
                        help="validation record(s) (DATA_EMPS_PULSES.mat): errors of the fitted models on them, beside "
                             "the published validation figures")
    parser.add_argument("--json", action="store_true")


def missing_record_message(data: str) -> str:
    """Where the EMPS record was looked for, what it is, where to get it and how to give it."""
    where = (f"looked for it at {data}, the project's shared folder beside a clone of the repository"
             if data == DEFAULT_DATA else f"{data}: no such file")
    return (f"hil emps needs the EMPS benchmark's identification record DATA_EMPS.mat (not shipped with the "
            f"package): {where} (resolved from {Path.cwd()}); get it from the benchmark's archive EMPS.zip "
            f"(nonlinear system identification benchmarks, 'EMPS'; the documentation's 'Get the EMPS record') "
            f"and give its path: hil emps --data PATH/DATA_EMPS.mat")


def run(args) -> int:
    from hil.ident.emps import (
        PUBLISHED,
        PUBLISHED_VALIDATION,
        chain_markdown,
        diagnosis_markdown,
        run_emps,
        table_markdown,
        validate_emps,
        validation_markdown,
    )
    from hil.ident.residual_analysis import analyse
    from hil.plots.report import write_report
    from hil.plots.residual_figures import comparison_figures, error_fall_figure
    if not Path(args.data).exists():
        raise UserError(missing_record_message(args.data))
    for v in args.validate:
        if not Path(v).exists():
            raise UserError(f"--validate {v}: no such file (the EMPS validation record DATA_EMPS_PULSES.mat)")
    from hil.commands.progress import bar
    with bar("emps", args) as prog:
        res = run_emps(args.data, args.config, args.quick, progress=prog, diagnose_steps=not args.no_diagnose,
                       validate=args.validate)
    rows, cfgs, diags = res.rows, res.configs, res.diagnoses
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # the fitted models as edits of the start config: its comments, layout and units kept, only the
    # fitted keys changed (hil.io.config_write, as hil fit and hil diagnose --out write theirs)
    from hil.io.config_write import write_config
    note = f"hil emps on {Path(args.data).name}"
    write_config(out / "emps_fitted.toml", args.config, cfgs["fitted"], note=note, inputs=(args.data, args.config))
    from hil.plant_config import without_replaced
    write_config(out / "emps_asymmetric.toml", args.config, without_replaced(cfgs["asymmetric"]), note=note,
                 inputs=(args.data, args.config))
    a, b = analyse(res.replay, cfgs["start"]), analyse(res.replay, cfgs["fitted"])
    figs = comparison_figures(a, out, after=b)
    figs.append(error_fall_figure(rows[1:], out / "error_fall.png"))
    md = table_markdown(rows)
    chk = res.check
    diag_md = diagnosis_markdown(diags)
    from hil.ident.emps import with_rigid
    val = []
    models = {"published reference (our loop)": with_rigid(cfgs["start"], PUBLISHED),
              "output-error refit of M, Fv, Fc, offset": cfgs["fitted"],
              "+ asymmetric_friction": cfgs["asymmetric"]}
    if res.chain is not None:           # the chain's model is validated beside the refits
        models[CHAIN_MODEL] = res.chain["config"]
    for v in args.validate:
        val += validate_emps(v, models)
    val_md = validation_markdown(val) if val else ""
    chain_md = chain_markdown(res.chain) if res.chain is not None else ""
    write_atomic(out / "table.md", md + "\n\n" + diag_md + "\n" + (f"\n{chain_md}\n" if chain_md else "")
                 + (f"\n{val_md}\n" if val_md else ""))
    from hil.plots.interactive import write_interactive
    title = "EMPS: start model against measurement, and the fitted model"
    write_interactive(a, out / "interactive.html", title, after=b, names=("start model", "fitted model"))
    write_report(out / "report.html", title, a, figs, after=b, interactive="interactive.html",
                 record=args.data, configs=[("start model", args.config), ("fitted model", out / "emps_fitted.toml")],
                 emps={"rows": rows, "published": PUBLISHED, "check": chk, "diagnoses": diags},
                 names=("start model", "fitted model"), validation=_chain_tables(res.chain) + _validation_tables(val))
    if args.docs:
        d = Path(args.docs)
        d.mkdir(parents=True, exist_ok=True)
        for f in figs:
            shutil.copy(f, d / f"emps_{Path(f).name}")
    if args.json:
        doc = {"rows": rows, "published": PUBLISHED, "check": chk, "diagnosis": diags, "out": str(out),
               "validation": val, "published_validation": PUBLISHED_VALIDATION}
        if res.chain is not None:
            from hil.ident.chain import chain_json
            doc.update(chain=chain_json(res.chain["chain"]), chain_final=res.chain["final"])
        print(dumps(doc, indent=1))
    else:
        print(md)
        print(diag_md)
        if chain_md:
            print(chain_md)
        if val_md:
            print(val_md)
        dev = chk["deviation"]
        print(f"output-error fit against published: M {dev['M']:+.2f} %, Fv {dev['Fv']:+.2f} %, Fc {dev['Fc']:+.2f} %, "
              f"offset {dev['offset_N']:+.3f} N; within 5 % / 0.5 N: {chk['within_5_percent_and_0.5_N']}; "
              f"errors match or beat the published: {chk['errors_match_or_beat_published']}")
        print(f"report: {out / 'report.html'}")
    return 0


def _chain_tables(chain) -> list:
    """The chain's steps with their estimation and held-out (validation) errors, as the report's table."""
    if chain is None:
        return []
    steps = list(chain["chain"]) + ([dict(chain["final"]["rejected"], step="refused")]
                                    if "rejected" in chain["final"] else [])
    rows = [[str(s["step"]), " + ".join(s["effects"]), c, f"{s['estimation_error'][c]:.4g}",
             f"{s['held_out']['before'][c]:.4g}", f"{s['held_out']['after'][c]:.4g}",
             f"{100 * s['held_out']['fall']:.1f} +- {100 * s['held_out']['uncertainty']:.1f}",
             "yes" if s["held_out"]["earned"] else "no"]
            for s in steps if "held_out" in s for c in s["estimation_error"]]
    if not rows:
        return []
    return [{"title": "The chain's steps: estimation and held-out errors",
             "note": f"RMS error per channel (SI: m, N); held out: {chain['final'].get('held_out', '')}; "
                     f"end: {chain['final']['end']}",
             "header": ["step", "added", "channel", "estimation", "held out before", "held out after",
                        "weighted fall %", "earned"],
             "rows": rows, "numeric": [3, 4, 5]}]


def _validation_tables(rows) -> list:
    """The EMPS validation errors (hil.ident.emps.validate_emps) beside the published validation
    figures, as the report's validation table (hil.plots.report)."""
    if not rows:
        return []
    from hil.ident.emps import PUBLISHED_VALIDATION as p
    body = [[r["model"], f"{r['position']:.4f}", f"{r['velocity']:.3f}", f"{r['force']:.2f}"] for r in rows]
    body.append(["published validation (Janot et al. 2019)", str(p["position"]), "", str(p["force"])])
    return [{"title": "Validation on DATA_EMPS_PULSES.mat (not used for the fit)",
             "note": "relative 2-norm errors, 100 ||y - y_sim|| / ||y||, %",
             "header": ["model (fitted on DATA_EMPS.mat)", "position %", "velocity %", "force %"],
             "rows": body, "numeric": [1, 2, 3]}]
