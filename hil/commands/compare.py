"""``hil compare``: replay a measurement through the model and show where it fails."""
from __future__ import annotations

from pathlib import Path

from hil.commands.record_inputs import add_common, load_inputs, make_replay, prompt_interrupt
from hil.errors import UserError
from hil.io.jsonout import JsonKey, dumps

HELP = "model against measurement: errors per channel and motion phase, residual analysis, plots, HTML report"
DESCRIPTION = """\
Replays the measured command (x_cmd) through the config's model with the same loops and sets the
simulated channels against the measured ones: RMS, peak, NRMSE fit %, relative error %, overshoot
difference, error per motion phase, residual spectrum peaks, whiteness (99 % band), correlation
with the command and with v, a, x, for the model and (--after) the fitted one. Writes the
overlay/residual/spectrum/scatter/correlation PNGs and report.html (one self-contained file, the figures
embedded).

  hil compare data.csv --config config/paper_bench.toml
  hil compare DATA_EMPS.mat --config config/emps.toml --map t=t,qg=x_cmd,qm=x_motor,vir*gtau=force
  hil compare pulses.csv --config config/paper_bench.toml          (a u_add channel: added after the controller)
  hil compare idf.mat --config motor.toml --open-loop --map "data[:,0]=t,data[:,2]=x_motor,data[:,4]=torque"
  hil compare log.txt --config lina.toml --map "data[:,0]=t[ms],data[:,2]=x_cmd[mm],data[:,3]=x_motor[mm]"
      (a maxon log: column 2 is the profile generator's demand, the command the loop follows; column 1 its target)
  hil compare data.csv --config old.toml --after new.toml     (before and after side by side)
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
CHANNEL_UNIT = "the channel's (m, N*m, N, V)"
JSON_KEYS = {
    "answer": JsonKey("", "the answer first: whether the model (the --after model where given) explains the record "
                          "down to its noise floor on every channel, then the evidence (each channel's fit, where the "
                          "residual is not white)"),
    "before": JsonKey("", "the analysis of the --config model against the record (keys before.*)"),
    "after": JsonKey("", "the same analysis of the --after model; null without --after"),
    "report": JsonKey("", "path of the self-contained report.html"),
    "figures": JsonKey("", "paths of the PNG figures written to --out"),
    "interactive": JsonKey("", "path of interactive.html: the overlay and residual of every channel, to zoom and pan "
                               "(self-contained, offline)"),
    "warnings": JsonKey("", "what deserves a look in the record (outliers, gaps, a slow log), one sentence each"),
    "before.channels": JsonKey(CHANNEL_UNIT, "per compared channel: rms, peak and noise_floor of the residual (the "
                                             "third-difference estimate) and record_floor (the record's own floor, "
                                             "quantization or standstill noise, as the diagnosis judges) in the "
                                             "channel's SI unit, named by unit; fit (NRMSE fit, %), relative_error "
                                             "(%), for positions overshoot_difference, following_error_rms_measured "
                                             "and _simulated (m); phase_rms (per motion phase), spectrum_peaks "
                                             "(frequency Hz, amplitude), whiteness (band_99, fraction_outside, white), "
                                             "cross_correlation_command (max, lag_s, band_99), correlation "
                                             "coefficients with velocity, acceleration, position, sign_velocity"),
    "before.phases": JsonKey("", "the motion phases the error is split into (names)"),
    "before.sample_period": JsonKey("s", "sample period of the record"),
    "before.shifts": JsonKey("samples", "per channel, the time shift --align applied (empty without it)"),
    "before.inputs": JsonKey("", "what drives the replay besides the command (open loop, u_add), in words"),
}


def add_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--after", metavar="FILE", help="a second (fitted) config to compare beside the first")
    parser.add_argument("--out", default="out/compare", metavar="DIR", help="folder for the plots and report.html")


# records this long report their progress on stderr (shorter ones only on a terminal)
PROGRESS_ROWS = 100_000


def progress(rows: int, quiet: bool = False):
    """A function that prints one progress line on stderr, or does nothing for a short record
    that is not run from a terminal (the one-line error contract of the tests and scripts), and
    nothing with ``quiet`` (--json)."""
    import sys
    import time
    if quiet or (rows < PROGRESS_ROWS and not sys.stderr.isatty()):
        return lambda msg: None
    t0 = time.perf_counter()
    return lambda msg: print(f"  [{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)


def strip(analysis):
    return {k: v for k, v in analysis.items() if not k.startswith("_")}


def run(args) -> int:
    from hil.config import load
    from hil.ident.residual_analysis import analyse
    from hil.plots.report import write_report
    from hil.plots.residual_figures import comparison_figures
    cfg, meas = load_inputs(args)
    after = load(args.after) if args.after else None
    if after is not None and after.rotary != cfg.rotary:
        kind = {True: "rotary", False: "linear"}
        raise UserError(f"--after {args.after}: a {kind[after.rotary]} actuator, --config {cfg.source} a "
                        f"{kind[cfg.rotary]} one: the models compared on one record must drive the same axis")
    say = progress(meas.t.size, quiet=args.json)
    with prompt_interrupt():
        say(f"replaying {meas.t.size} samples through {cfg.source}")
        rp = make_replay(args, cfg, meas)
        say("analysing the residuals")
        a = analyse(rp)
        b = analyse(rp, after) if after is not None else None
    say("writing the figures and the report")
    out = Path(args.out)
    figs = comparison_figures(a, out, after=b)
    from hil.plots.interactive import write_interactive
    title = f"{meas.source} against {cfg.source}"
    live = write_interactive(a, out / "interactive.html", title, after=b)
    notes = a["inputs"] + [f"warning: {w}" for w in meas.warnings]
    rep = write_report(out / "report.html", title, a, figs, after=b, notes=notes,
                       record=meas.source, configs=[("model", cfg.source), ("fitted model", after and after.source)],
                       interactive=live.name)
    from hil.plots.report import compare_verdict
    answer = compare_verdict(a, b)
    if args.json:
        print(dumps({"answer": answer, "before": strip(a), "after": strip(b) if b else None, "report": str(rep),
                     "figures": [str(f) for f in figs], "interactive": str(live), "warnings": meas.warnings},
                    indent=1))
    else:
        from hil.ident.scores import fmt_fit
        from hil.units import fmt_si
        print(answer.split(". ", 1)[0] + ".")          # the answer, then the numbers behind it
        for c, d in a["channels"].items():
            e = b["channels"][c] if b else None
            u = d["unit"]
            line = (f"{c:8s} RMS {fmt_si(d['rms'], u):>10s}  peak {fmt_si(d['peak'], u):>10s}  fit {fmt_fit(d['fit'])}  "
                    f"rel {_rel(d['relative_error'])}")
            if e:
                line += f"   after: RMS {fmt_si(e['rms'], u)}  fit {fmt_fit(e['fit'])}  rel {_rel(e['relative_error'])}"
            print(line)
        print(f"report: {rep}")
    return 0


def _rel(value) -> str:
    """A relative error in the text: undefined (a measured channel of zero RMS) says so, not 'nan %'."""
    return "undefined" if value is None or value != value else f"{value:.4g} %"
