"""A CiA 402 servo drive on CANopen as a backend (``canopen`` on ``python-can``: any interface).

Start-up (:meth:`CanopenBackend.open`): NMT pre-operational, SDO configuration from config
(mode, scaling, limits, drive-side guards), PDO mapping, NMT operational. :meth:`enable` walks
the CiA 402 state machine (hil.drivers.canopen.cia402's tables) up to OPERATION ENABLED over SDO. Then one
exchange per cycle: the host writes RPDO1 (controlword + the target of the mode) and sends the
SYNC (:meth:`sync`); the drive answers with TPDO1 (statusword, position actual, torque actual)
and TPDO2 (velocity actual, linear encoder 0x60E4.1), TPDO3 (tool-tip 0x60E4.2) where the
config says the drive has a tip sensor.

Threads. Start-up, SDO and shutdown run on canopen's notifier thread (python-can's ``Notifier``
hands each frame to ``Network.notify``). The cyclic phase, from :meth:`enable` until the next SDO
use (:meth:`disable`, :meth:`close`, homing, status), has no such thread: the notifier is stopped
and the loop's own thread takes the frames from the bus (:meth:`CanopenBackend.receive_until`,
the clock's wait for its next deadline: ``Bus.recv`` with a timeout, outside the interpreter
lock), decodes the TPDOs it mapped (one ``struct`` per PDO, from the mapping it wrote) and hands
every other frame (EMCY, heartbeat, SDO) to ``Network.notify``. The answer reaches the loop with
no hand-over between threads, and no receive thread competes with the loop for the lock. A cycle
whose answer is not in when the next one reads its feedback is recorded as missed
(``missed_total``, ``miss_run_max``, an event naming the cycle; the feedback keeps the last
answer) and ``canopen.pdo_miss_limit`` consecutive misses are ``lost communication``.

A tool-tip sensor on its own node (``canopen.tip_node_id``; object dictionary
hil/drivers/canopen/eds/tip_encoder_cia406.eds, a CiA 406-like linear encoder): configured at start-up over SDO
(profile 406 checked, measuring step 0x6005.1 read, TPDO1 mapped to position value 0x6004 and
sent on every SYNC), set OPERATIONAL with the drive, and its TPDO is part of each cycle's answer
(a missing one counts as a missing answer). It has no SYNC counter echo: its TPDO counts when it
arrives after the SYNC. ``hil home`` presets it (0x6003) to the homed position.

=====  ==============  ======================  =====================
mode   0x6060          the drive closes        the host sends
=====  ==============  ======================  =====================
csp    8               position and velocity   target position 0x607A
csv    9               velocity                target velocity 0x60FF
cst    10              nothing                 target torque 0x6071
=====  ==============  ======================  =====================

Drive-side guards set at start-up, so that the drive stops itself when the host or the link
dies: heartbeat consumer 0x1016 (the host produces a heartbeat) with abort-connection option
0x6007, following-error window 0x6065/0x6066, software position limits 0x607D, max torque
0x6072, max motor speed 0x6080.

Faults: EMCY messages are decoded and recorded (:attr:`CanopenBackend.emcy_log`), the drive's
heartbeat is watched (consumer timeout), missing TPDOs are counted; each shows as
``Feedback.fault`` (the fault rule of hil.drivers.base); a bus that refuses the SYNC or the RPDO is a
:class:`~hil.drivers.base.BackendFault` from :meth:`sync`. :meth:`quick_stop`, :meth:`fault_reset`,
clean shutdown (hil.drivers.base's ``shutdown``) in :meth:`disable` and :meth:`close` (disable, NMT
pre-operational), both of which leave a drive this backend did not start (``open``) alone: ``hil
status`` and ``hil reset`` only connect.

Configuration mistakes are :class:`~hil.errors.ConfigError` naming the key, raised when the
backend is built (a missing or unreadable object dictionary, an unknown interface, a tip sensor
on the drive's node id) or when the bus is opened (an interface not installed).
"""
from __future__ import annotations

import logging
import math
import socket
import struct
import sys
import threading
import time

import can
import canopen
from canopen.sdo.constants import REQUEST_UPLOAD, SDO_STRUCT

from hil.config import Field, register_section
from hil.control import controller_from_config
from hil.drivers.base import Backend, BackendFault, Feedback, Setpoint
from hil.drivers.canopen import canlog, cia402
from hil.drivers.canopen import eds as eds_files
from hil.errors import ConfigError
from hil.plant_config import plant_from_config

logger = logging.getLogger(__name__)


class _OneLine(logging.Filter):
    """python-can logs a failed periodic send with its traceback; the backend reports the fault in
    one line itself, so the record keeps its message and drops the traceback."""

    def filter(self, record: logging.LogRecord) -> bool:
        record.exc_info = record.exc_text = None
        return True


logging.getLogger("can.broadcastmanager").addFilter(_OneLine())

__all__ = ["CanopenBackend", "SECTION"]

TIP_PROFILE = 406            # 0x1000 bits 0..15 of the tip sensor node
TIP_KEY = "tip"              # the tip sensor's position value in the received values

