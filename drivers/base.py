"""The one small hardware contract every backend fulfils (real drive, simulated drive, embedded plant).

A backend is opened, enabled, exchanges one feedback and one setpoint per cycle, and is shut down
(disabled and closed). It says which loops it closes itself, and so what the host must close:

=============  ===============================  ==================================
``closes``      the backend takes                 the host runs
=============  ===============================  ==================================
``"both"``      a position setpoint               nothing (interpolation only)
``"velocity"``  a speed setpoint                  the position loop
``"none"``      a torque (controller output)      the position and velocity loops
=============  ===============================  ==================================

e.g. a CiA 402 drive in cyclic synchronous position mode closes both loops, in velocity mode the
host closes the position loop, in torque mode the host closes both.

Lifecycle (as python-can's ``BusABC`` and ros2_control's hardware interfaces have one)::

    created --open()--> open --enable()--> enabled --disable()--> open --close()--> closed
                                     quick_stop(): enabled -> stopping (the drive brakes) -> open
    shutdown(): from any state to closed (disable, then close); safe to call twice, never raises

``with open_backend(cfg) as b:`` opens on entry and shuts down on exit, however the block ends.

Which methods run in the real-time cycle (bounded time, no allocation of resources, no waiting
beyond the transport's own answer) and which do not:

=========================================  ===================================================
real-time (every cycle, in the loop)        ``read_feedback``, ``write_setpoint``, ``sync``;
                                            ``quick_stop`` in the cycle of a trip or fault
not real-time (before or after the cycle)   ``__init__``, ``open``, ``read_position``, ``start_at``,
                                            ``dry_run_model``, ``enable``, ``disable``,
                                            ``close``, ``shutdown``, and a backend's own
                                            services (homing, status, fault reset)
=========================================  ===================================================

Errors. Configuration and installation mistakes (a missing object dictionary, a bad port name or
command template, an unknown interface) raise :class:`hil.errors.ConfigError` naming the key and
the file, when the backend is built where possible; :class:`BackendFault` is a drive that does
not answer, is lost, or reports a fault. The one fault rule of the cycle:

Every fault has a kind, :class:`Fault` (and with it the exit code, :class:`hil.errors.StopKind`):
``DRIVE`` (the drive's own fault, its refusal, a drive that left the enabled state) or ``LINK``
(answers missing, late or garbled beyond the retries, a lost heartbeat or port); the backend says
which in ``Feedback.fault`` or ``BackendFault.kind``, where it decides the fault; nothing reads the
kind from the reason's words. A fault without a kind (``Fault.OTHER``: a test double, a start-up
that failed) takes the default of where it stops the run (:func:`fault_kind`); the supervisor's own
trips and ``loop overrun`` carry theirs from its rules.

* ``read_feedback()`` never raises for the drive: everything wrong that it learns (the drive's own
  fault, an answer missing, late or garbled beyond the retries, a lost heartbeat, a lost port) is
  reported in :attr:`Feedback.fault` (an enum: the cycle tests an integer, as Ruckig's ``Result``)
  and :attr:`Feedback.reason` (one line saying what, for a person). The supervisor's first check
  trips on it: the configured controlled stop in the same cycle, the run ends ``tripped`` with that
  line as its reason, the trip is latched like any other, and ``hil move`` exits with the code of
  its kind (hil.errors.STOP_EXIT_CODES: 1 drive fault, 4 lost communication). Between position
  ticks (a backend in torque mode) the loop trips the supervisor itself, the same way.
* ``write_setpoint()`` and ``sync()`` raise :class:`BackendFault` only where the setpoint could not
  be delivered (a transport that confirms every setpoint got no confirmation; a bus that refuses
  the frame): the loop commands the stop, latches the fault like a trip and the run ends
  ``fault`` (the exit code of its kind, as above).
* Outside the cycle (``open``, ``enable``, homing) a drive that does not answer or is in fault
  raises :class:`BackendFault`.
"""
from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from enum import IntEnum

