"""The CAN options of the commands that talk to a drive, as python-can users know them.

``-i/--interface``, ``-c/--channel``, ``-b/--bitrate`` (python-can's ``can.logger`` and
``can.viewer`` use the same letters) set ``canopen.interface``, ``canopen.channel`` and
``canopen.bitrate``; ``--can-log FILE`` records the bus (drivers.canopen.canlog).

Where the settings come from, first found wins: these options; the ``[canopen]`` keys the config
file writes; python-can's own configuration (``can.util.load_config``: the ``CAN_INTERFACE``,
``CAN_CHANNEL``, ``CAN_BITRATE`` environment variables, then ``~/.canrc`` or ``can.ini``); the
schema's defaults (the virtual bus).
"""
from __future__ import annotations

import argparse

__all__ = ["add_can_options", "can_overrides"]


def add_can_options(p) -> None:
    g = p.add_argument_group("CAN bus (backend canopen; default: the config's [canopen], then python-can's "
                             "configuration: CAN_INTERFACE/CAN_CHANNEL/CAN_BITRATE, ~/.canrc)")
    g.add_argument("-i", "--interface", default=None, metavar="NAME",
                   help="python-can interface: socketcan, pcan, kvaser, slcan, socketcand, virtual, ...")
    g.add_argument("-c", "--channel", default=None, metavar="NAME", help="python-can channel: can0, PCAN_USBBUS1, ...")
    g.add_argument("-b", "--bitrate", default=None, type=int, metavar="BIT/S", help="CAN bit rate, e.g. 1000000")
    # SUPPRESS: the global `hil --can-log FILE` stays when the command does not repeat it
    g.add_argument("--can-log", default=argparse.SUPPRESS, metavar="FILE",
                   help="record the bus (received and sent frames) with python-can's logger: FILE.asc or .blf")


def _python_can_config() -> dict:
    """python-can's configuration (environment, ~/.canrc, can.ini), {} when it names no interface."""
    try:
        import can
        conf = can.util.load_config()
    except Exception:           # no interface configured (python-can raises), or a broken file
        return {}
    return {k: v for k, v in conf.items() if v is not None}


def can_overrides(args, written) -> dict:
    """``canopen.*`` overrides: -i/-c/-b where given, else python-can's configuration for the keys
    the config file does not write (``written``: the keys it writes, ``Config.file_keys``)."""
    out = {}
    given = {"canopen.interface": getattr(args, "interface", None), "canopen.channel": getattr(args, "channel", None),
             "canopen.bitrate": getattr(args, "bitrate", None)}
    pc = None
    for key, value in given.items():
        if value is not None:
            out[key] = value
        elif key not in written:
            pc = _python_can_config() if pc is None else pc
            v = pc.get(key.split(".", 1)[1])
            if v is not None:
                out[key] = int(v) if key == "canopen.bitrate" else str(v)
    return out
