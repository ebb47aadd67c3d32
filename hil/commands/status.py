"""``hil status``: the CiA 402 drive's state, position and last faults (no configuration, no motion)."""
from __future__ import annotations


from hil.errors import UserError

HELP = "show the CANopen drive's state, position, error code and recent EMCY (no motion)"
DESCRIPTION = """Connect to the drive (the config's [canopen] section, or --set canopen.*) without
configuring it, and print its NMT state, CiA 402 state, statusword, mode, positions, error code
0x603F, and the supervisor's latched trip, if any.

  hil status --config config/paper_bench_canopen.toml --set canopen.interface=socketcand --set canopen.channel=can0
"""


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p, backend=False)
    p.add_argument("--json", action="store_true", help="print as JSON")


def connect(args):
    from drivers.canopen.backend import CanopenBackend
    from hil.commands.move import load_config
    cfg = load_config(args)
    be = CanopenBackend(cfg)
    try:
        be.connect()
        be.node.sdo[0x1000].raw
    except Exception as exc:                 # no bus, no server, no answer
        try:
            be.close()
        except Exception:
            pass
        raise UserError(f"no CiA 402 drive at node {be.node_id} on {be.interface}:{be.channel} ({exc})") from None
    return cfg, be


def run(args) -> int:
    from hil.io.jsonout import dumps
    from hil.supervisor import Supervisor
    cfg, be = connect(args)
    try:
        st = be.status()
    finally:
        be.close()
    sup = Supervisor(cfg)
    st["supervisor"] = {"tripped": sup.tripped, "reason": sup.reason}
    if args.json:
        print(dumps(st, indent=2))
    else:
        print(f"node {st['node']} ({st['nmt']}): {st['state']} (statusword {st['statusword']}), mode {st['mode']}")
        print(f"  position {st['position_m'] * 1e3:.4f} mm (motor), table {st['table_m'] * 1e3:.4f} mm, "
              f"error code {st['error_code']}")
        if "tip_node" in st:
            tip = st["tip_m"]
            print(f"  tip sensor node {st['tip_node']}: " + (f"{tip * 1e3:.4f} mm" if isinstance(tip, float) else tip))
        print(f"  supervisor: {'TRIPPED: ' + sup.reason if sup.tripped else 'clear'}")
    return 0
