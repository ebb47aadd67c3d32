"""A simulated CiA 402 servo drive on a CAN bus: a ``canopen`` LocalNode with the object dictionary
of drivers/canopen/eds/cia402_generic.eds, answering SDO (canopen's server), NMT (canopen's NMT slave), SYNC,
PDO, heartbeat and EMCY. Its shaft is the sim_plant model (drivers.sim.SimulatedPlant, through
its public API), advanced one cycle per SYNC, closing in the drive the loops the mode of operation
gives it (CSP: both, CSV: velocity, CST: none).

The drive is composed of parts with one job each, as the host's backend is:

=====================================  ===========================================================
part                                   its job
=====================================  ===========================================================
drivers.canopen.codec              the PDO mapping read back, objects packed (shared with the host)
drivers.canopen.cia402             the state machine's tables (shared with the host)
drivers.canopen.drive_guards       heartbeat and SYNC consumers, stale SYNCs after a stall
drivers.canopen.drive_stop         the quick stop's ramp and hold, the fault reaction
drivers.canopen.tip_sim            a tool-tip sensor on its own node (CiA 406-like)
drivers.canopen.socketcand_server  the transport of ``hil drive-sim`` in its own process
this module                            the node, the drive's state machine, one cycle, faults
=====================================  ===========================================================

Time: ``lockstep=True`` (the tests) makes the drive's clock the SYNC count, heartbeats included,
so that runs are deterministic (canopen's notifier thread hands the drive its frames);
``lockstep=False`` (``hil drive-sim`` in its own process, the in-process benchmark) runs the drive
as a drive runs: one thread (:meth:`DriveSim.serve`) takes each frame from the bus itself, and a
SYNC is answered at once with the TPDOs of the cycle it starts (the plant advanced by the
compiled drive step of drivers.sim, about 5 us, in about 20 us of cycle work in all), so that
the answer leaves within a fixed, short time of the SYNC (the figure is in ``hil drive-sim
--help``); the same thread produces the heartbeats on the wall clock and keeps the shaft moving
on its own clock when SYNCs stop (the link died: the drive-side guards must stop it).

Drive-side guards (set by the host over SDO at start-up; drivers.canopen.drive_guards):
heartbeat consumer 0x1016 and SYNC consumer, either of which, once lost while OPERATION ENABLED,
performs the abort-connection option 0x6007 (0 nothing, 1 fault, 2 disable voltage, 3 quick stop;
EMCY 0x8130 for the heartbeat, 0x8100 for the SYNC); following-error window 0x6065/0x6066,
software position limits 0x607D, max torque 0x6072. The consumers are evaluated before each frame
is handled (a drive that was stalled looks at its clock before it reads its backlog) and once a
period. A stale SYNC is discarded with the targets latched before it: the drive holds its last
fresh target and sends no answer to it. A quick stop (or an abort) cannot be undone by a stale
``ENABLE OPERATION`` either: transition 16 (QUICK STOP ACTIVE -> OPERATION ENABLED) exists only
with quick stop option codes 5..8 (0x605A); the host sets 2. Enabling (transition 4) starts from
the actual position: the targets received before it are dropped.

Fault injection (:meth:`DriveSim.inject`): ``emcy`` (a drive fault: EMCY + FAULT state),
``heartbeat_loss``, ``frozen_encoder``, ``late_pdo``, ``missing_pdo``, ``following_error``,
``tip_missing_pdo`` (the tip sensor's TPDO withheld).

Real-time (one drive cycle, with the drive's lock held): the SYNC, RPDO and heartbeat callbacks,
:meth:`DriveSim.handle_frame` and what they call; not real-time: the constructor, SDO writes of
the configuration, :meth:`DriveSim.inject`, :meth:`DriveSim.close`.
"""
from __future__ import annotations

import gc
import math
import struct
import threading
import time

import can
import canopen

