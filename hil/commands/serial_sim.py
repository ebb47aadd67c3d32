"""``hil serial-sim``: a simulated ASCII serial drive on a pseudo-terminal (drivers.serial.drive_sim)."""
from __future__ import annotations

import sys

from hil.errors import UserError

HELP = "run a simulated serial (ASCII) drive on a pseudo-terminal and print the port to use"
DESCRIPTION = """Run a simulated servo drive that speaks the config's [serial] command set on a new
pseudo-terminal, with the sim_plant model as its shaft, until Ctrl-C. It prints the port
(/dev/pts/N); run the host against it in another shell:

  hil serial-sim --config config/serial_ascii_example.toml
  hil move --config config/serial_ascii_example.toml --backend serial --set serial.port=/dev/pts/N \\
      --stroke 10mm --feed 7000mm/min --tacc 200ms --dwell 0.3s

Faults to inject (repeatable): KIND[@AFTER][xCOUNT][:OP], e.g. --fault timeout@20x3:set_position
(after 20 more commands, the next 3 set_position commands get no reply; the move above is about
97 commands, 7 at start-up and 2 a cycle). Kinds: timeout, partial, garbled, checksum,
unexpected, refuse, drive_fault, vanish, late (the reply 50 ms late), frozen_encoder.

The drive's watchdog: --watchdog TIME is its parameter (default 0: off) until the host's
watchdog command sets it (serial.watchdog, armed at open). When the host is silent that long
while the drive is enabled, the drive quick-stops and reports fault 1; after a freeze (kill
-STOP) it stops and drops unread whatever was queued on the line meanwhile.
"""


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p, backend=False, can=False)
    p.add_argument("--fault", action="append", default=[], metavar="KIND[@AFTER][xCOUNT][:OP]",
                   help="inject a fault (repeatable)")
    p.add_argument("--advance", choices=("setpoint", "wall"), default="wall",
                   help="the plant advances one cycle per setpoint, or with the wall clock (default)")
    p.add_argument("--watchdog", default="0s", metavar="TIME",
                   help="the drive's watchdog parameter until the host sets it (default 0s: off)")


def run(args) -> int:
    from drivers.serial.drive_sim import parse_fault, serve
    from hil.commands.move import load_config
    from hil.plant_config import plant_from_config
    from hil.units import parse_option
    cfg = load_config(args)
    watchdog = parse_option(args.watchdog, "time", "--watchdog")      # a UnitError is one line, exit 2
    if not 0 <= watchdog <= 60:
        raise UserError(f"--watchdog: expected a time from 0 s to 60 s, got {args.watchdog!r}")
    try:
        faults = [parse_fault(f) for f in args.fault]
    except ValueError as exc:
        raise UserError(f"--fault: {exc}") from None
    if not cfg.section("serial.commands"):
        raise UserError(f"{cfg.source}: no [serial.commands] section (see config/serial_ascii_example.toml)")

    def announce(path):
        print(path, flush=True)
        print(f"simulated serial drive on {path} (advance: {args.advance}); use --set serial.port={path}; "
              "Ctrl-C to stop", file=sys.stderr, flush=True)
    try:
        serve(cfg, plant_from_config(cfg), faults=faults, advance=args.advance, announce=announce, watchdog=watchdog)
    except KeyboardInterrupt:
        pass
    return 0
