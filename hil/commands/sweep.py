"""``hil sweep``: overshoot against commanded jerk, and the largest jerk a tolerance allows."""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path

from hil.errors import LimitError, UnitError, UserError
from hil.io.jsonout import JsonKey, dumps
from hil.io.safe_write import save_figure, write_atomic
from hil.units import parse_list, parse_option

HELP = "jerk sweep: overshoot vs. jerk, the largest safe jerk for a tolerance, 2-dof vs. 3-dof"
DESCRIPTION = """\
Run one sine-square move per jerk value (from rest, plus a dwell that captures the residual
vibration) and report per run: j_max, a_max, t_acc, overshoot of table and tip (whole move and
dwell, floored at 0), peak following errors, residual tip vibration, settling times.

Jerks: --tacc (the NC's acceleration times; j_max = 2 a_max^2 / V_f, a_max = pi G0 / (2 t_acc)),
or --jmax as a list (10,20,50) or a log-spaced range (1..2000 with --points, default 40).
Analyses (--analysis): mechatronic (the closed loops on the simulated plant, default),
transmission (Section 3: the motor follows the path, x2 = TF2 x1, x3 = TF3 x2), or both.

--tolerance 8um: the most conservative largest jerk (first crossing of the tip overshoot,
refined by bisection on the simulated overshoot) and every admissible interval.
--compare CONFIG: the same for another model (the 2-dof one) and the error of its estimate.
Local minima (vibration cancellation) are listed and explained with the dominant frequency; a
jerk minimizing the tip overshoot within a move-time budget is proposed (--budget).

Runs go to all cores (--jobs) or to a Dask cluster (--scheduler); every finished run is kept
in --out/runs.jsonl, so an interrupted sweep resumes where it stopped (--restart: start over).

examples:
  hil sweep --config config/paper_bench.toml --stroke 590mm --feed 15m/min --g0 30m/min \\
      --tacc 60ms,80ms,90ms,100ms,151ms,200ms,250ms,280ms,300ms
  hil sweep --config config/paper_bench.toml --compare config/paper_bench_2dof.toml \\
      --stroke 590mm --feed 15m/min --jmax 1..2000m/s^3 --points 40 --tolerance 8um --json
"""

