"""The ``hil`` command line: one sub-command per module ``hil/commands/<name>.py``.

Each command module defines ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``,
and imports what it needs inside ``run``: building the parser imports every command module, and
``hil --help`` must not wait for numpy, scipy, numba or matplotlib
(``benchmarks/bench_startup.py`` times it).
Every error the project raises on purpose derives from :class:`hil.errors.HilError`; ``main``
catches that root and prints one line: exit 2 for what the user can fix (bad config, bad data,
refused moves), 1 for a drive fault, 130 for an interrupt. Never a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.util
import re
import sys

from hil import __version__
from hil.errors import HilError

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


class HilArgumentParser(argparse.ArgumentParser):
    """argparse, with negative quantities as values: argparse takes an argument that starts with
    '-' for an option unless it looks like a plain negative number (``-5``, ``-.5``); a quantity
    with its unit (``--distance -5mm``, ``--stroke -0.1m``, ``--set plant.x0=-2mm``) does not. Here
    anything that starts with '-' and a digit or '.digit' is a value (no option of hil looks like
    that); the sub-command parsers are built of this class too (``add_subparsers`` takes the
    parent's class)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-\.?\d")


def build_parser() -> argparse.ArgumentParser:
    parser = HilArgumentParser(
        prog="hil",
        description="Hardware-in-the-loop runtime and model toolkit for feed drives of compliant machine tools. "
                    "Runs on the embedded simulated plant unless a backend is chosen.")
    parser.add_argument("--version", action="version", version=f"hil {__version__}")
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
    except HilError as exc:
        # one line, and the exit code of the error's kind (2: fix and retry; 1: drive fault;
        # a run stopped early: how it stopped, hil.errors.STOP_EXIT_CODES)
        print(f"hil {args.command}: {exc.label}: {exc}", file=sys.stderr)
        return exc.exit_code
    except (FileExistsError, FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError) as exc:
        # a path the user gave that cannot be read or written as asked (e.g. --out naming a file)
        if exc.filename is None:
            raise
        print(f"hil {args.command}: error: {exc.filename}: {exc.strerror}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"hil {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
