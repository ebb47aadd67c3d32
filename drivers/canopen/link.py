"""The CAN link of the CANopen backend: the bus opened (python-can through ``canopen.Network``; a
socketcand server probed first), frames sent, the bus's errors turned into one line, and the
threads that take the received frames.

Threads. Start-up, SDO and shutdown run on canopen's notifier thread (python-can's ``Notifier``
hands each frame to ``Network.notify``). The cyclic phase (:meth:`CanLink.start_cycling` until
:meth:`CanLink.stop_cycling`) has no such thread: the notifier is stopped and the loop's own
thread takes the frames from the bus (:meth:`CanLink.receive_until`, the clock's wait for its next
deadline: ``Bus.recv`` with a timeout, outside the interpreter lock), hands the TPDOs it mapped to
the answer tracker (drivers.canopen.tracker) and every other frame (EMCY, heartbeat, SDO) to
``Network.notify``. The answer reaches the loop with no hand-over between threads.

Real-time: :meth:`CanLink.receive_until`, :meth:`CanLink.take`, :meth:`CanLink.send`,
:meth:`CanLink.barrier`; the rest is not.
"""
from __future__ import annotations

import logging
import socket
import threading
import time

import can
import canopen
from canopen.sdo.constants import REQUEST_UPLOAD, SDO_STRUCT

from drivers.canopen import canlog
from drivers.errors import BackendFault, ConfigError, StopKind

__all__ = ["CanLink", "one_line", "probe_socketcand", "BusErrors", "quiet_periodic_send_errors"]

logger = logging.getLogger("drivers.canopen.backend")


class _OneLine(logging.Filter):
    """python-can logs a failed periodic send with its traceback; the backend reports the fault in
    one line itself, so the record keeps its message and drops the traceback."""

    def filter(self, record: logging.LogRecord) -> bool:
        record.exc_info = record.exc_text = None
        return True


_ONE_LINE = _OneLine()


def quiet_periodic_send_errors() -> None:
    """Install the one-line filter on python-can's periodic sender's logger (once; called when a
    backend opens, not at import: importing the backend changes no logging)."""
    log = logging.getLogger("can.broadcastmanager")
    if _ONE_LINE not in log.filters:
        log.addFilter(_ONE_LINE)


def one_line(exc: BaseException, limit: int = 200) -> str:
    """An exception as one short line: python-can's socketcand interface puts a whole traceback
    into its error's text (``Failed to receive: ... Traceback ...``), which must not reach a
    reason on the screen, in move.json or in the latch."""
    text = str(exc).split("Traceback (most recent call last)")[0]
    text = " ".join(text.split())
    if not text:
        text = type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


def probe_socketcand(host: str, port: int, timeout: float) -> None:
    """Before python-can connects (it would retry for 10 s, then wait for the server's greeting
    without a timeout): a server must accept and greet (``< hi >``) within ``timeout``; else a
    BackendFault saying which. Every read here has a timeout."""
    try:
        conn = socket.create_connection((host, port), timeout=timeout)
    except OSError as exc:
        raise BackendFault(f"no socketcand server at {host}:{port} ({one_line(exc)}); start 'hil drive-sim' "
                           "or point canopen.host/port at one", StopKind.LINK) from None
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
                           f"server, or a hung one", StopKind.LINK)


class AnswerEvent(threading.Event):
    """Set when the whole answer to the last SYNC is in. In the cyclic phase nothing but the
    caller's own thread takes frames from the bus: :meth:`wait` receives until the answer is in
    or the timeout has passed."""

    def __init__(self, link: "CanLink"):
        super().__init__()
        self._link = link

    def wait(self, timeout: float | None = None) -> bool:
        link = self._link
        if not link.cycling:
            return super().wait(timeout)
        t_end = time.perf_counter() + (3600.0 if timeout is None else timeout)
        recv = link.network.bus.recv
        while not self.is_set():
            msg = recv(max(0.0, t_end - time.perf_counter()))
            if msg is None:
                break
            link.take(msg)
        return self.is_set()


class BusErrors(can.Listener):
    """A listener of the notifier's thread that takes the bus's error: python-can's Notifier
    re-raises an error no listener handles, and the thread dies printing its traceback (the
    drive's process killed: ``ConnectionResetError`` under the socketcand client). Here it becomes
    the link's one-line ``lost communication`` (``Feedback.fault``) and a log line."""

    # python-can's notifier goes on receiving after a handled error, and a dead socket fails at
    # once: the thread waits this long per further error instead of spinning on it (until the
    # backend stops the notifier at close)
    IDLE_AFTER_ERROR = 0.1

    def __init__(self, link: "CanLink"):
        self.link = link
        self.failed = False

    def on_message_received(self, msg) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        if self.failed:
            time.sleep(self.IDLE_AFTER_ERROR)
            return
        self.failed = True
        self.link.note_rx_error(f"lost communication: the CAN bus failed ({one_line(exc)})")
        logger.warning("%s", self.link.rx_error)