CSV_FIELDS = ("model", "analysis", "grid", "j_max", "a_max", "t_acc", "peak_speed", "ramp_time", "duration",
              "overshoot_table_um", "overshoot_tip_um", "peak_following_error_table_um",
              "peak_following_error_tip_um", "residual_tip_um", "settling_time_table", "settling_time_tip",
              "peak_torque", "f_dom_tip_hz")


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints). sweep.json in --out holds the same.
_TOL = "with --tolerance"
_CMP = "with --compare"
_CMP_TOL = "with --compare and --tolerance"
_RUN = "runs[]"
JSON_KEYS = {
    "config": JsonKey("", "path of the config"),
    "name": JsonKey("", "meta.name of the config"),
    "move": JsonKey("m, m/s, s", "the moves: stroke_m, feed_m_per_s, g0_m_per_s, dwell_s (as run: at least what "
                                 "the overshoot needs), record_period_s (of the dominant-frequency estimate), swept "
                                 "(`j_max` or `t_acc`)"),
    "analysis": JsonKey("", "`mechatronic`, `transmission` or `both` (--analysis)"),
    "runs": JsonKey("", "one entry per run of the primary analysis, by jerk (entries runs[].*); refinement and "
                        "proposal runs are not in it"),
    f"{_RUN}.j_max": JsonKey("m/s^3", "peak jerk"),
    f"{_RUN}.a_max": JsonKey("m/s^2", "peak acceleration"),
    f"{_RUN}.t_acc": JsonKey("s", "NC acceleration time (from G0; null without G0)"),
    f"{_RUN}.peak_speed": JsonKey("m/s", "peak speed"),
    f"{_RUN}.ramp_time": JsonKey("s", "duration of one acceleration ramp"),
    f"{_RUN}.duration": JsonKey("s", "duration of the move"),
    f"{_RUN}.overshoot_table_um": JsonKey("um", "overshoot of the table (whole move and dwell, floored at 0)"),
    f"{_RUN}.overshoot_tip_um": JsonKey("um", "overshoot of the tool tip"),
    f"{_RUN}.peak_following_error_table_um": JsonKey("um", "largest |x_cmd - x_table|"),
    f"{_RUN}.peak_following_error_tip_um": JsonKey("um", "largest |x_cmd - x_tip|"),
    f"{_RUN}.residual_tip_um": JsonKey("um", "half the peak-to-peak tip motion in the dwell"),
    f"{_RUN}.settling_time_table": JsonKey("s", "until the table stays within 1 um (null: not settled)"),
    f"{_RUN}.settling_time_tip": JsonKey("s", "the same for the tip"),
    f"{_RUN}.peak_torque": JsonKey("N*m or N", "largest motor torque (rotary) or force (linear)"),
    f"{_RUN}.f_dom_tip_hz": JsonKey("Hz", "dominant frequency of the tip's residual vibration (null: too little)"),
    f"{_RUN}.refine": JsonKey("", "a refinement or proposal run (false in runs: the grid)"),
    "runs_transmission": JsonKey("", "the transmission analysis' runs, as runs", when="--analysis both"),
    "tolerance_um": JsonKey("um", "the tip overshoot tolerance", when=_TOL),
    "max_jerk": JsonKey("m/s^3", "the most conservative largest jerk keeping the tip overshoot within the "
                                 "tolerance (null: none in the range)", when=_TOL),
    "max_jerk_t_acc": JsonKey("s", "the NC acceleration time of max_jerk (null without G0)", when=_TOL),
    "admissible": JsonKey("m/s^3", "every admissible jerk interval [low, high], each checked by runs (split "
                                   "where one inside exceeds the tolerance)", when=_TOL),
    "verification": JsonKey("um", "the check of max_jerk by runs just below it: runs, spacing_rel, "
                                  "largest_overshoot_um, moved, peaks (j_max, overshoot_tip_um), bracket_rel; "
                                  "null when not checked", when=_TOL),
    "compare_config": JsonKey("", "path of the compared config", when=_CMP),
    "compare_name": JsonKey("", "its meta.name", when=_CMP),
    "compare_runs": JsonKey("", "its runs, as runs", when=_CMP),
    "compare_runs_transmission": JsonKey("", "its transmission runs", when="--compare and --analysis both"),
    "max_jerk_compare": JsonKey("m/s^3", "max_jerk of the compared model", when=_CMP_TOL),
    "admissible_compare": JsonKey("m/s^3", "its admissible intervals", when=_CMP_TOL),
    "verification_compare": JsonKey("um", "its verification", when=_CMP_TOL),
    "estimate_error_pct": JsonKey("%", "100 (max_jerk_compare - max_jerk) / max_jerk_compare: how far the compared "
                                       "model's estimate is off", when=_CMP_TOL),
    "dominant_frequency_hz": JsonKey("Hz", "median dominant tip frequency of the runs (null: no vibration)"),
    "local_minima": JsonKey("m/s^3, um, s", "overshoot dips: j_max, t_acc, overshoot_tip_um, ramp_time, and f_dom_hz, "
                                            "cycles, explanation (f_dom T_r = k + 1/2)"),
    "predicted_cancellation": JsonKey("m/s^3, s", "jerks where the ramp cancels the dominant vibration: k, cycles, "
                                                  "ramp_time, j_max"),
    "answer": JsonKey("m/s^3", "the answer to the question asked, as the report's headline and the text's first line "
                               "give it: question, j_max (with --tolerance the largest jerk within it; else the "
                               "proposal's), text"),
    "proposal": JsonKey("m/s^3, s, um", "the jerk minimizing the tip overshoot within the time budget: j_max, t_acc, "
                                        "a_max, duration, overshoot_tip_um, overshoot_table_um, residual_tip_um, "
                                        "budget_s, fastest_s, analysis (or j_max null and a note)"),
    "note": JsonKey("", "what could not be answered, and a dwell extended, in words (null: nothing)"),
    "stats": JsonKey("", "computed and reused (from runs.jsonl) runs"),
    "files": JsonKey("", "paths written: csv, json, runs, plot (unless --no-plot), report"),
}


