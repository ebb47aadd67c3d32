"""Servo drives with an ASCII command interface over RS-232 / RS-485 (pyserial).

The command set is configuration (``[serial]``, see :mod:`drivers.serial.protocol`,
``config/serial_ascii_example.toml`` and the README (Serial drives)); a user adapts the backend to a drive
without writing code.

One cycle is two transactions, each one command line and one reply line: ``read`` (positions,
speed, torque, fault state) and ``set_position`` (position mode: the drive closes both loops) or
``set_speed`` (velocity mode: the host closes the position loop).

Robustness. Every command must be confirmed by its reply; a setpoint counts only when the drive
echoes it. A missing reply (timeout), a partial or garbled line, a checksum error, an unexpected
reply or the drive's error reply is retried, at most ``serial.retries`` times and only while the
transaction's time budget lasts (``serial.budget``, default: half the cycle); a port that vanished
is reopened within the same budget. Then the transaction has failed, with the reason; following
the fault rule of drivers.base, a failed ``read`` in the cycle is reported as ``Feedback.fault``
(the supervisor trips on it), a setpoint the drive did not confirm raises
:class:`~drivers.base.BackendFault` (the loop stops the axis), and so does anything that fails
outside the cycle (``open``, ``enable``). Retrying is safe because every cyclic command is absolute
(a target, not an increment): executing it twice is executing it once. The drive's own watchdog is
armed at :meth:`open` where the command set has one (``watchdog``), so that the drive stops when
the host falls silent.

Configuration mistakes (no port, a port name pyserial does not know, a command template or reply
pattern that cannot work, a missing command) are :class:`~hil.errors.ConfigError` naming the key
and the configuration file, raised when the backend is built, and so is a device name that does
not exist when :meth:`open` first opens it; a port that exists but does not open (busy, no
permission) is a BackendFault at :meth:`open`. Every fault says its kind where it is decided
(``Feedback.fault_kind``, ``BackendFault.kind``): a drive fault (the drive's fault code or its
refusal) or the link's (no, late or garbled answer beyond the retries, the port lost); its reason
starts with ``drive fault`` or ``lost communication``, the same words as the other backends'.
"""
from __future__ import annotations

import math
import os
import select
import time

import serial

from drivers.base import Backend, BackendFault, Fault, Feedback, Setpoint
from drivers.control import controller_from_config, measured_speed, new_velocity_state, position_law, velocity_law
from drivers.errors import BackendError, ConfigError, StopKind
from drivers.serial.protocol import CommandSet, DriveRefused, GarbledReply, ReplyError, UnsafeCommand
from drivers.serial.schema import SECTION

__all__ = ["SerialBackend", "SerialStats", "SECTION", "BAUDRATES"]

_WELL = (Fault.NONE, "")    # what a healthy reading reports (nothing built per cycle)

# the standard rates of a UART (POSIX termios and pyserial's list, and the 14400 ... 256000 of
# Windows and RS-485 drives): anything else is a typing mistake (0, 11520), not a drive's setting
BAUDRATES = (50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 14400, 19200, 28800, 38400,
             57600, 76800, 115200, 128000, 230400, 250000, 256000, 460800, 500000, 576000, 921600, 1000000,
             1152000, 1500000, 2000000, 2500000, 3000000, 3500000, 4000000)


# -- the configuration section ------------------------------------------------------------------------
# the [serial] keys: drivers.serial.schema.SECTION (hil.config validates them)


def _warm_up_host_loop(cfg, plant) -> None:
    """Compile the host loop's laws now: their first call (hundreds of ms of JIT loading) must not
    fall between enabling the drive and the first cycle, or the drive's watchdog trips."""
    if plant is None:       # a config without a plant model: nothing to warm up
        return
    try:
        p = controller_from_config(cfg, plant).as_array()
        s = new_velocity_state()
        position_law(p, 0.0, 0.0, 0.0)
        measured_speed(p, s, 0.0, 0.0)
        velocity_law(p, s, 0.0, 0.0, 0.0)
    except Exception:       # a config without a plant model: nothing to warm up
        pass


class SerialStats:
    """Counters of one session: transactions, retries and why, bytes exchanged."""

    def __init__(self):
        self.transactions = 0
        self.retries = 0
        self.reasons: dict[str, int] = {}
        self.bytes_out = 0
        self.bytes_in = 0
        self.reopened = 0

    def note(self, reason: str) -> None:
        self.retries += 1
        key = reason.split(":")[0]
        self.reasons[key] = self.reasons.get(key, 0) + 1

    def as_dict(self) -> dict:
        return dict(transactions=self.transactions, retries=self.retries, reasons=dict(self.reasons),
                    bytes_out=self.bytes_out, bytes_in=self.bytes_in, reopened=self.reopened)