from drivers.base import Setpoint
from drivers.canopen import cia402
from drivers.canopen import eds as eds_files
from drivers.canopen.codec import pdo_plan, store, stored_bytes
from drivers.canopen.drive_guards import STALE_CYCLES, DriveGuards
from drivers.canopen.drive_stop import QS_EASE, QS_MIN_HOLD, QS_REST_SPEED, QuickStopRamp
from drivers.canopen.socketcand_server import LOOPBACK, SocketcandServerBus
from drivers.canopen.tip_sim import TipSensorSim
from drivers.rt import SampleBuffer, fine_timer_slack
from drivers.sim import SimulatedPlant

__all__ = ["DriveSim", "TipSensorSim", "FAULTS", "SocketcandServerBus", "LOOPBACK", "STALE_CYCLES",
           "QS_REST_SPEED", "QS_MIN_HOLD", "QS_EASE"]


FAULTS = ("emcy", "heartbeat_loss", "frozen_encoder", "late_pdo", "missing_pdo", "following_error",
          "tip_missing_pdo")

# Objects the drive itself updates every cycle: written straight into the node's data store (the
# SDO server reads them from there), not through the SDO layer, which costs tens of microseconds
# per access; they do not invalidate the cached configuration.
_LIVE = {0x6040, 0x6041, 0x6064, 0x606C, 0x6077, 0x60E4, 0x2001, 0x603F, 0x1001, 0x6061}
_TARGETS = ((0x607A, 0), (0x60FF, 0), (0x6071, 0))
_INT32 = (-2 ** 31, 2 ** 31 - 1)


class Injected:
    """The faults injected now (:meth:`DriveSim.inject`; all gone with :meth:`clear`)."""

    def __init__(self):
        self.clear()

    def clear(self) -> None:
        self.frozen: tuple | None = None    # the readings frozen at (motor, table, tip, speed)
        self.missing = 0                    # TPDO answers still to withhold
        self.late = 0.0                     # s: every answer this late
        self.fe_offset = 0.0                # m: an offset on the position readings
        self.held: list = []                # late answers: (release at sync count, frames)
        self.hb_dead = False                # the drive's heartbeat stopped