from drivers.errors import BackendFault, StopKind, fault_kind

__all__ = ["Backend", "Feedback", "Fault", "Setpoint", "BackendFault", "LOOPS", "fault_kind"]

LOOPS = ("both", "velocity", "none")

log = logging.getLogger(__name__)


class Fault(IntEnum):
    """What a cycle's :class:`Feedback` reports: whether the drive is well and, if not, the kind of
    its fault (the cycle tests this integer, never the reason's text). ``stop_kind`` is how a run
    it ends stops (None: the default of where it stops, :func:`fault_kind`)."""
    NONE = 0        # the drive is well
    DRIVE = 1       # the drive's own fault, its refusal, a drive that left the enabled state
    LINK = 2        # answers missing, late or garbled beyond the retries, a lost heartbeat or port
    OTHER = 3       # a fault without a kind (a test double)

    @property
    def stop_kind(self) -> StopKind | None:
        return _STOP_KIND[self]

    @classmethod
    def of(cls, kind: StopKind | None) -> "Fault":
        """The fault of a :class:`BackendFault`'s ``kind`` (not real-time)."""
        return {StopKind.DRIVE_FAULT: cls.DRIVE, StopKind.LINK: cls.LINK}.get(kind, cls.OTHER)


# the line of a fault reported without one (a backend's omission must still stop the axis, and say so)
UNNAMED_FAULT = "drive fault (the backend gave no reason)"

_STOP_KIND = {Fault.NONE: None, Fault.DRIVE: StopKind.DRIVE_FAULT, Fault.LINK: StopKind.LINK, Fault.OTHER: None}


@dataclass
class Feedback:
    """One cycle's measurements, SI, linear units on the load side.

    ``x_tip`` is NaN where no tool-tip sensor exists. ``v_motor`` is the motor speed as a linear
    speed (m/s); ``output`` the actual torque (N m) or command. ``fault`` is :attr:`Fault.NONE`
    while the drive is well, else the fault's kind, and ``reason`` one line saying what is wrong
    (the fault rule of the module docstring); the positions are then the last ones known. ``stale``
    is True where this cycle's answer did not come in (a missed PDO, a failed read): the readings
    repeat the last answer while the command moves on, so a figure of the run must not count them
    as the axis's (they are recorded as the ``stale`` channel where the backend can miss,
    :attr:`Backend.misses_answers`).

    A backend keeps one Feedback and updates it in place every cycle (nothing is built in the
    cycle): what :meth:`Backend.read_feedback` returns holds until its next call; a caller that
    keeps one longer keeps a copy (``dataclasses.replace(fb)``)."""
    x_motor: float
    x_table: float
    v_motor: float
    output: float = 0.0
    x_tip: float = math.nan
    fault: Fault = Fault.NONE
    # the position the position loop uses where it differs from the recorded one (a simulated scale
    # read late over a fieldbus); NaN: x_table or x_motor, as the controller's position_feedback says
    x_feedback: float = math.nan
    stale: bool = False
    reason: str = ""

    @property
    def fault_kind(self) -> StopKind | None:
        """How a run this fault ends stops (None: the default of where it stops, :func:`fault_kind`)."""
        return self.fault.stop_kind

    @property
    def fault_line(self) -> str:
        """The fault's line for a person ("" while well; :data:`UNNAMED_FAULT` where the backend gave
        none: a fault always stops the axis and says so)."""
        return (self.reason or UNNAMED_FAULT) if self.fault else ""

    def set_fault(self, fault: Fault, reason: str) -> None:
        """Report a fault (or, with ``Fault.NONE`` and ``""``, none) in place (real-time)."""
        self.fault, self.reason = fault, reason


@dataclass
class Setpoint:
    """What the host sends for one cycle; the backend uses the field its mode needs
    (position in m, speed in controller units (rad/s of the motor, or m/s), output in N m or V)."""
    position: float = 0.0
    speed: float = 0.0
    output: float = 0.0


