"""The one small hardware contract every backend fulfils (real drive, simulated drive, embedded plant).

A backend is opened, enabled, exchanges one feedback and one setpoint per cycle, and is disabled
and closed. It says which loops it closes itself, and so what the host must close:

=============  ===============================  ==================================
``closes``      the backend takes                 the host runs
=============  ===============================  ==================================
``"both"``      a position setpoint               nothing (interpolation only)
``"velocity"``  a speed setpoint                  the position loop
``"none"``      a torque (controller output)      the position and velocity loops
=============  ===============================  ==================================

e.g. a CiA 402 drive in cyclic synchronous position mode closes both loops, in velocity mode the
host closes the position loop, in torque mode the host closes both.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

from hil.errors import BackendFault

__all__ = ["Backend", "Feedback", "Setpoint", "BackendFault", "LOOPS"]

LOOPS = ("both", "velocity", "none")


@dataclass
class Feedback:
    """One cycle's measurements, SI, linear units on the load side.

    ``x_tip`` is NaN where no tool-tip sensor exists. ``v_motor`` is the motor speed as a linear
    speed (m/s); ``output`` the actual torque (N m) or command."""
    x_motor: float
    x_table: float
    v_motor: float
    output: float = 0.0
    x_tip: float = math.nan
    fault: str = ""


@dataclass
class Setpoint:
    """What the host sends for one cycle; the backend uses the field its mode needs
    (position in m, speed in controller units (rad/s of the motor, or m/s), output in N m or V)."""
    position: float = 0.0
    speed: float = 0.0
    output: float = 0.0


class Backend(ABC):
    """Base class of backends. Subclasses set ``name``, ``closes`` and ``cycle_time``."""

    name: str = "backend"
    closes: str = "none"
    cycle_time: float = 0.0      # seconds between exchanges (the host's clock ticks at this period)
    simulated: bool = False      # True: time advances only when the host calls sync()

    @abstractmethod
    def open(self) -> None: ...

    @abstractmethod
    def enable(self) -> None: ...

    @abstractmethod
    def read_feedback(self) -> Feedback: ...

    @abstractmethod
    def write_setpoint(self, setpoint: Setpoint) -> None: ...

    def sync(self) -> None:
        """End of the cycle: a simulated plant advances one cycle, a CANopen bus gets its SYNC."""

    def quick_stop(self) -> None:
        """Controlled stop (CiA 402 quick stop where the drive has one); default: disable."""
        self.disable()

    @abstractmethod
    def disable(self) -> None: ...

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        try:
            self.disable()
        finally:
            self.close()
        return False