def add_arguments(p) -> None:
    p.add_argument("--config", required=True, metavar="FILE", help="axis configuration (TOML)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config parameter, e.g. --set plant.c2=33 (repeatable; applied to --compare "
                        "where that model has the parameter)")
    p.add_argument("--stroke", metavar="LENGTH", required=True, help="stroke of each move, e.g. 590mm")
    p.add_argument("--feed", metavar="SPEED", required=True, help="feed (peak speed), e.g. 15m/min")
    p.add_argument("--g0", metavar="SPEED", help="rapid speed G0 for t_acc (default: the config's nc.g0)")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--tacc", metavar="TIMES", help="acceleration times, e.g. 60ms,80ms,100ms (or a range 60ms..300ms with --points)")
    g.add_argument("--jmax", metavar="JERKS", help="jerks: a list 10,20,50m/s^3 or a log-spaced range 1..2000m/s^3")
    p.add_argument("--points", metavar="N", type=int, default=40, help="points of a range (default 40)")
    p.add_argument("--analysis", choices=("mechatronic", "transmission", "both"), default="mechatronic",
                   help="which model (default mechatronic; the JSON runs hold it unless transmission)")
    p.add_argument("--tolerance", metavar="LENGTH", help="tip overshoot tolerance, e.g. 8um: largest safe jerk and admissible intervals")
    p.add_argument("--compare", metavar="CONFIG", help="a second model (e.g. the 2-dof one) to compare with")
    p.add_argument("--budget", metavar="TIME|PERCENT", help="move-time budget for the proposed jerk: a time (2.5s) or a percent over the "
                                    "fastest move of the range (default 5%%)")
    p.add_argument("--dwell", metavar="TIME", help="standstill after each move (default: max(1 s, 10 periods of the lowest "
                                                   "mode); a shorter one than the overshoot needs is extended)")
    p.add_argument("--record-every", type=int, default=8, metavar="N",
                   help="velocity steps per sample of the dominant-frequency estimate (default 8 = 0.5 ms at 62.5 us; "
                        "the overshoot is taken at every velocity step)")
    p.add_argument("--jobs", metavar="N", type=int, help="local worker processes (default: all cores)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on a dask.distributed scheduler, e.g. "
                   "tcp://127.0.0.1:8786; another machine's only over tls:// or with --allow-remote-scheduler")
    p.add_argument("--allow-remote-scheduler", action="store_true",
                   help="accept a --scheduler on another machine without encryption: Dask unpickles what it "
                   "receives, so the scheduler and the network can run code here; only where you trust both")
    p.add_argument("--backend", metavar="NAME", help="run the moves on this runtime backend (canopen, serial, sim) instead of "
                                     "the compiled simulation; one after the other, with return moves")
    p.add_argument("--out", default="out/sweep", metavar="DIR", help="output folder (default out/sweep)")
    p.add_argument("--restart", action="store_true", help="forget the finished runs in --out and start over")
    p.add_argument("--no-plot", action="store_true", help="do not write the figure")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    from hil.commands.scope import add_scope_options
    add_scope_options(p)


# the most runs one sweep asks for (each is a whole closed-loop run; 10^8 grew to 6.9 GB)
MAX_POINTS = 10_000

_RANGE = re.compile(r"^\s*(.+?)\s*\.\.\s*(.+?)\s*$")


