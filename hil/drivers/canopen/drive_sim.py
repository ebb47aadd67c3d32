"""A simulated CiA 402 servo drive on a CAN bus: a ``canopen`` LocalNode with the object dictionary
of hil/drivers/canopen/eds/cia402_generic.eds, answering SDO (canopen's server), NMT (canopen's NMT slave), SYNC,
PDO, heartbeat and EMCY. Its shaft is the hil.sim_plant model (hil.drivers.sim.SimulatedPlant), advanced
one cycle per SYNC, closing in the drive the loops the mode of operation gives it (CSP: both,
CSV: velocity, CST: none).

Time: ``lockstep=True`` (the tests) makes the drive's clock the SYNC count, heartbeats included,
so that runs are deterministic (canopen's notifier thread hands the drive its frames);
``lockstep=False`` (``hil drive-sim`` in its own process, the in-process benchmark) runs the drive
as a drive runs: one thread (:meth:`DriveSim.serve`) takes each frame from the bus itself, and a
SYNC is answered at once with the TPDOs of the cycle it starts (the plant advanced by the
compiled drive step of hil.drivers.sim, about 5 us, in about 20 us of cycle work in all), so that
the answer leaves within a fixed, short time of the SYNC (the figure is in ``hil drive-sim
--help``); the same thread produces the heartbeats on the wall clock and keeps the shaft moving
on its own clock when SYNCs stop (the link died: the drive-side guards must stop it).

Drive-side guards (set by the host over SDO at start-up): heartbeat consumer 0x1016 and SYNC
consumer (communication cycle period 0x1006 times the SYNC loss limit 0x2003, a count of cycles),
either of which, once lost while OPERATION ENABLED, performs the abort-connection option 0x6007
(0 nothing, 1 fault, 2 disable voltage, 3 quick stop; EMCY 0x8130 for the heartbeat, 0x8100 for
the SYNC); following-error window 0x6065/0x6066, software position limits 0x607D, max torque
0x6072. The consumers are evaluated before each frame is handled (a drive that was stalled looks
at its clock before it reads its backlog) and once a period.

Stale setpoints. A drive whose processor stalled finds a backlog of RPDOs and SYNCs when it
resumes. It never executes them: the SYNC consumer acts first where the stall was longer than its
time; after a shorter stall (more than ``STALE_CYCLES`` periods in which the drive ran nothing)
every SYNC whose counter (CiA 301 SYNC counter, 1..0x1019, which the host sends) belongs to a
cycle more than ``STALE_CYCLES`` periods older than the drive's clock is discarded with the
targets latched before it: the drive holds its last fresh target and sends no answer to it. A
quick stop (or an abort) cannot be undone by a stale ``ENABLE OPERATION`` either: transition 16
(QUICK STOP ACTIVE -> OPERATION ENABLED) exists only with quick stop option codes 5..8 (0x605A);
the host sets 2. Enabling (transition 4) starts from the actual position: the targets received
before it are dropped.

Quick stop and fault reaction (0x605A = 2): the speed reference ramps from the present speed to
zero at the quick-stop deceleration 0x6085 (position units per s^2; 0xFFFFFFFF: what the torque
limit allows), then the drive holds the position where the motor came to rest (its speed crossed
zero), never a stale target, until the motor and the table are at rest, and only then switches
the power stage off.

Fault injection (:meth:`DriveSim.inject`): ``emcy`` (a drive fault: EMCY + FAULT state),
``heartbeat_loss``, ``frozen_encoder``, ``late_pdo``, ``missing_pdo``, ``following_error``,
``tip_missing_pdo`` (the tip sensor's TPDO withheld).

A tool-tip sensor on its own node (``tip_node_id``, config ``canopen.tip_node_id``):
:class:`TipSensorSim`, a CiA 406-like absolute linear encoder (hil/drivers/canopen/eds/tip_encoder_cia406.eds) on
the same bus, whose position value 0x6004 is the plant's tip mass, sent in its TPDO1 on every SYNC.
"""
from __future__ import annotations

import gc
import math
import select
import socket
import struct
import threading
import time
from collections import deque

import can
import canopen
import numpy as np

from hil.control import P, new_velocity_state, velocity_law
from hil.drivers.base import Setpoint
from hil.drivers.canopen import cia402
from hil.drivers.canopen import eds as eds_files
from hil.drivers.rt import fine_timer_slack
from hil.drivers.sim import SimulatedPlant
from hil.errors import ConfigError

__all__ = ["DriveSim", "TipSensorSim", "FAULTS", "SocketcandServerBus"]


FAULTS = ("emcy", "heartbeat_loss", "frozen_encoder", "late_pdo", "missing_pdo", "following_error",
          "tip_missing_pdo")

_FMT = {1: "b", 2: "h", 4: "i"}          # signed by default; unsigned objects fixed below
_UNSIGNED = {0x6040, 0x6041, 0x603F, 0x1001}


