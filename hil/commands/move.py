"""``hil move``: one sine-square move (optionally back again), checked against the limits first."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from hil import config as config_mod
from hil.errors import STOP_FAILED_EXIT, UserError
from hil.io.jsonout import JsonKey, dumps
from hil.units import parse_option

if TYPE_CHECKING:
    from hil.profiles import Trajectory

HELP = "run a sine-square move on the backend (the simulated plant by default)"
DESCRIPTION = """Run one jerk-limited sine-square move (Eq. 15-16 of the paper), record it and report
overshoot, following errors and settling at table and tool tip.

How fast to accelerate: --tacc (the NC's acceleration time to reach G0; G0 from the config's
nc.g0 or --g0), or --amax, or --jmax. A stroke too short to reach the feed keeps the quantity
given and lowers the peak speed. Limits are checked before any motion (--check: only check).

On an axis (--backend canopen or serial) the move starts where the axis stands, read from the
drive before it is enabled (the stroke is relative); --start makes that a check: the axis must
stand within limits.start_window (0.1 mm) of it, else the move is refused. A trip not yet reset
('hil reset') refuses every move. Exit codes: 0 complete, 1 drive fault, 2 refused (a mistake),
3 supervisor trip, 4 lost communication, 5 loop overrun, 130 Ctrl-C.

example:
  hil move --config config/paper_bench.toml --stroke 100mm --feed 7000mm/min --tacc 200ms
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
_DONE = "the move completed"
_STOPPED = "the move did not complete"
JSON_NOTE = ("`--check` prints only `ok`, `j_max`, `a_max`, `peak_speed`, `duration`, `reduced_peak_speed` and "
             "`units`; a stroke below the axis resolution prints `ok`, `moved` (false) and `reason`.")
JSON_KEYS = {
    "status": JsonKey("", "`complete`, or how the run ended: `tripped`, `fault`, `aborted`"),
    "reason": JsonKey("", "why it did not complete (empty when complete)"),
    "record": JsonKey("", "path of the record (move.csv)"),
    "plot": JsonKey("", "path of move.png"),
    "backend": JsonKey("", "the backend it ran on"),
    "start_m": JsonKey("m", "where the move started (on an axis: where it stood)"),
    "overshoot_table_um": JsonKey("um", "overshoot of the table past the target", when=_DONE),
    "overshoot_tip_um": JsonKey("um", "overshoot of the tool tip past the target", when=_DONE),
    "peak_following_error_table_um": JsonKey("um", "largest |x_cmd - x_table|", when=_DONE),
    "peak_following_error_tip_um": JsonKey("um", "largest |x_cmd - x_tip|", when=_DONE),
    "residual_tip_um": JsonKey("um", "half the peak-to-peak tip motion after the command ended (null: no record "
                                     "after it, --dwell 0s)", when=_DONE),
    "settling_time_table": JsonKey("s", "from the end of the command until the table stays within --band; null: "
                                        "never settled in the record", when=_DONE),
    "settling_time_tip": JsonKey("s", "the same for the tip", when=_DONE),
    "settle_band_um": JsonKey("um", "the settling band (--band)", when=_DONE),
    "observed_after_s": JsonKey("s", "record after the end of the command, where settling and residual vibration are "
                                     "measured (0: they cannot be, null; the overshoot covers the command only)",
                                when=_DONE),
    "stale_samples": JsonKey("", "rows whose feedback repeats the last answer (a cycle without its answer on a "
                                 "fieldbus or serial line), left out of the following errors", when=_DONE),
    "overruns": JsonKey("", "cycles of the real-time loop that missed their deadline", when=_DONE),
    "peak_torque": JsonKey("N*m or N", "largest motor torque (rotary) or force (linear)", when=_DONE),
    "j_max": JsonKey("m/s^3", "peak jerk of the move", when=_DONE + ", or --check"),
    "a_max": JsonKey("m/s^2", "peak acceleration", when=_DONE + ", or --check"),
    "peak_speed": JsonKey("m/s", "peak speed (below the feed when the stroke is too short)",
                          when=_DONE + ", or --check"),
    "t_acc": JsonKey("s", "NC acceleration time (null when not given by --tacc)", when=_DONE),
    "shaper": JsonKey("Hz, s", "the input shaper the command passed through (hil.shaping): kind, frequency_hz, "
                               "damping_ratio, amplitudes, times_s, duration_s (the command ends this much after "
                               "the move); null without one", when=_DONE),
    "units": JsonKey("", "the SI unit of each key that does not name its own", when=_DONE + ", or --check"),
    "stop": JsonKey("", "the kind of stop: `drive_fault`, `trip` (the supervisor), `link` (lost communication), "
                        "`overrun`, `interrupt`",
                    when=_STOPPED),
    "controlled_stop": JsonKey("", "the controlled stop commanded: `how` (quick_stop or disable), `ok` (false: it "
                                   "failed, the host did not stop the axis) and `error`", when=_STOPPED),
    "exit_code": JsonKey("", "the exit code of that kind: 1, 3, 4, 5, 130; 6 where the controlled stop failed",
                         when=_STOPPED),
    "stopped_at_s": JsonKey("s", "time of the record's last sample", when=_STOPPED),
    "ok": JsonKey("", "true: the move fits the limits (or there is nothing to move)",
                  when="with --check, or a stroke below the resolution"),
    "duration": JsonKey("s", "duration of the whole trajectory", when="with --check"),
    "reduced_peak_speed": JsonKey("", "the stroke is too short to reach the feed", when="with --check"),
    "moved": JsonKey("", "false: nothing was sent", when="a stroke below the resolution"),
}


