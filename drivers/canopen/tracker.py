"""The cyclic SYNC/answer tracker of the CANopen backend: which SYNC is the last one sent (its
counter, 1..:data:`~drivers.canopen.codec.SYNC_OVERFLOW`), which TPDOs of its answer are in,
the values they carried, and the counts of a run (SYNCs, missed and late answers, the longest run
of misses, the answer latency).

A TPDO counts as the answer to the last SYNC only when it is one: with the SYNC counter echo
(0x2001 in the last TPDO of the answer) the echo must show the counter of the last SYNC (the TPDOs
before it are held until then); without it, a TPDO counts when it arrives after the SYNC. A late
answer is counted, logged and dropped. The tool-tip sensor's TPDO has no echo: it counts when it
arrives.

Real-time: every method but the constructor and :meth:`configure`. The counters are plain
integers, the sets and dictionaries are cleared, never replaced, and the latency goes into a
:class:`~drivers.rt.SampleBuffer` allocated once: a cycle without misses leaves nothing behind.
The events (misses, late answers) go into the bounded log the caller passes.
"""
from __future__ import annotations

import threading
import time

from drivers.canopen.codec import SYNC_ECHO, SYNC_OVERFLOW, TIP_FMT, TIP_KEY, pdo_struct
from drivers.rt import SampleBuffer

__all__ = ["AnswerTracker"]


class AnswerTracker:
    """The answer to the last SYNC. ``event`` is set when the whole answer is in (the backend
    passes one whose ``wait`` takes the frames itself in the cyclic phase); ``events`` is the
    backend's bounded event log (``append`` only)."""

    def __init__(self, event: threading.Event, events):
        self.lock = threading.Lock()
        self.event = event
        self.events = events
        self.values: dict = {}       # the received values: index (or (index, sub), or TIP_KEY) -> raw
        self.fresh: set = set()      # COB-IDs whose part of the answer to the last SYNC is in
        self.want: set = set()       # COB-IDs that make up a whole answer
        self.pending: dict = {}      # echo: the TPDOs before the one with the echo, held until it
        self.decode: dict = {}       # COB-ID -> (struct, keys): the mapped TPDOs, decoded in one call
        self.echo = True             # the drive echoes the SYNC counter (0x2001)
        self.echo_cob = None         # the TPDO that carries the echo (the last one)
        self.tip_cob = None          # the tool-tip sensor's TPDO (no echo)
        self.counter = 0             # the last SYNC's counter
        self.sync_sent = 0.0         # time.perf_counter() of the last SYNC
        self.syncs = 0
        self.late_total = 0
        self.missed_total = 0
        self.miss_run = 0            # consecutive cycles without their answer, now
        self.miss_run_max = 0        # the longest such run
        self.only_tip_missing = False  # the last miss: the tip sensor's TPDO alone
        self.answer_latency = SampleBuffer()     # SYNC sent -> the whole TPDO answer taken (s)

    # -- not real-time ---------------------------------------------------------------------------
    def configure(self, tpdo: dict, echo: bool, tip_cob) -> None:
        """The answer's parts: ``tpdo`` (COB-ID -> mapped ``[(index, sub, bits)]``), whether the
        last TPDO carries the SYNC echo, the tip sensor's COB-ID (or None)."""
        self.decode = {cob: pdo_struct(entries) for cob, entries in tpdo.items()}
        self.tip_cob = tip_cob
        if tip_cob:
            self.decode[tip_cob] = (TIP_FMT, (TIP_KEY,))
        self.want = set(tpdo) | ({tip_cob} if tip_cob else set())
        self.echo = echo
        self.echo_cob = max(tpdo) if echo else None

    def assume_answered(self, values: dict) -> None:
        """The first cycle reads the state as configured (``values`` read over SDO)."""
        self.miss_run = 0
        self.fresh = set(self.want)
        self.values.update(values)

    # -- real-time -------------------------------------------------------------------------------
    def next_sync(self) -> int:
        """A new SYNC goes out: from here on only its answer is fresh. Returns its counter."""
        with self.lock:
            self.counter = self.counter % SYNC_OVERFLOW + 1
            self.fresh.clear()
            self.pending.clear()
            self.event.clear()
            self.sync_sent = time.perf_counter()
        return self.counter

    def complete(self) -> bool:
        return self.fresh >= self.want

    def on_tpdo(self, can_id, data, timestamp) -> None:
        """A TPDO of the drive (the receiving thread's callback)."""
        plan = self.decode.get(can_id)
        if plan is None:
            return
        fmt, keys = plan
        values = dict(zip(keys, fmt.unpack_from(data)))
        with self.lock:
            if self.echo:
                self.pending[can_id] = values
                if can_id != self.echo_cob:
                    return
                echo = values.get(SYNC_ECHO)
                if echo != self.counter:
                    self.late_total += 1
                    self.events.append(f"cycle {self.syncs}: late TPDO (answers SYNC {echo}, "
                                       f"expected {self.counter})")
                    self.pending.clear()
                    return
                for cob, vals in self.pending.items():
                    self.values.update(vals)
                    self.fresh.add(cob)
                self.pending.clear()
            else:
                if time.perf_counter() < self.sync_sent:
                    self.late_total += 1
                    return
                self.values.update(values)
                self.fresh.add(can_id)
            self._check_complete()

    def on_tip(self, can_id, data, timestamp) -> None:
        """The tip sensor's TPDO1 (position value 0x6004): no SYNC counter, taken when it arrives
        after the SYNC (in lockstep the barrier orders it)."""
        if len(data) < 4:
            return
        v = TIP_FMT.unpack_from(data, 0)[0]
        with self.lock:
            self.values[TIP_KEY] = v
            self.fresh.add(can_id)
            self._check_complete()

    def _check_complete(self) -> None:          # with the lock held
        if self.fresh >= self.want:
            if not self.event.is_set():
                self.answer_latency.append(time.perf_counter() - self.sync_sent)
            self.event.set()

    def close_cycle(self) -> bool:
        """The cycle reads its feedback: whether its answer is in is settled. True where it is;
        else the miss is counted and :attr:`only_tip_missing` says whether the drive answered."""
        with self.lock:
            if self.fresh >= self.want:
                self.miss_run = 0
                return True
            self.only_tip_missing = self.want - self.fresh == {self.tip_cob}     # a set only on a miss
        self.miss_run += 1
        self.missed_total += 1
        self.miss_run_max = max(self.miss_run_max, self.miss_run)
        return False