class Backend(ABC):
    """Base class of backends. Subclasses set ``name``, ``closes`` and ``cycle_time`` and implement
    the parts; the base class owns :meth:`shutdown` and the context manager (python-can's
    ``BusABC.recv`` over ``_recv_internal`` is the model)."""

    name: str = "backend"
    closes: str = "none"
    cycle_time: float = 0.0      # seconds between exchanges (the host's clock ticks at this period)
    simulated: bool = False      # True: time advances only when the host calls sync()
    misses_answers: bool = False  # True: a cycle's answer can fail to come in (Feedback.stale; a fieldbus, a line)

    # -- not real-time -----------------------------------------------------------------------------
    @abstractmethod
    def open(self) -> None:
        """Connect and configure the drive; raises ConfigError or BackendFault."""

    def read_position(self) -> Feedback | None:
        """Where the axis stands, read from the drive (not real-time: after :meth:`open`, before
        :meth:`enable`): the positions of a :class:`Feedback`. The runtime plans every move from
        here (or refuses one planned from elsewhere) before it enables the drive. ``None``: this
        backend puts the axis where the run starts itself (a simulated stand-in); every backend of
        ``drivers.BACKENDS`` that drives an axis answers. Raises BackendFault where the drive does
        not answer."""
        return None

    def start_at(self, position: float) -> None:
        """Put the axis at rest at ``position`` before a run (not real-time): what a simulated
        stand-in does (it starts where it is told); default: nothing, an axis is where it stands
        (:meth:`read_position`)."""

    def dry_run_model(self):
        """``(plant, controller)`` where the whole run can be computed at once, offline, through the
        compiled loop of the same cycle (the embedded plant in torque mode); None (default): the
        run goes cycle by cycle (not real-time)."""
        return None

    @abstractmethod
    def enable(self) -> None:
        """Power the drive up to where it follows setpoints, holding the present position."""

    # -- real-time: the cycle --------------------------------------------------------------------
    @abstractmethod
    def read_feedback(self) -> Feedback:
        """This cycle's measurements; a faulted or lost drive is reported in ``Feedback.fault``. A
        backend updates one Feedback in place and returns it (real-time: nothing built per cycle)."""

    @abstractmethod
    def write_setpoint(self, setpoint: Setpoint) -> None:
        """This cycle's setpoint; raises BackendFault only where it could not be delivered."""

    def sync(self) -> None:
        """End of the cycle: a simulated plant advances one cycle, a CANopen bus gets its SYNC."""

    def quick_stop(self) -> None:
        """Controlled stop (CiA 402 quick stop where the drive has one); default: disable. Called in
        the cycle of a trip or fault."""
        self.disable()

    # -- not real-time: the end -------------------------------------------------------------------
    @abstractmethod
    def disable(self) -> None:
        """Take the torque off (after a quick stop has finished). Does nothing on a backend that
        is not open, or did not start the drive."""

    @abstractmethod
    def close(self) -> None:
        """Release the link. Does nothing on a backend that is already closed."""

    def shutdown(self) -> None:
        """Bring the drive to a safe state and release the link: :meth:`disable`, then :meth:`close`
        (also when disable fails or is interrupted). Safe to call twice and at any point of the
        lifecycle; what fails on the way is logged, never raised: the link may be gone, and the
        drive-side guards (watchdog, heartbeat consumer) stop the axis then."""
        try:
            self._attempt("disable", self.disable)
        finally:
            self._attempt("close", self.close)

    def _attempt(self, what: str, step) -> None:
        try:
            step()
        except Exception as exc:
            log.warning("%s backend: %s at shutdown failed: %s", self.name, what, exc)

    def __enter__(self):
        try:
            self.open()
        except BaseException:
            self.shutdown()         # a start-up that failed half-way releases what it took
            raise
        return self

    def __exit__(self, *exc):
        self.shutdown()
        return False
