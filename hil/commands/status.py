"""``hil status``: the CiA 402 drive's state, position and last faults (no configuration, no motion)."""
from __future__ import annotations

from contextlib import contextmanager

from hil.errors import ConfigError, UserError
from hil.io.jsonout import JsonKey, dumps

HELP = "show the supervisor's latched trip and the CANopen drive's state, position, error code (no motion)"
DESCRIPTION = """Connect to the drive (the config's [canopen] section, or --set canopen.*) without
configuring it, and print its NMT state, CiA 402 state, statusword, mode, positions, error code
0x603F, and the supervisor's latched trip, if any (its reason, time and latch file; on any
backend).

  hil status --config config/paper_bench_canopen.toml --set canopen.interface=socketcand --set canopen.channel=can0
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
_CO = "the canopen backend"
JSON_KEYS = {
    "supervisor": JsonKey("", "the supervisor's latch: tripped, reason, time (UTC), latch_file"),
    "node": JsonKey("", "the drive's node id", when=_CO),
    "nmt": JsonKey("", "its NMT state", when=_CO),
    "state": JsonKey("", "its CiA 402 state (OPERATION ENABLED, FAULT, ...)", when=_CO),
    "statusword": JsonKey("", "statusword 0x6041, hexadecimal", when=_CO),
    "mode": JsonKey("", "the backend's mode of operation (csp, cst, ...)", when=_CO),
    "position_m": JsonKey("m", "position actual value 0x6064 (motor)", when=_CO),
    "table_m": JsonKey("m", "the table's position (0x60E4)", when=_CO),
    "error_code": JsonKey("", "error code 0x603F, hexadecimal", when=_CO),
    "emcy": JsonKey("", "the last EMCY messages received", when=_CO),
    "tip_node": JsonKey("", "the tip sensor's node id", when=_CO + ", with a tip sensor node"),
    "tip_m": JsonKey("m", "the tip sensor's position (or why it did not answer)",
                     when=_CO + ", with a tip sensor node"),
}


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p, backend=False)
    p.add_argument("--backend", metavar="NAME", help="the drive to ask (canopen); default: the config's backend.type (others: "
                   "the supervisor's latch only)")
    p.add_argument("--json", action="store_true", help="print as JSON")


@contextmanager
def connected(args):
    """``with connected(args) as (cfg, be):`` the config and the drive's node, connected only (no
    NMT command, no configuration); shut down (the bus released) when the block ends."""
    from drivers.canopen.backend import CanopenBackend
    from hil.commands.move import load_config
    cfg = load_config(args)
    be = CanopenBackend(cfg, can_log=getattr(args, "can_log", None))   # a mistake in the config (e.g. the EDS): ConfigError, exit 2
    try:
        be.connect()
        be.node.sdo[0x1000].raw
    except ConfigError:                      # an interface not installed
        be.shutdown()
        raise
    except Exception as exc:                 # no bus, no server, no answer
        be.shutdown()
        raise UserError(f"no CiA 402 drive at node {be.node_id} on {be.interface}:{be.channel} ({exc})") from None
    try:
        yield cfg, be
    finally:
        be.shutdown()


def latch_state(cfg) -> dict:
    """The supervisor's latch: tripped or not, the reason, when, and the file."""
    from hil.supervisor import Supervisor
    sup = Supervisor(cfg)
    return {"tripped": sup.tripped, "reason": sup.reason, "time": sup.tripped_at, "latch_file": str(sup.latch_file)}


def run(args) -> int:
    from hil.commands.move import load_config
    cfg = load_config(args)
    backend = args.backend or cfg.get("backend.type", "sim")
    st = {}
    if backend == "canopen":
        with connected(args) as (cfg, be):
            st = be.status()
    st["supervisor"] = latch = latch_state(cfg)
    if args.json:
        print(dumps(st, indent=2))
        return 0
    if backend == "canopen":
        print(f"node {st['node']} ({st['nmt']}): {st['state']} (statusword {st['statusword']}), mode {st['mode']}")
        print(f"  position {st['position_m'] * 1e3:.4f} mm (motor), table {st['table_m'] * 1e3:.4f} mm, "
              f"error code {st['error_code']}")
        if "tip_node" in st:
            tip = st["tip_m"]
            print(f"  tip sensor node {st['tip_node']}: " + (f"{tip * 1e3:.4f} mm" if isinstance(tip, float) else tip))
    print("  supervisor: " + (f"TRIPPED at {latch['time'] or 'an unknown time'}: {latch['reason']} (motion refused "
                              f"until 'hil reset'; latch {latch['latch_file']})" if latch["tripped"] else "clear"))
    return 0
