"""A CiA 402 servo drive on CANopen as a backend (``canopen`` on ``python-can``: any interface): a
thin backend that composes the parts, each with one job.

=====================================  ===========================================================
part                                   its job
=====================================  ===========================================================
drivers.canopen.section            the ``[canopen]`` keys; the settings, read once
drivers.canopen.codec              the PDO mapping, how each object is packed (both sides), the units (Scaling)
drivers.canopen.startup            SDO configuration, guards and PDO mapping at start-up
drivers.canopen.link               the bus: connect, send, the receiving thread, the barrier
drivers.canopen.tracker            the SYNC and its answer: fresh, missed, late, latency
drivers.canopen.heartbeat          the host's heartbeat and the drive's
drivers.canopen.statemachine       CiA 402 up and down, quick stop's end, homing, fault reset
=====================================  ===========================================================

Start-up (:meth:`CanopenBackend.open`): NMT pre-operational, SDO configuration from config
(mode, scaling, limits, drive-side guards), PDO mapping, NMT operational. :meth:`enable` walks
the CiA 402 state machine up to OPERATION ENABLED over SDO. Then one exchange per cycle: the host
writes RPDO1 (controlword + the target of the mode) and sends the SYNC (:meth:`sync`); the drive
answers with TPDO1 (statusword, position actual, torque actual) and TPDO2 (velocity actual,
linear encoder 0x60E4.1), TPDO3 (tool-tip 0x60E4.2) where the config says the drive has a tip
sensor. A cycle whose answer is not in when the next one reads its feedback is recorded as missed
(``missed_total``, ``miss_run_max``, an event naming the cycle; the feedback keeps the last
answer) and ``canopen.pdo_miss_limit`` consecutive misses are ``lost communication``.

A tool-tip sensor on its own node (``canopen.tip_node_id``; object dictionary
drivers/canopen/eds/tip_encoder_cia406.eds, a CiA 406-like linear encoder): configured at start-up over SDO
(profile 406 checked, measuring step 0x6005.1 read, TPDO1 mapped to position value 0x6004 and
sent on every SYNC), set OPERATIONAL with the drive, and its TPDO is part of each cycle's answer
(a missing one counts as a missing answer). ``hil home`` presets it (0x6003) to the homed position.

=====  ==============  ======================  =====================
mode   0x6060          the drive closes        the host sends
=====  ==============  ======================  =====================
csp    8               position and velocity   target position 0x607A
csv    9               velocity                target velocity 0x60FF
cst    10              nothing                 target torque 0x6071
=====  ==============  ======================  =====================

Faults: EMCY messages are decoded and recorded (:attr:`CanopenBackend.emcy_log`), the drive's
heartbeat is watched (consumer timeout), missing TPDOs are counted; each shows as
``Feedback.fault`` (the fault rule of drivers.base); a bus that refuses the SYNC or the RPDO is a
:class:`~drivers.base.BackendFault` from :meth:`sync`. :meth:`quick_stop`, :meth:`fault_reset`,
clean shutdown (drivers.base's ``shutdown``) in :meth:`disable` and :meth:`close` (disable, NMT
pre-operational), both of which leave a drive this backend did not start (``open``) alone: ``hil
status`` and ``hil reset`` only connect.

Process-wide state: a real-time run (not lockstep) lowers the interpreter's thread switch
interval at :meth:`open` (``canopen.switch_interval``) and :meth:`close` puts it back.

Configuration mistakes are :class:`~hil.errors.ConfigError` naming the key, raised when the
backend is built (a missing or unreadable object dictionary, an unknown interface, a tip sensor
on the drive's node id) or when the bus is opened (an interface not installed).
"""
from __future__ import annotations

import math
import sys
import time
from collections import deque

import canopen

from drivers.base import Backend, Fault, Feedback, Setpoint
from drivers.canopen import cia402
from drivers.canopen import eds as eds_files
from drivers.canopen.codec import NM, RPDO_TARGET, TIP_KEY, TPDO_MAPS, Scaling
from drivers.canopen.heartbeat import Heartbeats
from drivers.canopen.link import AnswerEvent, BusErrors, CanLink, one_line, quiet_periodic_send_errors
from drivers.canopen.section import SECTION, CanopenSettings
from drivers.canopen.startup import configure_drive, configure_tip, sdo_retry
from drivers.canopen.statemachine import DriveStateMachine, fault_text
from drivers.canopen.tracker import AnswerTracker
from drivers.errors import BackendFault, StopKind
from drivers.rt import SampleBuffer