def parse_values(text: str, kind: str, points: int, what: str) -> list[float]:
    """A list ("60ms,80ms", "60,80ms") or a log-spaced range ("1..2000m/s^3", "60ms..300ms") of quantities,
    each with its unit (the last one's applies to the bare numbers before it)."""
    from hil.sweep import jerk_grid
    m = _RANGE.match(text)
    if m:                       # the unit of the high end applies to a bare low end; none at all: refused
        lo_t, hi_t = m.group(1), m.group(2)
        unit = re.sub(r"^[\s+\-0-9.eE]*", "", hi_t)
        if unit and re.fullmatch(r"[+\-]?[0-9.]+([eE][+\-]?[0-9]+)?", lo_t):
            lo_t = f"{lo_t} {unit}"
        try:
            lo, hi = parse_option(lo_t, kind, what), parse_option(hi_t, kind, what)
        except UnitError as exc:
            if unit:
                raise
            from hil.units import option_units
            first = option_units(kind).split(",")[0].strip()
            raise UserError(f"{exc}; a range carries the unit on its high end, e.g. "
                            f"{m.group(1)}..{m.group(2)}{first}") from None
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise UserError(f"{what} {text!r}: the range must be finite")
        try:
            return jerk_grid(lo, hi, points)
        except ValueError as exc:
            raise UserError(f"{what} {text!r}: {exc}") from None
    vals = parse_list(text, kind, what, option=True)
    if any(not v > 0 or not math.isfinite(v) for v in vals):
        raise UserError(f"{what}: every value must be positive and finite, got {text!r}")
    if len(vals) > MAX_POINTS:
        raise UserError(f"{what}: {len(vals)} values, at most {MAX_POINTS}")
    return sorted(set(vals))


def _budget(text):
    if text is None:
        return None, 5.0
    t = text.strip()
    if t.endswith("%"):
        try:
            pct = float(t[:-1])
        except ValueError:
            raise UserError(f"--budget: cannot read {text!r} (a time like 2.5s or a percent like 5%)") from None
        if pct < 0:
            raise UserError(f"--budget: the percent must be >= 0, got {text!r}")
        return None, pct
    v = parse_option(t, "time", "--budget")
    if not v > 0:
        raise UserError(f"--budget: must be positive, got {text!r}")
    return v, None


def settings_from_args(args, cfg):
    from hil.sweep import SweepSettings
    stroke = parse_option(args.stroke, "length", "--stroke")
    feed = parse_option(args.feed, "speed", "--feed")
    if stroke == 0:
        raise UserError("--stroke: must not be 0")
    if not feed > 0:
        raise UserError(f"--feed: must be positive, got {args.feed!r}")
    g0 = parse_option(args.g0, "speed", "--g0") if args.g0 else cfg.get("nc.g0")
    if not 2 <= args.points <= MAX_POINTS:
        raise UserError(f"--points: expected 2 .. {MAX_POINTS}, got {args.points}")
    if args.tacc:
        if not g0:
            raise UserError("--tacc needs the rapid speed G0: give --g0 or nc.g0 in the config")
        by, values = "t_acc", parse_values(args.tacc, "time", args.points, "--tacc")
    else:
        by, values = "j_max", parse_values(args.jmax, "jerk", args.points, "--jmax")
    tol = parse_option(args.tolerance, "length", "--tolerance") if args.tolerance else None
    if tol is not None and not tol > 0:
        raise UserError(f"--tolerance: must be positive, got {args.tolerance!r}")
    dwell = parse_option(args.dwell, "time", "--dwell") if args.dwell else None
    if dwell is not None and dwell < 0:
        raise UserError(f"--dwell: must be >= 0, got {args.dwell!r}")
    if args.record_every < 1:
        raise UserError(f"--record-every: must be >= 1, got {args.record_every}")
    budget, pct = _budget(args.budget)
    return SweepSettings(stroke=stroke, feed=feed, values=values, by=by, g0=g0, dwell=dwell,
                         record_every=args.record_every, analysis=args.analysis, tolerance=tol,
                         budget=budget, budget_pct=pct)


def write_csv(report: dict, path: Path) -> None:
    import io
    with io.StringIO(newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS, extrasaction="ignore")
        w.writeheader()
        an = "transmission" if report["analysis"] == "transmission" else "mechatronic"
        for model, key, a in (("main", "runs", an), ("main", "runs_transmission", "transmission"),
                              ("compare", "compare_runs", an),
                              ("compare", "compare_runs_transmission", "transmission")):
            for r in report.get(key) or []:
                w.writerow({**r, "model": model, "analysis": a, "grid": not r.get("refine")})
        write_atomic(path, fh.getvalue())


