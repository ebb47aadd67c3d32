"""The drive's own errors, beside the backend contract (:mod:`drivers.base`): the root of the
project's one error tree and the branches a backend raises, with how a run stops.

The tree is one for the user: :mod:`hil.errors` takes these classes as they are and adds the
branches of the runtime and the tools (units, limits, measurements, ...); the command line catches
the root, :class:`HilError`, prints one line and exits with the error's ``exit_code``. They live
here, at the drives' layer, because a backend raises them and ``drivers`` never imports ``hil``.
"""
from __future__ import annotations

from enum import StrEnum

__all__ = ["HilError", "ConfigError", "BackendError", "BackendFault", "STOP_EXIT_CODES", "STOP_FAILED_EXIT", "StopKind",
           "fault_kind"]

# how a run that moved ended -> the command's exit code (README, Safety: the exit codes)
STOP_EXIT_CODES = {
    "complete": 0,
    "drive_fault": 1,
    "trip": 3,
    "link": 4,
    "overrun": 5,
    "interrupt": 130,
}


# a run whose controlled stop itself failed (the quick stop or the disable not delivered: the link was
# gone): whatever ended it, the axis was not stopped by the host; the drive's own guards (its
# watchdog, its heartbeat consumer) are what stop it then. Outranks the kind's own exit code.
STOP_FAILED_EXIT = 6


class StopKind(StrEnum):
    """How a run ended (the keys of :data:`STOP_EXIT_CODES`); ``exit_code`` is the command's. A
    ``StrEnum``: it prints and writes to JSON as its value (``"drive_fault"``)."""
    COMPLETE = "complete"
    DRIVE_FAULT = "drive_fault"
    TRIP = "trip"
    LINK = "link"
    OVERRUN = "overrun"
    INTERRUPT = "interrupt"

    @property
    def exit_code(self) -> int:
        return STOP_EXIT_CODES[self.value]


class HilError(Exception):
    """Root of the project's errors. ``exit_code`` and ``label`` say how the CLI reports it."""
    exit_code = 2
    label = "error"


class ConfigError(HilError, ValueError):
    """A configuration key, value or file that cannot be used; the message names the key."""


class BackendError(ConfigError):
    """An unknown backend, or one that is not available in this installation."""


class BackendFault(HilError, RuntimeError):
    """The backend lost the drive, or the drive reported a fault. ``reason`` says which."""
    exit_code = 1
    label = "drive fault"

    def __init__(self, reason: str, kind: StopKind | None = None):
        super().__init__(reason)
        self.reason = reason
        # drive_fault or link where the backend says which (drivers.base's fault rule)
        self.kind = kind


def fault_kind(kind: StopKind | None, default: StopKind) -> StopKind:
    """The kind of a backend's fault: ``kind`` where the backend gave one, else ``default``
    (:data:`StopKind.TRIP` for a ``Feedback.fault``, :data:`StopKind.LINK` for a setpoint not
    delivered or a start-up that failed). Called once, when the run stops."""
    return default if kind is None else kind