class CanLink:
    """The bus of one backend. ``answers`` is the answer tracker the TPDOs go to, ``events`` the
    backend's bounded event log; ``can_log``: a file to trace the bus into (``hil --can-log``)."""

    def __init__(self, cfg, settings, answers, events, bus=None, can_log: str | None = None):
        self.cfg, self.settings, self.answers, self.events = cfg, settings, answers, events
        self._bus = bus
        self.can_log = can_log
        self.network = None
        self.recorder = None         # the bus trace of hil --can-log (drivers.canopen.canlog)
        self.cycling = False         # the cyclic phase: the loop's thread takes the frames, no notifier thread
        self.rx_error = ""           # the bus failed on receive in the cyclic phase (a Feedback.fault)
        self.pdo_frames_on_loop = 0  # TPDO frames the loop's thread took from the bus (cyclic phase)

    @property
    def where(self) -> str:
        return f"{self.settings.interface}:{self.settings.channel}"

    def note_rx_error(self, reason: str) -> None:
        """The first failure of the bus on receive: kept for the next feedback, logged as an event."""
        if not self.rx_error:
            self.rx_error = reason
            self.events.append(f"cycle {self.answers.syncs}: {reason}")

    # -- not real-time ---------------------------------------------------------------------------
    def connect(self) -> canopen.Network:
        """The bus opened and watched for errors, the trace attached where asked."""
        s = self.settings
        self.network = canopen.Network(self._bus)
        self.network.NOTIFIER_CYCLE = 0.05          # the receive thread stops within 50 ms
        if self._bus is None:
            self._open_bus(s.interface)
        else:
            self.network.connect()
        # a bus that fails under the notifier's thread (the drive's end of the link gone: a reset
        # connection) is this backend's fault to report in one line, not a thread's traceback
        errors = BusErrors(self)
        self.network.listeners.append(errors)
        if self.network.notifier is not None:
            self.network.notifier.add_listener(errors)
        # hil --can-log FILE: python-can's logger on the bus, received and sent frames (drivers.canopen.canlog)
        self.recorder = canlog.attach(self.network, self.can_log)
        return self.network

    def _open_bus(self, interface: str) -> None:
        cfg = self.cfg
        if interface == "socketcand":
            host, port = cfg.get("canopen.host", "127.0.0.1"), int(cfg.get("canopen.port", 29536))
            # python-can warns of every TCP segment that splits a frame: harmless
            # and logs a lost connection with its traceback: the backend reports the cause itself, in one line
            logging.getLogger("can.interfaces.socketcand.socketcand").setLevel(logging.CRITICAL)
            probe_socketcand(host, port, float(cfg.get("canopen.connect_timeout", 2.0)))
        kw = dict(interface=interface, channel=self.settings.channel)
        if interface == "socketcand":
            kw.update(host=cfg.get("canopen.host", "127.0.0.1"), port=cfg.get("canopen.port", 29536),
                      tcp_tune=True)          # TCP_NODELAY: no Nagle delay between RPDO and SYNC
        elif interface != "virtual":
            kw["bitrate"] = cfg.get("canopen.bitrate", 1000000)
        # python-can's socketcand client reads its handshake without a timeout: a server that
        # stops talking after the probe would hold this process forever
        old_timeout = socket.getdefaulttimeout()
        if interface == "socketcand":
            socket.setdefaulttimeout(float(cfg.get("canopen.connect_timeout", 2.0)))
        try:
            self.network.connect(**kw)
        except can.CanInterfaceNotImplementedError as exc:     # the interface's library is not installed
            self.network = None
            raise ConfigError(f"{cfg.source}: canopen.interface: {interface} is not available "
                              f"({one_line(exc)})") from None
        except (can.CanError, OSError) as exc:
            self.network = None
            raise BackendFault(f"cannot open the CAN bus {self.where} ({one_line(exc)})", StopKind.LINK) from None
        finally:
            socket.setdefaulttimeout(old_timeout)

    def start_cycling(self) -> None:
        """From now on the loop's thread takes every frame from the bus (:meth:`receive_until`, the
        barrier, the feedback): canopen's notifier thread is stopped (it returns within its
        ``NOTIFIER_CYCLE``), so that no second thread takes the answer, runs callbacks on it and
        competes with the loop for the interpreter lock while the loop runs. (The host's
        heartbeat stays on python-can's periodic thread: it wakes every 100 ms for one send, and
        it keeps the drive's heartbeat consumer content between enable and the loop's start.)"""
        net = self.network
        if self.cycling or net is None or net.notifier is None:
            return
        net.notifier.stop(4 * net.NOTIFIER_CYCLE + 1.0)
        self.cycling = True

    def stop_cycling(self) -> None:
        """Back to canopen's notifier thread (SDO, shutdown): the frames already in are taken here
        first, in order, then a new notifier serves the network (and the periodic heartbeat)."""
        if not self.cycling:
            return
        net = self.network
        self.receive_until(0.0)
        self.cycling = False
        net.notifier = can.Notifier(net.bus, net.listeners, net.NOTIFIER_CYCLE)
        if self.recorder is not None:           # hil --can-log: the trace goes on with the new notifier
            self.recorder.follow(net.notifier)

    def disconnect(self) -> None:
        """The bus released and the trace closed; ``network`` is None after. Never raises."""
        try:
            self.network.disconnect()
        except Exception as exc:
            self.events.append(f"close: {one_line(exc)}")
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None
        self.network = None

    # -- real-time -------------------------------------------------------------------------------
    def receive_until(self, t_end: float) -> None:
        """Take the frames from the bus on the calling thread (the loop's) until ``t_end``
        (``time.perf_counter``; one in the past: only those already in), (real-time).

        ``Bus.recv`` with a timeout waits outside the interpreter lock, so the loop's wait for its
        next deadline is this wait. Never raises: a bus that fails here is the next feedback's
        ``fault``."""
        if not self.cycling:
            return
        recv, take, now = self.network.bus.recv, self.take, time.perf_counter
        try:
            while True:
                msg = recv(max(0.0, t_end - now()))
                if msg is None:
                    return
                take(msg)
        except (can.CanError, OSError) as exc:     # the fault rule: the next feedback says so
            self.note_rx_error(f"lost communication: the CAN bus failed on receive ({one_line(exc)})")

    def take(self, msg) -> None:
        """One received frame (real-time): a mapped TPDO to the answer tracker, everything else
        (EMCY, heartbeat, SDO, NMT) to canopen's dispatch, which runs its callbacks as its
        notifier would."""
        if self.recorder is not None:           # hil --can-log: the frames the loop's thread takes
            self.recorder.on_message_received(msg)
        if msg.is_error_frame or msg.is_remote_frame:
            return
        cob = msg.arbitration_id
        answers = self.answers
        if cob in answers.decode:
            self.pdo_frames_on_loop += 1
            if cob == answers.tip_cob:
                answers.on_tip(cob, msg.data, msg.timestamp)
            else:
                answers.on_tpdo(cob, msg.data, msg.timestamp)
        else:
            self.network.notify(cob, msg.data, msg.timestamp)

    def send(self, cob_id: int, data) -> None:
        """One frame (real-time); a bus that refuses it (the interface or the server is gone) is a
        BackendFault: the setpoint could not be delivered (the fault rule of drivers.base)."""
        try:
            self.network.send_message(cob_id, data)
        except (can.CanError, OSError) as exc:
            raise BackendFault(f"lost communication: the CAN bus refused a frame ({one_line(exc)})",
                               StopKind.LINK) from None

    def barrier(self, sdo) -> None:
        """Lockstep (real-time): an SDO upload of 0x1001 after the SYNC. The drive handles the
        frames in order and sends its TPDOs while it handles the SYNC, before it answers the SDO;
        the host handles the answers in order too: when the SDO answer is in, every TPDO the drive
        sent for this SYNC has been taken. A missing or late TPDO is then the drive's doing, never
        the scheduler's, however loaded the machine. In the cyclic phase the loop's thread sends
        the request (canopen's own SDO request format) and takes the frames until the answer."""
        timeout, syncs = self.settings.pdo_timeout, self.answers.syncs
        if self.cycling:
            recv, t_end = self.network.bus.recv, time.perf_counter() + timeout
            try:
                sdo.send_request(SDO_STRUCT.pack(REQUEST_UPLOAD, 0x1001, 0) + bytes(4))
                while True:
                    msg = recv(max(0.0, t_end - time.perf_counter()))
                    if msg is None:
                        self.events.append(f"cycle {syncs}: no SDO answer to the barrier")
                        return
                    if msg.arbitration_id == sdo.tx_cobid:
                        return
                    self.take(msg)
            except (can.CanError, OSError) as exc:        # the fault rule: this feedback says so
                self.note_rx_error(f"lost communication: the CAN bus failed ({one_line(exc)})")
        old = sdo.RESPONSE_TIMEOUT
        sdo.RESPONSE_TIMEOUT = max(old, timeout)
        try:
            sdo.upload(0x1001, 0)
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
            self.events.append(f"cycle {syncs}: no SDO answer to the barrier ({one_line(exc)})")
        finally:
            sdo.RESPONSE_TIMEOUT = old
