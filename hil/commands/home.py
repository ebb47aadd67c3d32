"""``hil home``: CiA 402 homing (mode 6) on the drive."""
from __future__ import annotations

from hil.io.jsonout import JsonKey, dumps
from hil.units import parse_option

HELP = "home the CANopen drive (homing mode 6; method 37: the present position becomes --offset)"
DESCRIPTION = """Home the drive: homing mode (6) with the method given (default 37, CiA 402 'homing
on the present position': no motion, the present position becomes the home offset 0x607C).
Other methods are the drive's own; the simulated drive knows 35 and 37.

--scope shows the drive's position before and after homing (over SDO; homing runs on the
drive, not in the host's cycle) and the outcome as an event.
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
JSON_KEYS = {
    "homed": JsonKey("", "true: homing attained"),
    "method": JsonKey("", "the homing method used (0x6098)"),
    "position_m": JsonKey("m", "the drive's position after homing"),
    "tip_m": JsonKey("m", "the tip sensor's position after homing", when="with a tip sensor node"),
}


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p, backend=False)
    p.add_argument("--offset", metavar="LENGTH", default="0mm", help="position of the home point (default 0mm)")
    p.add_argument("--method", metavar="N", type=int, default=37, help="homing method 0x6098 (default 37)")
    p.add_argument("--json", action="store_true", help="print as JSON")
    from hil.commands.scope import add_scope_options
    add_scope_options(p)


def run(args) -> int:
    from drivers.base import BackendFault
    from drivers.canopen.backend import CanopenBackend
    from hil.backends import require_supervision
    from hil.commands.move import load_config
    from hil.commands.scope import check_scope_options, scope_for
    from hil.errors import UserError
    from hil.supervisor import refuse_if_tripped
    cfg = load_config(args)
    refuse_if_tripped(cfg)            # homing may move the axis: a latched trip refuses it too
    offset = parse_option(args.offset, "length", "--offset")
    require_supervision(cfg, "canopen")
    check_scope_options(args)
    be = CanopenBackend(cfg, can_log=getattr(args, "can_log", None))
    with scope_for(args, cfg, "home") as ring:
        try:
            with be:                   # opened (full start-up); shut down (disabled, closed) at the end
                t0 = _scope_row(ring, None, be)
                out = be.home(offset=offset, method=args.method)
                _scope_row(ring, t0, be, "complete", f"homed (method {args.method})")
        except BackendFault as exc:
            if ring is not None and ring.count:
                ring.event(ring.last_t, "fault", exc.reason)
            raise UserError(exc.reason) from None
    print(dumps(out, indent=2) if args.json else
          f"homed (method {out['method']}): position {out['position_m'] * 1e3:.4f} mm")
    return 0


def _scope_row(ring, t0, be, end: str = "", reason: str = ""):
    """With --scope: the drive's position (SDO) as a row of the scope, at the time since ``t0``
    (None: the first row, t = 0); ``end``: the event that ends the run. Returns the start time."""
    import math
    import time
    now = time.perf_counter()
    if ring is None:
        return now
    fb = be.read_position()
    t = 0.0 if t0 is None else now - t0
    ring.write(t, math.nan, fb.x_motor, fb.x_table, fb.x_tip, math.nan, math.nan, 0.0, 0.0)
    if end:
        ring.event(t, end, reason)
    return now if t0 is None else t0
