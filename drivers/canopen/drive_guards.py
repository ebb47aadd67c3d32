"""The simulated drive's own guards against a host or a link that died: the heartbeat consumer
(0x1016) and the SYNC consumer (communication cycle period 0x1006 times the SYNC loss limit 0x2003,
a count of cycles), either of which, once lost while OPERATION ENABLED, makes the drive perform the
abort-connection option 0x6007; and the judgement of stale SYNCs after a stall of the drive.

Stale setpoints. A drive whose processor stalled finds a backlog of RPDOs and SYNCs when it
resumes. It never executes them: the SYNC consumer acts first where the stall was longer than its
time; after a shorter stall (more than ``STALE_CYCLES`` periods in which the drive ran nothing)
every SYNC whose counter belongs to a cycle more than ``STALE_CYCLES`` periods older than the
drive's clock is stale (the drive discards it with its targets). A backlog drains faster than the
clock runs, each of its SYNCs nearer the drive's clock than the one before; a SYNC as far behind
as the one before it came a period later: the host is sending live again (it paused with the
drive, a stall of the whole machine, and its counter lost those cycles), and nothing more is
stale. (Judged by the counter alone, such a host's every SYNC stayed "behind" until the counter
wrapped: 240 cycles discarded, a lost-communication trip of a healthy link.)

Real-time: every method but the constructor (each runs with the drive's lock held).
``drive`` is the :class:`~drivers.canopen.drive_sim.DriveSim` these guards belong to.
"""
from __future__ import annotations

import time

__all__ = ["DriveGuards", "STALE_CYCLES"]

STALE_CYCLES = 2          # a SYNC this many periods older than the drive's clock is stale


class DriveGuards:
    """The consumers' clocks and the stall reference of one drive."""

    def __init__(self, drive):
        self.drive = drive
        self.last_host_heartbeat = 0.0       # the host's heartbeat last seen (the consumers' clock)
        self.last_sync_wall = time.perf_counter()
        self.last_awake = time.perf_counter()         # the drive's thread last looked at its clock
        self.armed = False                 # the SYNC consumer watches from the first SYNC in OPERATION ENABLED
        self.own_cycles = 0                # cycles run without a SYNC since the last one (lockstep consumer)
        self.stall_ref: tuple[int, float] | None = None    # (SYNC counter, wall time) before a stall
        self.behind: float | None = None     # how far the last SYNC judged against stall_ref was behind (cycles)
        self.last_counter = 0

    def on_sync(self, counter: int, enabled: bool) -> None:
        """A fresh SYNC: the SYNC consumer's clock restarts (and watches once enabled)."""
        self.last_sync_wall = time.perf_counter()
        self.own_cycles = 0
        self.last_counter = counter
        if enabled:
            self.armed = True

    def restart(self) -> None:
        """Enabling: the SYNC consumer waits for the first SYNC of this run; no stall is judged."""
        self.armed = False
        self.own_cycles = 0
        self.stall_ref = self.behind = None

    def watch(self, conf) -> None:
        """The heartbeat consumer and the SYNC consumer: either lost while OPERATION ENABLED
        performs the abort-connection option (0x6007)."""
        d = self.drive
        if d.state != "OPERATION ENABLED":
            return
        timeout = conf["hb_timeout"]
        if timeout > 0 and d.hb_now() - self.last_host_heartbeat > timeout:
            d.abort_connection("host heartbeat lost", 0x8130)
            return
        limit = conf["sync_loss"]
        if limit and self.armed:
            if d.lockstep:
                lost = self.own_cycles >= limit
            else:
                lost = time.perf_counter() - self.last_sync_wall > limit * conf["comm_period"]
            if lost:
                d.abort_connection(f"SYNC lost ({limit} cycles of {conf['comm_period'] * 1e3:g} ms)", 0x8100)

    def stale(self, counter: int, conf, now: float | None = None) -> bool:
        """After a stall of the drive (``stall_ref``: the last SYNC before it, counter and wall
        time): a SYNC of the backlog, whose cycle is more than ``STALE_CYCLES`` periods older than
        the drive's clock (``now``, default the wall clock) and nearer it than the SYNC before (the
        module docstring). Without a SYNC counter nothing tells a backlog's age: only the consumers
        act then."""
        ref = self.stall_ref
        if ref is None:
            return False
        c0, t0 = ref
        overflow = conf["overflow"]
        if not (counter and c0 and overflow):
            self.stall_ref = None
            return False
        ahead = (counter - c0) % overflow          # the cycles this SYNC is after the one before the stall
        behind = ((time.perf_counter() if now is None else now) - t0) / conf["comm_period"] - ahead
        last, self.behind = self.behind, behind
        draining = last is None or behind < last - 0.5
        if STALE_CYCLES < behind < overflow // 2 and draining:   # beyond half the counter's range: no judgement
            return True
        self.stall_ref = self.behind = None        # caught up, or live again: nothing more is stale
        return False

    def before_frame(self, t: float, conf) -> None:
        """Wall-clock mode, before a frame is handled: a drive whose thread did not run for more
        than ``STALE_CYCLES`` + 1 periods (it wakes once a period at least) was stalled; it
        remembers the last SYNC before the stall (the backlog is judged against it) and evaluates
        its consumers now, before the backlog."""
        d = self.drive
        # the drive's thread wakes at least once a period (a frame, or its duty): a longer gap is
        # a stall of the drive itself, not a pause of the host (which only delays the SYNCs)
        awake, self.last_awake = self.last_awake, t
        if self.stall_ref is None and t - awake > (STALE_CYCLES + 1) * d.period and self.last_counter \
                and awake - self.last_sync_wall <= STALE_CYCLES * d.period:
            # (only a stall while the SYNCs came: the last one is the reference the backlog is judged by)
            self.stall_ref, self.behind = (self.last_counter, self.last_sync_wall), None
            pl = d.plant
            d.log.append((d.syncs, f"stalled {(t - awake) * 1e3:.0f} ms at motor position "
                                   f"{pl.x[0] * 1e3:.4f} mm, speed {pl.x[pl.plant.n] * 1e3:.2f} mm/s"))
        self.watch(conf)
