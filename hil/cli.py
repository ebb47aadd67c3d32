"""The ``hil`` command line: one sub-command per module ``hil/commands/<name>.py``.

Each command module defines ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``,
and imports what it needs inside ``run``: building the parser imports every command module, and
``hil --help`` must not wait for numpy, scipy, numba or matplotlib
(``benchmarks/bench_startup.py`` times it).
Every error the project raises on purpose derives from :class:`hil.errors.HilError`; ``main``
catches that root and prints one line: exit 2 for what the user can fix (bad config, bad data,
refused moves), 1 for a drive fault, 130 for an interrupt, 141 when stdout was closed before
everything was printed (``hil move ... | head -1``: the run has ended and is recorded; printing
stopped, stdout goes to the null device). Never a traceback.

Global options (before the command): ``--version``; ``--log-level LEVEL`` (the library logs
through ``logging``, one logger per module named after it: ``hil.ident.diagnosis``,
``drivers.canopen.backend``; the level applies to them and to the bus libraries, canopen and
python-can; without it the project's loggers show warnings and the bus libraries only critical
messages, since the backends already report their failures as one clear line);
``--can-log FILE.asc|.blf`` (python-can's trace of the CAN bus of every canopen backend the command
connects, drivers.canopen.canlog; also accepted after the CAN commands).
An unknown command gets a "did you mean" (difflib).
"""
from __future__ import annotations

import argparse
import contextlib
import difflib
import errno
import importlib
import importlib.util
import io
import logging
import os
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
    "fleet": "hil.commands.fleet",
    "emps": "hil.commands.emps",
    "frf": "hil.commands.frf",
    "tune": "hil.commands.tune",
    "drive-sim": "hil.commands.drive_sim",
    "home": "hil.commands.home",
    "jog": "hil.commands.jog",
    "status": "hil.commands.status",
    "reset": "hil.commands.reset",
    "serial-sim": "hil.commands.serial_sim",
    "scope": "hil.commands.scope",
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

    def error(self, message):
        """argparse's message, with "did you mean" for a mistyped command or choice."""
        m = re.search(r"invalid choice: '?([^'\s]*)'? \(choose from (.*)\)", message)
        if m:
            choices = [c.strip().strip("'\"") for c in m.group(2).split(",")]
            close = difflib.get_close_matches(m.group(1), choices, n=1, cutoff=0.6)
            if close:
                message += f"; did you mean '{close[0]}'?"
        super().error(message)


LOG_LEVELS = ("debug", "info", "warning", "error", "critical")
# the bus libraries: they log what the backends already report as one clear line (an SDO transfer
# aborted because no drive answers); shown from --log-level on
BUS_LOGGERS = ("canopen", "can")


