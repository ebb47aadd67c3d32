"""The ``hil`` command line: one sub-command per module ``hil/cmd_<name>.py``.

Each command module defines ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``.
Errors the user can fix (bad config, bad data, refused moves) print one clear line and exit 2;
they never end in a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys

from drivers import BackendError
from drivers.base import BackendFault

from hil.closed_loop import UnstableLoopError
from hil.config import ConfigError
from hil.io.measurement import MeasurementError
from hil.profiles import LimitError
from hil.supervisor import SupervisorTripped
from hil.units import UnitError

# command name -> module (kept in the order `hil --help` lists them). A module not yet present in
# this checkout is left out of the listing.
COMMANDS = {
    "model": "hil.commands.model",
    "move": "hil.commands.move",
    "sweep": "hil.commands.sweep",
    "compare": "hil.commands.compare",
    "diagnose": "hil.commands.diagnose",
    "fit": "hil.commands.fit",
    "synth": "hil.commands.synth",
    "emps": "hil.commands.emps",
    "frf": "hil.commands.frf",
    "drive-sim": "hil.commands.drive_sim",
    "home": "hil.commands.home",
    "jog": "hil.commands.jog",
    "status": "hil.commands.status",
    "reset": "hil.commands.reset",
    "serial-sim": "hil.commands.serial_sim",
}


class UserError(Exception):
    """An error in what the user asked for; printed as one line, exit status 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hil",
        description="Hardware-in-the-loop runtime and model toolkit for feed drives of compliant machine tools. "
                    "Runs on the embedded simulated plant unless a backend is chosen.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, modname in COMMANDS.items():
        if importlib.util.find_spec(modname) is None:
            continue
        mod = importlib.import_module(modname)
        p = sub.add_parser(name, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    # the bus libraries log what the backends already report as one clear line (e.g. an SDO
    # transfer aborted because no drive answers): keep their logs for --debug users of the API
    import logging
    logging.getLogger("canopen").setLevel(logging.CRITICAL)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except (ConfigError, UnitError, UserError, MeasurementError, BackendError, LimitError, SupervisorTripped,
            UnstableLoopError) as exc:
        print(f"hil {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BackendFault as exc:
        print(f"hil {args.command}: drive fault: {exc.reason}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"hil {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    # run the imported module's main, so that the commands and this code share one UserError class
    from hil.cli import main as _main
    sys.exit(_main())
