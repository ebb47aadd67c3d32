"""The scope's ring buffer: what the real-time cycle writes and the scope's server reads.

The cycle must never wait for the scope. So the buffer is preallocated (a float64 array of
``capacity`` rows, one column per :data:`SCOPE_CHANNELS`), the cycle writes one row in place and
advances a write counter (``count``, rows written since the start), and there is no lock: the
reader copies a window and checks the counter before and after the copy (a seqlock on the row
index). A row the writer may have overwritten during the copy (its slot reused by a row with
written meanwhile) is dropped from the copy (:meth:`ScopeRing.window`),
so the reader gets a consistent, contiguous run of rows, never a half-written one.

The writer's stores reach memory in the order they are written (the row first, then the
counter; Python's interpreter lock orders them within a process, and x86's total store order
across processes, where the buffer is a shared file mapping read by the server's own process),
which is what the seqlock needs; a row is written through a memoryview of the buffer, element by
element, so a write allocates nothing that is kept.

Events (a trip, how the run ended) go into a second, preallocated table of ``(row index, time,
kind code)`` and fixed slots of reason text (UTF-8, at most 254 bytes), with their own counter.

One ring may watch several runs one after the other (a sweep's runs on an axis): each run's
clock starts at 0, so a row whose time is before the last row's starts a new run, and the ring
shifts that run's times (and its events') to go on one sample period after the last row: the
time axis of the page is one line.

Channels, SI: ``t`` (s), ``x_cmd``, ``x_motor``, ``x_table``, ``x_tip`` (m; NaN where the backend
has no tool-tip sensor), ``e_table``, ``e_tip`` (m, following errors), ``output`` (N m or N, the
controller's output), ``speed`` (m/s, the motor's speed as a linear speed at the table) and
``state`` (the supervisor's state, :data:`STATES`).
"""
from __future__ import annotations

import numpy as np

__all__ = ["ScopeRing", "SCOPE_CHANNELS", "STATES", "EVENT_KINDS"]

SCOPE_CHANNELS = ("t", "x_cmd", "x_motor", "x_table", "x_tip", "e_table", "e_tip", "output", "speed", "state")
# the supervisor's state as a number in the ``state`` channel
STATES = {"running": 0.0, "tripped": 1.0, "fault": 2.0, "aborted": 3.0, "complete": 4.0}
# what an event is; an event's code is its index here
EVENT_KINDS = ("trip", "fault", "aborted", "complete", "start")


REASON_BYTES = 256        # an event's reason, UTF-8, cut to this length in the shared buffer
_HEADER = 32              # bytes: count (int64), event count (int64), the last row's time (float64), spare


