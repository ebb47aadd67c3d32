"""A trace of the CAN bus during a run, written by python-can's own loggers (``--can-log FILE``).

``can.Logger`` picks the format from the file's suffix (``.asc``: Vector ASCII, ``.blf``: Vector
binary, ``.log``, ``.csv``, ...), the files every CAN tool reads. The recorder is one
``can.Listener``:

* received frames: attached to the canopen network's notifier (the thread that already takes every
  received frame and hands it to canopen's subscribers) during start-up, SDO and shutdown, and
  handed over by the loop's own thread during the cyclic phase (drivers.canopen.backend takes its
  frames itself then), so nothing is added to the receive path but one call per frame;
* sent frames: the bus's ``send`` is wrapped, each frame written after it went out, marked as
  transmitted (``is_rx = False``; ``Tx`` in an ASC file).

Writing is the logger's (a buffered file write under a lock, the notifier and the cycle thread
both write). It is for commissioning and fault finding, not for timing figures: a run with a trace
does a little more per frame.

The command line checks the name once (:func:`check`, ``hil --can-log FILE``) and passes it to the
backend it opens (``open_backend(cfg, can_log=FILE)``; no process-wide setting); the canopen
backend attaches a recorder when it connects (:func:`attach`) and stops it when it closes.
"""
from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path

import can

__all__ = ["BusRecorder", "check", "attach", "FORMATS"]

logger = logging.getLogger(__name__)

# the formats of python-can's writers that need no further package (its .mf4 needs asammdf)
FORMATS = (".asc", ".blf", ".log", ".csv", ".trc")


def check(path: str | Path) -> str:
    """The trace's file name checked before anything connects: the suffix names the format
    (python-can: .asc, .blf, .log, .csv, .trc) and no symbolic link stands there; ValueError
    saying what is wrong, else the name."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"--can-log {path}: expected a file ending in {', '.join(FORMATS)} (the format "
                         f"python-can writes), got {suffix or 'no suffix'}")
    _refuse_link(path)
    return str(path)


def _refuse_link(path) -> None:
    """A symbolic link at the trace's name is refused, never followed (it could point at any
    file the user may write), as hil.io.safe_write does for every output."""
    if Path(path).is_symlink():
        raise ValueError(f"--can-log {path}: is a symbolic link; refusing to write through it")


class BusRecorder(can.Listener):
    """Every frame received (through the notifier) and sent (through the bus) written to ``path``
    by :class:`can.Logger`."""

    def __init__(self, path: str | Path):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        _refuse_link(path)
        # created here without following a link (O_NOFOLLOW), then python-can's writer opens it
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0), 0o644))
        self.path = str(path)
        self._writer = can.Logger(self.path)
        self._lock = threading.Lock()
        self._bus = None
        self._send = None
        self._notifier = None
        self.frames = 0

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            if self._writer is None:
                return
            self._writer.on_message_received(msg)
            self.frames += 1

    def attach(self, notifier, bus) -> "BusRecorder":
        """Listen on ``notifier`` (received frames) and wrap ``bus.send`` (sent frames)."""
        if notifier is not None:
            notifier.add_listener(self)
            self._notifier = notifier
        if bus is not None:
            original = bus.send
            self._bus, self._send = bus, original

            def send(msg, timeout=None):
                original(msg, timeout)
                if not msg.timestamp:
                    msg.timestamp = time.time()
                msg.is_rx = False
                self.on_message_received(msg)
            bus.send = send
        logger.info("recording the CAN bus into %s", self.path)
        return self

    def stop(self) -> None:
        """python-can's notifier calls this when it stops; the canopen backend stops its notifier
        for the cyclic phase (the loop's thread then hands its frames here) and starts a new one
        after it, so a notifier's stop does not end the trace: :meth:`close` does."""

    def follow(self, notifier) -> None:
        """Listen on ``notifier`` from now on (a new one, after the cyclic phase)."""
        if notifier is not None and self._writer is not None:
            notifier.add_listener(self)
            self._notifier = notifier

    def close(self) -> None:
        """Detach and close the file (safe to call twice)."""
        if self._notifier is not None:
            try:
                self._notifier.remove_listener(self)
            except ValueError:
                pass
            self._notifier = None
        if self._bus is not None:
            self._bus.send = self._send
            self._bus = None
        with self._lock:
            if self._writer is not None:
                self._writer.stop()
                self._writer = None
                logger.info("CAN trace: %d frames in %s", self.frames, self.path)


def attach(network, path: str | Path | None) -> BusRecorder | None:
    """A recorder into ``path`` (the backend's ``can_log`` option) on a connected
    ``canopen.Network``; None where no trace was asked for."""
    if path is None or network is None:
        return None
    return BusRecorder(path).attach(getattr(network, "notifier", None), getattr(network, "bus", None))
