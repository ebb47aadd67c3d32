"""``hil jog``: a short relative move from where the axis is, supervised."""
from __future__ import annotations

from hil.io.jsonout import JsonKey, dumps
from hil.units import parse_option

HELP = "jog the axis by a distance from its present position (CANopen backend by default, supervised)"
DESCRIPTION = """Move the axis by --distance from where it stands, at --speed with --amax, through the
runtime (the position read from the drive before it is enabled, limits checked from there before
motion, the supervisor watching every cycle). A latched trip refuses it until 'hil reset'.

  hil jog --config config/paper_bench_canopen.toml --distance 5mm --speed 600mm/min
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
JSON_KEYS = {
    "start_m": JsonKey("m", "where the axis stood"),
    "end_m": JsonKey("m", "where the table stopped"),
    "status": JsonKey("", "`complete`, `tripped`, `fault` or `aborted`"),
    "reason": JsonKey("", "why it did not complete (empty when complete)"),
    "ok": JsonKey("", "true: nothing to move", when="a distance below the axis resolution"),
    "moved": JsonKey("", "false: nothing was sent", when="a distance below the axis resolution"),
}


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p, backend=False)
    p.add_argument("--backend", metavar="NAME", default="canopen", help="canopen (default), serial or sim")
    p.add_argument("--distance", metavar="LENGTH", required=True, help="signed distance, e.g. 5mm or -2mm")
    p.add_argument("--speed", metavar="SPEED", default="600mm/min", help="jog speed (default 600mm/min)")
    p.add_argument("--amax", metavar="ACCELERATION", default="0.5m/s^2", help="acceleration (default 0.5m/s^2)")
    p.add_argument("--json", action="store_true", help="print as JSON")
    from hil.commands.scope import add_scope_options
    add_scope_options(p)


def run(args) -> int:
    from drivers import BackendError
    from hil.backends import open_backend
    from hil.commands.move import _no_move, load_config
    from hil.commands.scope import check_scope_options, scope_for
    from hil.errors import UserError
    from hil.profiles import LimitError, MoveSpec, Trajectory
    from hil.runtime import run_trajectory
    from hil.supervisor import refuse_if_tripped
    cfg = load_config(args)
    if _no_move(cfg, parse_option(args.distance, "length", "--distance"), "--distance", args.json):
        return 0
    refuse_if_tripped(cfg)                 # before anything connects
    check_scope_options(args)
    traj = Trajectory(start=0.0)           # a relative move: the runtime plans it from where the axis stands
    try:
        traj.move(MoveSpec(stroke=parse_option(args.distance, "length", "--distance"),
                           feed=parse_option(args.speed, "speed", "--speed"), a_max=parse_option(args.amax, "acceleration", "--amax")))
    except ValueError as exc:
        raise UserError(str(exc)) from None
    traj.dwell(0.1)
    try:
        backend = open_backend(cfg, args.backend, can_log=getattr(args, "can_log", None))
        # the simulated plant starts at 0: checked here; an axis: checked from where it stands (runtime)
        with scope_for(args, cfg, "jog") as ring:
            rec = run_trajectory(cfg, traj, backend=backend, settle=0.0, check=args.backend == "sim", start="follow",
                                 scope=ring)
    except (LimitError, BackendError) as exc:
        raise UserError(str(exc)) from None
    if len(rec["t"]) < 1:
        raise UserError(f"the jog did not start on {backend.name}: {rec.status}: {rec.reason}")
    start = rec.start
    out = {"start_m": start, "end_m": float(rec["x_table"][-1]), "status": rec.status, "reason": rec.reason}
    if args.json:
        print(dumps(out, indent=2))
    elif rec.status == "complete":
        print(f"jog {start * 1e3:.3f} -> {out['end_m'] * 1e3:.3f} mm: complete")
    else:
        from hil.supervisor import trip_hint
        print(f"jog DID NOT COMPLETE: {rec.status}: {rec.reason}; the axis stopped at {out['end_m'] * 1e3:.3f} mm "
              f"(from {start * 1e3:.3f} mm); {trip_hint(cfg)}")
    return rec.stop.exit_code
