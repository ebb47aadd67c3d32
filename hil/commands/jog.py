"""``hil jog``: a short relative move from where the axis is, supervised."""
from __future__ import annotations

from hil.io.jsonout import dumps
from hil.units import parse

HELP = "jog the axis by a distance from its present position (CANopen backend, supervised)"
DESCRIPTION = """Move the axis by --distance from where it stands, at --speed with --amax, through the
runtime (limits checked before motion, the supervisor watching every cycle).

  hil jog --config config/paper_bench_canopen.toml --distance 5mm --speed 600mm/min
"""


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p, backend=False)
    p.add_argument("--distance", required=True, help="signed distance, e.g. 5mm or -2mm")
    p.add_argument("--speed", default="600mm/min", help="jog speed (default 600mm/min)")
    p.add_argument("--amax", default="0.5m/s^2", help="acceleration (default 0.5m/s^2)")
    p.add_argument("--json", action="store_true", help="print as JSON")


def run(args) -> int:
    from drivers.canopen.backend import CanopenBackend
    from hil.commands.move import _no_move, load_config
    from hil.commands.status import connected
    from hil.errors import UserError
    from hil.profiles import AxisLimits, LimitError, MoveSpec, Trajectory, check_limits
    from hil.runtime import run_trajectory
    from hil.supervisor import Supervisor, SupervisorTripped
    if _no_move(load_config(args), parse(args.distance, "length", "--distance"), "--distance", args.json):
        return 0
    with connected(args) as (cfg, be):
        start = be.node.sdo[0x6064].raw / be.counts_per_m
    traj = Trajectory(start=start)
    traj.move(MoveSpec(stroke=parse(args.distance, "length", "--distance"), feed=parse(args.speed, "speed", "--speed"),
                       a_max=parse(args.amax, "acceleration", "--amax")))
    traj.dwell(0.1)
    try:
        check_limits(traj, AxisLimits.from_config(cfg))
    except LimitError as exc:
        raise UserError(str(exc)) from None
    sup = Supervisor(cfg, real_time=True)
    try:
        sup.arm()
    except SupervisorTripped as exc:
        raise UserError(str(exc)) from None
    rec = run_trajectory(cfg, traj, backend=CanopenBackend(cfg), settle=0.0, supervisor=sup, check=False)
    out = {"start_m": start, "end_m": float(rec["x_table"][-1]), "status": rec.status, "reason": rec.reason}
    print(dumps(out, indent=2) if args.json else
          f"jog {start * 1e3:.3f} -> {out['end_m'] * 1e3:.3f} mm: {rec.status} {rec.reason}".rstrip())
    return 0 if rec.status == "complete" else 1