def _text(r: dict) -> str:
    from hil.sweep.sweep import sweep_answer
    mv = r["move"]
    lines = [f"answer: {(r.get('answer') or sweep_answer(r))['text']}",
             f"{r.get('name') or r['config']}: {len(r['runs'])} moves of {mv['stroke_m'] * 1e3:g} mm at "
             f"{mv['feed_m_per_s'] * 60:g} m/min ({r['analysis']}; dwell {mv['dwell_s']:g} s, recorded every "
             f"{mv['record_period_s'] * 1e3:g} ms)",
             f"{'j_max':>9} {'a_max':>7} {'t_acc':>7} {'over table':>10} {'over tip':>9} {'FE table':>9} "
             f"{'FE tip':>9} {'resid tip':>9} {'settle tip':>10}",
             f"{'m/s^3':>9} {'m/s^2':>7} {'ms':>7} {'um':>10} {'um':>9} {'um':>9} {'um':>9} {'um':>9} {'s':>10}"]

    def fmt(v, f):
        return "-" if v is None else format(v, f)

    for x in r["runs"]:
        lines.append(f"{x['j_max']:9.4g} {x['a_max']:7.3g} {fmt(x['t_acc'] and x['t_acc'] * 1e3, '7.1f')} "
                     f"{x['overshoot_table_um']:10.3f} {x['overshoot_tip_um']:9.3f} "
                     f"{x['peak_following_error_table_um']:9.1f} {x['peak_following_error_tip_um']:9.1f} "
                     f"{fmt(x['residual_tip_um'], '9.2f')} {fmt(x['settling_time_tip'], '10.3f')}")
    if r.get("tolerance_um") is not None:
        mj = r.get("max_jerk")
        lines.append(f"tolerance {r['tolerance_um']:g} um at the tip: max jerk "
                     + (f"{mj:.4g} m/s^3 (t_acc {r['max_jerk_t_acc'] * 1e3:.0f} ms)" if mj and r.get("max_jerk_t_acc")
                        else f"{mj:.4g} m/s^3" if mj else "none in range"))
        lines.append("  admissible: " + (", ".join(f"[{a:.4g}, {b:.4g}]" for a, b in r["admissible"]) or "none"))
        if "max_jerk_compare" in r:
            mc = r["max_jerk_compare"]
            lines.append(f"  {r.get('compare_name') or r['compare_config']}: max jerk "
                         + (f"{mc:.4g} m/s^3" if mc else "none in range")
                         + (f"; its estimate is off by {r['estimate_error_pct']:.1f} %"
                            if r.get("estimate_error_pct") is not None else ""))
    if r.get("local_minima"):
        lines.append(f"overshoot dips (dominant tip frequency {r['dominant_frequency_hz']:.2f} Hz):"
                     if r.get("dominant_frequency_hz") else "overshoot dips:")
        for m in r["local_minima"]:
            lines.append(f"  j_max {m['j_max']:.4g} m/s^3: {m['overshoot_tip_um']:.2f} um; "
                         + m.get("explanation", ""))
    p = r.get("proposal")
    if p:
        if p.get("j_max"):
            lines.append(f"proposed: j_max {p['j_max']:.4g} m/s^3"
                         + (f" (t_acc {p['t_acc'] * 1e3:.0f} ms)" if p.get("t_acc") else "")
                         + f": tip overshoot {p['overshoot_tip_um']:.2f} um, move {p['duration']:.3f} s"
                         + (f" (budget {p['budget_s']:.3f} s)" if p.get("budget_s") else ""))
        else:
            lines.append(f"proposal: {p.get('note')}")
    if r.get("note"):
        lines.append(f"note: {r['note']}")
    st = r.get("stats", {})
    lines.append(f"{st.get('computed', 0)} runs computed, {st.get('reused', 0)} taken from earlier runs; "
                 + ", ".join(f"{k}: {v}" for k, v in (r.get("files") or {}).items()))
    return "\n".join(lines)