SECTION = {
    "canopen.interface": Field("str", "python-can interface (socketcan, pcan, kvaser, slcan, socketcand, virtual...)",
                               default="virtual"),
    "canopen.channel": Field("str", "python-can channel (can0, /dev/ttyACM0, a virtual channel name...)",
                             default="hil"),
    "canopen.bitrate": Field("int", "CAN bit rate (bit/s)", default=1000000, nonnegative=True),
    "canopen.host": Field("str", "socketcand server address (127.0.0.1 only for the simulated drive)",
                          default="127.0.0.1"),
    "canopen.port": Field("int", "socketcand server port", default=29536, nonnegative=True),
    "canopen.node_id": Field("int", "the drive's node id (1..127)", default=1, positive=True, maximum=127),
    "canopen.host_node_id": Field("int", "the node id of the host's heartbeat (1..127)", default=127, positive=True,
                                  maximum=127),
    "canopen.eds": Field("str", "object dictionary of the drive (EDS); default hil/drivers/canopen/eds/cia402_generic.eds",
                         default=""),
    "canopen.mode": Field("str", "mode of operation: csp (the drive closes both loops), csv (velocity), cst "
                          "(torque: the host closes both)", default="csp", choices=("csp", "csv", "cst")),
    "canopen.counts_per_rev": Field("int", "motor encoder counts per motor revolution (0x608F)", default=1048576,
                                    positive=True),
    "canopen.gear_motor_revs": Field("int", "gear ratio: motor revolutions (0x6091.1)", default=1, positive=True),
    "canopen.gear_shaft_revs": Field("int", "gear ratio: screw revolutions (0x6091.2)", default=1, positive=True),
    "canopen.rated_torque": Field("torque", "motor rated torque (0x6076); torques go in per mille of it",
                                  default=10.0, positive=True),
    "canopen.tip_sensor": Field("bool", "the drive sends a tool-tip position 0x60E4.2 (a second encoder input)",
                                default=True),
    "canopen.tip_node_id": Field("int", "node id of a separate tool-tip sensor (CiA 406-like encoder, position "
                                 "0x6004 in TPDO1 on every SYNC); 0: none (the tip is the drive's 0x60E4.2 "
                                 "where canopen.tip_sensor, else not measured)", default=0, nonnegative=True,
                                 maximum=127),
    "canopen.tip_eds": Field("str", "object dictionary of the tip sensor node; default "
                             "hil/drivers/canopen/eds/tip_encoder_cia406.eds", default=""),
    "canopen.heartbeat": Field("time", "drive's heartbeat producer time (0x1017)", default=0.1, positive=True),
    "canopen.heartbeat_timeout": Field("time", "host: the drive's heartbeat is lost after this", default=0.35,
                                       positive=True),
    "canopen.host_heartbeat": Field("time", "host's heartbeat period", default=0.1, positive=True),
    "canopen.drive_heartbeat_timeout": Field("time", "drive: the host's heartbeat is lost after this (0x1016)",
                                             default=0.35, positive=True),
    "canopen.abort_option": Field("int", "0x6007, the drive's action when the host's heartbeat or SYNC is lost: "
                                  "0 none, 1 fault, 2 disable voltage, 3 quick stop", default=3, nonnegative=True,
                                  maximum=3),
    "canopen.sync_timeout": Field("time", "drive: the SYNC is lost after this long without one (SYNC consumer: "
                                  "0x1006 x the loss limit 0x2003 in cycles, rounded up); then 0x6007 acts; 0: off",
                                  default=0.1, nonnegative=True),
    "canopen.quick_stop_deceleration": Field("acceleration", "drive: quick-stop deceleration (0x6085); default: "
                                             "what the drive derives (the simulated drive: 80 % of what "
                                             "the torque limit gives the axis)", default=None, positive=True),
    "canopen.following_error_window": Field("length", "drive-side following-error window (0x6065) on the motor "
                                            "position; default 1.5 x limits.following_error_table", default=None,
                                            positive=True),
    "canopen.following_error_timeout": Field("time", "drive-side following-error time out (0x6066)",
                                             default=0.01, nonnegative=True),
    "canopen.pdo_timeout": Field("time", "lockstep: how long the SDO barrier after a SYNC may take before the "
                                 "drive counts as gone (a loaded machine: generous)", default=5.0, positive=True),
    "canopen.pdo_miss_limit": Field("int", "consecutive cycles without TPDO before 'lost communication'",
                                    default=2, positive=True),
    "canopen.lockstep": Field("bool", "drive time advances with SYNC only (a simulated drive in this process)",
                              default=False),
    "canopen.switch_interval": Field("time", "real-time runs: the interpreter's thread switch interval at most this "
                                     "(process-wide; Python's default 5 ms delays the receive threads)",
                                     default=1e-4, positive=True),
    "canopen.connect_timeout": Field("time", "socketcand: how long the server may take to accept and greet",
                                     default=2.0, positive=True),
    "canopen.sdo_timeout": Field("time", "SDO response timeout", default=0.5, positive=True),
    "canopen.stop_timeout": Field("time", "how long the host keeps the SYNC going while the drive finishes a "
                                  "quick stop", default=2.0, positive=True),
}


def _lookup(key: str):
    return SECTION.get(key)


register_section("canopen", _lookup, lambda: list(SECTION))

RPDO_TARGET = {"csp": (0x607A, 0, 32), "csv": (0x60FF, 0, 32), "cst": (0x6071, 0, 16)}
TPDO_MAPS = [
    [(0x6041, 0, 16), (0x6064, 0, 32), (0x6077, 0, 16)],
    [(0x606C, 0, 32), (0x60E4, 1, 32)],
    [(0x60E4, 2, 32), (0x603F, 0, 16), (0x2001, 0, 8)],
]
SYNC_ECHO = 0x2001          # the drive's copy of the SYNC counter, in the last TPDO of each answer
SYNC_OVERFLOW = 240         # 0x1019: the SYNC carries a counter 1..240
_SIGNED = {0x6064: "i", 0x606C: "i", 0x60E4: "i", 0x6077: "h", 0x6071: "h", 0x607A: "i", 0x60FF: "i"}
_TIP_FMT = struct.Struct("<i")


def _one_line(exc: BaseException, limit: int = 200) -> str:
    """An exception as one short line: python-can's socketcand interface puts a whole traceback
    into its error's text (``Failed to receive: ... Traceback ...``), which must not reach a
    reason on the screen, in move.json or in the latch."""
    text = str(exc).split("Traceback (most recent call last)")[0]
    text = " ".join(text.split())
    if not text:
        text = type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _probe_socketcand(host: str, port: int, timeout: float) -> None:
    """Before python-can connects (it would retry for 10 s, then wait for the server's greeting
    without a timeout): a server must accept and greet (``< hi >``) within ``timeout``; else a
    BackendFault saying which. Every read here has a timeout."""
    try:
        conn = socket.create_connection((host, port), timeout=timeout)
    except OSError as exc:
        raise BackendFault(f"no socketcand server at {host}:{port} ({_one_line(exc)}); start 'hil drive-sim' "
                           "or point canopen.host/port at one") from None
    got = b""
    try:
        t_end = time.monotonic() + timeout
        while b">" not in got and len(got) < 64:
            conn.settimeout(max(1e-3, t_end - time.monotonic()))
            chunk = conn.recv(64)
            if not chunk:
                break
            got += chunk
    except OSError:
        pass
    finally:
        conn.close()
    if b"< hi >" not in got:
        said = f"it sent {got[:40]!r}" if got else "it sent nothing"
        raise BackendFault(f"the socketcand server at {host}:{port} accepted but did not greet "
                           f"('< hi >') within {timeout:g} s ({said}; canopen.connect_timeout): not a socketcand "
                           f"server, or a hung one")


def _pdo_struct(entries) -> tuple[struct.Struct, tuple]:
    """One mapped PDO (``[(index, sub, bits)]``, the table :meth:`CanopenBackend.configure` maps)
    as one ``struct`` and the keys of its values: the whole frame decoded in one call."""
    fmt = "<" + "".join(_SIGNED.get(i, {8: "B", 16: "H"}.get(b, "I")) for i, _, b in entries)
    return struct.Struct(fmt), tuple(i if i != 0x60E4 else (i, s) for i, s, _ in entries)


class _AnswerEvent(threading.Event):
    """Set when the whole answer to the last SYNC is in. In the cyclic phase nothing but the
    caller's own thread takes frames from the bus: :meth:`wait` receives (``receive_until``) until
    the answer is in or the timeout has passed."""

    def __init__(self, backend):
        super().__init__()
        self._backend = backend

    def wait(self, timeout: float | None = None) -> bool:
        be = self._backend
        if not be.cycling:
            return super().wait(timeout)
        t_end = time.perf_counter() + (3600.0 if timeout is None else timeout)
        recv = be.network.bus.recv
        while not self.is_set():
            msg = recv(max(0.0, t_end - time.perf_counter()))
            if msg is None:
                break
            be._take(msg)
        return self.is_set()