class ScopeRing:
    """A fixed-size ring of the loop's signals, one writer (the cycle), any number of readers.

    Everything lives in one flat buffer: a header (the row counter, the event counter, the last
    row's time), the rows, the events and their reasons. By default the buffer is this process's
    memory; with ``path`` it is a memory-mapped file (``/dev/shm`` where there is one), so that the
    scope's server can run in its own process and read it there (:meth:`attach`): it then never
    holds this process's interpreter lock, which the cycle needs.

    Parameters
    ----------
    capacity : int
        Rows kept (default 2**16: 65 s of a 1 kHz position clock).
    events : int
        Events kept (trips, the run's end), the oldest overwritten.
    path : str or Path, optional
        A file to map the buffer from (created, or with ``attach`` opened).
    """

    def __init__(self, capacity: int = 1 << 16, events: int = 64, path=None, attach: bool = False):
        if capacity < 2 or events < 1:
            raise ValueError(f"scope ring: capacity {capacity} (at least 2), events {events} (at least 1)")
        self.capacity = int(capacity)
        self.n = len(SCOPE_CHANNELS)
        self.n_events = int(events)
        size = _HEADER + 8 * self.capacity * self.n + 8 * 3 * self.n_events + REASON_BYTES * self.n_events
        self.path, self._map = path, None
        if path is None:
            buf = bytearray(size)
        else:
            import mmap
            import os
            fd = os.open(path, os.O_RDWR | (0 if attach else os.O_CREAT | os.O_TRUNC), 0o600)
            try:
                if not attach:
                    os.ftruncate(fd, size)
                buf = self._map = mmap.mmap(fd, size)
            finally:
                os.close(fd)
        mv = memoryview(buf)
        self._ints = mv[0:16].cast("q")                       # count, event count
        self._last = mv[16:24].cast("d")                      # the last row's time (s)
        off = _HEADER
        self.data = np.frombuffer(buf, float, self.capacity * self.n, off).reshape(self.capacity, self.n)
        self._flat = mv[off:off + 8 * self.capacity * self.n].cast("d")   # element stores, no temporaries
        off += 8 * self.capacity * self.n
        self.event_rows = np.frombuffer(buf, float, 3 * self.n_events, off).reshape(self.n_events, 3)
        self._event_flat = mv[off:off + 24 * self.n_events].cast("d")
        off += 24 * self.n_events
        self._reasons = mv[off:off + REASON_BYTES * self.n_events]
        if not attach:
            self.data[:] = np.nan
            self._last[0] = -np.inf
        self.state = 0.0                                      # written into every row (the writer's)
        self.t0 = 0.0                                         # added to the times of this run (see above)
        self.dt = 0.0                                         # the last row's time step

    @classmethod
    def attach(cls, path, capacity: int, events: int) -> ScopeRing:
        """The ring another process writes, mapped from its file (a reader)."""
        return cls(capacity, events, path=path, attach=True)

    def close(self) -> None:
        """Unmap the file (a ring in a file); the writer also removes the file."""
        if self._map is not None:
            # the views into the map must go before it can be closed
            for name in ("_ints", "_last", "_flat", "_event_flat", "_reasons"):
                getattr(self, name).release()
            self.data = self.event_rows = None
            self._map.close()
            self._map = None

    @property
    def count(self) -> int:
        """Rows written since the start (the seqlock's counter)."""
        return self._ints[0]

    @property
    def event_count(self) -> int:
        return self._ints[1]

    @property
    def last_t(self) -> float:
        """The time of the last row written (s, with the run's shift; -inf before the first)."""
        return self._last[0]

    # --- the writer (real-time) -------------------------------------------------------------------
    def write(self, t, x_cmd, x_motor, x_table, x_tip, e_table, e_tip, output, speed) -> None:
        """One row (real-time: stores into the preallocated buffer, then advances the counter)."""
        f = self._flat
        count = self._ints[0]
        i = (count % self.capacity) * 10
        last = self._last[0]
        t = t + self.t0
        if t < last:                 # a new run's clock starts at 0: go on after the last row
            self.t0 += last + (self.dt or 1e-3) - t
            t = last + (self.dt or 1e-3)
        else:
            self.dt = t - last if count else 0.0
        f[i] = t
        f[i + 1] = x_cmd
        f[i + 2] = x_motor
        f[i + 3] = x_table
        f[i + 4] = x_tip
        f[i + 5] = e_table
        f[i + 6] = e_tip
        f[i + 7] = output
        f[i + 8] = speed
        f[i + 9] = self.state
        self._last[0] = t
        self._ints[0] = count + 1    # after the row: a reader that sees the new count sees the row

    def event(self, t: float, kind: str, reason: str = "") -> None:
        """An event at time ``t`` (s) of the last row written: a trip, a fault, the run's end
        (``kind`` one of :data:`EVENT_KINDS`; at a trip or the run's end, not every cycle: the
        reason is encoded into the buffer). A trip, fault or abort also sets the state of the
        rows written after it."""
        code = EVENT_KINDS.index(kind)
        e = self._ints[1]
        j = e % self.n_events
        text = reason.encode("utf-8")[:REASON_BYTES - 2]
        r = self._reasons
        r[j * REASON_BYTES:j * REASON_BYTES + 2] = len(text).to_bytes(2, "little")
        r[j * REASON_BYTES + 2:j * REASON_BYTES + 2 + len(text)] = text
        f = self._event_flat
        f[3 * j] = self._ints[0] - 1
        f[3 * j + 1] = t + self.t0
        f[3 * j + 2] = code
        self._ints[1] = e + 1
        if kind in ("trip", "fault", "aborted"):
            self.state = STATES["tripped" if kind == "trip" else kind]

    # --- the reader (the server's thread or process) ----------------------------------------------
    def window(self, since: int = 0, most: int | None = None) -> tuple[int, np.ndarray]:
        """The rows with index ``>= since`` written so far (at most ``most``, the newest), as a copy:
        ``(index of the first row returned, rows)``. Rows the writer overwrote during the copy are
        dropped (the seqlock), so the rows are consistent and contiguous; at most ``capacity - 1``
        rows (the oldest slot is the one the writer may be filling)."""
        cap = self.capacity
        before = self.count
        first = max(since, before - cap, 0)
        if most is not None:
            first = max(first, before - most)
        if first >= before:
            return before, np.zeros((0, self.n))
        slots = np.arange(first, before) % cap
        rows = self.data[slots]                      # the copy (fancy indexing copies)
        after = self.count
        # the writer, meanwhile, wrote rows before..after-1 and may be writing row ``after``: their
        # slots held rows after-cap .. after; those are no longer the rows we asked for
        stale = after + 1 - cap
        if stale > first:
            rows = rows[stale - first:]
            first = stale
        return first, rows

    def events(self, since: int = 0) -> tuple[int, list[tuple[int, float, str, str]]]:
        """The events with index ``>= since``: ``(next index, [(row, t, kind, reason), ...])``."""
        n = self.n_events
        end = self.event_count
        out = []
        for e in range(max(since, end - n), end):
            j = e % n
            row, t, code = self.event_rows[j]
            r = bytes(self._reasons[j * REASON_BYTES:(j + 1) * REASON_BYTES])
            reason = r[2:2 + int.from_bytes(r[:2], "little")].decode("utf-8", "replace")
            out.append((int(row), float(t), EVENT_KINDS[int(code)], reason))
        return end, out