def add_common(p, backend: bool = True, can: bool = True) -> None:
    p.add_argument("--config", required=True, metavar="FILE", help="axis configuration (TOML)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config parameter, e.g. --set plant.c2=33 (repeatable)")
    if backend:
        p.add_argument("--backend", metavar="NAME",
                       help="sim (default), canopen or serial; default: the config's backend.type")
    if can:
        from hil.commands.canbus import add_can_options
        add_can_options(p)


def load_config(args):
    overrides = dict(config_mod.parse_assignment(s) for s in args.set)
    cfg = config_mod.load(args.config, overrides)
    if not hasattr(args, "bitrate"):            # a command without the CAN options
        return cfg
    given = any(getattr(args, k, None) is not None for k in ("interface", "channel", "bitrate"))
    if given or (getattr(args, "backend", None) or cfg.get("backend.type", "sim")) == "canopen":
        # -i/-c/-b, then python-can's configuration for what the file does not write; --set wins
        from hil.commands.canbus import can_overrides
        extra = {k: v for k, v in can_overrides(args, cfg.file_keys).items() if k not in overrides}
        if extra:                   # applied to the config loaded: the file is read once
            changed = cfg.with_values(extra)
            changed.overrides, changed.file_keys = {**extra, **overrides}, cfg.file_keys
            cfg = changed
    return cfg


def add_arguments(p) -> None:
    add_common(p)
    p.add_argument("--stroke", metavar="LENGTH", required=True, help="signed stroke, e.g. 100mm or -0.1m")
    p.add_argument("--feed", metavar="SPEED", required=True, help="feed (peak speed), e.g. 7000mm/min")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--tacc", metavar="TIME", help="NC acceleration time to reach G0, e.g. 200ms (one of --tacc, "
                   "--amax, --jmax; default: the config's nc.t_acc)")
    g.add_argument("--amax", metavar="ACCELERATION", help="peak acceleration, e.g. 4m/s^2")
    g.add_argument("--jmax", metavar="JERK", help="peak jerk, e.g. 200m/s^3")
    p.add_argument("--g0", metavar="SPEED", help="rapid speed G0 (default: the config's nc.g0)")
    p.add_argument("--start", metavar="LENGTH", help="start position. Simulated plant: where it starts (default 0mm). An axis "
                   "(canopen, serial): where it must stand (within limits.start_window), else refused; "
                   "default: the move starts where the axis stands")
    p.add_argument("--back", action="store_true", help="return to the start after the dwell")
    p.add_argument("--shaper", metavar="KIND@FREQ[:DAMPING]", default=None,
                   help="shape the command for a mode so that the tool tip arrives still: zv, zvd, ei or si at a "
                        "frequency (zvd@14.94Hz; the damping ratio of the model's nearest mode unless given), auto "
                        "(ZVD at the model's lowest mode) or none; default: the config's nc.shaper (none)")
    p.add_argument("--dwell", metavar="TIME", default="1s", help="standstill after each move (default 1s)")
    p.add_argument("--band", metavar="LENGTH", default="1um", help="settling band around the target (default 1um)")
    p.add_argument("--check", action="store_true", help="check the move against the limits, do not run it")
    p.add_argument("--out", metavar="DIR", default="out/move", help="output folder for the record and the plot (default out/move)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--realtime", action="store_true",
                   help="on the simulated plant's dry run: show it in the scope at real-time pace (the command takes "
                        "the run's duration); the record is the same")
    from hil.commands.scope import add_scope_options
    add_scope_options(p)