def _fmt(index: int, bits: int) -> str:
    f = _FMT[bits // 8]
    return f.upper() if index in _UNSIGNED else f


# Objects the drive itself updates every cycle: written straight into the node's data store (the
# SDO server reads them from there), not through the SDO layer, which costs tens of microseconds
# per access; they do not invalidate the cached configuration.
_LIVE = {0x6040, 0x6041, 0x6064, 0x606C, 0x6077, 0x60E4, 0x2001, 0x603F, 0x1001, 0x6061}


def _raw(node, index: int, sub: int) -> bytes:
    """The stored bytes of an object (the data store, else the dictionary's default)."""
    try:
        return node.data_store[index][sub]
    except KeyError:
        return node.get_data(index, sub)


def _put(node, index: int, sub: int, fmt: str, value: int) -> None:
    node.data_store.setdefault(index, {})[sub] = struct.pack("<" + fmt, value)


def _pdo_plan(node, comm_base: int, map_base: int, n: int):
    """(COB-ID or None when disabled, [(index, sub, bytes, struct format)]) of one PDO."""
    comm, mapping = node.sdo[comm_base + n], node.sdo[map_base + n]
    cob = comm[1].raw
    entries = []
    for k in range(1, mapping[0].raw + 1):
        entry = mapping[k].raw
        index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        entries.append((index, sub, bits // 8, _fmt(index, bits)))
    return (None if cob & 0x80000000 or not entries else cob & 0x7FF), entries


STALE_CYCLES = 2          # a SYNC this many periods older than the drive's clock is stale
QS_REST_SPEED = 1e-4      # m/s: motor and table below this, the quick stop has ended
QS_MIN_HOLD = 0.02        # s: and the position held at least this long
QS_EASE = 0.01            # s: the quick-stop deceleration falls to zero over about this time


class DriveSim:
    """``DriveSim(cfg, bus=bus)`` on an existing python-can bus, or ``interface=``/``channel=``.

    ``lockstep=False``: the drive's thread (:meth:`serve`) is started here unless ``thread=False``
    (``hil drive-sim`` runs :meth:`serve` on its main thread)."""

    def __init__(self, cfg, bus=None, interface: str | None = None, channel: str | None = None,
                 node_id: int | None = None, eds: str | None = None, lockstep: bool = True, bitrate: int = 1000000,
                 tip_node_id: int | None = None, thread: bool = True):
        self.cfg = cfg
        self.node_id = node_id or int(cfg.get("canopen.node_id", 1))
        self.lockstep = lockstep
        self.lock = threading.RLock()
        od = eds_files.load(cfg, "canopen.eds", self.node_id, eds)     # a bad file: ConfigError, no bus opened
        self._own_bus = bus is None
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.05          # the receive thread stops within 50 ms
        if lockstep:              # canopen's notifier thread hands the frames over
            if bus is None:
                self.network.connect(interface=interface or cfg.get("canopen.interface", "virtual"),
                                     channel=channel or cfg.get("canopen.channel", "hil"), bitrate=bitrate)
            else:
                self.network.connect()
        elif bus is None:         # the drive's own thread takes the frames (serve): no notifier
            self.network.bus = can.Bus(interface=interface or cfg.get("canopen.interface", "virtual"),
                                       channel=channel or cfg.get("canopen.channel", "hil"), bitrate=bitrate)
        self.node = canopen.LocalNode(self.node_id, od)
        # heartbeats are produced here (on the SYNC clock in lockstep, else the wall clock)
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_write_callback(self._on_sdo_write)
        self.network.add_node(self.node)
        self.network.subscribe(0x80, self._on_sync)
        for n in range(4):
            self.network.subscribe(0x200 + 0x100 * n + self.node_id, self._on_rpdo)
        self.host_id = 0
        self.network.subscribe(0x700 + int(cfg.get("canopen.host_node_id", 127)), self._on_host_heartbeat)
        # drive state
        self._conf = None
        self.state = "SWITCH ON DISABLED"
        self.cw = 0
        self.mode = "csp"
        self.plant: SimulatedPlant | None = None
        self._make_plant("csp")
        self.time = 0.0
        self.syncs = 0
        self.rx: dict[tuple[int, int], int] = {}
        self.target_position = 0
        self.target_velocity = 0
        self.target_torque = 0
        self.last_host_heartbeat = 0.0
        self.host_heartbeat_seen = False
        self._next_hb = 0.0
        self.emcy_sent: list[tuple[float, int]] = []
        self.log: list[tuple[int, str]] = []          # (sync count, event)
        self.quick_stop_at: int | None = None         # sync count when the quick stop was received
        self.fault_at: int | None = None              # sync count when the drive faulted
        self.fault_code = 0
        self._qs_state = new_velocity_state()
        self._fe_count = 0
        self._home_offset = 0.0
        self.sw_extra = 0
        self.sync_counter = 0
        self._held: list[tuple[int, list]] = []     # late TPDOs: (release at sync count, frames)
        # injected faults
        self.inject_state: dict[str, float] = {}
        self._frozen: tuple | None = None
        self._missing = 0
        self._late = 0.0
        self._fe_offset = 0.0
        self._hb_dead = False
        self._last_sync_wall = time.perf_counter()
        self._last_awake = time.perf_counter()         # the drive's thread last looked at its clock
        self._sync_armed = False           # the SYNC consumer watches from the first SYNC in OPERATION ENABLED
        self._own_cycles = 0               # cycles run without a SYNC since the last one (lockstep consumer)
        self._stall_ref: tuple[int, float] | None = None    # (SYNC counter, wall time) before a stall
        self._last_counter = 0
        self.stale_syncs = 0               # SYNCs (and their targets) discarded as stale
        self.frames_rejected = 0           # malformed frames ignored
        self._stall_for = 0.0              # serve: stall this long (the freeze fault)
        self._qs: dict | None = None       # the quick stop's ramp and hold
        self._stop = threading.Event()
        self._idle_thread = None
        self.answer_times: list[float] = []        # serve: SYNC taken from the bus -> its TPDOs sent (s)
        self.node.sdo[0x6041].raw = cia402.statusword_for(self.state)
        tip_id = int(cfg.get("canopen.tip_node_id", 0) or 0) if tip_node_id is None else int(tip_node_id)
        self.tip_sensor = TipSensorSim(self, tip_id) if tip_id else None
        self._warm_up()
        self.node.nmt.state = "PRE-OPERATIONAL"
        self.network.send_message(0x700 + self.node_id, [0])        # boot-up
        if not lockstep and thread:
            self._idle_thread = threading.Thread(target=self.serve, name="drive-sim", daemon=True)
            self._idle_thread.start()

    # -- plant ----------------------------------------------------------------------------------
    def _make_plant(self, mode: str) -> None:
        closes = cia402.MODE_CLOSES[mode]
        new = SimulatedPlant(self.cfg, closes=closes)
        if self.plant is not None:
            new.x[:] = self.plant.x
            new._u_act = self.plant._u_act
            new._prev_position = self.plant.x[0]
        new.open()
        self.plant = new
        self.mode = mode
        self.period = new.cycle_time

    def _hb_now(self) -> float:
        """The heartbeat consumer's clock: the SYNC clock in lockstep, else the wall clock."""
        return self.time if self.lockstep else time.perf_counter()

    def _warm_up(self) -> None:
        """Run the compiled plant and loop functions once on a throw-away copy, so that the first
        SYNC is not held up by loading them (a late first answer)."""
        x = self.plant.x.copy()
        self.plant.enabled = True
        self.plant.sync()
        self._quick_stop_step(1.0)
        self._qs = None
        self.plant.enabled = False
        self.plant.x[:] = x
        self.plant._u_act = 0.0
        self.plant._s = new_velocity_state()
        self.plant._prev_position = None

    def home_at(self, position: float) -> None:
        with self.lock:
            self.plant.home_at(position)

    # scaling (the same as the host's: from the drive's own 0x608F/0x6091/0x6092)
    def _scales(self):
        d = self.node
        cpr = d.sdo[0x608F][1].raw / max(d.sdo[0x608F][2].raw, 1)
        gear = d.sdo[0x6091][1].raw / max(d.sdo[0x6091][2].raw, 1)
        feed = d.sdo[0x6092][1].raw * 1e-6 / max(d.sdo[0x6092][2].raw, 1)      # um per shaft rev
        return cpr * gear / feed, d.sdo[0x6076].raw * 1e-3                         # counts per m, rated N m

    def _config(self) -> dict:
        """The configuration the host set over SDO (scaling, limits, guards, PDO mapping), read once
        after every SDO write to a configuration object and cached: one cycle reads no SDO object."""
        c = self._conf
        if c is None:
            d = self.node.sdo
            cpm, rated = self._scales()
            c = {"cpm": cpm, "rated": rated, "lo": d[0x607D][1].raw, "hi": d[0x607D][2].raw,
                 "tmax": d[0x6072].raw * 1e-3 * rated, "hb_timeout": (d[0x1016][1].raw & 0xFFFF) * 1e-3,
                 "fe_window": d[0x6065].raw, "fe_time_ms": d[0x6066].raw, "hb_ms": d[0x1017].raw,
                 "sync_loss": d[0x2003].raw if 0x2003 in self.node.object_dictionary else 0,
                 "comm_period": (d[0x1006].raw * 1e-6) or self.period, "qs_option": d[0x605A].raw,
                 "overflow": d[0x1019].raw, "qs_dec": d[0x6085].raw,
                 "tpdo": [_pdo_plan(self.node, 0x1800, 0x1A00, n) for n in range(4)],
                 "rpdo": [_pdo_plan(self.node, 0x1400, 0x1600, n)[1] for n in range(4)]}
            self._conf = c
        return c

    # -- bus callbacks ---------------------------------------------------------------------------
    def _on_sdo_write(self, index, subindex, od, data):
        with self.lock:
            if index not in _LIVE:
                self._conf = None          # configuration changed: read it again at the next cycle
            if index == 0x6040:
                self._controlword(struct.unpack("<H", data)[0])
            elif index == 0x6060:
                code = struct.unpack("<b", data)[0]
                if code == cia402.HOMING_MODE:
                    if self.mode != "csp":
                        self._make_plant("csp")           # homing holds the shaft in position
                    self.mode = "hm"
                    self.target_position = self.node.sdo[0x6064].raw
                    self.rx.pop((0x607A, 0), None)
                for name, c in cia402.MODES.items():
                    if c == code and name != self.mode:
                        self._make_plant(name)
                self.node.sdo[0x6061].raw = code
            elif index == 0x1016 and subindex == 1:
                self.last_host_heartbeat = self._hb_now()

    def _controlword(self, cw: int) -> None:
        prev, self.cw = self.cw, cw
        old = self.state
        if self.mode == "hm" and old == "OPERATION ENABLED" and cw & 0x10 and not prev & 0x10:
            self._home()
        new = cia402.next_state(old, cw, prev)
        if new == old:
            return
        if old == "QUICK STOP ACTIVE" and new == "OPERATION ENABLED" and \
                self.node.sdo[0x605A].raw not in (5, 6, 7, 8):
            # transition 16 exists only with quick stop option codes 5..8: with 2, a quick stop
            # ends in SWITCH ON DISABLED, whatever controlword arrives during it (a stale one)
            if self._qs is not None and not self._qs.get("told"):
                self._qs["told"] = True
                self.log.append((self.syncs, "ENABLE OPERATION ignored in QUICK STOP ACTIVE (0x605A not 5..8)"))
            return
        if new == "QUICK STOP ACTIVE":
            self._start_quick_stop()
        if new == "OPERATION ENABLED":
            self.plant._prev_position = None
            self.plant._s = new_velocity_state()
            self.last_host_heartbeat = self._hb_now()
            self._fe_count = 0
            self._hold_actual()
        if old == "FAULT":
            self.fault_code = 0
            self.node.sdo[0x603F].raw = 0
            self.node.emcy.reset()
        self._set_state(new)

    def _set_state(self, new: str) -> None:
        self.log.append((self.syncs, f"{self.state} -> {new}"))
        self.state = new
        self.plant.enabled = new == "OPERATION ENABLED"
        if new != "OPERATION ENABLED":
            self.sw_extra = 0
        self.node.sdo[0x6041].raw = cia402.statusword_for(new, self.sw_extra)

    def _hold_actual(self) -> None:
        """Enabling starts where the axis stands: the position target is the actual position,
        the targets received before (a stale RPDO of an earlier run) are dropped, the SYNC
        consumer waits for the first SYNC of this run."""
        for key in ((0x607A, 0), (0x60FF, 0), (0x6071, 0)):
            self.rx.pop(key, None)
        self.target_position = struct.unpack("<i", _raw(self.node, 0x6064, 0)[:4])[0]
        self.target_velocity = self.target_torque = 0
        self._sync_armed = False
        self._own_cycles = 0
        self._stall_ref = None

    def _start_quick_stop(self) -> None:
        self.quick_stop_at = self.syncs
        self._qs_state = new_velocity_state()
        pl = self.plant
        v = float(pl.x[pl.plant.n])
        self._qs = {"ramp": v, "dir": 1.0 if v >= 0 else -1.0, "hold": None, "held": 0.0}

    def _home(self) -> None:
        """Homing method 35/37 (CiA 402: the present position is the home position): the position
        reading becomes the home offset 0x607C; statusword bits 12 (homing attained) and 10."""
        method = self.node.sdo[0x6098].raw
        if method not in (35, 37):
            self.sw_extra = 1 << cia402.SW_BITS["following_error"]        # bit 13: homing error
        else:
            cpm, _ = self._scales()
            x_motor = self.plant.read_feedback().x_motor
            self._home_offset = self.node.sdo[0x607C].raw / cpm - x_motor
            self.target_position = int(round((x_motor + self._home_offset) * cpm))
            self.node.sdo[0x6064].raw = self.target_position
            self.sw_extra = (1 << cia402.SW_BITS["setpoint_acknowledge"]) | (1 << cia402.SW_BITS["target_reached"])
        self.log.append((self.syncs, f"homing method {method}: offset {self._home_offset:.6f} m"))
        self.node.sdo[0x6041].raw = cia402.statusword_for(self.state, self.sw_extra)

    def _on_rpdo(self, can_id, data, timestamp):
        n = ((can_id - self.node_id) - 0x200) // 0x100
        with self.lock:
            if self.node.nmt.state != "OPERATIONAL":
                return
            entries = self._config()["rpdo"][n]
            if len(data) < sum(e[2] for e in entries):
                # CiA 301: a PDO shorter than its mapping is not processed (EMCY 0x8210)
                self.frames_rejected += 1
                self.log.append((self.syncs, f"RPDO{n + 1} of {len(data)} bytes ignored (length error)"))
                self.node.emcy.send(0x8210, self.node.sdo[0x1001].raw, b"")
                return
            off = 0
            for index, sub, nbytes, f in entries:
                value = struct.unpack_from("<" + f, data, off)[0]
                off += nbytes
                if index == 0x6040:
                    self._controlword(value)          # the controlword acts on receipt
                else:
                    self.rx[(index, sub)] = value     # targets act at the next SYNC

    def _on_host_heartbeat(self, can_id, data, timestamp):
        with self.lock:
            self.last_host_heartbeat = self._hb_now()
            self.host_heartbeat_seen = True

    def _on_sync(self, can_id, data, timestamp):
        with self.lock:
            counter = data[0] if data else 0       # CiA 301 SYNC counter (0x1019 > 0)
            if self._stale(counter):
                self.stale_syncs += 1
                self.log.append((self.syncs, f"stale SYNC {counter} discarded with its targets"))
                for key in ((0x607A, 0), (0x60FF, 0), (0x6071, 0)):
                    self.rx.pop(key, None)
                self._cycle(from_sync=False)          # time goes on; the last fresh target held, no answer
                return
            self._last_sync_wall = time.perf_counter()
            self._own_cycles = 0
            self._last_counter = counter
            if self.state == "OPERATION ENABLED":
                self._sync_armed = True
            self.sync_counter = counter
            _put(self.node, 0x2001, 0, "B", self.sync_counter)
            self._cycle(from_sync=True)

    def _stale(self, counter: int) -> bool:
        """After a stall of the drive (``_stall_ref``: the last SYNC before it, counter and wall
        time): a SYNC whose cycle is more than ``STALE_CYCLES`` periods older than the drive's
        clock. Without a SYNC counter nothing tells a backlog's age: only the consumers act then."""
        ref = self._stall_ref
        if ref is None:
            return False
        conf = self._config()
        c0, t0 = ref
        overflow = conf["overflow"]
        if not (counter and c0 and overflow):
            self._stall_ref = None
            return False
        ahead = (counter - c0) % overflow          # the cycles this SYNC is after the one before the stall
        behind = (time.perf_counter() - t0) / conf["comm_period"] - ahead
        if STALE_CYCLES < behind < overflow // 2:   # beyond half the counter's range: no judgement
            return True
        self._stall_ref = None                     # caught up: the drive's clock and the host's agree again
        return False

    def _before_frame(self, t: float) -> None:
        """Wall-clock mode, before a frame is handled: a drive whose thread did not run for more
        than ``STALE_CYCLES`` + 1 periods (it wakes once a period at least) was stalled; it
        remembers the last SYNC before the stall (the backlog is judged against it) and evaluates
        its consumers now, before the backlog."""
        # the drive's thread wakes at least once a period (a frame, or its duty): a longer gap is
        # a stall of the drive itself, not a pause of the host (which only delays the SYNCs)
        awake, self._last_awake = self._last_awake, t
        if self._stall_ref is None and t - awake > (STALE_CYCLES + 1) * self.period and self._last_counter \
                and awake - self._last_sync_wall <= STALE_CYCLES * self.period:
            # (only a stall while the SYNCs came: the last one is the reference the backlog is judged by)
            self._stall_ref = (self._last_counter, self._last_sync_wall)
            pl = self.plant
            self.log.append((self.syncs, f"stalled {(t - awake) * 1e3:.0f} ms at motor position "
                                         f"{pl.x[0] * 1e3:.4f} mm, speed {pl.x[pl.plant.n] * 1e3:.2f} mm/s"))
        self._watch(self._config())

    def stall(self, seconds: float) -> None:
        """The freeze fault in wall-clock mode: the drive's thread stops for ``seconds`` (it reads
        nothing, sends nothing: the frames queue as they would in a stalled drive's receive
        buffer), then carries on with its backlog."""
        self._stall_for = float(seconds)

    def serve(self, seconds: float = 0.0, on_duty=None) -> None:
        """Wall-clock mode: the drive's one thread, until :meth:`close` (or ``seconds``, 0: no
        end). It takes each frame from the bus itself (``Bus.recv`` with a timeout: the wait gives
        the interpreter lock away) and hands it to canopen's dispatch (``Network.notify``: SYNC,
        RPDO, SDO, NMT, the host's heartbeat), so a SYNC is answered on this thread, with no
        hand-over to another; between frames, once a period, the heartbeat and the shaft's own
        cycle when the SYNCs have stopped (3 periods without one). ``answer_times``: per SYNC,
        the time from taking it off the bus to its TPDOs written to the bus. ``on_duty(self)``, where
        given, is called once a period with the drive's lock held (hil drive-sim's fault schedule)."""
        fine_timer_slack()
        # what exists now (numba, the dictionaries) is never collected: a full collection of it
        # would hold an answer up by milliseconds; the cycle's own garbage goes by reference count
        gc.collect()
        gc.freeze()
        bus, now = self.network.bus, time.perf_counter
        hold, release = getattr(bus, "hold", None), getattr(bus, "release", None)
        t_end = now() + seconds if seconds else math.inf
        duty = now()
        times = self.answer_times
        while not self._stop.is_set() and now() < t_end:
            try:
                msg = bus.recv(max(0.0, min(duty, t_end) - now()))
            except (can.CanError, OSError, ValueError):
                if self._stop.is_set():
                    return
                raise
            if msg is not None:
                t_in = now()
                if self.handle_frame(msg, hold, release) and msg.arbitration_id == 0x80:
                    times.append(now() - t_in)
            t = now()
            if t >= duty:
                with self.lock:
                    self._before_frame(t)
                    if t - self._last_sync_wall > 3 * self.period:
                        self._cycle(from_sync=False)
                    self._heartbeat_wall()
                    if on_duty is not None:
                        on_duty(self)
                duty += self.period
                if duty <= t:                     # held up: the next duty one period from now
                    duty = t + self.period
                if self._stall_for > 0:           # the freeze fault: the thread stalls, the frames queue
                    stall, self._stall_for = self._stall_for, 0.0
                    time.sleep(stall)

    def handle_frame(self, msg, hold=None, release=None) -> bool:
        """Wall-clock mode: one frame taken off the bus, handed to canopen's dispatch (SYNC,
        RPDO, SDO, NMT, the host's heartbeat) after the consumers have looked at the clock. A
        malformed frame (a PDO or SDO of the wrong size, an unknown command) is logged and
        dropped, as a bus drops it: the drive carries on. True when the frame was handled."""
        if msg.is_error_frame or msg.is_remote_frame:
            return False
        with self.lock:
            self._before_frame(time.perf_counter())
        notify = self.network.notify
        try:
            if msg.arbitration_id == 0x80 and hold is not None:
                hold()                          # the whole answer goes out in one write
                try:
                    notify(0x80, msg.data, msg.timestamp)
                finally:
                    release()
            else:
                notify(msg.arbitration_id, msg.data, msg.timestamp)
        except (can.CanError, OSError):
            raise
        except Exception as exc:          # a malformed frame: dropped
            self.frames_rejected += 1
            self.log.append((self.syncs, f"frame 0x{msg.arbitration_id:X} {bytes(msg.data).hex()} ignored "
                                         f"({type(exc).__name__})"))
            return False
        return True

    def _heartbeat_wall(self):
        ms = self._config()["hb_ms"]
        if ms and not self._hb_dead and time.perf_counter() >= self._next_hb:
            self._next_hb = time.perf_counter() + ms * 1e-3
            self.network.send_message(0x700 + self.node_id, [self.node.nmt._state])

    def advance(self, cycles: int) -> None:
        """Let ``cycles`` periods pass without a SYNC (the link is dead; lockstep tests)."""
        for _ in range(cycles):
            with self.lock:
                self._cycle(from_sync=False)

    # -- one drive cycle -------------------------------------------------------------------------
    def _watch(self, conf) -> None:
        """The heartbeat consumer (0x1016) and the SYNC consumer (0x1006 x 0x2003): either lost
        while OPERATION ENABLED performs the abort-connection option (0x6007)."""
        if self.state != "OPERATION ENABLED":
            return
        timeout = conf["hb_timeout"]
        if timeout > 0 and self._hb_now() - self.last_host_heartbeat > timeout:
            self._abort_connection("host heartbeat lost", 0x8130)
            return
        limit = conf["sync_loss"]
        if limit and self._sync_armed:
            if self.lockstep:
                lost = self._own_cycles >= limit
            else:
                lost = time.perf_counter() - self._last_sync_wall > limit * conf["comm_period"]
            if lost:
                self._abort_connection(f"SYNC lost ({limit} cycles of {conf['comm_period'] * 1e3:g} ms)", 0x8100)

    def _cycle(self, from_sync: bool) -> None:
        self.syncs += 1
        self.time += self.period
        if not from_sync:
            self._own_cycles += 1
        conf = self._config()
        cpm, rated = conf["cpm"], conf["rated"]
        pl = self.plant
        operational = self.node.nmt.state == "OPERATIONAL"
        self._watch(conf)
        # targets latched at SYNC, clamped to the software limits
        lo, hi = conf["lo"], conf["hi"]
        if (0x607A, 0) in self.rx:
            self.target_position = min(max(self.rx[(0x607A, 0)], lo), hi)
        if (0x60FF, 0) in self.rx:
            self.target_velocity = self.rx[(0x60FF, 0)]
        if (0x6071, 0) in self.rx:
            self.target_torque = self.rx[(0x6071, 0)]
        tmax = conf["tmax"]
        if self.state == "OPERATION ENABLED":
            if self.mode in ("csp", "hm"):
                pl.write_setpoint(Setpoint(position=self.target_position / cpm - self._home_offset))
            elif self.mode == "csv":
                pl.write_setpoint(Setpoint(speed=self.target_velocity / cpm * pl.ctrl.speed_scale))
            else:
                u = self.target_torque * 1e-3 * rated
                pl.write_setpoint(Setpoint(output=max(-tmax, min(tmax, u))))
            pl.sync()
        elif self.state in ("QUICK STOP ACTIVE", "FAULT REACTION ACTIVE"):
            if self._quick_stop_step(tmax, conf):
                # quick stop option 2 / fault reaction 0x605E = 2: stop on the quick-stop ramp, then disable
                self._set_state("SWITCH ON DISABLED" if self.state == "QUICK STOP ACTIVE" else "FAULT")
        else:
            pl.enabled = False
            pl.sync()
        if self._fe_offset:
            pl.x[: pl.plant.n] += 0.0                      # the load does not move: offset on the reading
        actual = self._actual(cpm, rated)
        # drive-side guards
        if self.state == "OPERATION ENABLED":
            if not (lo <= actual["pos"] <= hi):
                self.fault(0x8612)
            win = conf["fe_window"]
            if self.mode in ("csp", "hm") and win != 0xFFFFFFFF and abs(self.target_position - actual["pos"]) > win:
                self._fe_count += 1
                if self._fe_count * self.period * 1e3 > conf["fe_time_ms"]:
                    self.fault(0x8611)
            else:
                self._fe_count = 0
        # heartbeat on the drive's clock (lockstep)
        if self.lockstep:
            ms = conf["hb_ms"]
            if ms and not self._hb_dead and self.time + 1e-12 >= self._next_hb:
                self._next_hb = self.time + ms * 1e-3
                self.network.send_message(0x700 + self.node_id, [self.node.nmt._state])
        if from_sync and self.tip_sensor is not None:
            self.tip_sensor.on_sync(actual["tip_plant"])
        if from_sync and operational:
            self._send_tpdos(actual)

    def _qs_deceleration(self, tmax: float, conf) -> float:
        """The quick-stop deceleration (m/s^2): 0x6085 (position units per s^2), or where it is
        0 or 0xFFFFFFFF, 80 % of what the torque limit gives the whole axis."""
        raw = conf["qs_dec"] if conf is not None else 0xFFFFFFFF
        if raw and raw != 0xFFFFFFFF:
            return raw / conf["cpm"]
        pl = self.plant.plant
        return 0.8 * tmax * pl.force_gain / pl.total_mass

    def _quick_stop_step(self, tmax: float, conf=None) -> bool:
        """One cycle of the quick stop (option 2) or fault reaction: the speed reference ramps to
        zero at the quick-stop deceleration, the drive's velocity loop follows it; when the
        ramp is at zero and the motor's speed has crossed zero (it stands), the position where it
        stands is held (the position loop on the motor). True when the motor and the table are at
        rest and the position has been held ``QS_MIN_HOLD``: the stop has ended."""
        pl = self.plant
        n, tv = pl.plant.n, pl.ctrl.velocity_period
        if self._qs is None:
            self._start_quick_stop()
        q = self._qs
        dv = self._qs_deceleration(tmax, conf) * tv
        scale, kv = pl.ctrl.speed_scale, pl._p[P.KV]
        steps = max(1, int(round(self.period / tv)))
        m = pl.plant.chain.m
        for _ in range(steps):
            if q.get("done"):
                pl._step(0.0)                           # the power stage is off: the axis coasts
                continue
            v = pl.x[n]
            if q["hold"] is None:
                r = q["ramp"]
                # the deceleration eases off near zero speed (jerk-limited over QS_EASE): the end
                # of the ramp does not set the compliant axis swinging back
                step = min(dv, math.sqrt(2.0 * dv / QS_EASE * tv * abs(r)), abs(r))
                q["ramp"] = r = 0.0 if abs(r) - step < 1e-9 else r - math.copysign(step, r)
                if r == 0.0 and v * q["dir"] <= 0.0:
                    q["hold"] = float(pl.x[0])           # where the motor came to rest
                    self._qs_state = new_velocity_state()   # the braking torque is not carried on
                w_ref = r
            else:
                w_ref = kv * (q["hold"] - pl.x[0])
                q["held"] += tv
                # the axis's momentum (the compliant masses still swing): the power stage goes off
                # when it crosses zero with the motor and table at rest, so that nothing carries
                # the axis on once it coasts
                p = float(np.dot(m, pl.x[n:]))
                if q["held"] >= QS_MIN_HOLD and abs(v) < QS_REST_SPEED and abs(pl.x[n + pl.plant.table]) < \
                        QS_REST_SPEED and (p * q.get("p", p) <= 0.0 or abs(p) < 1e-6 * pl.plant.total_mass):
                    q["done"] = True
                    self.log.append((self.syncs, f"quick stop ended: held at {q['hold']:.6f} m"))
                    pl._step(0.0)
                    continue
                q["p"] = p
            u = velocity_law(pl._p, self._qs_state, w_ref * scale, v * scale, 0.0)
            pl._step(max(-tmax, min(tmax, u)))
        return bool(q.get("done"))

    def _actual(self, cpm: float, rated: float) -> dict:
        pl = self.plant
        n = pl.plant.n
        fb = pl.read_feedback()
        x_motor, x_table, x_tip = fb.x_motor, fb.x_table, fb.x_tip
        if math.isnan(x_tip):
            x_tip = x_table
        tip_plant = x_tip        # the tip mass as a separate sensor sees it (the drive's homing is not its)
        x_motor += self._home_offset
        x_table += self._home_offset + self._fe_offset
        x_tip += self._home_offset + self._fe_offset
        if self._frozen is not None:
            x_motor, x_table, x_tip, v = self._frozen
        else:
            v = pl.x[n]
        act = {"pos": int(round(x_motor * cpm)), "vel": int(round(v * cpm)),
               "torque": int(round(pl._u_act / rated * 1e3)) if self.state == "OPERATION ENABLED" else 0,
               "table": int(round(x_table * 1e9)), "tip": int(round(x_tip * 1e9)), "v": v,
               "x": (x_motor, x_table, x_tip), "tip_plant": tip_plant}
        d = self.node
        clamp = lambda v: max(-2 ** 31, min(2 ** 31 - 1, v))      # noqa: E731
        _put(d, 0x6064, 0, "i", clamp(act["pos"]))
        _put(d, 0x606C, 0, "i", clamp(act["vel"]))
        _put(d, 0x6077, 0, "h", max(-32768, min(32767, act["torque"])))
        _put(d, 0x60E4, 1, "i", clamp(act["table"]))
        _put(d, 0x60E4, 2, "i", clamp(act["tip"]))
        return act

    def _send_tpdos(self, actual) -> None:
        if self._missing > 0:
            self._missing -= 1
            self.log.append((self.syncs, "TPDO withheld"))
            return
        frames = []
        node = self.node
        for cob, entries in self._config()["tpdo"]:
            if cob is None:
                continue
            frames.append((cob, b"".join(_raw(node, index, sub)[:nbytes] for index, sub, nbytes, _ in entries)))
        due = [f for f in self._held if f[0] <= self.syncs]
        self._held = [f for f in self._held if f[0] > self.syncs]
        for _, old in due:                                   # late answers to earlier SYNCs go out first
            for cob, data in old:
                self.network.send_message(cob, data)
        if self._late > 0:
            delay = self._late
            self.log.append((self.syncs, f"TPDO late by {delay * 1e3:g} ms"))
            if self.lockstep:
                # drive time is the SYNC count: the answer goes out with a later SYNC's
                self._held.append((self.syncs + max(1, int(math.ceil(delay / self.period - 1e-9))), frames))
            else:
                threading.Timer(delay, lambda: [self.network.send_message(c, d) for c, d in frames]).start()
            return
        for cob, data in frames:
            self.network.send_message(cob, data)

    # -- faults ------------------------------------------------------------------------------------
    def fault(self, code: int = 0x2310, data: bytes = b"") -> None:
        """The drive faults: EMCY, error register, 0x603F; FAULT REACTION ACTIVE (the shaft brakes on
        the quick-stop ramp, fault reaction option 2), then FAULT (disabled)."""
        with self.lock:
            if self.state in ("FAULT", "FAULT REACTION ACTIVE"):
                return
            self.fault_code = code
            self.node.sdo[0x603F].raw = code
            self.node.sdo[0x1001].raw = 0x01 | (0x10 if code & 0xFF00 == 0x8100 else 0)
            self.node.emcy.send(code, self.node.sdo[0x1001].raw, data)
            self.emcy_sent.append((self.time, code))
            self.fault_at = self.syncs
            was_enabled = self.state in ("OPERATION ENABLED", "QUICK STOP ACTIVE")
            self._set_state("FAULT REACTION ACTIVE")
            self._start_quick_stop()
            if not was_enabled:
                self._set_state("FAULT")

    def _abort_connection(self, cause: str = "host heartbeat lost", code: int = 0x8130) -> None:
        """CiA 402 abort connection option code 0x6007: 0 no action, 1 fault (fault reaction, then
        FAULT), 2 disable voltage (SWITCH ON DISABLED: the power stage off), 3 quick stop (then
        SWITCH ON DISABLED, 0x605A = 2). Every action but 0 sends the EMCY ``code``."""
        option = self.node.sdo[0x6007].raw
        self.log.append((self.syncs, f"{cause}, abort connection option {option}"))
        self._sync_armed = False
        if option == 1:
            self.fault(code)
        elif option == 2:
            self.node.emcy.send(code, 0x11, b"")
            self._set_state("SWITCH ON DISABLED")
        elif option == 3:
            self.node.emcy.send(code, 0x11, b"")
            self._start_quick_stop()
            self._set_state("QUICK STOP ACTIVE")

    def inject(self, fault: str, value: float | int | None = None) -> None:
        """Inject a fault: emcy [code], heartbeat_loss, frozen_encoder, late_pdo [seconds],
        missing_pdo [count], following_error [metres of offset on the position reading].

        ``late_pdo``: from now on every TPDO answers its SYNC ``value`` seconds late (default two
        cycles; in lockstep, with the SYNC ``ceil(value / period)`` cycles later), until
        :meth:`clear_injections`: a drive or bus that no longer keeps up."""
        with self.lock:
            self.log.append((self.syncs, f"inject {fault} {value if value is not None else ''}".strip()))
            if fault == "emcy":
                self.fault(int(value or 0x2310))
            elif fault == "heartbeat_loss":
                self._hb_dead = True
                self.node.nmt.stop_heartbeat()
            elif fault == "frozen_encoder":
                cpm, rated = self._scales()
                a = self._actual(cpm, rated)
                self._frozen = (*a["x"], a["v"])
            elif fault == "late_pdo":
                self._late = float(value if value is not None else 2 * self.period)
            elif fault == "missing_pdo":
                self._missing = int(value or 1)
            elif fault == "following_error":
                self._fe_offset = float(value if value is not None else 0.01)
            elif fault == "tip_missing_pdo":
                if self.tip_sensor is None:
                    raise ValueError("tip_missing_pdo: this drive simulation has no tip sensor node")
                self.tip_sensor.missing = int(value or 1)
            else:
                raise ValueError(f"unknown fault {fault!r} (known: {', '.join(FAULTS)})")

    def clear_injections(self) -> None:
        with self.lock:
            self._frozen, self._missing, self._late, self._fe_offset = None, 0, 0.0, 0.0
            self._held = []
            self._hb_dead = False

    def close(self) -> None:
        self._stop.set()
        if self.tip_sensor is not None:
            self.tip_sensor.node.nmt.stop_heartbeat()
        if self._idle_thread is not None:
            self._idle_thread.join(1.0)
        self.node.nmt.stop_heartbeat()
        try:
            self.network.disconnect()
        except Exception:
            pass


class TipSensorSim:
    """A tool-tip sensor on its own CANopen node: a CiA 406-like absolute linear encoder
    (hil/drivers/canopen/eds/tip_encoder_cia406.eds) on the drive's bus. Position value 0x6004 = the plant's tip mass
    in steps of 0x6005.1 nm, plus the preset 0x6003 (written at homing: the value the sensor
    shows there); TPDO1 (0x6004) on every SYNC while OPERATIONAL, sent before the drive's TPDOs in
    the same SYNC (in lockstep, the host's SDO barrier covers it too). It answers SDO and NMT
    (canopen's LocalNode); its heartbeat (0x1017) is not produced."""

    def __init__(self, drive: DriveSim, node_id: int, eds: str | None = None):
        if node_id == drive.node_id:
            raise ConfigError(f"{drive.cfg.source}: canopen.tip_node_id: {node_id} is the drive's node id")
        self.drive = drive
        self.node_id = node_id
        self.node = canopen.LocalNode(node_id, eds_files.load(drive.cfg, "canopen.tip_eds", node_id, eds))
        self.node.add_write_callback(self._on_sdo_write)
        drive.network.add_node(self.node)
        self._plan = None            # (step m, COB-ID or None, mapping), cached until an SDO write
        self.offset = 0.0            # m, set by the preset
        self.missing = 0
        self.sent = 0
        self._last_tip = 0.0
        self.node.nmt.state = "PRE-OPERATIONAL"
        drive.network.send_message(0x700 + node_id, [0])        # boot-up

    def _step(self) -> float:
        return max(1, self.node.sdo[0x6005][1].raw) * 1e-9

    def _on_sdo_write(self, index, subindex, od, data):
        self._plan = None
        if index == 0x6003:              # preset: the present position shows this value from now on
            preset = struct.unpack("<i", data)[0]
            self.offset = preset * self._step() - self._last_tip
            self.node.sdo[0x6004].raw = preset

    def on_sync(self, x_tip: float) -> None:
        self._last_tip = x_tip
        if self._plan is None:
            self._plan = (self._step(), *_pdo_plan(self.node, 0x1800, 0x1A00, 0))
        step, cob, entries = self._plan
        value = int(round((x_tip + self.offset) / step))
        _put(self.node, 0x6004, 0, "i", max(-2 ** 31, min(2 ** 31 - 1, value)))
        if self.node.nmt.state != "OPERATIONAL" or cob is None:
            return
        if self.missing > 0:
            self.missing -= 1
            self.drive.log.append((self.drive.syncs, "tip sensor TPDO withheld"))
            return
        data = b"".join(_raw(self.node, index, sub)[:nbytes] for index, sub, nbytes, _ in entries)
        self.sent += 1
        self.drive.network.send_message(cob, data)


# -- the separate-process transport: a socketcand-protocol server on the loopback address ------------
LOOPBACK = ("127.0.0.1", "localhost", "::1")


class SocketcandServerBus(can.BusABC):
    """A python-can bus that *is* a small socketcand server (raw mode) on 127.0.0.1: the simulated
    drive uses it as its bus, and every other process reaches the drive with python-can's own
    socketcand interface (``interface="socketcand", host="127.0.0.1", port=..., channel=...``).
    Frames a client sends go to the drive and to the other clients, as on one CAN bus. Only the
    loopback address is served: nothing leaves the machine.

    No thread of its own: :meth:`recv` (the drive's thread) waits in one ``select`` on the
    listening socket and the clients, accepts, answers the handshake and parses the frames
    there, so that a SYNC reaches the drive with no hand-over between threads. :meth:`send`
    writes to every client at once (a lock keeps frames whole when a fault timer sends too)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 29536, channel: str = "can0", **kwargs):
        if host not in LOOPBACK:
            raise ValueError(f"the simulated drive serves 127.0.0.1 only, not {host!r}")
        self._pending: deque = deque()
        self._conns: dict = {}                 # socket -> its unparsed text
        self._clients: list = []               # sockets in raw mode: they get every frame
        self._clients_lock = threading.Lock()
        self._held: list | None = None         # frames held back by hold() until release()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind(("127.0.0.1", int(port)))
        self._sock.listen(4)
        self.port = self._sock.getsockname()[1]
        self.channel = channel
        self.channel_info = f"socketcand server {channel}@127.0.0.1:{self.port}"
        self._t0 = time.time()
        self._closed = False
        super().__init__(channel=channel, **kwargs)

    def _accept(self) -> None:
        try:
            conn, _ = self._sock.accept()
        except OSError:
            return
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            conn.sendall(b"< hi >")
        except OSError:
            conn.close()
            return
        self._conns[conn] = ""

    def _drop(self, conn) -> None:
        self._conns.pop(conn, None)
        with self._clients_lock:
            if conn in self._clients:
                self._clients.remove(conn)
        conn.close()

    # the longest command a client may send (a "< send 1FFFFFFF 8 FF FF FF FF FF FF FF FF >" is 46
    # characters): input beyond it without a closing ">" is dropped, so a client cannot grow the
    # buffer without limit, and each received chunk is scanned once
    MAX_COMMAND = 256

    def _read(self, conn) -> None:
        """What one client sent: the handshake (open, rawmode) and its frames; a malformed command
        is ignored (the client stays connected, as on a bus where a bad frame is dropped)."""
        try:
            data = conn.recv(4096)
        except OSError:
            data = b""
        if not data:
            self._drop(conn)
            return
        buf = self._conns[conn] + data.decode("ascii", "replace")
        pos = 0
        try:
            while True:
                end = buf.find(">", pos)
                if end < 0:
                    break
                start = buf.find("<", pos, end)
                body, pos = (buf[start + 1:end] if start >= 0 else ""), end + 1
                self._command(conn, body.split(), conn in self._clients)
        except OSError:
            self._drop(conn)
            return
        buf = buf[pos:]
        if len(buf) > self.MAX_COMMAND:          # no ">" in sight: not a command, drop it
            start = buf.rfind("<")
            buf = buf[start:] if 0 <= start and len(buf) - start <= self.MAX_COMMAND else ""
        self._conns[conn] = buf

    def _command(self, conn, cmd, ready: bool) -> bool:
        """One socketcand command of a client; a malformed one is ignored (the client stays
        connected, as on a bus where a bad frame is dropped). Returns whether it is in raw mode."""
        if not cmd:
            return ready
        if cmd[0] == "open":
            conn.sendall(b"< ok >")
        elif cmd[0] == "rawmode":
            conn.sendall(b"< ok >")
            with self._clients_lock:
                if conn not in self._clients:
                    self._clients.append(conn)
            return True
        elif cmd[0] == "send" and ready and len(cmd) >= 3:
            try:
                can_id, n = int(cmd[1], 16), int(cmd[2], 16)
                if not (0 <= can_id <= 0x1FFFFFFF and 0 <= n <= 8 and len(cmd) == 3 + n):
                    return ready
                payload = bytes(int(b, 16) for b in cmd[3:3 + n])
            except ValueError:          # not hexadecimal, or a byte beyond 0xFF
                return ready
            msg = can.Message(arbitration_id=can_id, data=payload, is_extended_id=len(cmd[1]) > 3,
                              timestamp=time.time(), is_rx=True, channel=self.channel)
            self._pending.append(msg)
            self._broadcast(msg, skip=conn)
        return ready

    def _broadcast(self, msg, skip=None):
        cid = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
        line = f"< frame {cid} {time.time() - self._t0:.6f} {bytes(msg.data).hex().upper()} >".encode()
        with self._clients_lock:
            if self._held is not None and skip is None:
                self._held.append(line)
                return
            self._write(line, skip)

    def _write(self, data: bytes, skip=None) -> None:
        for c in self._clients:
            if c is not skip:
                try:
                    c.sendall(data)
                except OSError:
                    pass

    def send(self, msg, timeout=None):
        self._broadcast(msg)

    def hold(self) -> None:
        """From now on the frames sent are held until :meth:`release`, which writes them to each
        client at once: the drive's whole answer to a SYNC in one TCP segment (one wake-up of the
        host, as the frames of one answer follow each other on a CAN bus)."""
        with self._clients_lock:
            self._held = []

    def release(self) -> None:
        with self._clients_lock:
            held, self._held = self._held, None
            if held:
                self._write(b"".join(held))

    def _recv_internal(self, timeout):
        if self._pending:
            return self._pending.popleft(), False
        t_end = None if timeout is None else time.perf_counter() + timeout
        while not self._closed:
            left = None if t_end is None else max(0.0, t_end - time.perf_counter())
            try:
                ready, _, _ = select.select([self._sock, *self._conns], [], [], left)
            except (OSError, ValueError):         # closed meanwhile
                break
            for s in ready:
                if s is self._sock:
                    self._accept()
                elif s in self._conns:
                    self._read(s)
            if self._pending:
                return self._pending.popleft(), False
            if t_end is not None and time.perf_counter() >= t_end:
                break
        return None, False

    def shutdown(self):
        self._closed = True
        try:
            self._sock.close()
        except OSError:
            pass
        for c in list(self._conns):
            try:
                c.close()
            except OSError:
                pass
        self._conns = {}
        with self._clients_lock:
            self._clients = []
        super().shutdown()