def feed(ring: ScopeRing, channels: dict, speed=None, status: str = "complete", reason: str = "",
         pace: float | None = 1.0, stop=None, sleep=None) -> int:
    """Write a computed or recorded run into ``ring`` row by row: the dry run on the simulated
    plant (computed at once by the compiled loop, then shown as it would have run) and ``hil
    scope RECORD.csv``.

    ``channels``: the measurement-format channels (``t``, ``x_cmd``, ``x_motor``, ``x_table``,
    ``x_tip``, ``e_table``, ``e_tip``, ``torque`` or ``command``); ``speed``: the motor's speed
    (m/s) per row, default the derivative of ``x_motor``. ``pace``: how many seconds of the run per
    second of wall time (1.0: real time; None: all at once). ``stop``: a
    :class:`threading.Event` that ends it early. The run's end (``status``, ``reason``) becomes
    the last row's event. Returns the rows written.
    """
    import time

    t = np.asarray(channels["t"], float)
    n = t.size
    if n == 0:
        return 0
    out = channels["torque"] if "torque" in channels else channels.get("command", np.zeros(n))
    if speed is None:
        speed = np.gradient(channels["x_motor"], t) if n > 1 else np.zeros(n)
    cols = [t, channels["x_cmd"], channels["x_motor"], channels["x_table"], channels.get("x_tip", channels["x_table"]),
            channels["e_table"], channels["e_tip"], out, speed]
    rows = np.column_stack([np.asarray(c, float) for c in cols]).tolist()
    sleep = sleep or time.sleep
    wall0 = time.perf_counter()
    k = 0
    while k < n:
        if stop is not None and stop.is_set():
            break
        if pace is None:
            due = n
        else:
            due = int(np.searchsorted(t, t[0] + (time.perf_counter() - wall0) * pace, side="right"))
        for row in rows[k:max(due, k)]:
            ring.write(*row)
        k = max(due, k)
        if k < n:
            sleep(0.005)
    if k >= n:
        kind = {"tripped": "trip", "fault": "fault", "aborted": "aborted"}.get(status, "complete")
        ring.event(float(t[-1]), kind, reason)
    return k