__all__ = ["CanopenBackend", "SECTION", "EVENTS_KEPT"]

EVENTS_KEPT = 1000           # the events (misses, faults, stops) and EMCYs a backend keeps: the latest
# the statuswords' (mask, value) the real-time cycle tests, bound once: no state name made or
# compared while the drive is well (the CiA 402 states are mutually exclusive under their masks)
_FAULT_WORDS = tuple(cia402.STATUSWORD[s] for s in ("FAULT", "FAULT REACTION ACTIVE"))
_ENABLED_WORD = cia402.STATUSWORD["OPERATION ENABLED"]
_WELL = (Fault.NONE, "")    # what a healthy cycle reports (nothing built per cycle)


class CanopenBackend(Backend):
    """``CanopenBackend(cfg)``; ``bus``: a python-can bus to use instead of opening the configured
    one; ``interface``, ``channel``, ``mode``, ``lockstep``, ``node_id`` override the config's
    keys; ``can_log``: a file to trace the bus into (``hil --can-log``, drivers.canopen.canlog)."""

    name = "canopen"
    misses_answers = True         # a SYNC without its TPDO in time (Feedback.stale)
    records_can = True            # takes open_backend's can_log (a trace of the bus)

    @staticmethod
    def check_settings(cfg) -> None:
        """What the configuration says of the drive, checked without a bus (``hil move --check``):
        the [canopen] settings, as the backend reads them when it is built (not real-time)."""
        CanopenSettings.from_config(cfg, has_bus=True)

    def __init__(self, cfg, bus=None, interface: str | None = None, channel: str | None = None,
                 mode: str | None = None, lockstep: bool | None = None, node_id: int | None = None,
                 can_log: str | None = None):
        """Not real-time: the settings read and checked, the object dictionaries loaded (a missing
        or broken file is a mistake named before anything connects), the parts built."""
        self.cfg = cfg
        s = self.settings = CanopenSettings.from_config(cfg, has_bus=bus is not None, interface=interface,
                                                        channel=channel, mode=mode, lockstep=lockstep,
                                                        node_id=node_id)
        self.closes, self.cycle_time, self.simulated = s.closes, s.cycle_time, s.lockstep
        self.scale = sc = Scaling(s.counts_per_m, s.rated, s.speed_scale)     # every drive unit <-> SI
        self._fb = Feedback(0.0, 0.0, 0.0)      # the cycle's one Feedback, updated in place (drivers.base)
        # the mode's target of a setpoint, bound once: the cycle compares no strings
        self._target_of = {"csp": lambda sp: sc.position_target(sp.position),
                           "csv": lambda sp: sc.speed_target(sp.speed)}.get(s.mode, lambda sp: sc.torque_target(sp.output))
        self._od = eds_files.load(cfg, "canopen.eds", s.node_id)
        self._tip_od = eds_files.load(cfg, "canopen.tip_eds", s.tip_id) if s.tip_id else None
        self.events: deque[str] = deque(maxlen=EVENTS_KEPT)
        self.emcy_log: deque[dict] = deque(maxlen=EVENTS_KEPT)
        self.link = CanLink(cfg, s, None, self.events, bus=bus, can_log=can_log)
        self.answers = self.link.answers = AnswerTracker(AnswerEvent(self.link), self.events)
        self.heartbeats = Heartbeats(s, self.link)
        self.machine = DriveStateMachine(self)
        self.node = self.tip_node = None
        self.tip_step = NM               # m per count of the tip sensor node (0x6005.1)
        self.started = False             # open() has begun: the drive is this backend's to stop and release
        self.enabled = False
        self._rpdo = None                # the RPDO's struct (controlword + target), from the mapping
        self._cw = cia402.COMMANDS["ENABLE OPERATION"]
        self._target = 0
        self.quick_stop_sync: int | None = None
        self.stopped_state = ""
        self._switch_interval = None     # the interpreter's switch interval before open() lowered it
        self.sync_to_rpdo = SampleBuffer()       # the time to send the RPDO (s)
        self.setpoint_latency = SampleBuffer()   # SYNC k sent -> RPDO k+1 (from feedback k) sent (s)

    # -- the parts' figures, by the names the tests and benchmarks read ----------------------------
    mode = property(lambda self: self.settings.mode)
    lockstep = property(lambda self: self.settings.lockstep)
    node_id = property(lambda self: self.settings.node_id)
    tip_id = property(lambda self: self.settings.tip_id)
    tip = property(lambda self: self.settings.tip)
    rated = property(lambda self: self.settings.rated)
    interface = property(lambda self: self.settings.interface)
    channel = property(lambda self: self.settings.channel)
    counts_per_m = property(lambda self: self.settings.counts_per_m)
    speed_scale = property(lambda self: self.settings.speed_scale)
    network = property(lambda self: self.link.network)
    cycling = property(lambda self: self.link.cycling)
    pdo_frames_on_loop = property(lambda self: self.link.pdo_frames_on_loop)
    syncs = property(lambda self: self.answers.syncs)
    missed_total = property(lambda self: self.answers.missed_total)
    late_total = property(lambda self: self.answers.late_total)
    miss_run_max = property(lambda self: self.answers.miss_run_max)
    answer_latency = property(lambda self: self.answers.answer_latency)

    # -- start-up (not real-time) -----------------------------------------------------------------
    def open(self) -> None:
        """Full start-up: connect, NMT pre-operational, SDO configuration and PDO mapping, NMT
        operational, the host's heartbeat (not real-time)."""
        s = self.settings
        self.started = True
        quiet_periodic_send_errors()
        if not s.lockstep and self._switch_interval is None:
            # a thread beside the loop (a drive simulated in this process, the heartbeat's) must
            # give the interpreter back soon, not after Python's default 5 ms switch interval;
            # close() puts the process-wide setting back
            self._switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(min(self._switch_interval, s.switch_interval))
        self.connect()
        self.node.nmt.state = "PRE-OPERATIONAL"
        sdo_retry(lambda: self.node.sdo[0x1000].raw, f"drive {s.node_id}", self.link.where)   # the drive answers
        if self.tip_node is not None:
            self.tip_node.nmt.state = "PRE-OPERATIONAL"
            self.tip_step = configure_tip(self.tip_node.sdo, self.cfg, s.tip_id, self.answers.tip_cob,
                                          self.link.where)
        layout = configure_drive(self.node, self.cfg, s)
        self._rpdo = layout.rpdo
        self.answers.configure(layout.tpdo, layout.echo, self.answers.tip_cob)
        if self.tip_node is not None:
            self.tip_node.nmt.state = "OPERATIONAL"
        self.node.nmt.state = "OPERATIONAL"
        self.heartbeats.start(self._on_heartbeat_send_error)

    def connect(self) -> None:
        """Only the bus and the drive's node (status, fault reset): no NMT command, no
        configuration (not real-time)."""
        s = self.settings
        network = self.link.connect()
        self.node = network.add_node(s.node_id, self._od)
        self.node.sdo.RESPONSE_TIMEOUT = self.cfg.get("canopen.sdo_timeout", 0.5)
        self.node.emcy.add_callback(self._on_emcy)
        network.subscribe(0x700 + s.node_id, self.heartbeats.on_drive_heartbeat)
        for n in range(len(TPDO_MAPS)):
            network.subscribe(0x180 + 0x100 * n + s.node_id, self.answers.on_tpdo)
        if s.tip_id:
            self.tip_node = network.add_node(s.tip_id, self._tip_od)
            self.tip_node.sdo.RESPONSE_TIMEOUT = self.node.sdo.RESPONSE_TIMEOUT
            self.answers.tip_cob = 0x180 + s.tip_id
            network.subscribe(self.answers.tip_cob, self.answers.on_tip)

    def state(self) -> str:
        """The drive's CiA 402 state, over SDO (not real-time)."""
        return self.machine.state()

    def enable(self) -> None:
        """CiA 402 state machine up to OPERATION ENABLED (over SDO), holding the present position
        (not real-time)."""
        s = self.settings
        sdo = self.node.sdo
        pos = sdo[0x6064].raw
        self._target = pos if s.mode == "csp" else 0
        sdo[RPDO_TARGET[s.mode][0]].raw = self._target
        self.machine.enable()
        self._cw = cia402.COMMANDS["ENABLE OPERATION"]
        self.enabled = True
        values = {0x6041: sdo[0x6041].raw, 0x6064: pos, 0x6077: 0, 0x606C: sdo[0x606C].raw,
                  (0x60E4, 1): sdo[0x60E4][1].raw, (0x60E4, 2): sdo[0x60E4][2].raw, 0x603F: 0}
        if self.tip_node is not None:
            values[TIP_KEY] = self.tip_node.sdo[0x6004].raw
        self.answers.assume_answered(values)      # the first cycle reads the state as configured
        self.link.start_cycling()

    def read_position(self) -> Feedback:
        """Where the axis stands, over SDO (not real-time; after :meth:`open`, before :meth:`enable`):
        position actual 0x6064, the linear encoder 0x60E4.1, the tip (its node's 0x6004, or
        0x60E4.2)."""
        s, sdo = self.settings, self.node.sdo
        try:
            x_motor = self.scale.position(sdo[0x6064].raw)
            x_table = self.scale.table(sdo[0x60E4][1].raw)
            if self.tip_node is not None:
                x_tip = self.tip_node.sdo[0x6004].raw * self.tip_step
            else:
                x_tip = self.scale.table(sdo[0x60E4][2].raw) if s.tip else math.nan
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
            raise BackendFault(f"lost communication: drive {s.node_id} does not answer SDO (position: "
                               f"{one_line(exc)})", StopKind.LINK) from None
        return Feedback(x_motor=x_motor, x_table=x_table, v_motor=0.0, x_tip=x_tip)

    def home(self, offset: float = 0.0, method: int = 37, timeout: float = 5.0) -> dict:
        """Homing mode (6), method 37 (or 35): the present position becomes ``offset`` (m, 0x607C)
        (not real-time; drivers.canopen.statemachine)."""
        return self.machine.home(offset, method, timeout)

    def fault_reset(self) -> str:
        """FAULT RESET over SDO; returns the state after it (not real-time)."""
        return self.machine.fault_reset()

    # -- callbacks of the receiving thread ---------------------------------------------------------
    def _on_emcy(self, err) -> None:
        entry = {"t": self.heartbeats.now(), "code": f"0x{err.code:04X}", "register": err.register,
                 "text": cia402.emcy_text(err.code), "data": bytes(err.data).hex()}
        self.emcy_log.append(entry)
        self.events.append(f"EMCY {entry['code']} {entry['text']}")

    def _on_heartbeat_send_error(self, exc: Exception) -> bool:
        """The host's heartbeat could not be sent (python-can's send thread): the link's fault in
        one line; False stops the task (the drive's heartbeat consumer then acts)."""
        BusErrors(self.link).on_error(exc)
        return False

    def fault_text(self) -> str:
        with self.answers.lock:
            code = self.answers.values.get(0x603F, 0)
        return fault_text(self.emcy_log, code)

    # -- the cycle (real-time) ---------------------------------------------------------------------
    def receive_until(self, t_end: float) -> None:
        """The clock's wait for its next deadline: the frames taken on the loop's thread until
        ``t_end`` (real-time; drivers.canopen.link)."""
        self.link.receive_until(t_end)

    def read_feedback(self) -> Feedback:
        """This cycle's answer (real-time): in lockstep after the SDO barrier, else what came in
        after the clock's wait. A missing answer is counted and the last one repeated (``stale``);
        the fault rule of drivers.base in ``fault``."""
        s, answers = self.settings, self.answers
        if s.lockstep and not answers.complete():
            self.link.barrier(self.node.sdo)
        elif self.link.cycling:
            self.link.receive_until(0.0)              # what came in after the clock's wait
        fresh = answers.close_cycle()
        fault, reason = _WELL if fresh else self._missed()
        with answers.lock:
            rx = answers.values
            position, table, v, torque, sw = (rx.get(0x6064, 0), rx.get((0x60E4, 1), 0), rx.get(0x606C, 0),
                                              rx.get(0x6077, 0), rx.get(0x6041, 0))
            tip = rx.get(TIP_KEY, 0) if s.tip_id else rx.get((0x60E4, 2), 0)
        sc = self.scale
        if s.tip_id:
            x_tip = tip * self.tip_step
        else:
            x_tip = sc.table(tip) if s.tip else math.nan
        if not fault:
            fault, reason = self._fault(sw)
        fb = self._fb
        fb.x_motor, fb.x_table, fb.v_motor = sc.position(position), sc.table(table), sc.position(v)
        fb.output, fb.x_tip, fb.stale = sc.torque(torque), x_tip, not fresh
        fb.fault, fb.reason = fault, reason
        return fb

    def _missed(self) -> tuple[Fault, str]:
        """A cycle without its answer (real-time): logged; after ``canopen.pdo_miss_limit`` in a
        row, the fault (the link's) and its line."""
        answers = self.answers
        who = "tip sensor node %d" % self.settings.tip_id if answers.only_tip_missing else "drive"
        self.events.append(f"cycle {answers.syncs}: no TPDO after SYNC from the {who}")
        if answers.miss_run >= self.settings.pdo_miss_limit:
            return Fault.LINK, f"lost communication: no TPDO from the {who} for {answers.miss_run} cycles"
        return _WELL

    def _fault(self, sw: int) -> tuple[Fault, str]:
        """The fault the link and the drive show and its line (real-time): a failed bus or a lost
        heartbeat (the link's), a drive in FAULT or out of OPERATION ENABLED (the drive's);
        ``(Fault.NONE, "")`` while all is well."""
        if self.link.rx_error:
            return Fault.LINK, self.link.rx_error
        for mask, value in _FAULT_WORDS:
            if sw & mask == value:
                return Fault.DRIVE, f"drive fault: {self.fault_text()}"
        if self.enabled and sw & _ENABLED_WORD[0] != _ENABLED_WORD[1]:
            return Fault.DRIVE, f"drive fault: the drive left OPERATION ENABLED ({cia402.state_from_statusword(sw)})"
        lost = self.heartbeats.lost()
        return (Fault.LINK, lost) if lost else _WELL

    def write_setpoint(self, sp: Setpoint) -> None:
        """The target of the mode, in drive units, for the next RPDO (real-time)."""
        self._target = self._target_of(sp)

    def sync(self) -> None:
        """RPDO (controlword + target), then SYNC: the drive applies the target and answers
        (real-time)."""
        t0 = time.perf_counter()
        self._send_rpdo()
        self.sync_to_rpdo.append(time.perf_counter() - t0)
        self.send_sync()

    def _send_rpdo(self) -> None:
        sent = self.answers.sync_sent
        if sent:
            self.setpoint_latency.append(time.perf_counter() - sent)
        self.link.send(0x200 + self.settings.node_id, self._rpdo.pack(self._cw, self._target))

    def send_sync(self) -> None:
        """The SYNC with its counter (real-time); from here on only the answer to this SYNC is
        fresh. In lockstep the drive's clock advances with it."""
        counter = self.answers.next_sync()
        self.link.send(0x80, bytes((counter,)) if self.answers.echo else b"")
        self.answers.syncs += 1
        if self.settings.lockstep:
            self.heartbeats.on_sync()

    def quick_stop(self) -> None:
        """The controlled stop ``supervisor.stop`` asks for, now, by RPDO (the drive acts on receipt;
        real-time, in the cycle of a trip): CiA 402 quick stop (controlword 0x0002; the drive brakes
        on its quick-stop ramp, 0x605A) or disable (DISABLE VOLTAGE: the power stage off, the axis
        coasts). :meth:`disable` then keeps the SYNC going until the drive is at rest, and repeats
        the command over SDO where the drive did not take it."""
        how = self.settings.stop_how
        self._cw = cia402.COMMANDS["QUICK STOP" if how == "quick_stop" else "DISABLE VOLTAGE"]
        self.quick_stop_sync = self.syncs
        self.events.append(f"cycle {self.syncs}: {how.replace('_', ' ')} commanded")
        self.enabled = False
        try:
            self._send_rpdo()
        except Exception as exc:
            # not delivered (the bus is gone): said, so the run reports its stop as failed; disable()
            # at the shutdown tries again over SDO, and the drive's own guards stop it where that fails
            raise BackendFault(f"lost communication: the {how.replace('_', ' ')} was not sent ({one_line(exc)})",
                               StopKind.LINK) from None

    # -- the end (not real-time) -------------------------------------------------------------------
    def wait_stopped(self, max_cycles: int | None = None) -> str:
        """Keep the SYNC going until the drive has finished its quick stop or fault reaction (not
        real-time; drivers.canopen.statemachine)."""
        return self.machine.wait_stopped(self._cw, max_cycles)

    def disable(self) -> None:
        """Let a quick stop (or fault reaction) finish, then SHUTDOWN (READY TO SWITCH ON: no torque)
        (not real-time). Nothing on a drive this backend did not start, or after :meth:`close`."""
        if not self.started or self.node is None or self.network is None:
            return
        self.link.stop_cycling()
        with self.answers.lock:
            sw = self.answers.values.get(0x6041, 0)
        stopping = self.quick_stop_sync is not None and self._cw != cia402.COMMANDS["ENABLE OPERATION"] or \
            cia402.state_from_statusword(sw) in ("QUICK STOP ACTIVE", "FAULT REACTION ACTIVE")
        self.stopped_state = self.machine.shutdown(stopping, self._cw, self.stopped_state)
        self.enabled = False

    def close(self) -> None:
        """The host's heartbeat stopped, the nodes this backend started put back to NMT
        pre-operational (their PDOs stop), the bus released, the thread switch interval put back
        (not real-time). Nothing after the first call."""
        if self.network is None:
            self._restore_switch_interval()
            return
        try:
            self.link.stop_cycling()
            self.heartbeats.stop()
            if self.started and self.node is not None:
                self.node.nmt.state = "PRE-OPERATIONAL"
                if self.tip_node is not None:
                    self.tip_node.nmt.state = "PRE-OPERATIONAL"
        except Exception as exc:        # the link may be gone: the drive-side guards act then
            self.events.append(f"close: {one_line(exc)}")
        self.link.disconnect()
        self.started = False
        self._restore_switch_interval()

    def _restore_switch_interval(self) -> None:
        if self._switch_interval is not None:
            sys.setswitchinterval(self._switch_interval)
            self._switch_interval = None

    def status(self) -> dict:
        """The drive's state, position and last EMCYs over SDO (``hil status``; not real-time)."""
        self.link.stop_cycling()
        s, sdo = self.settings, self.node.sdo
        if self.node.nmt.state == "INITIALISING":         # no heartbeat seen yet: wait for one
            try:
                self.node.nmt.wait_for_heartbeat(2 * max(sdo[0x1017].raw, 100) * 1e-3)
            except Exception:
                pass
        sw = sdo[0x6041].raw
        nmt = self.node.nmt.state
        if nmt == "INITIALISING":       # python-canopen's state before a heartbeat: not what a node answering SDO is
            nmt = "unknown (no heartbeat seen; the node answers SDO)"
        out = {"node": s.node_id, "nmt": nmt, "state": cia402.state_from_statusword(sw),
               "statusword": f"0x{sw:04X}", "mode": s.mode, "position_m": self.scale.position(sdo[0x6064].raw),
               "table_m": self.scale.table(sdo[0x60E4][1].raw), "error_code": f"0x{sdo[0x603F].raw:04X}",
               "emcy": list(self.emcy_log)[-5:]}
        if self.tip_node is not None:
            try:
                step = self.tip_node.sdo[0x6005][1].raw * NM
                out["tip_node"] = s.tip_id
                out["tip_m"] = self.tip_node.sdo[0x6004].raw * step
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
                out["tip_node"], out["tip_m"] = s.tip_id, f"no answer ({one_line(exc)})"
        return out
