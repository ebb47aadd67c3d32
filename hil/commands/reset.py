"""``hil reset``: CiA 402 fault reset on the drive and the supervisor's latch cleared."""
from __future__ import annotations

from hil.io.jsonout import JsonKey, dumps

HELP = "reset a drive fault (controlword bit 7) and clear the supervisor's latched trip"
DESCRIPTION = """Send FAULT RESET (controlword 0x0080, rising edge) to the drive and clear the
supervisor's latch (latch.json in the state directory, $HIL_STATE_DIR or
$XDG_STATE_HOME/compliant-axis-hil, or supervisor.latch_file), so that motion is allowed again. Find and fix
the cause first: 'hil status' shows the error code and the trip reason.
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
_CO = "the canopen backend, without --supervisor-only"
JSON_KEYS = {
    "supervisor_was": JsonKey("", "the latch before the reset: `clear` or `tripped at TIME: REASON`"),
    "error_code": JsonKey("", "the drive's error code 0x603F before the reset, hexadecimal", when=_CO),
    "state": JsonKey("", "the drive's CiA 402 state after the fault reset", when=_CO),
}


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p, backend=False)
    p.add_argument("--backend", metavar="NAME", help="the drive to reset (canopen); default: the config's backend.type (others: "
                   "the supervisor's latch only)")
    p.add_argument("--supervisor-only", action="store_true", help="only clear the supervisor's latch")
    p.add_argument("--json", action="store_true", help="print as JSON")


def run(args) -> int:
    from hil.commands.move import load_config
    from hil.supervisor import Supervisor
    cfg = load_config(args)
    sup = Supervisor(cfg)
    out = {"supervisor_was": (f"tripped at {sup.tripped_at or 'an unknown time'}: {sup.reason}" if sup.tripped
                              else "clear")}
    backend = args.backend or cfg.get("backend.type", "sim")
    if not args.supervisor_only and backend == "canopen":
        from hil.commands.status import connected
        with connected(args) as (_, be):
            out["error_code"] = f"0x{be.node.sdo[0x603F].raw:04X}"
            out["state"] = be.fault_reset()
    sup.reset()                  # the latch last: a drive that could not be reached keeps it
    print(dumps(out, indent=2) if args.json else
          "; ".join(f"{k.replace('_', ' ')}: {v}" for k, v in out.items()))
    return 0 if out.get("state", "SWITCH ON DISABLED") != "FAULT" else 1