class _BusErrors(can.Listener):
    """A listener of the notifier's thread that takes the bus's error: python-can's Notifier
    re-raises an error no listener handles, and the thread dies printing its traceback (the
    drive's process killed: ``ConnectionResetError`` under the socketcand client). Here it becomes
    the backend's one-line ``lost communication`` (``Feedback.fault``) and a log line."""

    # python-can's notifier goes on receiving after a handled error, and a dead socket fails at
    # once: the thread waits this long per further error instead of spinning on it (until the
    # backend stops the notifier at close)
    IDLE_AFTER_ERROR = 0.1

    def __init__(self, backend: "CanopenBackend"):
        self.backend = backend
        self.failed = False

    def on_message_received(self, msg) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        if self.failed:
            time.sleep(self.IDLE_AFTER_ERROR)
            return
        self.failed = True
        be = self.backend
        if not be._rx_error:
            be._rx_error = f"lost communication: the CAN bus failed ({_one_line(exc)})"
            be.events.append(f"cycle {be.syncs}: {be._rx_error}")
        logger.warning("%s", be._rx_error)


class CanopenBackend(Backend):
    name = "canopen"
    misses_answers = True         # a SYNC without its TPDO in time (Feedback.stale)

    def __init__(self, cfg, bus=None, interface: str | None = None, channel: str | None = None,
                 mode: str | None = None, lockstep: bool | None = None, node_id: int | None = None):
        self.cfg = cfg
        self.mode = mode or cfg.get("canopen.mode", "csp")
        if self.mode not in cia402.MODES:
            raise ConfigError(f"{cfg.source}: canopen.mode: expected one of {', '.join(cia402.MODES)}, "
                              f"got {self.mode!r}")
        self.closes = cia402.MODE_CLOSES[self.mode]
        tv, tp = cfg["control.velocity_period"], cfg["control.position_period"]
        if self.mode == "cst" and tv > 1e-3 + 1e-12:
            raise ConfigError(f"{cfg.source}: canopen.mode cst: the host's velocity loop must run at 1 ms or "
                              f"faster with its own gains (control.velocity_period is {tv * 1e3:g} ms): the "
                              f"velocity PI sampled at the position period is unstable")
        self.cycle_time = tv if self.mode == "cst" else tp
        self.lockstep = bool(cfg.get("canopen.lockstep", False) if lockstep is None else lockstep)
        self.simulated = self.lockstep
        self._bus = bus
        self.interface = interface or cfg.get("canopen.interface", "virtual")
        self.channel = channel or cfg.get("canopen.channel", "hil")
        if bus is None and self.interface not in can.VALID_INTERFACES:
            raise ConfigError(f"{cfg.source}: canopen.interface: unknown python-can interface {self.interface!r} "
                              f"(known: {', '.join(sorted(can.VALID_INTERFACES))})")
        self.node_id = node_id or int(cfg.get("canopen.node_id", 1))
        self.host_id = int(cfg.get("canopen.host_node_id", 127))
        pitch = cfg.get("plant.pitch") or 1.0
        self.counts_per_m = (cfg.get("canopen.counts_per_rev", 1048576) * cfg.get("canopen.gear_motor_revs", 1)
                             / cfg.get("canopen.gear_shaft_revs", 1) / pitch)
        self.rated = float(cfg.get("canopen.rated_torque", 10.0))
        self.speed_scale = controller_from_config(cfg, plant_from_config(cfg)).speed_scale
        self.tip_id = int(cfg.get("canopen.tip_node_id", 0) or 0)
        sync_timeout = float(cfg.get("canopen.sync_timeout", 0.1))
        self.sync_loss_cycles = int(math.ceil(sync_timeout / self.cycle_time - 1e-9)) if sync_timeout > 0 else 0
        if self.sync_loss_cycles > SYNC_OVERFLOW // 2:
            raise ConfigError(f"{cfg.source}: canopen.sync_timeout: {sync_timeout * 1e3:g} ms is "
                              f"{self.sync_loss_cycles} cycles; expected at most {SYNC_OVERFLOW // 2} (half the "
                              f"SYNC counter's range, so that the drive can tell a stale SYNC from a fresh one)")
        if self.tip_id and self.tip_id == self.node_id:
            raise ConfigError(f"{cfg.source}: canopen.tip_node_id: {self.tip_id} is the drive's node id")
        # the object dictionaries now: a missing or broken file is a mistake named before anything connects
        self._od = eds_files.load(cfg, "canopen.eds", self.node_id)
        self._tip_od = eds_files.load(cfg, "canopen.tip_eds", self.tip_id) if self.tip_id else None
        self.tip = bool(cfg.get("canopen.tip_sensor", True)) and not self.tip_id     # the drive's 0x60E4.2
        self.tip_node = None
        self._tip_cob = None
        self._tip_step = 1e-9
        self.network = None
        self.node = None
        self.started = False         # open() has begun: the drive is this backend's to stop and release
        self.emcy_log: list[dict] = []
        self.events: list[str] = []
        self._recorder = None          # the bus trace of hil --can-log (hil.drivers.canopen.canlog)
        self._rx = {}
        self._fresh = set()
        self._want = set()
        self._event = _AnswerEvent(self)
        self._lock = threading.Lock()
        self._cw = cia402.COMMANDS["ENABLE OPERATION"]
        self._target = 0
        self._misses = 0
        self.missed_total = 0
        self._time = 0.0
        self._hb_last = None
        self._host_hb_next = 0.0
        self._host_hb_task = None
        self.syncs = 0
        self.quick_stop_sync: int | None = None
        self.sync_to_rpdo: list[float] = []
        self._last = Feedback(0.0, 0.0, 0.0)
        self.enabled = False
        self.echo = True
        self._echo_cob = None
        self._pending: dict = {}
        self._sync_counter = 0
        self._sync_sent = 0.0
        self.late_total = 0
        self.missed_total = 0
        self.host_heartbeat_dead = False
        self.stopped_state = ""
        self._rx_error = ""          # the bus failed on receive in the cyclic phase (a Feedback.fault)
        self.miss_run_max = 0        # the longest run of consecutive cycles without their answer
        self.cycling = False         # the cyclic phase: the loop's thread takes the frames, no notifier thread
        self.pdo_frames_on_loop = 0  # TPDO frames the loop's thread took from the bus (cyclic phase)
        self._decode: dict = {}      # COB-ID -> (struct, keys): the mapped TPDOs, decoded in one call
        self.answer_latency: list[float] = []      # SYNC sent -> the whole TPDO answer taken (s)
        self.setpoint_latency: list[float] = []    # SYNC k sent -> RPDO k+1 (from feedback k) sent (s)

    # -- start-up --------------------------------------------------------------------------------
    def open(self) -> None:
        """Full start-up: connect, NMT pre-operational, SDO configuration and PDO mapping, NMT
        operational, the host's heartbeat."""
        cfg = self.cfg
        self.started = True
        if not self.lockstep:
            # a thread beside the loop (a drive simulated in this process, the heartbeat's) must
            # give the interpreter back soon, not after Python's default 5 ms switch interval
            sys.setswitchinterval(min(sys.getswitchinterval(), float(cfg.get("canopen.switch_interval", 1e-4))))
        self.connect()
        self.node.nmt.state = "PRE-OPERATIONAL"
        self._sdo_retry(lambda: self.node.sdo[0x1000].raw)        # the drive answers
        if self.tip_node is not None:
            self.tip_node.nmt.state = "PRE-OPERATIONAL"
            self.configure_tip()
        self.configure()
        if self.tip_node is not None:
            self.tip_node.nmt.state = "OPERATIONAL"
        self.node.nmt.state = "OPERATIONAL"
        if not self.lockstep:
            self._host_hb_task = self.network.send_periodic(0x700 + self.host_id, [0x05],
                                                            cfg.get("canopen.host_heartbeat", 0.1))
            # python-can's send thread re-raises a failed send unless told otherwise, and dies with
            # its traceback on the screen (the drive's process killed: a broken pipe)
            task = getattr(self._host_hb_task, "_task", None)
            if task is not None and hasattr(task, "on_error"):
                task.on_error = self._on_heartbeat_send_error
        else:
            self._send_host_heartbeat()
        self._hb_last = self._now()

    def connect(self) -> None:
        """Only the bus and the drive's node (status, fault reset): no NMT command, no configuration."""
        cfg = self.cfg
        self.network = canopen.Network(self._bus)
        self.network.NOTIFIER_CYCLE = 0.05          # the receive thread stops within 50 ms
        if self._bus is None and self.interface == "socketcand":
            host, port = cfg.get("canopen.host", "127.0.0.1"), int(cfg.get("canopen.port", 29536))
            # python-can warns of every TCP segment that splits a frame: harmless
            # and logs a lost connection with its traceback: the backend reports the cause itself, in one line
            logging.getLogger("can.interfaces.socketcand.socketcand").setLevel(logging.CRITICAL)
            _probe_socketcand(host, port, float(cfg.get("canopen.connect_timeout", 2.0)))
        if self._bus is None:
            kw = dict(interface=self.interface, channel=self.channel)
            if self.interface == "socketcand":
                kw.update(host=cfg.get("canopen.host", "127.0.0.1"), port=cfg.get("canopen.port", 29536),
                          tcp_tune=True)          # TCP_NODELAY: no Nagle delay between RPDO and SYNC
            elif self.interface != "virtual":
                kw["bitrate"] = cfg.get("canopen.bitrate", 1000000)
            # python-can's socketcand client reads its handshake without a timeout: a server that
            # stops talking after the probe would hold this process forever
            old_timeout = socket.getdefaulttimeout()
            if self.interface == "socketcand":
                socket.setdefaulttimeout(float(cfg.get("canopen.connect_timeout", 2.0)))
            try:
                self.network.connect(**kw)
            except can.CanInterfaceNotImplementedError as exc:     # the interface's library is not installed
                self.network = None
                raise ConfigError(f"{cfg.source}: canopen.interface: {self.interface} is not available "
                                  f"({_one_line(exc)})") from None
            except (can.CanError, OSError) as exc:
                self.network = None
                raise BackendFault(f"cannot open the CAN bus {self.interface}:{self.channel} ({_one_line(exc)})") from None
            finally:
                socket.setdefaulttimeout(old_timeout)
        else:
            self.network.connect()
        # a bus that fails under the notifier's thread (the drive's end of the link gone: a reset
        # connection) is this backend's fault to report in one line, not a thread's traceback
        errors = _BusErrors(self)
        self.network.listeners.append(errors)
        if self.network.notifier is not None:
            self.network.notifier.add_listener(errors)
        # hil --can-log FILE: python-can's logger on the bus, received and sent frames (hil.drivers.canopen.canlog)
        self._recorder = canlog.attach(self.network)
        self.node = self.network.add_node(self.node_id, self._od)
        self.node.sdo.RESPONSE_TIMEOUT = cfg.get("canopen.sdo_timeout", 0.5)
        self.node.emcy.add_callback(self._on_emcy)
        self.network.subscribe(0x700 + self.node_id, self._on_heartbeat)
        for n in range(len(TPDO_MAPS)):
            self.network.subscribe(0x180 + 0x100 * n + self.node_id, self._on_tpdo)
        if self.tip_id:
            self.tip_node = self.network.add_node(self.tip_id, self._tip_od)
            self.tip_node.sdo.RESPONSE_TIMEOUT = self.node.sdo.RESPONSE_TIMEOUT
            self._tip_cob = 0x180 + self.tip_id
            self.network.subscribe(self._tip_cob, self._on_tip)

    def configure_tip(self) -> None:
        """The tool-tip sensor node: its profile (CiA 406), its measuring step, TPDO1 = position
        value 0x6004 on every SYNC."""
        sdo = self.tip_node.sdo
        try:
            devtype = self._sdo_retry(lambda: sdo[0x1000].raw)
        except BackendFault:
            raise BackendFault(f"tip sensor node {self.tip_id} does not answer SDO on "
                               f"{self.interface}:{self.channel} (canopen.tip_node_id)") from None
        if devtype & 0xFFFF != TIP_PROFILE:
            raise ConfigError(f"{self.cfg.source}: canopen.tip_node_id: node {self.tip_id} is not an encoder "
                              f"(device type 0x{devtype:08X}, profile {devtype & 0xFFFF}, expected {TIP_PROFILE})")
        self._tip_step = sdo[0x6005][1].raw * 1e-9
        if not self._tip_step > 0:
            raise BackendFault(f"tip sensor node {self.tip_id}: measuring step 0x6005.1 is 0")
        sdo[0x1800][1].raw = self._tip_cob | 0x80000000
        sdo[0x1A00][0].raw = 0
        sdo[0x1A00][1].raw = (0x6004 << 16) | 32
        sdo[0x1A00][0].raw = 1
        sdo[0x1800][2].raw = 1
        sdo[0x1800][1].raw = self._tip_cob

    def _sdo_retry(self, fn, tries: int = 5):
        for i in range(tries):
            try:
                return fn()
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError):
                if i == tries - 1:
                    raise BackendFault(f"drive {self.node_id} does not answer SDO on {self.interface}:{self.channel}")
                time.sleep(0.05)

    def configure(self) -> None:
        """SDO configuration: mode, scaling, limits, drive-side guards, PDO mapping."""
        cfg, sdo = self.cfg, self.node.sdo
        sdo[0x6060].raw = cia402.MODES[self.mode]
        sdo[0x608F][1].raw = int(cfg.get("canopen.counts_per_rev", 1048576))
        sdo[0x608F][2].raw = 1
        sdo[0x6091][1].raw = int(cfg.get("canopen.gear_motor_revs", 1))
        sdo[0x6091][2].raw = int(cfg.get("canopen.gear_shaft_revs", 1))
        sdo[0x6092][1].raw = int(round((cfg.get("plant.pitch") or 1.0) * 1e6))      # um per screw revolution
        sdo[0x6092][2].raw = 1
        sdo[0x6076].raw = int(round(self.rated * 1e3))                               # mN m
        torque = cfg.get("limits.torque") or cfg["control.output_limit"]
        sdo[0x6072].raw = min(0xFFFF, int(round(torque / self.rated * 1e3)))
        speed_rpm = cfg["limits.speed"] * self.counts_per_m / cfg.get("canopen.counts_per_rev", 1048576) * 60
        sdo[0x6080].raw = int(math.ceil(speed_rpm * 1.2))
        sdo[0x607D][1].raw = int(math.floor(cfg["limits.travel_min"] * self.counts_per_m))
        sdo[0x607D][2].raw = int(math.ceil(cfg["limits.travel_max"] * self.counts_per_m))
        fe = cfg.get("canopen.following_error_window") or (
            1.5 * cfg["limits.following_error_table"] if "limits.following_error_table" in cfg else None)
        sdo[0x6065].raw = 0xFFFFFFFF if fe is None else int(round(fe * self.counts_per_m))
        sdo[0x6066].raw = int(round(cfg.get("canopen.following_error_timeout", 0.01) * 1e3))
        sdo[0x605A].raw = 2
        sdo[0x6007].raw = int(cfg.get("canopen.abort_option", 3))
        qs_dec = cfg.get("canopen.quick_stop_deceleration")
        if qs_dec is not None:
            sdo[0x6085].raw = max(1, min(0xFFFFFFFE, int(round(qs_dec * self.counts_per_m))))
        sdo[0x1016][1].raw = (self.host_id << 16) | int(round(cfg.get("canopen.drive_heartbeat_timeout", 0.35) * 1e3))
        sdo[0x1017].raw = int(round(cfg.get("canopen.heartbeat", 0.1) * 1e3))
        sdo[0x1006].raw = int(round(self.cycle_time * 1e6))
        us = self.cycle_time * 1e6
        if abs(us / 1000 - round(us / 1000)) < 1e-9 and us / 1000 <= 255:
            sdo[0x60C2][1].raw, sdo[0x60C2][2].raw = int(round(us / 1000)), -3
        else:
            sdo[0x60C2][1].raw, sdo[0x60C2][2].raw = min(255, int(round(us / 100))), -4
        # PDO mapping (disable, map, enable)
        rmap = [(0x6040, 0, 16), RPDO_TARGET[self.mode]]
        self._rpdo_fmt = "<H" + _SIGNED[rmap[1][0]]
        self._map(0x1400, 0x1600, 0x200, 0, rmap)
        self.echo = SYNC_ECHO in self.node.object_dictionary
        tmaps = [list(m) for m in TPDO_MAPS]
        if not self.tip:
            tmaps[2] = [e for e in tmaps[2] if e[0] != 0x60E4]
        if not self.echo:
            tmaps[2] = [e for e in tmaps[2] if e[0] != SYNC_ECHO]
        else:
            sdo[0x1019].raw = SYNC_OVERFLOW
        if 0x2003 in self.node.object_dictionary:
            # the SYNC consumer: a drive-specific object (this EDS's 0x2003); on another drive the
            # manufacturer's own (docs/guide/canopen.md)
            sdo[0x2003].raw = self.sync_loss_cycles
        tmaps = [m for m in tmaps if m]
        self._tpdo = {}
        for n in range(4):
            entries = tmaps[n] if n < len(tmaps) else []
            self._map(0x1800, 0x1A00, 0x180, n, entries)
            if entries:
                self._tpdo[0x180 + 0x100 * n + self.node_id] = entries
        self._decode = {cob: _pdo_struct(entries) for cob, entries in self._tpdo.items()}
        if self._tip_cob:
            self._decode[self._tip_cob] = (_TIP_FMT, (TIP_KEY,))
        self._want = set(self._tpdo) | ({self._tip_cob} if self._tip_cob else set())
        self._echo_cob = max(self._tpdo) if self.echo else None      # the last TPDO carries the echo

    def _map(self, comm_base, map_base, cob_base, n, entries):
        sdo = self.node.sdo
        cob = cob_base + 0x100 * n + self.node_id
        sdo[comm_base + n][1].raw = cob | 0x80000000
        sdo[map_base + n][0].raw = 0
        for k, (index, sub, bits) in enumerate(entries, 1):
            sdo[map_base + n][k].raw = (index << 16) | (sub << 8) | bits
        sdo[map_base + n][0].raw = len(entries)
        sdo[comm_base + n][2].raw = 1                          # synchronous, every SYNC
        if entries:
            sdo[comm_base + n][1].raw = cob

    def state(self) -> str:
        self._stop_cycling()
        return cia402.state_from_statusword(self.node.sdo[0x6041].raw)

    def enable(self) -> None:
        """CiA 402 state machine up to OPERATION ENABLED (over SDO), holding the present position."""
        sdo = self.node.sdo
        pos = sdo[0x6064].raw
        if self.mode == "csp":
            self._target = pos
        else:
            self._target = 0
        sdo[RPDO_TARGET[self.mode][0]].raw = self._target
        for _ in range(12):
            st = self.state()
            if st == "OPERATION ENABLED":
                break
            cmd = cia402.NEXT_TO_ENABLE[st]
            if cmd == "FAULT RESET":
                raise BackendFault(f"drive in FAULT ({self._fault_text()}); run 'hil reset' first")
            if cmd is not None:
                sdo[0x6040].raw = cia402.COMMANDS[cmd]
            else:
                time.sleep(0.01)
        else:
            raise BackendFault(f"drive did not reach OPERATION ENABLED (stuck in {self.state()})")
        self._cw = cia402.COMMANDS["ENABLE OPERATION"]
        self.enabled = True
        self._misses = 0
        self._fresh = set(self._want)       # the first cycle reads the state as configured
        self._rx.update({0x6041: sdo[0x6041].raw, 0x6064: pos, 0x6077: 0, 0x606C: sdo[0x606C].raw,
                         (0x60E4, 1): sdo[0x60E4][1].raw, (0x60E4, 2): sdo[0x60E4][2].raw, 0x603F: 0})
        if self.tip_node is not None:
            self._rx[TIP_KEY] = self.tip_node.sdo[0x6004].raw
        self._start_cycling()

    def read_position(self) -> Feedback:
        """Where the axis stands, over SDO (not real-time; after :meth:`open`, before :meth:`enable`):
        position actual 0x6064, the linear encoder 0x60E4.1, the tip (its node's 0x6004, or
        0x60E4.2)."""
        sdo = self.node.sdo
        try:
            x_motor = sdo[0x6064].raw / self.counts_per_m
            x_table = sdo[0x60E4][1].raw * 1e-9
            if self.tip_node is not None:
                x_tip = self.tip_node.sdo[0x6004].raw * self._tip_step
            else:
                x_tip = sdo[0x60E4][2].raw * 1e-9 if self.tip else math.nan
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
            raise BackendFault(f"lost communication: drive {self.node_id} does not answer SDO (position: {_one_line(exc)})") \
                from None
        return Feedback(x_motor=x_motor, x_table=x_table, v_motor=0.0, x_tip=x_tip)

    def home(self, offset: float = 0.0, method: int = 37, timeout: float = 5.0) -> dict:
        """Homing mode (6), method 37 (or 35): the present position becomes ``offset`` (m, 0x607C).
        Enables the drive, starts homing (controlword bit 4), waits for homing attained (statusword
        bit 12), shuts down and returns to the configured mode."""
        sdo = self.node.sdo
        sdo[0x6098].raw = int(method)
        sdo[0x607C].raw = int(round(offset * self.counts_per_m))
        sdo[0x6060].raw = cia402.HOMING_MODE
        ok, err = False, False
        try:
            self.enable()
            self._stop_cycling()              # homing runs over SDO
            sdo[0x6040].raw = cia402.COMMANDS["ENABLE OPERATION"] | 0x10
            t_end = time.perf_counter() + timeout
            while time.perf_counter() < t_end:
                sw = sdo[0x6041].raw
                err = bool(sw & (1 << cia402.SW_BITS["following_error"]))
                ok = bool(sw & (1 << cia402.SW_BITS["setpoint_acknowledge"]) and sw & (1 << cia402.SW_BITS["target_reached"]))
                if ok or err:
                    break
                self._send_sync()
                if not self.lockstep:
                    time.sleep(self.cycle_time)
            sdo[0x6040].raw = cia402.COMMANDS["ENABLE OPERATION"]
        finally:
            self.disable()
            sdo[0x6060].raw = cia402.MODES[self.mode]
        pos = sdo[0x6064].raw / self.counts_per_m
        if err or not ok:
            raise BackendFault(f"homing method {method} {'failed (statusword bit 13)' if err else 'timed out'}")
        out = {"homed": True, "method": method, "position_m": pos}
        if self.tip_node is not None:         # the axis at rest: the tip sensor shows the homed position too
            self.tip_node.sdo[0x6003].raw = int(round(pos / self._tip_step))
            out["tip_m"] = self.tip_node.sdo[0x6004].raw * self._tip_step
        return out

    def fault_reset(self) -> str:
        self._stop_cycling()
        sdo = self.node.sdo
        sdo[0x6040].raw = 0x00
        sdo[0x6040].raw = cia402.COMMANDS["FAULT RESET"]
        sdo[0x6040].raw = 0x00
        return self.state()

    # -- callbacks ---------------------------------------------------------------------------------
    def _now(self) -> float:
        return self._time if self.lockstep else time.perf_counter()

    def _on_tpdo(self, can_id, data, timestamp):
        """TPDOs are taken as the answer to the last SYNC only when they are: with the SYNC counter
        echo, the TPDO that carries it must show the counter of the last SYNC (the others of the
        same answer come before it and are held until then); without it, a TPDO counts only if it
        arrived after the SYNC. A late answer is logged and dropped."""
        plan = self._decode.get(can_id)
        if plan is None:
            return
        fmt, keys = plan
        values = dict(zip(keys, fmt.unpack_from(data)))
        with self._lock:
            if self.echo:
                self._pending[can_id] = values
                if can_id != self._echo_cob:
                    return
                echo = values.get(SYNC_ECHO)
                if echo != self._sync_counter:
                    self.late_total += 1
                    self.events.append(f"cycle {self.syncs}: late TPDO (answers SYNC {echo}, "
                                       f"expected {self._sync_counter})")
                    self._pending = {}
                    return
                for cob, vals in self._pending.items():
                    self._rx.update(vals)
                    self._fresh.add(cob)
                self._pending = {}
            else:
                if time.perf_counter() < self._sync_sent:
                    self.late_total += 1
                    return
                self._rx.update(values)
                self._fresh.add(can_id)
            if self._fresh >= self._want:
                if not self._event.is_set():
                    self.answer_latency.append(time.perf_counter() - self._sync_sent)
                self._event.set()

    def _on_tip(self, can_id, data, timestamp):
        """The tip sensor's TPDO1 (position value 0x6004): no SYNC counter, taken when it arrives
        after the SYNC (in lockstep the barrier orders it)."""
        if len(data) < 4:
            return
        v = _TIP_FMT.unpack_from(data, 0)[0]
        with self._lock:
            self._rx[TIP_KEY] = v
            self._fresh.add(can_id)
            if self._fresh >= self._want:
                if not self._event.is_set():
                    self.answer_latency.append(time.perf_counter() - self._sync_sent)
                self._event.set()

    def _on_heartbeat(self, can_id, data, timestamp):
        self._hb_last = self._now()

    def _on_emcy(self, err):
        entry = {"t": self._now(), "code": f"0x{err.code:04X}", "register": err.register,
                 "text": cia402.emcy_text(err.code), "data": bytes(err.data).hex()}
        self.emcy_log.append(entry)
        self.events.append(f"EMCY {entry['code']} {entry['text']}")

    def _fault_text(self) -> str:
        if self.emcy_log:
            e = self.emcy_log[-1]
            return f"EMCY {e['code']} {e['text']}"
        code = self._rx.get(0x603F, 0)
        return f"error code 0x{code:04X} {cia402.emcy_text(code)}" if code else "no EMCY"

    # -- the cyclic phase: the loop's own thread takes the frames --------------------------------------
    def _start_cycling(self) -> None:
        """From now on the loop's thread takes every frame from the bus (:meth:`receive_until`, the
        barrier, :meth:`read_feedback`): canopen's notifier thread is stopped (it returns within
        its ``NOTIFIER_CYCLE``), so that no second thread takes the answer, runs callbacks on it
        and competes with the loop for the interpreter lock while the loop runs. (The host's
        heartbeat stays on python-can's periodic thread: it wakes every 100 ms for one send, and
        it keeps the drive's heartbeat consumer content between enable and the loop's start.)"""
        net = self.network
        if self.cycling or net is None or net.notifier is None:
            return
        net.notifier.stop(4 * net.NOTIFIER_CYCLE + 1.0)
        self.cycling = True

    def _stop_cycling(self) -> None:
        """Back to canopen's notifier thread (SDO, shutdown): the frames already in are taken here
        first, in order, then a new notifier serves the network (and the periodic heartbeat)."""
        if not self.cycling:
            return
        net = self.network
        self.receive_until(0.0)
        self.cycling = False
        net.notifier = can.Notifier(net.bus, net.listeners, net.NOTIFIER_CYCLE)
        if self._recorder is not None:           # hil --can-log: the trace goes on with the new notifier
            self._recorder.follow(net.notifier)

    def receive_until(self, t_end: float) -> None:
        """Take the frames from the bus on the calling thread (the loop's) until ``t_end``
        (``time.perf_counter``; one in the past: only those already in), (real-time).

        ``Bus.recv`` with a timeout waits outside the interpreter lock, so the loop's wait for its
        next deadline is this wait. The TPDOs this backend mapped are decoded here
        (:meth:`_on_tpdo`, :meth:`_on_tip`); every other frame (EMCY, heartbeat, SDO, NMT) goes to
        canopen (``Network.notify``), which runs its callbacks as its notifier would. Never
        raises: a bus that fails here is the next :meth:`read_feedback`'s ``fault``."""
        if not self.cycling:
            return
        recv, take, now = self.network.bus.recv, self._take, time.perf_counter
        try:
            while True:
                msg = recv(max(0.0, t_end - now()))
                if msg is None:
                    return
                take(msg)
        except (can.CanError, OSError) as exc:     # the fault rule: the next feedback says so
            if not self._rx_error:
                self._rx_error = f"lost communication: the CAN bus failed on receive ({_one_line(exc)})"
                self.events.append(f"cycle {self.syncs}: {self._rx_error}")

    def _take(self, msg) -> None:
        if self._recorder is not None:           # hil --can-log: the frames the loop's thread takes
            self._recorder.on_message_received(msg)
        if msg.is_error_frame or msg.is_remote_frame:
            return
        cob = msg.arbitration_id
        if cob in self._decode:
            self.pdo_frames_on_loop += 1
            if cob == self._tip_cob:
                self._on_tip(cob, msg.data, msg.timestamp)
            else:
                self._on_tpdo(cob, msg.data, msg.timestamp)
        else:
            self.network.notify(cob, msg.data, msg.timestamp)

    # -- cycle ---------------------------------------------------------------------------------------
    def read_feedback(self) -> Feedback:
        if self.lockstep and not self._fresh >= self._want:
            self._barrier()
        elif self.cycling:
            self.receive_until(0.0)              # what came in after the clock's wait
        with self._lock:
            fresh = self._fresh >= self._want
            rx = dict(self._rx)
        fault = ""
        if fresh:
            self._misses = 0
        else:                        # recorded as missed: counted, logged, the feedback is the last answer
            self._misses += 1
            self.missed_total += 1
            self.miss_run_max = max(self.miss_run_max, self._misses)
            with self._lock:
                lacking = self._want - self._fresh
            who = "tip sensor node %d" % self.tip_id if lacking == {self._tip_cob} else "drive"
            self.events.append(f"cycle {self.syncs}: no TPDO after SYNC from the {who}")
            if self._misses >= int(self.cfg.get("canopen.pdo_miss_limit", 2)):
                fault = f"lost communication: no TPDO from the {who} for {self._misses} cycles"
        cpm = self.counts_per_m
        x_motor = rx.get(0x6064, 0) / cpm
        x_table = rx.get((0x60E4, 1), 0) * 1e-9
        if self.tip_id:
            x_tip = rx.get(TIP_KEY, 0) * self._tip_step
        else:
            x_tip = rx.get((0x60E4, 2), 0) * 1e-9 if self.tip else math.nan
        v = rx.get(0x606C, 0) / cpm
        out = rx.get(0x6077, 0) * 1e-3 * self.rated
        sw = rx.get(0x6041, 0)
        st = cia402.state_from_statusword(sw)
        if not fault and self._rx_error:
            fault = self._rx_error
        if not fault:
            if st in ("FAULT", "FAULT REACTION ACTIVE"):
                fault = f"drive fault: {self._fault_text()}"
            elif self.enabled and st != "OPERATION ENABLED":
                fault = f"drive fault: the drive left OPERATION ENABLED ({st})"
            elif self._hb_last is not None and self._now() - self._hb_last > self.cfg.get(
                    "canopen.heartbeat_timeout", 0.35):
                fault = f"lost communication: drive heartbeat lost ({(self._now() - self._hb_last) * 1e3:.0f} ms)"
        fb = Feedback(x_motor=x_motor, x_table=x_table, v_motor=v, output=out, x_tip=x_tip, fault=fault,
                      stale=not fresh)
        self._last = fb
        return fb

    def write_setpoint(self, sp: Setpoint) -> None:
        cpm = self.counts_per_m
        if self.mode == "csp":
            self._target = int(round(sp.position * cpm))
        elif self.mode == "csv":
            self._target = int(round(sp.speed / self.speed_scale * cpm))
        else:
            self._target = max(-32768, min(32767, int(round(sp.output / self.rated * 1e3))))

    def _barrier(self) -> None:
        """Lockstep: an SDO upload of 0x1001 after the SYNC. The drive handles the frames in order
        and sends its TPDOs while it handles the SYNC, before it answers the SDO; the host handles
        the answers in order too: when the SDO answer is in, every TPDO the drive sent for this
        SYNC has been taken. A missing or late TPDO is then the drive's doing, never the
        scheduler's, however loaded the machine. In the cyclic phase the loop's thread sends the
        request (canopen's own SDO request format) and takes the frames until the answer."""
        sdo = self.node.sdo
        if self.cycling:
            recv, t_end = self.network.bus.recv, time.perf_counter() + float(self.cfg.get("canopen.pdo_timeout", 5.0))
            try:
                sdo.send_request(SDO_STRUCT.pack(REQUEST_UPLOAD, 0x1001, 0) + bytes(4))
                while True:
                    msg = recv(max(0.0, t_end - time.perf_counter()))
                    if msg is None:
                        self.events.append(f"cycle {self.syncs}: no SDO answer to the barrier")
                        return
                    if msg.arbitration_id == sdo.tx_cobid:
                        return
                    self._take(msg)
            except (can.CanError, OSError) as exc:        # the fault rule: this feedback says so
                if not self._rx_error:
                    self._rx_error = f"lost communication: the CAN bus failed ({_one_line(exc)})"
                    self.events.append(f"cycle {self.syncs}: {self._rx_error}")
        old = sdo.RESPONSE_TIMEOUT
        sdo.RESPONSE_TIMEOUT = max(old, float(self.cfg.get("canopen.pdo_timeout", 5.0)))
        try:
            sdo.upload(0x1001, 0)
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
            self.events.append(f"cycle {self.syncs}: no SDO answer to the barrier ({_one_line(exc)})")
        finally:
            sdo.RESPONSE_TIMEOUT = old

    def _send_rpdo(self) -> None:
        if self._sync_sent:
            self.setpoint_latency.append(time.perf_counter() - self._sync_sent)
        self._send(0x200 + self.node_id, struct.pack(self._rpdo_fmt, self._cw, self._target))

    def _on_heartbeat_send_error(self, exc: Exception) -> bool:
        """The host's heartbeat could not be sent (python-can's send thread): the link's fault in
        one line; False stops the task (the drive's heartbeat consumer then acts)."""
        _BusErrors(self).on_error(exc)
        return False

    def _send_host_heartbeat(self) -> None:
        self._send(0x700 + self.host_id, [0x05])
        self._host_hb_next = self._time + self.cfg.get("canopen.host_heartbeat", 0.1)

    def sync(self) -> None:
        """RPDO (controlword + target), then SYNC: the drive applies the target and answers."""
        t0 = time.perf_counter()
        self._send_rpdo()
        self.sync_to_rpdo.append(time.perf_counter() - t0)
        self._send_sync()

    def _send(self, cob_id: int, data) -> None:
        """One frame; a bus that refuses it (the interface or the server is gone) is a BackendFault:
        the setpoint could not be delivered (the fault rule of hil.drivers.base)."""
        try:
            self.network.send_message(cob_id, data)
        except (can.CanError, OSError) as exc:
            raise BackendFault(f"lost communication: the CAN bus refused a frame ({_one_line(exc)})") from None

    def _send_sync(self) -> None:
        """The SYNC (with its counter); from here on only the answer to this SYNC is fresh."""
        with self._lock:
            self._sync_counter = self._sync_counter % SYNC_OVERFLOW + 1
            self._fresh = set()
            self._pending = {}
            self._event.clear()
            self._sync_sent = time.perf_counter()
        self._send(0x80, bytes([self._sync_counter]) if self.echo else b"")
        self.syncs += 1
        if self.lockstep:
            self._time += self.cycle_time
            if self._time + 1e-12 >= self._host_hb_next and not self.host_heartbeat_dead:
                self._send_host_heartbeat()

    def quick_stop(self) -> None:
        """The controlled stop ``supervisor.stop`` asks for, now, by RPDO (the drive acts on receipt):
        CiA 402 quick stop (controlword 0x0002; the drive brakes on its quick-stop ramp, 0x605A) or
        disable (DISABLE VOLTAGE: the power stage off, the axis coasts). :meth:`disable` then keeps
        the SYNC going until the drive is at rest, and repeats the command over SDO where the
        drive did not take it."""
        how = self.cfg.get("supervisor.stop", "quick_stop")
        self._cw = cia402.COMMANDS["QUICK STOP" if how == "quick_stop" else "DISABLE VOLTAGE"]
        self.quick_stop_sync = self.syncs
        self.events.append(f"cycle {self.syncs}: {how.replace('_', ' ')} commanded")
        try:
            self._send_rpdo()
        except Exception:
            pass
        self.enabled = False

    def wait_stopped(self, max_cycles: int | None = None) -> str:
        """Keep the SYNC going (the drive's clock in lockstep) until the drive has finished its quick
        stop or fault reaction; its state is read over SDO (TPDOs may be what failed). A drive still
        in OPERATION ENABLED did not get the RPDO: the stop is commanded again over SDO."""
        limit = max_cycles or int(math.ceil(self.cfg.get("canopen.stop_timeout", 2.0) / self.cycle_time))
        self._stop_cycling()
        sdo, st, errors = self.node.sdo, "unknown", 0
        for _ in range(limit):
            self._send_sync()
            if not self.lockstep:
                time.sleep(self.cycle_time)
            try:
                st = cia402.state_from_statusword(sdo[0x6041].raw)
                if st == "OPERATION ENABLED":
                    self.events.append(f"cycle {self.syncs}: stop repeated over SDO")
                    sdo[0x6040].raw = self._cw
                    continue
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
                errors += 1
                self.events.append(f"cycle {self.syncs}: no SDO answer while stopping ({_one_line(exc)})")
                if errors >= 3:
                    self.events.append("drive unreachable: the drive-side guards (0x1016/0x6007) stop it")
                    return "unreachable"
                continue
            if st not in ("QUICK STOP ACTIVE", "FAULT REACTION ACTIVE"):
                return st
        return st

    def disable(self) -> None:
        """Let a quick stop (or fault reaction) finish, then SHUTDOWN (READY TO SWITCH ON: no torque).
        Nothing on a drive this backend did not start, or after :meth:`close`."""
        if not self.started or self.node is None or self.network is None:
            return
        self._stop_cycling()
        try:
            if self.quick_stop_sync is not None and self._cw != cia402.COMMANDS["ENABLE OPERATION"] or \
                    cia402.state_from_statusword(self._rx.get(0x6041, 0)) in ("QUICK STOP ACTIVE",
                                                                             "FAULT REACTION ACTIVE"):
                self.stopped_state = self.wait_stopped()
            if self.stopped_state != "unreachable":
                st = self.state()
                if st in ("OPERATION ENABLED", "SWITCHED ON", "QUICK STOP ACTIVE"):
                    self.node.sdo[0x6040].raw = cia402.COMMANDS["SHUTDOWN"]
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
            self.events.append(f"disable: {_one_line(exc)}")
        self.enabled = False

    def close(self) -> None:
        """The host's heartbeat stopped, the nodes this backend started put back to NMT
        pre-operational (their PDOs stop), the bus released. Nothing after the first call."""
        if self.network is None:
            return
        try:
            self._stop_cycling()
            if self._host_hb_task is not None:
                self._host_hb_task.stop()
                self._host_hb_task = None
            if self.started and self.node is not None:
                self.node.nmt.state = "PRE-OPERATIONAL"
                if self.tip_node is not None:
                    self.tip_node.nmt.state = "PRE-OPERATIONAL"
        except Exception as exc:        # the link may be gone: the drive-side guards act then
            self.events.append(f"close: {_one_line(exc)}")
        try:
            self.network.disconnect()
        except Exception as exc:
            self.events.append(f"close: {_one_line(exc)}")
        if self._recorder is not None:
            self._recorder.close()
            self._recorder = None
        self.network = None
        self.started = False

    def status(self) -> dict:
        self._stop_cycling()
        sdo = self.node.sdo
        if self.node.nmt.state == "INITIALISING":         # no heartbeat seen yet: wait for one
            try:
                self.node.nmt.wait_for_heartbeat(2 * max(sdo[0x1017].raw, 100) * 1e-3)
            except Exception:
                pass
        sw = sdo[0x6041].raw
        out = {"node": self.node_id, "nmt": self.node.nmt.state, "state": cia402.state_from_statusword(sw),
                "statusword": f"0x{sw:04X}", "mode": self.mode, "position_m": sdo[0x6064].raw / self.counts_per_m,
                "table_m": sdo[0x60E4][1].raw * 1e-9, "error_code": f"0x{sdo[0x603F].raw:04X}",
                "emcy": self.emcy_log[-5:]}
        if self.tip_node is not None:
            try:
                step = self.tip_node.sdo[0x6005][1].raw * 1e-9
                out["tip_node"] = self.tip_id
                out["tip_m"] = self.tip_node.sdo[0x6004].raw * step
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
                out["tip_node"], out["tip_m"] = self.tip_id, f"no answer ({_one_line(exc)})"
        return out