def build_trajectory(args, cfg) -> Trajectory:
    from hil.profiles import MoveSpec, Trajectory

    g0 = parse_option(args.g0, "speed", "--g0") if args.g0 else cfg.get("nc.g0")
    t_acc = parse_option(args.tacc, "time", "--tacc") if args.tacc else None
    if not (args.tacc or args.amax or args.jmax):
        t_acc = cfg.get("nc.t_acc")          # a tuned config carries its acceleration (hil tune)
        if t_acc is None:
            raise UserError(f"give one of --tacc, --amax or --jmax (e.g. --tacc 200ms), or nc.t_acc in {cfg.source}")
    try:
        spec = MoveSpec(stroke=parse_option(args.stroke, "length", "--stroke"), feed=parse_option(args.feed, "speed", "--feed"),
                        t_acc=t_acc, g0=g0 if t_acc is not None else None,
                        a_max=parse_option(args.amax, "acceleration", "--amax") if args.amax else None,
                        j_max=parse_option(args.jmax, "jerk", "--jmax") if args.jmax else None)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    dwell = parse_option(args.dwell, "time", "--dwell")
    traj = Trajectory(start=parse_option(args.start, "length", "--start") if args.start else 0.0)
    traj.move(spec)
    traj.dwell(dwell)
    if args.back:
        traj.move(MoveSpec(-spec.stroke, spec.feed, spec.t_acc, spec.g0, spec.a_max, spec.j_max))
        traj.dwell(dwell)
    from hil.shaping import config_shaper, shaped
    try:
        return shaped(traj, config_shaper(cfg, getattr(args, "shaper", None)))
    except ValueError as exc:
        raise UserError(str(exc)) from None


def _no_move(cfg, stroke: float, option: str, as_json: bool) -> bool:
    """A zero or sub-resolution stroke is no move: say so in one line (nothing is sent)."""
    from hil.profiles import is_null_stroke
    res = max(cfg.get("sensors.table_resolution", 0.0) or 0.0, cfg.get("sensors.motor_resolution", 0.0) or 0.0)
    if not is_null_stroke(stroke, res):
        return False
    msg = (f"no move: {option} {stroke * 1e3:g} mm is below the axis resolution "
           f"({max(res, 1e-9) * 1e3:g} mm); nothing was sent")
    print(dumps({"ok": True, "moved": False, "reason": msg}, indent=2) if as_json else msg)
    return True


def _check_backend_settings(cfg, name: str | None) -> None:
    """--check: the backend's own settings too (a serial command the move would refuse), checked as
    the backend reads them, without connecting: one line, exit 2."""
    from drivers import BackendError, backend_class
    try:
        cls = backend_class(name or cfg.get("backend.type", "sim"))
    except BackendError as exc:
        raise UserError(str(exc)) from None
    check = getattr(cls, "check_settings", None)
    if check is not None:
        check(cfg)


