"""The record inputs shared by ``hil compare``, ``hil diagnose`` and ``hil fit``: their common
options (the record(s), ``--config``, ``--set``, ``--map``, ``--channels``, ``--align``,
``--open-loop``), reading the configuration and the records (each refused or warned about as
:func:`hil.io.measurement.check_usable` and :func:`hil.io.importers.data_warnings` say), the replay
of a record through the model (one, or several fitted as one), and the Ctrl-C of a long replay.
"""
from __future__ import annotations

from contextlib import contextmanager

__all__ = ["add_common", "check_candidates", "load_inputs", "load_records", "make_records", "make_replay", "prompt_interrupt"]


def add_common(parser, records: bool = False) -> None:
    """The record(s), config, --set, --map, --channels, --align, --json; ``records``: any number of
    records of one axis, fitted together, and ``--validate RECORD...`` (hil fit, hil diagnose)."""
    formats = "CSV in the project's format, a text log, an Excel .xlsx sheet, or a MATLAB .mat record (v7.3 too)"
    if records:
        parser.add_argument("data", nargs="+", help=f"measurement(s) of one axis, fitted together: {formats}")
        parser.add_argument("--validate", action="extend", nargs="+", default=[], metavar="RECORD[:MAP]",
                            help="records not used for the fit: their errors are reported beside the "
                                 "estimation records'; each read with --map, or with its own map after a colon "
                                 "(a validation record with inputs of its own: "
                                 "'DATA_EMPS_PULSES.mat:t=t,qg=x_cmd,qm=x_motor,vir*gtau=force,pulses_N=u_add[V]')")
    else:
        parser.add_argument("data", help=f"measurement: {formats}")
    parser.add_argument("--config", required=True, metavar="FILE", help="axis configuration (TOML)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    parser.add_argument("--map", action="append", default=[], metavar="SOURCE=CHANNEL[unit]",
                        help="column, variable or expression -> channel, the same for every format: "
                             "pos=x_table[mm], vir*gtau=force, data[:,2]=x_motor (0-based column; data(:,3) "
                             "1-based as in MATLAB) (repeatable, or comma-separated)")
    parser.add_argument("--sheet", default=None, metavar="NAME", help="the sheet of an Excel file (default: the first)")
    parser.add_argument("--open-loop", action="store_true",
                        help="an open-loop run (torque steps, a chirp): the recorded torque (rotary) or command/force "
                             "(linear) drives the plant, no position loop; the positions are compared")
    parser.add_argument("--channels", metavar="CHANNELS", default=None, help="comma-separated channels to use (default: all measured)")
    parser.add_argument("--align", action="store_true", help="align each channel in time by cross-correlation")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def load_inputs(args):
    """The config (``--config`` with ``--set``) and the record (``data`` with ``--map``)."""
    from hil.config import load, parse_assignment
    cfg = load(args.config, dict(parse_assignment(s) for s in args.set))
    return cfg, _read_record(args, cfg, args.data)


LARGE_RECORD_BYTES = 50 << 20      # a record above this takes noticeably long to read: said before it is


def _say_if_large(path) -> None:
    """One line on stderr before a large record is read (a 10^7-row CSV took 90 s in silence)."""
    import os
    import sys
    try:
        size = os.stat(path).st_size
    except OSError:
        return                  # reading it says what is wrong
    if size > LARGE_RECORD_BYTES:
        print(f"reading {path} ({size / 2**20:.0f} MiB): a large record takes a while to read and replay (a record "
              f"of every n-th row, at the loop's own period, replays in a fraction of the time)", file=sys.stderr,
              flush=True)


def _read_record(args, cfg, path, mapping=None):
    import sys

    from hil.io.importers import data_warnings, parse_mapping, read_any
    from hil.io.measurement import check_usable
    mapping = args.map if mapping is None else [mapping]
    _say_if_large(path)
    meas = read_any(path, parse_mapping(mapping) or None, sheet=getattr(args, "sheet", None))
    # degenerate records are refused, never diagnosed
    check_usable(meas, (cfg["limits.travel_min"], cfg["limits.travel_max"]), cfg["control.position_period"],
                 cfg["control.velocity_period"], open_loop=getattr(args, "open_loop", False))
    # what can still be replayed but deserves a look: outliers, gaps, a slow log
    meas.warnings = data_warnings(meas, cfg["control.position_period"])
    from hil.io.importers import unmapped_inputs
    from hil.io.measurement import CHANNELS
    meas.warnings += unmapped_inputs([c for c in meas.channels if c not in CHANNELS], meas.channels, meas.source)
    for w in meas.warnings:
        print(f"warning: {w}", file=sys.stderr)        # each warning names its file already
    return meas


