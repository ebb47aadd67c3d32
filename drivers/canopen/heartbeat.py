"""The heartbeats of the CANopen backend: the host's, produced (python-can's periodic sender on the
wall clock; in lockstep on the SYNC clock, one per ``canopen.host_heartbeat`` of drive time), and
the drive's, consumed (lost after ``canopen.heartbeat_timeout``). The drive's heartbeat consumer
(0x1016) stops the drive when the host's stops; this side reports a drive whose heartbeat stopped.

Real-time: :meth:`Heartbeats.on_sync`, :meth:`Heartbeats.lost`, :meth:`Heartbeats.on_drive_heartbeat`
(a callback of the receiving thread); :meth:`Heartbeats.start` and :meth:`Heartbeats.stop` are not.
"""
from __future__ import annotations

import time

__all__ = ["Heartbeats"]


class Heartbeats:
    """``settings``: drivers.canopen.section.CanopenSettings; ``link``: the backend's
    drivers.canopen.link.CanLink (frames go out through it)."""

    def __init__(self, settings, link):
        self.settings, self.link = settings, link
        self.time = 0.0              # lockstep: the drive's clock, advanced by each SYNC
        self.next_send = 0.0         # lockstep: when the host's next heartbeat is due
        self.task = None             # wall clock: python-can's periodic send of the host's heartbeat
        self.drive_last = None       # when the drive's heartbeat was last seen (None: before open)

    def now(self) -> float:
        """The drive's clock in lockstep, else the wall clock."""
        return self.time if self.settings.lockstep else time.perf_counter()

    # -- not real-time ---------------------------------------------------------------------------
    def start(self, on_send_error) -> None:
        """The host's heartbeat starts (``on_send_error(exc)``: python-can's send thread failed;
        it returns False to stop the task); the drive's counts as seen now."""
        s = self.settings
        if not s.lockstep:
            self.task = self.link.network.send_periodic(0x700 + s.host_id, [0x05], s.host_heartbeat)
            # python-can's send thread re-raises a failed send unless told otherwise, and dies with
            # its traceback on the screen (the drive's process killed: a broken pipe)
            task = getattr(self.task, "_task", None)
            if task is not None and hasattr(task, "on_error"):
                task.on_error = on_send_error
        else:
            self.send()
        self.drive_last = self.now()

    def stop(self) -> None:
        if self.task is not None:
            self.task.stop()
            self.task = None

    # -- real-time -------------------------------------------------------------------------------
    def send(self) -> None:
        self.link.send(0x700 + self.settings.host_id, [0x05])
        self.next_send = self.time + self.settings.host_heartbeat

    def on_sync(self) -> None:
        """Lockstep: a SYNC went out, the drive's clock advances a cycle (the heartbeat when due)."""
        self.time += self.settings.cycle_time
        if self.time + 1e-12 >= self.next_send:
            self.send()

    def on_drive_heartbeat(self, can_id, data, timestamp) -> None:
        self.drive_last = self.now()

    def lost(self) -> str:
        """"" while the drive's heartbeat comes, else the fault's line."""
        if self.drive_last is None:
            return ""
        silent = self.now() - self.drive_last
        if silent > self.settings.heartbeat_timeout:
            return f"lost communication: drive heartbeat lost ({silent * 1e3:.0f} ms)"
        return ""
