"""``hil home``: CiA 402 homing (mode 6) on the drive."""
from __future__ import annotations

from hil.io.jsonout import JsonKey, dumps
from hil.units import parse_option

HELP = "home the CANopen drive (homing mode 6; method 37: the present position becomes --offset)"
DESCRIPTION = """Home the drive: homing mode (6) with the method given (default 37, CiA 402 'homing
on the present position': no motion, the present position becomes the home offset 0x607C).
Other methods are the drive's own; the simulated drive knows 35 and 37.
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


def run(args) -> int:
    from hil.commands.move import load_config
    from hil.drivers import require_supervision
    from hil.drivers.base import BackendFault
    from hil.drivers.canopen.backend import CanopenBackend
    from hil.errors import UserError
    from hil.supervisor import refuse_if_tripped
    cfg = load_config(args)
    refuse_if_tripped(cfg)            # homing may move the axis: a latched trip refuses it too
    offset = parse_option(args.offset, "length", "--offset")
    require_supervision(cfg, "canopen")
    be = CanopenBackend(cfg, can_log=getattr(args, "can_log", None))
    try:
        with be:                   # opened (full start-up); shut down (disabled, closed) at the end
            out = be.home(offset=offset, method=args.method)
    except BackendFault as exc:
        raise UserError(exc.reason) from None
    print(dumps(out, indent=2) if args.json else
          f"homed (method {out['method']}): position {out['position_m'] * 1e3:.4f} mm")
    return 0