def run(args) -> int:
    from hil.commands.progress import shown
    from hil.config import load, parse_assignment
    from hil.sweep import run_sweep

    overrides = dict(parse_assignment(s) for s in args.set)
    cfg = load(args.config, overrides)
    cmp_cfg = None
    if args.compare:
        cmp_cfg = load(args.compare)
        shared = {k: v for k, v in overrides.items() if k in cmp_cfg.keys()}   # e.g. control gains
        cmp_cfg = load(args.compare, shared) if shared else cmp_cfg
    s = settings_from_args(args, cfg)
    if args.scheduler:
        from hil.sweep.executors import check_scheduler_address
        check_scheduler_address(args.scheduler, args.allow_remote_scheduler)
    from hil.supervisor import refuse_if_tripped
    refuse_if_tripped(cfg)             # a trip not reset refuses motion on every backend
    from hil.commands.scope import check_scope_options
    check_scope_options(args)          # before anything runs
    if args.scope and not args.backend:
        raise UserError("--scope: the model sweep moves no axis (it runs the compiled model in worker processes); "
                        "with --backend sim, canopen or serial its moves run through the runtime, and the scope "
                        "shows them")
    # an unstable loop has no overshoot to report (issue 18): refused, for the compared model too
    from hil.closed_loop import check_loop_stability
    for c in (cfg, cmp_cfg):
        if c is not None and s.analysis != "transmission":
            check_loop_stability(c)
    if s.analysis != "mechatronic" and cfg.n_masses < 2:
        raise UserError(f"--analysis {s.analysis}: the transmission analysis needs a chain of at least 2 masses")
    # the configs' input shapers (nc.shaper: a sweep compares shaped and plain commands by --compare),
    # checked before any run; the transmission analysis takes the plain profile
    from hil.shaping import config_shaper
    for c in (cfg, cmp_cfg):
        if c is None:
            continue
        try:
            sh = config_shaper(c)
        except ValueError as exc:
            raise UserError(str(exc)) from None
        if sh is not None and s.analysis != "mechatronic":
            raise UserError(f"{c.source}: nc.shaper {sh}: the transmission analysis takes the plain profile; "
                            f"shaped commands are swept with --analysis mechatronic")
    if args.jobs is not None and args.jobs < 1:
        raise UserError(f"--jobs: must be >= 1, got {args.jobs}")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out {args.out}: cannot create the folder ({exc.strerror or exc})") from None
    from hil.commands.scope import scope_for
    try:
        with scope_for(args, cfg, "sweep") as ring:
            report = run_sweep(cfg, s, compare_cfg=cmp_cfg, out_dir=out, jobs=args.jobs, scheduler=args.scheduler,
                               backend=args.backend, progress=not args.no_progress and shown(args),
                               resume=not args.restart, scope=ring, can_log=getattr(args, "can_log", None))
    except LimitError as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        if args.scheduler:
            raise UserError(f"--scheduler {args.scheduler}: cannot reach it ({exc})") from None
        raise
    except Exception as exc:
        # a backend that cannot be opened, or a scheduler address that is not one
        from drivers import BackendError
        if isinstance(exc, BackendError) or (args.scheduler and isinstance(exc, (ValueError, TimeoutError))):
            raise UserError(str(exc)) from None
        raise
    if cmp_cfg is not None:
        report["compare_name"] = cmp_cfg.get("meta.name", "")
    files = {"csv": str(out / "sweep.csv"), "json": str(out / "sweep.json"), "runs": str(out / "runs.jsonl")}
    write_csv(report, out / "sweep.csv")
    if not args.no_plot:
        from hil.plots.sweep import sweep_figure
        fig = sweep_figure(report)
        save_figure(fig, out / "sweep.png", dpi=110)
        import matplotlib.pyplot as plt
        plt.close(fig)
        files["plot"] = str(out / "sweep.png")
    from hil.plots.report import write_sweep_report
    files["report"] = str(out / "report.html")
    report["files"] = files
    write_sweep_report(out / "report.html", report, [out / "sweep.png"] if "plot" in files else [])
    write_atomic(out / "sweep.json", dumps(report, indent=2))
    if args.json:
        print(dumps(report, indent=2))
    else:
        print(_text(report))
    return 0
