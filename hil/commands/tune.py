"""``hil tune``: tune the cascade against margins, shape the command for the tip, verify, write a config."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from hil.errors import UserError
from hil.io.jsonout import JsonKey, dumps
from hil.units import parse_angle_deg, parse_gain_db, parse_option

HELP = "tune the gains against margins, shape the command for the tool tip, verify, write a tuned config"
DESCRIPTION = """\
Commissioning in one command, on any backend (the simulated plant by default):
  1. pre-checks: the move fits the limits; a loop the model shows unstable gets its velocity
     gain halved until stable;
  2. the frequency responses measured as 'hil frf' measures them; the velocity gain, then the
     position gain, set to 0.9 x the largest that keeps --pm and --gm on the loop as measured,
     each measured again (backed off while a margin is short);
  3. for the move given (--stroke, --feed): NC acceleration times from 100 to 400 ms, each
     without a shaper and through ZV, ZVD, EI and SI shapers for the tip's mode as measured, run on
     the model (its mode moved to where it was measured) and with its modes off by the fit's
     uncertainty, at least --mode-error (5 %); the one whose tip is within --tolerance earliest
     in the worst case is chosen;
  4. a verification move on the backend, supervised, that measures when the tip is within the
     tolerance.
Writes DIR/tuned.toml (the input config with every changed key, each with its reason: the
gains, nc.t_acc, nc.g0, nc.shaper), so that 'hil move --config DIR/tuned.toml --stroke ...
--feed ...' alone makes the tuned move, DIR/tune.json, and DIR/tune.html, the report (the answer
first, the margins and the tip's arrival before and after, every command tried). Nothing is
written to a drive.

  hil tune --config config/paper_bench.toml --stroke 100mm --feed 7000mm/min --tolerance 5um --out out/tune