def load_records(args):
    """The config, the estimation records (``data``: one or more) and the ``--validate`` records,
    each read with the same ``--map``."""
    from hil.config import load, parse_assignment
    cfg = load(args.config, dict(parse_assignment(s) for s in args.set))
    paths = [args.data] if isinstance(args.data, str) else list(args.data)
    est = [_read_record(args, cfg, p) for p in paths]
    val = [_read_record(args, cfg, *split_record_map(p)) for p in getattr(args, "validate", None) or []]
    _warn_self_validation(paths, getattr(args, "validate", None) or [])
    return cfg, est, val


def _warn_self_validation(estimation, validation) -> None:
    """A --validate record that is an estimation record itself (the same file) validates nothing:
    its errors are the estimation's. Said once per such record, not refused (a quick check of the
    command line is a fair use)."""
    import os
    import sys
    for v in validation:
        path = split_record_map(v)[0]
        for e in estimation:
            try:
                same = os.path.samefile(path, e)
            except OSError:
                continue
            if same:
                print(f"warning: --validate {path}: the estimation record itself; its validation errors are the "
                      f"fit's own and say nothing of how the model predicts another record", file=sys.stderr)


def split_record_map(arg: str) -> tuple[str, str | None]:
    """``RECORD[:MAP]`` -> (record, map or None): the record is the longest part before a colon that
    names a file (a map holds colons itself: ``data[:,0]=t``); the whole argument when it names
    one, or when no part does (then reading it says that the file is missing)."""
    from pathlib import Path
    if Path(arg).is_file():
        return arg, None
    cuts = [i for i, ch in enumerate(arg) if ch == ":"]
    for i in cuts:
        if Path(arg[:i]).is_file():
            return arg[:i], arg[i + 1:] or None
    return arg, None


def make_records(args, cfg, measurements):
    """One record: its Replay; several: :class:`hil.ident.records.Records`, fitted as one, on the
    channels every record has (or ``--channels``). Their floor is theirs alone: the ``--validate``
    records never join it (issue 50: a held-out record raised the floor it was judged against)."""
    from hil.ident.records import Records, common_channels
    if len(measurements) == 1:
        return make_replay(args, cfg, measurements[0])
    parts = [make_replay(args, cfg, m) for m in measurements]
    chans = common_channels(parts)
    if any(p.channels != chans for p in parts):
        from hil.ident.replay import Replay
        parts = [Replay(m, cfg, chans, align=getattr(args, "align", False),
                        open_loop=getattr(args, "open_loop", False)) for m in measurements]
    return Records(parts)


def check_candidates(names, cfg, option: str) -> None:
    """Refuse, in one line naming ``option``, a candidate name the catalogue and the config do not
    know, or an effect this axis cannot have (with the reason: backlash without a transmission
    link), before any record is read."""
    from hil.errors import UserError
    from hil.plant_config import candidate, plant_from_config
    plant = plant_from_config(cfg) if names else None
    for n in names or ():
        try:
            why = candidate(n, cfg).unsuited(plant)
        except KeyError as exc:
            raise UserError(f"{option}: {str(exc).strip(chr(39) + chr(34))}") from None
        if why:
            raise UserError(f"{option} {n}: cannot act on this axis: {why}")


def make_replay(args, cfg, meas):
    """The record replayed through the config, on the ``--channels`` asked for, ``--align``-ed."""
    from hil.ident.replay import Replay
    chans = args.channels.split(",") if getattr(args, "channels", None) else None
    rp = Replay(meas, cfg, chans, align=getattr(args, "align", False), open_loop=getattr(args, "open_loop", False))
    if chans is None:
        _warn_unused_channels(rp)
    return rp


def _warn_unused_channels(rp) -> None:
    """A channel of the record that the replay could compare and does not is said once: a force
    mapped on a rotary axis (which compares its torque), a torque on a linear one."""
    import sys

    comparable = ("x_motor", "x_table", "x_tip", "torque", "force", "command")
    source = getattr(rp.meas, "open_loop_source", rp.meas)
    unused = [c for c in comparable if c in source and c not in rp.channels and c != rp.drive_channel]
    for c in unused:
        print(f"warning: {rp.meas.source}: channel {c!r} is mapped but the replay does not use it (on this "
              f"{'rotary' if rp.cfg.rotary else 'linear'} axis the model compares "
              f"{', '.join(rp.channels)}); check the map", file=sys.stderr)


@contextmanager
def prompt_interrupt():
    """Ctrl-C ends the process at once inside the block (the default action of SIGINT): the
    compiled replay holds the interpreter for seconds on a long record, where a KeyboardInterrupt
    would wait for it. For computing only: nothing may be half-written inside the block."""
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
