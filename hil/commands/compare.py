"""``hil compare``: replay a measurement through the model and show where it fails."""
from __future__ import annotations

from pathlib import Path

from hil.io.jsonout import dumps

HELP = "model against measurement: errors per channel and motion phase, residual analysis, plots, HTML report"
DESCRIPTION = """\
Replays the measured command (x_cmd) through the config's model with the same loops and sets the
simulated channels against the measured ones: RMS, peak, NRMSE fit %, relative error %, overshoot
difference, error per motion phase, residual spectrum peaks, whiteness (99 % band), correlation
with the command and with v, a, x. Writes overlay/residual/spectrum/scatter PNGs and report.html.

  hil compare data.csv --config config/paper_bench.toml
  hil compare DATA_EMPS.mat --config config/emps.toml --map t=t,qg=x_cmd,qm=x_motor,vir*gtau=force
  hil compare data.csv --config old.toml --after new.toml     (before and after side by side)
"""


def add_common(parser) -> None:
    parser.add_argument("data", help="measurement: CSV in the project's format, or a MATLAB .mat record")
    parser.add_argument("--config", required=True, metavar="FILE", help="axis configuration (TOML)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    parser.add_argument("--map", action="append", default=[], metavar="SOURCE=CHANNEL[unit]",
                        help="column or variable -> channel, the same for CSV and .mat: pos=x_table[mm], "
                             "vir*gtau=force (repeatable, or comma-separated)")
    parser.add_argument("--channels", default=None, help="comma-separated channels to use (default: all measured)")
    parser.add_argument("--align", action="store_true", help="align each channel in time by cross-correlation")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def add_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--after", metavar="FILE", help="a second (fitted) config to compare beside the first")
    parser.add_argument("--out", default="out/compare", metavar="DIR", help="folder for the plots and report.html")


def load_inputs(args):
    """The config (``--config`` with ``--set``) and the record (``data`` with ``--map``)."""
    from hil.config import load, parse_assignment
    from hil.io.importers import parse_mapping, read_any
    cfg = load(args.config, dict(parse_assignment(s) for s in args.set))
    return cfg, read_any(args.data, parse_mapping(args.map) or None)


def make_replay(args, cfg, meas):
    """The record replayed through the config, on the ``--channels`` asked for, ``--align``-ed."""
    from hil.ident.replay import Replay
    chans = args.channels.split(",") if getattr(args, "channels", None) else None
    return Replay(meas, cfg, chans, align=getattr(args, "align", False))


def strip(analysis):
    return {k: v for k, v in analysis.items() if not k.startswith("_")}


def run(args) -> int:
    from hil.config import load
    from hil.ident.compare import analyse
    from hil.plots.compare import comparison_figures
    from hil.plots.report import write_report
    cfg, meas = load_inputs(args)
    rp = make_replay(args, cfg, meas)
    a = analyse(rp)
    b = analyse(rp, load(args.after)) if args.after else None
    out = Path(args.out)
    figs = comparison_figures(a, out, after=b)
    rep = write_report(out / "report.html", f"{meas.source} against {cfg.source}", a, figs, after=b)
    if args.json:
        print(dumps({"before": strip(a), "after": strip(b) if b else None, "report": str(rep),
                          "figures": [str(f) for f in figs]}, indent=1))
    else:
        for c, d in a["channels"].items():
            e = b["channels"][c] if b else None
            line = f"{c:8s} RMS {d['rms']:.4g} {d['unit']}  peak {d['peak']:.4g}  fit {d['fit']:.2f} %  rel {d['relative_error']:.4g} %"
            if e:
                line += f"   after: RMS {e['rms']:.4g}  fit {e['fit']:.2f} %  rel {e['relative_error']:.4g} %"
            print(line)
        print(f"report: {rep}")
    return 0