"""

# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
JSON_KEYS = {
    "answer": JsonKey("", "one sentence: the tuned move's tip within the tolerance after how long, against the "
                          "move as given"),
    "changes": JsonKey("SI", "every changed config key: key, before, after, reason"),
    "margins_before": JsonKey("deg, dB, Hz", "velocity_loop and position_loop as measured with the given gains: "
                                             "phase_margin_deg, gain_margin_db, crossover_hz, bandwidth_hz"),
    "margins_after": JsonKey("deg, dB, Hz", "the same, measured with the tuned gains"),
    "modes": JsonKey("Hz, 1", "the modes fitted in the last measurement (as hil frf's modes)"),
    "mode_error": JsonKey("", "relative frequency error the shaper was chosen to tolerate"),
    "candidates": JsonKey("s", "every command tried: t_acc_s, shaper, settle_s (tip within the tolerance, from "
                               "the start of the move, on the model), settle_worst_s (with the mode error), move_s"),
    "choice": JsonKey("s", "the candidate chosen (null: none brought the tip within the tolerance)"),
    "verified": JsonKey("s", "the verification move on the backend: backend, settle_s (null: not within the "
                             "tolerance), given_settle_s (the move with the given config and --tacc), status"),
    "steps": JsonKey("", "what was done, in order"),
    "tuned_config": JsonKey("", "path of the tuned config"),
    "plot": JsonKey("", "path of tune.png: the tip's arrival before and after, the shapers' residual vibration "
                        "against the mode's frequency error", when="without --no-plot"),
    "report": JsonKey("", "path of tune.html: the answer, the changes and their reasons, the margins before and "
                          "after, every command tried with the one chosen first, the verification, the figures "
                          "(tune.png and tune_loops.png, the open loops as measured before and after)"),
}


REFERENCE_DWELL = 5.0       # s of standstill after the move as given (the reference of the answer)


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p)
    p.add_argument("--sim-set", action="append", default=[], metavar="KEY=VALUE",
                   help="change the simulated plant only, not the model (to rehearse a plant unlike its model; "
                        "simulated backend), repeatable")
    p.add_argument("--stroke", metavar="LENGTH", required=True, help="signed stroke of the move to tune for, e.g. 100mm")
    p.add_argument("--feed", metavar="SPEED", required=True, help="feed of the move, e.g. 7000mm/min")
    p.add_argument("--tolerance", metavar="LENGTH", default="5um",
                   help="the tool tip's tolerance around its target (default 5um)")
    p.add_argument("--tacc", metavar="TIME", default="200ms",
                   help="the NC acceleration time of the move as given, the reference of the answer (default 200ms)")
    p.add_argument("--mode-error", metavar="PERCENT", default="5%",
                   help="the least frequency error of the tip's mode the command must tolerate (default 5%%; 0%%: "
                        "the fastest at the mode as measured, e.g. a ZV, which rings again if the mode moves)")
    p.add_argument("--pm", metavar="ANGLE", default="45deg", help="phase margin to keep (default 45deg)")
    p.add_argument("--gm", metavar="GAIN", default="8dB", help="gain margin to keep (default 8dB)")
    p.add_argument("--dwell", metavar="TIME", default="600ms",
                   help="standstill after each move, to see the tip settle (default 600ms)")
    p.add_argument("--out", metavar="DIR", default="out/tune", help="output folder (default out/tune)")
    p.add_argument("--no-plot", action="store_true", help="no figure (tune.png)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _frf_args(args) -> argparse.Namespace:
    """``hil frf``'s options at their defaults, with this command's config, --set and backend."""
    from hil.commands import frf
    p = argparse.ArgumentParser()
    frf.add_arguments(p)
    ns = p.parse_args(["--config", args.config])
    ns.set, ns.backend, ns.sim_set = list(args.set), args.backend, list(args.sim_set)
    for k in ("interface", "channel", "bitrate"):
        setattr(ns, k, getattr(args, k, None))
    if hasattr(args, "can_log"):
        ns.can_log = args.can_log
    ns.json = True
    return ns


def _settle_on_backend(cfg, backend_name, traj, stroke: float, tol: float, out: Path, name: str,
                       can_log=None) -> tuple[dict, dict | None]:
    """A move on the backend (supervised, limits checked before motion), and when the tip is
    within ``tol`` for good, from the record; and the record's channels with the target (None:
    the move did not complete)."""
    from drivers import BackendError
    from hil.backends import open_backend
    from hil.runtime import run_trajectory
    from hil.tune import tip_settle_time
    try:
        backend = open_backend(cfg, backend_name, can_log=can_log)
    except BackendError as exc:
        raise UserError(str(exc)) from None
    rec = run_trajectory(cfg, traj, backend=backend, out_file=out / f"{name}.csv", settle=0.0, start="follow")
    ch = rec.channels
    if rec.status != "complete" or len(ch["t"]) < 2:
        return {"backend": backend.name, "status": str(rec.status), "reason": rec.reason, "settle_s": None}, None
    target = rec.start + stroke
    s = tip_settle_time(ch["t"], ch["x_tip"], target, tol)
    return ({"backend": backend.name, "status": str(rec.status), "settle_s": s if math.isfinite(s) else None,
             "record": str(rec.path)}, dict(ch, target=target))


def run(args) -> int:
    from hil import tune
    from hil.commands.frf import check_margins, measure_axis
    from hil.commands.move import load_config
    from hil.commands.progress import shown
    from hil.config import parse_assignment
    from hil.io.config_write import write_config
    from hil.profiles import AxisLimits, LimitError, MoveSpec, Trajectory, check_limits
    cfg = load_config(args)
    pm_min, gm_min_db = parse_angle_deg(args.pm, "--pm"), parse_gain_db(args.gm, "--gm")
    check_margins(pm_min, gm_min_db)
    stroke, feed = parse_option(args.stroke, "length", "--stroke"), parse_option(args.feed, "speed", "--feed")
    tol = parse_option(args.tolerance, "length", "--tolerance")
    t_acc0, dwell = parse_option(args.tacc, "time", "--tacc"), parse_option(args.dwell, "time", "--dwell")
    if not tol > 0:
        raise UserError(f"--tolerance {args.tolerance}: expected a positive length, e.g. 5um")
    least = _percent(args.mode_error, "--mode-error")
    say = (lambda m: print(f"tune: {m}", file=sys.stderr, flush=True)) if shown(args) else (lambda m: None)
    g0 = cfg.get("nc.g0") or AxisLimits.from_config(cfg).speed
    given = Trajectory()
    try:                                      # pre-check: the move as given fits the limits
        given.move(MoveSpec(stroke, feed, t_acc=t_acc0, g0=g0))
        given.dwell(max(dwell, REFERENCE_DWELL))      # long enough to see it settle without a shaper
        check_limits(given, AxisLimits.from_config(cfg))
    except (ValueError, LimitError) as exc:
        raise UserError(f"the move as given: {exc}") from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    changes, steps = [], []
    cfg0 = cfg
    cfg = tune.stable_start(cfg, changes)
    frf_args = _frf_args(args)

    def measure(c):
        say(f"measuring the frequency responses (kp {c['control.kp']:.4g}, kv {c['control.kv']:.4g})")
        return measure_axis(frf_args, c, pm_min, gm_min_db)[0]
    cfg, first, last = tune.tune_gains(cfg, measure, pm_min, gm_min_db, changes, steps)
    before, after = tune.margins_of(first), tune.margins_of(last)
    mode = tune.tip_mode(last.modes)
    say("choosing the command: acceleration times and shapers on the model")
    cands, choice, eps = tune.choose_command(cfg, mode, stroke, feed, tol, dwell, least_error=least,
                                             progress=lambda f: say(f"{f:.0%} of the acceleration times tried"))
    if choice is not None:
        new = {"nc.t_acc": choice.t_acc, "nc.shaper": str(choice.shaper) if choice.shaper else "none"}
        if cfg.get("nc.g0") is None:
            new["nc.g0"] = g0
        for k, v in new.items():
            if cfg.get(k) != v:
                where = (f"worst case over modes +-{eps:.0%} off" if eps >= 0.001 else
                         "at the mode as measured, no error tolerated")
                changes.append(tune.Change(k, cfg.get(k), v, f"the fastest of {len(cands)} commands tried to bring "
                                           f"the tip within {tol * 1e6:g} um, {where}"))
        cfg = cfg.with_values(new)
    steps.append(f"tried {len(cands)} commands on the model; chose {choice.label if choice else 'none'}")
    say("verification moves on the backend")
    backend_name = args.backend or cfg.get("backend.type", "sim")
    can_log = getattr(args, "can_log", None)
    if args.sim_set and backend_name != "sim":
        raise UserError("--sim-set changes the simulated plant only; it has no meaning with --backend " + backend_name)
    plant = dict(parse_assignment(s) for s in args.sim_set)
    true = (lambda c: c.with_values(plant)) if plant else (lambda c: c)      # the plant the moves run on
    verified, tuned_rec = {}, None
    if choice is not None:
        traj = tune.command_trajectory(stroke, feed, choice.t_acc, cfg.get("nc.g0") or g0, dwell, choice.shaper)
        verified, tuned_rec = _settle_on_backend(true(cfg), backend_name, traj, stroke, tol, out, "tuned_move", can_log)
    ref, given_rec = _settle_on_backend(true(cfg0), backend_name, given, stroke, tol, out, "given_move", can_log)
    verified["given_settle_s"] = ref.get("settle_s")
    steps.append("verified on the backend: the tuned move and the move as given")
    tuned_path = out / "tuned.toml"
    notes = {}
    for c in changes:                         # the last reason of each key beside it
        notes[c.key] = f"hil tune: {c.reason}"
    write_config(tuned_path, cfg0.source, cfg, note=notes)
    res = tune.TuneResult(_answer(tol, verified, choice), changes, before, after, last.modes, eps, cands, choice,
                          verified, steps)
    report = dict(res.as_json(), tuned_config=str(tuned_path), report=str(out / "tune.html"))
    figures = []
    if not args.no_plot:
        from hil.plots.tune import plot_loops, plot_tune
        report["plot"] = str(plot_tune(out / "tune.png", tol, given_rec, tuned_rec, mode, eps,
                                       {"as given": verified.get("given_settle_s"),
                                        "tuned": verified.get("settle_s")}))
        figures = [report["plot"], plot_loops(out / "tune_loops.png", first, last)]
    from hil.io.safe_write import write_atomic
    from hil.plots.report import write_tune_report
    write_tune_report(out / "tune.html", report, figures, config=str(args.config), tolerance=tol)
    write_atomic(out / "tune.json", dumps(report, indent=2))
    if args.json:
        print(dumps(report, indent=2))
    else:
        _print(res, tuned_path, report.get("plot"), report["report"])
    return 0


def _percent(text: str, option: str) -> float:
    """``5%`` (or ``0.05``) as 0.05; one line naming the option otherwise."""
    t = str(text).strip()
    try:
        v = float(t[:-1]) / 100 if t.endswith("%") else float(t)
    except ValueError:
        raise UserError(f"{option} {text!r}: expected a share such as 5% or 0.05") from None
    if not 0 <= v < 0.5:
        raise UserError(f"{option} {text!r}: expected a share from 0% to below 50%")
    return v


def _answer(tol: float, verified: dict, choice) -> str:
    t, t0 = verified.get("settle_s"), verified.get("given_settle_s")
    um = f"{tol * 1e6:g} um"
    if choice is None or t is None:
        return f"no command tried brings the tip within {um} in the record: widen --tolerance or lengthen --dwell"
    ref = f"the move as given: {t0 * 1e3:.0f} ms" if t0 is not None else "the move as given never gets there"
    return f"the tuned move has the tool tip within {um} {t * 1e3:.0f} ms after its start ({ref})"


def _print(res, tuned_path, plot=None, html=None) -> None:
    from hil.tune import value_text as _value
    print(res.answer)
    for c in res.changes:
        print(f"  {c.key}: {_value(c.key, c.before)} -> {_value(c.key, c.after)}   ({c.reason})")
    for loop, m in res.margins_after.items():
        b = res.margins_before.get(loop, {})
        fmt = lambda v, u: "none in the band" if v is None else f"{v:.1f} {u}"   # noqa: E731
        print(f"  {loop.replace('_', ' ')}: phase margin {fmt(b.get('phase_margin_deg'), 'deg')} -> "
              f"{fmt(m.get('phase_margin_deg'), 'deg')}, gain margin {fmt(b.get('gain_margin_db'), 'dB')} -> "
              f"{fmt(m.get('gain_margin_db'), 'dB')} (measured)")
    if res.choice is not None:
        print(f"  command: {res.choice.label}; on the model with the mode as measured {res.choice.settle_s * 1e3:.0f} "
              f"ms, worst with the modes {res.mode_error:.0%} off {res.choice.settle_worst_s * 1e3:.0f} ms "
              f"({len(res.candidates)} commands tried)")
    print(f"  tuned config {tuned_path}" + (f", plot {plot}" if plot else "") + (f", report {html}" if html else ""))