class _StderrHandler(logging.StreamHandler):
    """A handler on the current sys.stderr (looked up at each record: a test's capture, a
    redirected stream), not the one of the first call."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


def setup_logging(level: str | None) -> None:
    """Logging on stderr: the project's loggers at ``level`` (default warning), the bus libraries'
    at ``level`` when given, else critical only."""
    root = logging.getLogger()
    if not any(getattr(h, "_hil", False) for h in root.handlers):
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        handler._hil = True
        root.addHandler(handler)
    root.setLevel(getattr(logging, (level or "warning").upper()))
    for name in BUS_LOGGERS:
        logging.getLogger(name).setLevel(logging.NOTSET if level else logging.CRITICAL)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser; ``only``: with that one command alone (a run of it: importing
    and building all eighteen costs 0.05 s of every start), else with every command (the help,
    a mistyped command, the docs)."""
    parser = HilArgumentParser(
        prog="hil",
        description="Hardware-in-the-loop runtime and model toolkit for feed drives of compliant machine tools. "
                    "Runs on the embedded simulated plant unless a backend is chosen.")
    parser.add_argument("--version", action="version", version=f"hil {__version__}")
    parser.add_argument("--log-level", type=str.lower, choices=LOG_LEVELS, default=None, metavar="LEVEL",
                        help=f"log messages from this level on ({', '.join(LOG_LEVELS)}; default: warnings of hil, "
                             f"only critical messages of the CAN libraries)")
    parser.add_argument("--can-log", default=None, metavar="FILE",
                        help="record the CAN bus (received and sent frames) with python-can's logger: FILE.asc "
                             "or .blf (also .log, .csv, .trc); a sweep on a backend writes one file per run, "
                             "FILE's name numbered in run order (bus.asc: bus-001.asc, bus-002.asc, ...)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, modname in COMMANDS.items():
        if only is not None and name != only:
            continue
        if importlib.util.find_spec(modname) is None:
            continue
        mod = importlib.import_module(modname)
        p = sub.add_parser(name, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


# the top-level options that take a value (the word after them is no command)
_VALUED = ("--log-level", "--can-log")


def _command_in(argv: list[str]) -> str | None:
    """The command ``argv`` names (its first word that is no option or an option's value), where
    it is one of :data:`COMMANDS`; else None."""
    skip = False
    for word in argv:
        if skip:
            skip = False
        elif word in _VALUED:
            skip = True
        elif word == "--" or not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


# the commands that never run the compiled simulator (no first-compile notice to give)
NO_SIMULATOR = frozenset({"model", "status", "reset", "scope", None})


def main(argv: list[str] | None = None) -> int:
    if sys.stdout is None:        # started with stdout closed (>&-): the run goes on, its text goes nowhere
        sys.stdout = open(os.devnull, "w")
    words = sys.argv[1:] if argv is None else argv
    parser = build_parser(_command_in(words))
    wants_json = "--json" in words
    said = io.StringIO()
    try:
        with contextlib.redirect_stderr(said) if wants_json else contextlib.nullcontext():
            args = _parse(parser, argv)
    except SystemExit as exc:
        if wants_json:
            sys.stderr.write(said.getvalue())
            if exc.code == 2:                   # argparse's usage error, said on stderr: JSON on stdout too
                last = (said.getvalue().strip().splitlines() or ["the command line"])[-1]
                _json_error(last.split(": error: ", 1)[-1], 2, "usage")
        raise
    if wants_json:
        sys.stderr.write(said.getvalue())
    setup_logging(args.log_level)
    if args.command not in NO_SIMULATOR:      # numba's import (0.3 s) where nothing compiles
        from hil.commands.progress import announce_compiles
        announce_compiles()
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    if getattr(args, "json", False):
        sys.stdout = _Watched(sys.stdout)
    try:
        return _run(args)
    finally:
        if isinstance(sys.stdout, _Watched):
            sys.stdout = sys.stdout.inner


_UNIT_WORD = re.compile(r"^(?:[a-zA-Z\u00b5\u03bc%\u00b0][a-zA-Z0-9/^*.\u00b5\u03bc\u00b2\u00b3]*|/[a-zA-Z].*)$")
_NUMBER_WORD = re.compile(r"^[+\-\u2212]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+\-]?[0-9]+)?$")


def _parse(parser, argv):
    """``parser.parse_args``, where a word left over is said by the command's own parser, with the
    fix where it is a unit written apart from its number (``--feed 7000 mm/min``: one word,
    ``7000mm/min``, or quoted)."""
    args, extras = parser.parse_known_args(argv)
    if not extras:
        return args
    words = list(sys.argv[1:] if argv is None else argv)
    hints = []
    for w in extras:
        i = words.index(w) if w in words else -1
        if i > 0 and _UNIT_WORD.match(w) and _NUMBER_WORD.match(words[i - 1]):
            hints.append(f"{words[i - 1]}{w}")
    hint = (f" (a quantity is one word: {', '.join(hints)}, without the space, or in quotes)" if hints else "")
    sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
    own = sub.choices.get(getattr(args, "command", None)) if sub is not None else None
    (own or parser).error(f"unrecognized arguments: {' '.join(extras)}{hint}")


class _Watched:
    """stdout, noting whether anything was written: a --json run that fails before printing its
    object prints one of its error instead (a script reading stdout gets JSON either way)."""

    def __init__(self, inner):
        self.inner, self.wrote = inner, False

    def write(self, text):
        self.wrote = self.wrote or bool(text)
        return self.inner.write(text)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def _json_error(message: str, code: int, label: str) -> None:
    """``{"error", "exit_code", "kind"}`` on stdout, where a --json run printed nothing."""
    import json
    out = sys.stdout
    if isinstance(out, _Watched):
        if out.wrote:
            return
        out = out.inner
    try:
        out.write(json.dumps({"error": message, "exit_code": code, "kind": label}) + "\n")
        out.flush()
    except (OSError, ValueError):
        pass


def _failed(args, message: str, code: int, label: str = "error") -> int:
    """One line on stderr (and its JSON on stdout with --json); returns the exit code."""
    print(f"hil {args.command}: {label}: {message}", file=sys.stderr)
    if getattr(args, "json", False):
        _json_error(message, code, label)
    return code


def _run(args) -> int:
    try:
        if args.can_log:           # checked here; each command passes it to the backend it opens
            from drivers.canopen import canlog
            try:
                canlog.check(args.can_log)
            except ValueError as exc:
                return _failed(args, str(exc), 2)
        rc = int(args._run(args) or 0)
        sys.stdout.flush()        # here, not at exit: a reader gone away is answered below
        return rc
    except BrokenPipeError:
        return _stdout_closed()
    except HilError as exc:
        # one line, and the exit code of the error's kind (2: fix and retry; 1: drive fault;
        # a run stopped early: how it stopped, hil.errors.STOP_EXIT_CODES)
        return _failed(args, str(exc), exc.exit_code, exc.label)
    except (FileExistsError, FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError) as exc:
        # a path the user gave that cannot be read or written as asked (e.g. --out naming a file)
        if exc.filename is None:
            raise
        return _failed(args, f"{exc.filename}: {exc.strerror}", 2)
    except KeyboardInterrupt:
        print(f"hil {args.command}: interrupted", file=sys.stderr)
        if getattr(args, "json", False):
            _json_error("interrupted", 130, "interrupted")
        return 130
    except OSError as exc:
        # a device that takes nothing more (stdout on /dev/full, a full disk): one line, not a
        # traceback and exit 1 (the drive-fault code); what was recorded before stays on disk
        if exc.errno not in (errno.ENOSPC, errno.EIO, errno.EDQUOT) or exc.filename is not None:
            raise
        _stdout_closed()
        print(f"hil {args.command}: error: a write failed ({exc.strerror}): standard output or a file of the "
              f"command; free space or write elsewhere (--out)", file=sys.stderr)
        return 2


def _stdout_closed() -> int:
    """The reader of stdout went away: point stdout at the null device (the interpreter's flush at
    exit would fail again, with a traceback-like message) and exit with STDOUT_CLOSED_EXIT."""
    from hil.errors import STDOUT_CLOSED_EXIT
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):     # not a real file (a test's capture)
        pass
    return STDOUT_CLOSED_EXIT


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