class DriveSim:
    """``DriveSim(cfg, plant, bus=bus)`` on an existing python-can bus, or ``interface=``/``channel=``;
    ``plant``: the shaft's model (``hil.plant_config.plant_from_config(cfg)``).

    ``lockstep=False``: the drive's thread (:meth:`serve`) is started here unless ``thread=False``
    (``hil drive-sim`` runs :meth:`serve` on its main thread)."""

    def __init__(self, cfg, plant, bus=None, interface: str | None = None, channel: str | None = None,
                 node_id: int | None = None, eds: str | None = None, lockstep: bool = True, bitrate: int = 1000000,
                 tip_node_id: int | None = None, thread: bool = True):
        self.cfg = cfg
        self.plant_model = plant
        self.node_id = node_id or int(cfg.get("canopen.node_id", 1))
        self.lockstep = lockstep
        self.lock = threading.RLock()
        od = eds_files.load(cfg, "canopen.eds", self.node_id, eds)     # a bad file: ConfigError, no bus opened
        self._open_network(bus, interface, channel, bitrate)
        self.node = canopen.LocalNode(self.node_id, od)
        self._serve_node()
        self._init_drive_state()
        self.node.sdo[0x6041].raw = cia402.statusword_for(self.state)
        tip_id = int(cfg.get("canopen.tip_node_id", 0) or 0) if tip_node_id is None else int(tip_node_id)
        self.tip_sensor = TipSensorSim(self, tip_id) if tip_id else None
        self._warm_up()
        self.node.nmt.state = "PRE-OPERATIONAL"
        self.network.send_message(0x700 + self.node_id, [0])        # boot-up
        if not lockstep and thread:
            self._idle_thread = threading.Thread(target=self.serve, name="drive-sim", daemon=True)
            self._idle_thread.start()

    # -- start-up (not real-time) -----------------------------------------------------------------
    def _open_network(self, bus, interface, channel, bitrate) -> None:
        cfg = self.cfg
        self._own_bus = bus is None
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.05          # the receive thread stops within 50 ms
        if self.lockstep:         # canopen's notifier thread hands the frames over
            if bus is None:
                self.network.connect(interface=interface or cfg.get("canopen.interface", "virtual"),
                                     channel=channel or cfg.get("canopen.channel", "hil"), bitrate=bitrate)
            else:
                self.network.connect()
        elif bus is None:         # the drive's own thread takes the frames (serve): no notifier
            self.network.bus = can.Bus(interface=interface or cfg.get("canopen.interface", "virtual"),
                                       channel=channel or cfg.get("canopen.channel", "hil"), bitrate=bitrate)

    def _serve_node(self) -> None:
        """The node on the network: SDO writes, SYNC, RPDOs and the host's heartbeat to this drive."""
        # heartbeats are produced here (on the SYNC clock in lockstep, else the wall clock)
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_write_callback(self._on_sdo_write)
        self.network.add_node(self.node)
        self.network.subscribe(0x80, self._on_sync)
        for n in range(4):
            self.network.subscribe(0x200 + 0x100 * n + self.node_id, self._on_rpdo)
        self.network.subscribe(0x700 + int(self.cfg.get("canopen.host_node_id", 127)), self._on_host_heartbeat)

    def _init_drive_state(self) -> None:
        self._conf = None                  # the configuration the host set over SDO, cached (_config)
        self.state = "SWITCH ON DISABLED"
        self.cw = 0
        self.mode = "csp"
        self.plant: SimulatedPlant | None = None
        self.stop_ramp = QuickStopRamp()
        self._make_plant("csp")
        self.time = 0.0
        self.syncs = 0
        self.sync_counter = 0
        self.rx: dict[tuple[int, int], int] = {}      # the targets received, latched at the next SYNC
        self.target_position = self.target_velocity = self.target_torque = 0
        self._next_hb = 0.0
        self.emcy_sent: list[tuple[float, int]] = []
        self.log: list[tuple[int, str]] = []          # (sync count, event)
        self.quick_stop_at: int | None = None         # sync count when the quick stop was received
        self.fault_at: int | None = None              # sync count when the drive faulted
        self.fault_code = 0
        self._fe_count = 0
        self._home_offset = 0.0
        self.sw_extra = 0
        self.guards = DriveGuards(self)
        self.injected = Injected()
        self.stale_syncs = 0               # SYNCs (and their targets) discarded as stale
        self.frames_rejected = 0           # malformed frames ignored
        self._stall_for = 0.0              # serve: stall this long (the freeze fault)
        self._stop = threading.Event()
        self._idle_thread = None
        self.answer_times = SampleBuffer()   # serve: SYNC taken from the bus -> its TPDOs sent (s)

    def _make_plant(self, mode: str) -> None:
        closes = cia402.MODE_CLOSES[mode]
        new = SimulatedPlant(self.cfg, self.plant_model, closes=closes)
        new.warm_up()                 # its cycles loaded before its first SYNC in the new mode
        if self.plant is not None:
            new.take_over(self.plant)
        new.open()
        self.plant = new
        self.mode = mode
        self.period = new.cycle_time

    def hb_now(self) -> float:
        """The heartbeat consumer's clock: the SYNC clock in lockstep, else the wall clock."""
        return self.time if self.lockstep else time.perf_counter()

    def _warm_up(self) -> None:
        """Run the drive's quick stop once on the plant, its state put back (SimulatedPlant.restored),
        so that the first SYNC is not held up by loading its compiled functions (a late first
        answer). The plant's own cycles (coasting while disabled, as the drive starts, included)
        were loaded when it was made (:meth:`_make_plant`): a first client's greeting is not held
        up either."""
        with self.plant.restored():
            self.plant.enabled = True
            self._quick_stop_step(1.0)
        self.stop_ramp.state = None

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
                 "tpdo": [pdo_plan(self.node, 0x1800, 0x1A00, n) for n in range(4)],
                 "rpdo": [pdo_plan(self.node, 0x1400, 0x1600, n)[1] for n in range(4)]}
            self._conf = c
        return c

    # -- the drive's state machine (an SDO write or an RPDO: on receipt) ------------------------------
    def _on_sdo_write(self, index, subindex, od, data):
        with self.lock:
            if index not in _LIVE:
                self._conf = None          # configuration changed: read it again at the next cycle
            if index == 0x6040:
                self._controlword(struct.unpack("<H", data)[0])
            elif index == 0x6060:
                self._mode_of_operation(struct.unpack("<b", data)[0])
            elif index == 0x1016 and subindex == 1:
                self.guards.last_host_heartbeat = self.hb_now()

    def _mode_of_operation(self, code: int) -> None:
        """0x6060 written: a new mode (a new shaft model, the motion carried over), or homing."""
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
            q = self.stop_ramp.state
            if q is not None and not q.get("told"):
                q["told"] = True
                self.log.append((self.syncs, "ENABLE OPERATION ignored in QUICK STOP ACTIVE (0x605A not 5..8)"))
            return
        if new == "QUICK STOP ACTIVE":
            self._start_quick_stop()
        if new == "OPERATION ENABLED":
            self.plant.restart_interpolation()
            self.plant.restart_velocity_loop()
            self.guards.last_host_heartbeat = self.hb_now()
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
        for key in _TARGETS:
            self.rx.pop(key, None)
        self.target_position = struct.unpack("<i", stored_bytes(self.node, 0x6064, 0)[:4])[0]
        self.target_velocity = self.target_torque = 0
        self.guards.restart()

    def _start_quick_stop(self) -> None:
        self.quick_stop_at = self.syncs
        self.stop_ramp.start(self.plant)

    def _quick_stop_step(self, tmax: float, conf=None) -> bool:
        """One cycle of the quick stop or fault reaction (drivers.canopen.drive_stop); True
        when it has ended."""
        if self.stop_ramp.state is None:
            self._start_quick_stop()
        return self.stop_ramp.step(self.plant, tmax, conf, self.period, self.log, self.syncs)

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

    # -- bus callbacks (real-time) ------------------------------------------------------------------
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
            self.guards.last_host_heartbeat = self.hb_now()

    def _on_sync(self, can_id, data, timestamp):
        with self.lock:
            counter = data[0] if data else 0       # CiA 301 SYNC counter (0x1019 > 0)
            if self.guards.stall_ref is not None and self.guards.stale(counter, self._config()):
                self.stale_syncs += 1
                self.log.append((self.syncs, f"stale SYNC {counter} discarded with its targets"))
                for key in _TARGETS:
                    self.rx.pop(key, None)
                self._cycle(from_sync=False)          # time goes on; the last fresh target held, no answer
                return
            self.guards.on_sync(counter, self.state == "OPERATION ENABLED")
            self.sync_counter = counter
            store(self.node, 0x2001, 0, "B", self.sync_counter)
            self._cycle(from_sync=True)

    # -- the drive's own thread (wall-clock mode) ---------------------------------------------------
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
                self._duty(t, on_duty)
                duty += self.period
                if duty <= t:                     # held up: the next duty one period from now
                    duty = t + self.period
                if self._stall_for > 0:           # the freeze fault: the thread stalls, the frames queue
                    stall, self._stall_for = self._stall_for, 0.0
                    time.sleep(stall)

    def _duty(self, t: float, on_duty) -> None:
        """Once a period (real-time): the consumers, the shaft's own cycle when the SYNCs have
        stopped, the heartbeat, the caller's duty."""
        with self.lock:
            self.guards.before_frame(t, self._config())
            if t - self.guards.last_sync_wall > 3 * self.period:
                self._cycle(from_sync=False)
            self._heartbeat_wall()
            if on_duty is not None:
                on_duty(self)

    def handle_frame(self, msg, hold=None, release=None) -> bool:
        """Wall-clock mode: one frame taken off the bus, handed to canopen's dispatch (SYNC,
        RPDO, SDO, NMT, the host's heartbeat) after the consumers have looked at the clock. A
        malformed frame (a PDO or SDO of the wrong size, an unknown command) is logged and
        dropped, as a bus drops it: the drive carries on. True when the frame was handled."""
        if msg.is_error_frame or msg.is_remote_frame:
            return False
        with self.lock:
            self.guards.before_frame(time.perf_counter(), self._config())
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
        if ms and not self.injected.hb_dead and time.perf_counter() >= self._next_hb:
            self._next_hb = time.perf_counter() + ms * 1e-3
            self.network.send_message(0x700 + self.node_id, [self.node.nmt._state])

    def advance(self, cycles: int) -> None:
        """Let ``cycles`` periods pass without a SYNC (the link is dead; lockstep tests)."""
        for _ in range(cycles):
            with self.lock:
                self._cycle(from_sync=False)

    # -- one drive cycle (real-time) --------------------------------------------------------------
    def _cycle(self, from_sync: bool) -> None:
        self.syncs += 1
        self.time += self.period
        if not from_sync:
            self.guards.own_cycles += 1
        conf = self._config()
        operational = self.node.nmt.state == "OPERATIONAL"
        self.guards.watch(conf)
        self._latch_targets(conf)
        self._move(conf)
        actual = self._actual(conf["cpm"], conf["rated"])
        if self.state == "OPERATION ENABLED":
            self._check_limits(conf, actual["pos"])
        # heartbeat on the drive's clock (lockstep)
        if self.lockstep:
            ms = conf["hb_ms"]
            if ms and not self.injected.hb_dead and self.time + 1e-12 >= self._next_hb:
                self._next_hb = self.time + ms * 1e-3
                self.network.send_message(0x700 + self.node_id, [self.node.nmt._state])
        if from_sync and self.tip_sensor is not None:
            self.tip_sensor.on_sync(actual["tip_plant"])
        if from_sync and operational:
            self._send_tpdos(actual)

    def _latch_targets(self, conf) -> None:
        """The targets received, latched at the SYNC, the position clamped to the software limits."""
        rx = self.rx
        if (0x607A, 0) in rx:
            self.target_position = min(max(rx[(0x607A, 0)], conf["lo"]), conf["hi"])
        if (0x60FF, 0) in rx:
            self.target_velocity = rx[(0x60FF, 0)]
        if (0x6071, 0) in rx:
            self.target_torque = rx[(0x6071, 0)]

    def _move(self, conf) -> None:
        """The shaft one cycle on: the mode's setpoint, the quick stop, or coasting."""
        pl, cpm, tmax = self.plant, conf["cpm"], conf["tmax"]
        if self.state == "OPERATION ENABLED":
            if self.mode in ("csp", "hm"):
                pl.write_setpoint(Setpoint(position=self.target_position / cpm - self._home_offset))
            elif self.mode == "csv":
                pl.write_setpoint(Setpoint(speed=self.target_velocity / cpm * pl.ctrl.speed_scale))
            else:
                u = self.target_torque * 1e-3 * conf["rated"]
                pl.write_setpoint(Setpoint(output=max(-tmax, min(tmax, u))))
            pl.sync()
        elif self.state in ("QUICK STOP ACTIVE", "FAULT REACTION ACTIVE"):
            if self._quick_stop_step(tmax, conf):
                # quick stop option 2 / fault reaction 0x605E = 2: stop on the quick-stop ramp, then disable
                self._set_state("SWITCH ON DISABLED" if self.state == "QUICK STOP ACTIVE" else "FAULT")
        else:
            pl.enabled = False
            pl.sync()

    def _check_limits(self, conf, pos: int) -> None:
        """The drive-side guards on the actual position: software limits, following-error window."""
        lo, hi = conf["lo"], conf["hi"]
        if not (lo <= pos <= hi):
            self.fault(0x8612)
        win = conf["fe_window"]
        if self.mode in ("csp", "hm") and win != 0xFFFFFFFF and abs(self.target_position - pos) > win:
            self._fe_count += 1
            if self._fe_count * self.period * 1e3 > conf["fe_time_ms"]:
                self.fault(0x8611)
        else:
            self._fe_count = 0

    def _actual(self, cpm: float, rated: float) -> dict:
        pl = self.plant
        fb = pl.read_feedback()
        x_motor, x_table, x_tip = fb.x_motor, fb.x_table, fb.x_tip
        if math.isnan(x_tip):
            x_tip = x_table
        tip_plant = x_tip        # the tip mass as a separate sensor sees it (the drive's homing is not its)
        fe_offset = self.injected.fe_offset
        x_motor += self._home_offset
        x_table += self._home_offset + fe_offset
        x_tip += self._home_offset + fe_offset
        if self.injected.frozen is not None:
            x_motor, x_table, x_tip, v = self.injected.frozen
        else:
            v = pl.x[pl.plant.n]
        act = {"pos": int(round(x_motor * cpm)), "vel": int(round(v * cpm)),
               "torque": int(round(pl.output_actual / rated * 1e3)) if self.state == "OPERATION ENABLED" else 0,
               "table": int(round(x_table * 1e9)), "tip": int(round(x_tip * 1e9)), "v": v,
               "x": (x_motor, x_table, x_tip), "tip_plant": tip_plant}
        d = self.node
        lo, hi = _INT32
        store(d, 0x6064, 0, "i", max(lo, min(hi, act["pos"])))
        store(d, 0x606C, 0, "i", max(lo, min(hi, act["vel"])))
        store(d, 0x6077, 0, "h", max(-32768, min(32767, act["torque"])))
        store(d, 0x60E4, 1, "i", max(lo, min(hi, act["table"])))
        store(d, 0x60E4, 2, "i", max(lo, min(hi, act["tip"])))
        return act

    def _send_tpdos(self, actual) -> None:
        inj = self.injected
        if inj.missing > 0:
            inj.missing -= 1
            self.log.append((self.syncs, "TPDO withheld"))
            return
        frames = []
        node = self.node
        for cob, entries in self._config()["tpdo"]:
            if cob is None:
                continue
            frames.append((cob, b"".join(stored_bytes(node, index, sub)[:nbytes] for index, sub, nbytes, _ in entries)))
        if inj.held:
            due = [f for f in inj.held if f[0] <= self.syncs]
            inj.held = [f for f in inj.held if f[0] > self.syncs]
            for _, old in due:                                   # late answers to earlier SYNCs go out first
                for cob, data in old:
                    self.network.send_message(cob, data)
        if inj.late > 0:
            self._send_late(frames, inj.late)
            return
        for cob, data in frames:
            self.network.send_message(cob, data)

    def _send_late(self, frames, delay: float) -> None:
        self.log.append((self.syncs, f"TPDO late by {delay * 1e3:g} ms"))
        if self.lockstep:
            # drive time is the SYNC count: the answer goes out with a later SYNC's
            self.injected.held.append((self.syncs + max(1, int(math.ceil(delay / self.period - 1e-9))), frames))
        else:
            threading.Timer(delay, lambda: [self.network.send_message(c, d) for c, d in frames]).start()

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

    def abort_connection(self, cause: str = "host heartbeat lost", code: int = 0x8130) -> None:
        """CiA 402 abort connection option code 0x6007: 0 no action, 1 fault (fault reaction, then
        FAULT), 2 disable voltage (SWITCH ON DISABLED: the power stage off), 3 quick stop (then
        SWITCH ON DISABLED, 0x605A = 2). Every action but 0 sends the EMCY ``code``."""
        option = self.node.sdo[0x6007].raw
        self.log.append((self.syncs, f"{cause}, abort connection option {option}"))
        self.guards.armed = False
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
            inj = self.injected
            if fault == "emcy":
                self.fault(int(value or 0x2310))
            elif fault == "heartbeat_loss":
                inj.hb_dead = True
                self.node.nmt.stop_heartbeat()
            elif fault == "frozen_encoder":
                cpm, rated = self._scales()
                a = self._actual(cpm, rated)
                inj.frozen = (*a["x"], a["v"])
            elif fault == "late_pdo":
                inj.late = float(value if value is not None else 2 * self.period)
            elif fault == "missing_pdo":
                inj.missing = int(value or 1)
            elif fault == "following_error":
                inj.fe_offset = float(value if value is not None else 0.01)
            elif fault == "tip_missing_pdo":
                if self.tip_sensor is None:
                    raise ValueError("tip_missing_pdo: this drive simulation has no tip sensor node")
                self.tip_sensor.missing = int(value or 1)
            else:
                raise ValueError(f"unknown fault {fault!r} (known: {', '.join(FAULTS)})")

    def clear_injections(self) -> None:
        with self.lock:
            self.injected.clear()

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