def run(args) -> int:
    from hil.analysis import move_figures
    from hil.closed_loop import UnstableLoopError, check_loop_stability
    from hil.commands.scope import check_scope_options
    from hil.profiles import AxisLimits, LimitError, check_limits, check_sampled
    from hil.units import SI_UNIT, fmt, parse_bounded
    cfg = load_config(args)
    band = parse_bounded(args.band, "length", "--band", positive=True, maximum=1.0)   # before anything moves
    check_scope_options(args)          # a bad --scope-port or --scope-hold: refused before anything moves
    if _no_move(cfg, parse_option(args.stroke, "length", "--stroke"), "--stroke", args.json):
        return 0
    traj = build_trajectory(args, cfg)
    try:
        check_limits(traj, AxisLimits.from_config(cfg))
        # and the command as it will be sent, sample by sample (--check included)
        tp = cfg["control.position_period"]
        x_cmd = traj.sample(tp)[1]            # sampled once: checked here, run below
        check_sampled(x_cmd, tp, AxisLimits.from_config(cfg))
        check_loop_stability(cfg)
    except (LimitError, UnstableLoopError) as exc:
        raise UserError(str(exc)) from None
    first = traj.moves[0]
    if args.check:
        _check_backend_settings(cfg, args.backend)
        summary = {"ok": True, "j_max": first.j_max, "a_max": first.a_max, "peak_speed": first.peak_speed,
                   "duration": traj.duration, "reduced_peak_speed": first.reduced}
        summary["units"] = {"j_max": "m/s^3", "a_max": "m/s^2", "peak_speed": "m/s", "duration": "s"}
        print(dumps(summary, indent=2) if args.json else
              f"move fits the limits: j_max {fmt(first.j_max, 'jerk')}, a_max {fmt(first.a_max, 'acceleration')}, "
              f"peak speed {first.peak_speed * 60e3:.0f} mm/min, duration {fmt(traj.duration, 'time')}")
        return 0
    from drivers import BackendError
    from hil.backends import open_backend
    from hil.runtime import run_trajectory
    try:
        backend = open_backend(cfg, args.backend, can_log=getattr(args, "can_log", None))
    except BackendError as exc:
        raise UserError(str(exc)) from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from hil.commands.scope import scope_for
    with scope_for(args, cfg, "move") as ring:
        rec = run_trajectory(cfg, traj, backend=backend, out_file=out / "move.csv", settle=0.0, check=False,
                             start="check" if args.start else "follow", scope=ring, realtime=args.realtime,
                             samples=x_cmd)
    ch = rec.channels
    if len(ch["t"]) < 2:
        raise UserError(f"the move did not start on {backend.name}: {rec.status}: {rec.reason}")
    if rec.start is not None and rec.start != traj.start:       # planned from where the axis stood
        traj = traj.shifted(rec.start - traj.start)
        first = traj.moves[0]
    from hil.plots.move import plot_move
    title = (f"{cfg.get('meta.name') or cfg.source}: stroke {first.stroke * 1e3:g} mm from {traj.start * 1e3:.3f} mm, "
             f"feed {first.peak_speed * 60e3:.0f} mm/min, j_max {first.j_max:.0f} m/s^3")
    if rec.status != "complete":
        # a run that did not complete: say so first, and no overshoot or settling figures for it
        png = plot_move(ch, out / "move.png", title=title, stopped=(rec.status, rec.reason))
        kind = rec.stop
        stopped = rec.controlled_stop or {"how": cfg.get("supervisor.stop", "quick_stop"), "ok": True, "error": ""}
        exit_code = kind.exit_code if stopped["ok"] else STOP_FAILED_EXIT
        summary = {"status": rec.status, "reason": rec.reason, "stop": kind, "controlled_stop": stopped,
                   "exit_code": exit_code, "stopped_at_s": float(ch["t"][-1]),
                   "start_m": traj.start, "record": str(rec.path), "plot": str(png), "backend": backend.name}
        if args.json:
            print(dumps(summary, indent=2))
        else:
            print(f"move DID NOT COMPLETE on {backend.name}: {rec.status} ({kind}) at t = {ch['t'][-1]:.3f} s: "
                  f"{rec.reason}")
            if stopped["ok"]:
                print(f"  stopped with the configured controlled stop ({stopped['how']}); "
                      f"no overshoot or settling figures for an incomplete move")
            else:
                print(f"  the controlled stop ({stopped['how']}) FAILED (not confirmed by the drive): "
                      f"{stopped['error']}; the host's later disable may not have reached the drive either: its own "
                      f"guards (its watchdog, its heartbeat consumer) are what stop the axis then. Check the axis "
                      f"before anything else")
            from hil.supervisor import trip_hint
            print(f"  record {rec.path}, plot {png}; {trip_hint(cfg)}")
        return exit_code
    t_next = first.duration + (traj.segments[1].duration if len(traj.segments) > 1 and not hasattr(
        traj.segments[1], "stroke") else 0.0)
    fig = move_figures(ch["t"], ch["x_cmd"], ch["x_table"], ch["x_tip"], ch.get("torque", ch.get("command")),
                       first, 0.0, t_next, band, stale=ch.get("stale"),
                       tail=traj.shaper.duration if getattr(traj, "shaper", None) else 0.0)
    png = plot_move(ch, out / "move.png", title=title)
    shaper = getattr(traj, "shaper", None)
    summary = dict(fig.as_dict(), status=rec.status, reason=rec.reason, record=str(rec.path), plot=str(png),
                   backend=backend.name, start_m=traj.start, overruns=int(rec.loop.get("overruns", 0)),
                   shaper=shaper.as_json() if shaper is not None else None)
    drive = "torque" if cfg.rotary else "force"
    summary["units"] = {k: u for k, u in (("settling_time_table", "s"), ("settling_time_tip", "s"),
                                          ("peak_torque", SI_UNIT[drive]), ("j_max", "m/s^3"),
                                          ("a_max", "m/s^2"), ("peak_speed", "m/s"), ("t_acc", "s"),
                                          ("start_m", "m")) if k in summary}
    if args.json:
        print(dumps(summary, indent=2))
    else:
        st = lambda v: "not settled" if v is None else fmt(v, "time", unit="ms")  # noqa: E731
        print(f"move {fmt(first.stroke, 'length')} at {first.peak_speed * 60e3:.0f} mm/min on {backend.name}: "
              f"j_max {fmt(first.j_max, 'jerk')}, a_max {fmt(first.a_max, 'acceleration')}")
        blind = fig.observed_after_s <= 0.0     # no record after the command (--dwell 0s)
        if shaper is not None:
            print(f"  command shaped by {shaper.kind.upper()} at {shaper.frequency:.4g} Hz, damping ratio "
                  f"{shaper.damping:.3g} ({len(shaper.times)} impulses; the command ends "
                  f"{fmt(shaper.duration, 'time', unit='ms')} after the move, settling counted from there)")
        print(f"  overshoot          table {fig.overshoot_table_um:8.2f} um   tip {fig.overshoot_tip_um:8.2f} um"
              + ("   (up to the command's end only: no dwell)" if blind else ""))
        print(f"  peak follow. error table {fig.peak_following_error_table_um:8.1f} um   tip "
              f"{fig.peak_following_error_tip_um:8.1f} um")
        if fig.stale_samples or summary["overruns"]:
            # a real axis: cycles without their answer repeat the last reading while the command
            # moves on; left out of the figures above, and said here rather than only in move.json
            print(f"  cycles without an answer {fig.stale_samples} (left out of the following errors), "
                  f"loop overruns {summary['overruns']}")
        if blind:
            print(f"  settling and residual tip vibration cannot be measured: no record after the command "
                  f"(--dwell {args.dwell}); peak {drive} {fmt(fig.peak_torque, drive, 3)}")
        else:
            print(f"  settling (+-{band * 1e6:g} um) table {st(fig.settling_time_table)}   tip "
                  f"{st(fig.settling_time_tip)}")
            print(f"  residual tip vibration {fig.residual_tip_um:.2f} um, peak {drive} {fmt(fig.peak_torque, drive, 3)}")
        print(f"  record {rec.path}, plot {png}")
    return 0