class _Timeout(ReplyError):
    pass


class _PortLost(Exception):
    pass


class SerialBackend(Backend):
    """A drive behind an ASCII command set. ``options`` override the ``[serial]`` keys of the config
    (``port=``, ``timeout=``, ...); ``free_run=True`` lets the host loop run as fast as the link
    permits (for a simulated drive that advances one cycle per setpoint; never for a real one)."""

    name = "serial"
    misses_answers = True         # a read that failed in the cycle (Feedback.stale)
    takes_plant = "optional"      # the host loop's laws are warmed up on it where the config has one

    @staticmethod
    def check_settings(cfg) -> None:
        """What the configuration says of the drive, checked without a port (``hil move --check``):
        the command set and its replies, as the backend reads them when it is built (not real-time)."""
        CommandSet.from_config(cfg)

    def __init__(self, cfg, port: str | None = None, free_run: bool = False, plant=None, **options):
        self.cfg = cfg
        self._plant = plant

        def opt(key, default=None):
            v = options.get(key)
            return v if v is not None else cfg.get(f"serial.{key}", default)

        self.port = port or opt("port", "")
        self.baudrate = opt("baudrate", 115200)
        if isinstance(self.baudrate, bool) or self.baudrate not in BAUDRATES:
            raise ConfigError(f"{cfg.source}: serial.baudrate: expected a standard rate ({BAUDRATES[0]} ... "
                              f"{BAUDRATES[-1]}, e.g. 9600, 115200, 1000000), got {self.baudrate!r}")
        self.parity = opt("parity", "N")
        self.stopbits = opt("stopbits", 1)
        if isinstance(self.stopbits, bool) or self.stopbits not in (1, 2):
            raise ConfigError(f"{cfg.source}: serial.stopbits: expected 1 or 2, got {self.stopbits!r}")
        mode = opt("mode", "position")
        self.closes = "both" if mode == "position" else "velocity"
        tp = cfg.get("control.position_period", 0.004)
        self.cycle_time = float(opt("cycle_time", None) or tp)
        if abs(self.cycle_time - tp) > 1e-9:     # the loop times its record and commands on control.position_period
            raise ConfigError(f"{cfg.source}: serial.cycle_time ({self.cycle_time:g} s) must equal "
                              f"control.position_period ({tp:g} s): set the position period instead")
        self.timeout = float(opt("timeout", None) or self.cycle_time / 4)
        self.retries = int(opt("retries", 2))
        self.budget = float(opt("budget", None) or self.cycle_time / 2)
        self.setup_timeout = float(opt("setup_timeout", None) or 0.2)
        self.watchdog = float(opt("watchdog", 0.0) or 0.0)
        self.cs: CommandSet = options.get("command_set") or CommandSet.from_config(cfg)
        self.k_pos = float(opt("scale_position", None) or 1e6)
        self.k_speed = float(opt("scale_speed", None) or self.k_pos)
        self.k_out = float(opt("scale_output", None) or 1.0)
        self.simulated = bool(free_run)
        self.stats = SerialStats()
        self.drive_name = ""
        self.enabled = False
        self._ser = None
        self._open = False           # between open() and close(): the drive is this backend's to disable
        self._open_once = False      # the port opened once: a port that vanishes later is the link's fault
        self._faulted = ""
        self._fb = Feedback(0.0, 0.0, 0.0)     # the cycle's one Feedback, updated in place (drivers.base)
        self._sets_position = self.closes == "both"          # bound once: the cycle compares no strings
        self._set_op = "set_position" if self._sets_position else "set_speed"
        # configuration mistakes now, as one line naming the key, before anything opens or moves
        src = cfg.source
        for op in ("enable", "disable", "read", self._set_op):
            if not self.cs.has(op):
                raise ConfigError(f"{src}: serial.commands.{op}: missing (the serial backend needs the {op} command)")
        if "x_motor" not in self.cs.groups("read"):
            raise ConfigError(f"{src}: serial.replies.read: no (?P<x_motor>...) group (the motor position)")
        if not self.port:
            raise BackendError(f"{src}: serial.port: no port; set it in the config or --set serial.port=/dev/ttyUSB0 "
                               "(hil serial-sim prints the port of the simulated drive)")
        try:                         # the name and the settings, checked without opening the port
            self._port_object(do_not_open=True)
        except ValueError as exc:
            raise ConfigError(f"{src}: serial.port {self.port!r}: {exc}") from None
        _warm_up_host_loop(cfg, self._plant)


    # -- the port ----------------------------------------------------------------------------------
    def _port_object(self, do_not_open: bool = False):
        return serial.serial_for_url(self.port, do_not_open=do_not_open, baudrate=self.baudrate, parity=self.parity,
                                     stopbits=self.stopbits, timeout=self.timeout, write_timeout=self.setup_timeout)

    def _open_port(self):
        if "://" not in self.port and not os.path.exists(self.port) and not self._open_once:
            # a device name that does not exist: a mistake in the configuration, not a drive fault
            raise ConfigError(f"{self.cfg.source}: serial.port: no device {self.port} (check the cable and the "
                              "name; hil serial-sim prints the port of the simulated drive)")
        try:
            ser = self._port_object()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise BackendFault(f"cannot open serial port {self.port}: {exc}") from None
        self._open_once = True
        self._ser = ser

    def _close_port(self):
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:
                pass

    # -- one transaction ---------------------------------------------------------------------------
    def _readline(self, deadline: float) -> bytes:
        """One reply line by ``deadline`` (real-time: ``select`` on the descriptor, no allocation
        beyond the line)."""
        ser, eol, cap = self._ser, self.cs.line_ending, self.cs.max_reply + 8
        try:
            fd = ser.fileno()
        except Exception:
            fd = None
        buf = bytearray()
        while True:
            left = deadline - time.perf_counter()
            if left <= 0:
                if buf:
                    raise GarbledReply(f"partial reply {bytes(buf[:40])!r} (no line ending)")
                raise _Timeout("no reply")
            if fd is not None:          # select on the descriptor: no tcsetattr per read for a new timeout
                if not select.select([fd], [], [], left)[0]:
                    continue
                chunk = os.read(fd, 4096)
                if not chunk:
                    raise OSError("port closed (read returned no data)")
            else:
                if ser.timeout != left:
                    ser.timeout = left
                chunk = ser.read(max(1, min(ser.in_waiting, cap)))
            if chunk:
                buf += chunk
                i = buf.find(eol)
                if i >= 0:
                    return bytes(buf[:i + len(eol)])
                if len(buf) > cap:
                    raise GarbledReply(f"reply longer than {self.cs.max_reply} bytes")

    def transact(self, op: str, setup: bool = False, **values) -> dict:
        """Send ``op`` and return the named groups of its confirmed reply; retry within the budget,
        then raise BackendFault (real-time in the cycle; with ``setup``, not)."""
        try:                # never anything but one line of printable ASCII (protocol.CommandSet.frame)
            frame = self.cs.encode(op, **values)
        except UnsafeCommand as exc:
            self._faulted = f"setpoint refused: {exc}"
            raise BackendFault(self._faulted) from None
        t0 = time.perf_counter()
        attempt_timeout = self.setup_timeout if setup else self.timeout
        end = t0 + (self.setup_timeout * (self.retries + 1) if setup else self.budget)
        last = ""
        self.stats.transactions += 1
        for attempt in range(self.retries + 1):
            now = time.perf_counter()
            if attempt and now >= end:
                break
            try:
                if self._ser is None:
                    self.stats.reopened += 1
                    self._open_port()
                ser = self._ser
                ser.reset_input_buffer()        # a late reply to an earlier attempt is not this one's
                ser.write(frame)
                self.stats.bytes_out += len(frame)
                line = self._readline(min(now + attempt_timeout, end))
                self.stats.bytes_in += len(line)
                return self.cs.parse(op, line, values)
            except ReplyError as exc:
                last = f"{type(exc).__name__}: {exc}" if not isinstance(exc, _Timeout) else \
                    f"timeout: no reply within {attempt_timeout * 1e3:.3g} ms"
                if isinstance(exc, DriveRefused):
                    last = f"refused: {exc}"
            except (serial.SerialException, OSError) as exc:
                last = f"port lost: {exc}"
                self._close_port()
            except BackendFault as exc:      # reopening failed
                last = f"port lost: {exc.reason}"
            if attempt < self.retries:
                self.stats.note(last)
        # the drive's refusal is the drive's doing, everything else is the link's
        kind = StopKind.DRIVE_FAULT if last.startswith("refused") else StopKind.LINK
        words = "drive fault" if kind is StopKind.DRIVE_FAULT else "lost communication"
        reason = (f"{words}: serial {op}: {last} (after {attempt + 1} attempt(s), "
                  f"{(time.perf_counter() - t0) * 1e3:.1f} ms)")
        self._faulted = reason
        raise BackendFault(reason, kind)

    # -- the contract --------------------------------------------------------------------------------
    def open(self) -> None:
        """Open the port, identify the drive, arm its watchdog (not real-time)."""
        self._faulted = ""
        self._open = True
        self._open_port()
        if self.cs.has("identify"):
            self.drive_name = self.transact("identify", setup=True).get("name", "")
        if self.cs.has("watchdog") and self.watchdog > 0:
            self.transact("watchdog", setup=True, ms=max(1, round(self.watchdog * 1e3)))

    def read_position(self) -> Feedback:
        """Where the axis is (not real-time; after :meth:`open`, before :meth:`enable`): one ``read``."""
        return self.read_feedback(setup=True)

    def enable(self) -> None:
        """Clear a fault where the command set can, enable, check (not real-time)."""
        fb = self.read_feedback(setup=True)
        if fb.fault and self.cs.has("clear_fault"):
            self.transact("clear_fault", setup=True)
        self.transact("enable", setup=True)
        fb = self.read_feedback(setup=True)
        if fb.fault:
            raise BackendFault(f"serial drive did not enable: {fb.reason}")
        self.enabled = True

    def read_feedback(self, setup: bool = False) -> Feedback:
        """The drive's reading (real-time). In the cycle a failed read is reported in
        ``Feedback.fault`` (the positions are the last ones read); with ``setup`` (enable, not
        real-time) it raises BackendFault."""
        try:
            g = self.transact("read", setup=setup)
        except BackendFault as exc:
            if setup:
                raise
            fb = self._fb              # the last reading stays, marked stale
            fb.fault, fb.reason, fb.stale = Fault.of(exc.kind), exc.reason, True
            return fb
        fb = self._fb
        fb.x_motor = xm = int(g["x_motor"]) / self.k_pos
        fb.x_table = int(g["x_table"]) / self.k_pos if "x_table" in g else xm
        fb.v_motor = int(g["v_motor"]) / self.k_pos if "v_motor" in g else math.nan      # counts/s
        fb.output = int(g["output"]) / self.k_out if "output" in g else 0.0
        code = int(g.get("fault", "0"))
        fb.fault, fb.reason = (Fault.DRIVE, f"drive fault {code}") if code else _WELL
        fb.stale = False
        return fb

    def write_setpoint(self, setpoint: Setpoint) -> None:
        """The setpoint, confirmed by the drive's echo (real-time)."""
        if self._sets_position:
            self.transact("set_position", position=self._counts("set_position", setpoint.position * self.k_pos))
        else:
            self.transact("set_speed", speed=self._counts("set_speed", setpoint.speed * self.k_speed))

    def _counts(self, op: str, value: float) -> int:
        """A setpoint in whole drive units; a NaN or infinite one, or one of more digits than a
        reply can confirm (protocol: 12), is never sent (BackendFault). Real-time."""
        if not math.isfinite(value) or abs(value) >= 1e12:
            self._faulted = (f"setpoint refused: serial {op}: {value!r} is not a finite number of at most 12 digits "
                             f"(drive units); not sent")
            raise BackendFault(self._faulted)
        return round(value)

    def quick_stop(self) -> None:
        """The drive's quick stop (or disable), in the cycle of a trip (real-time)."""
        op = "quick_stop" if self.cs.has("quick_stop") else "disable"
        self.enabled = False
        self.transact(op, setup=True)

    def disable(self) -> None:
        """Disable; after a fault (link likely gone) a failure here is recorded, not raised: the
        drive's watchdog stops it. Nothing before :meth:`open` or after :meth:`close` (not real-time)."""
        was = self.enabled
        self.enabled = False
        if not self._open or not self._open_once or self._ser is None and self._faulted:
            return                   # nothing opened, or the link is gone: nothing to tell the drive
        try:
            self.transact("disable", setup=True)
        except BackendFault:
            if not self._faulted and was:
                raise

    def close(self) -> None:
        """Release the port (not real-time; safe twice)."""
        self._open = False
        self._close_port()
