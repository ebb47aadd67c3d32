"""One error tree for the whole project (as python-control's ``control/exception.py`` and
python-can's ``can/exceptions.py`` have one).

Everything the project raises on purpose derives from :class:`HilError`; the command line
catches that root, prints one line and exits with the error's ``exit_code``:

- 2, a mistake the user can fix before anything moves (a configuration, a unit, a limit, a
  measurement file, an unstable loop, a refused request, a latched trip, a backend that cannot
  be opened);
- 1, a drive that was lost or faulted outside the cycle (:class:`BackendFault`);
- 130, an interrupt (Ctrl-C; a ``KeyboardInterrupt``, not a HilError).

A run that moved and did not complete ends with the exit code of *how* it stopped,
:data:`STOP_EXIT_CODES` (one fault rule for every backend: each of these ends in the configured
controlled stop and a record closed with its status and reason). How it stopped is a
:class:`StopKind`, decided where the stop is decided (a supervisor rule, the backend's fault, the
loop's interrupt) and carried with the run's :class:`RunStatus` to the exit code, as Ruckig's
``Result`` is; nothing reads it back from the reason's words::

    0    complete
    1    drive_fault   the drive reported a fault (EMCY / FAULT state, a fault code, a refusal)
    3    trip          the supervisor tripped (limits, following error, frozen feedback)
    4    link          lost communication (answers missing, late or garbled beyond the retries,
                       heartbeat lost, port lost)
    5    overrun       the real-time loop overran its watchdog
    130  interrupt     Ctrl-C

and 6 (:data:`STOP_FAILED_EXIT`) where the controlled stop itself failed (not delivered: the link
was gone), whatever ended the run.

Tree::

    HilError
    +-- ConfigError              configuration key, value or file
    |   +-- BackendError         unknown backend, or one not available in this installation
    +-- UnitError                a quantity that does not parse or has the wrong dimension
    +-- LimitError               a move beyond the axis limits, refused before motion
    +-- MeasurementError         a measurement file or record that cannot be used
    +-- UnstableLoopError        a loop configuration the model shows unstable
    +-- UserError                a request that cannot be carried out as asked
    +-- SupervisorTripped        motion refused: a trip is latched until ``hil reset``
    +-- BackendFault             the drive was lost or reported a fault (exit 1)
    +-- RunStopped               a run that moved ended early (exit code: how, STOP_EXIT_CODES)

The library never raises the CLI's errors and the CLI adds no classes of its own. The root and the
branches a backend raises (:class:`HilError`, :class:`ConfigError`, :class:`BackendError`,
:class:`BackendFault`, :class:`StopKind`) are defined beside the backend contract,
:mod:`drivers.errors`, since ``drivers`` never imports ``hil``; this module adds the rest and is
the one place the user imports the tree from. The physics (``sim_plant``) sits below both and
raises plain ``ValueError``; the layer that reads a configuration into it turns those into
:class:`ConfigError` naming the key.
"""
from __future__ import annotations

from enum import StrEnum

from drivers.errors import (
    STOP_EXIT_CODES,
    STOP_FAILED_EXIT,
    BackendError,
    BackendFault,
    ConfigError,
    HilError,
    StopKind,
    fault_kind,
)

__all__ = ["HilError", "ConfigError", "BackendError", "UnitError", "LimitError", "MeasurementError",
           "UnstableLoopError", "UserError", "SupervisorTripped", "BackendFault", "RunStopped",
           "STOP_EXIT_CODES", "STOP_FAILED_EXIT", "StopKind", "RunStatus", "fault_kind"]

# stdout closed before the command printed everything (``hil move ... | head -1``): 128 + SIGPIPE,
# what a shell reports for a process that SIGPIPE ended. The work is done by then (a run has ended,
# with its controlled stop where it needed one, and its record and files are written before
# anything is printed); only the printing stopped. Never 1, which says drive fault.
STDOUT_CLOSED_EXIT = 141


class RunStatus(StrEnum):
    """The status a run's record closes with (``hil.io.recorder``; written as its value): complete,
    tripped (a supervisor rule or a fault the backend reported), fault (a setpoint not delivered),
    aborted (Ctrl-C, an unexpected error), refused (before motion)."""
    RUNNING = "running"
    COMPLETE = "complete"
    TRIPPED = "tripped"
    FAULT = "fault"
    ABORTED = "aborted"
    REFUSED = "refused"


class UnitError(HilError, ValueError):
    """A quantity that does not parse, or whose dimension is not the one expected."""


class LimitError(HilError, ValueError):
    """A move that exceeds the axis limits; refused before any motion."""


class MeasurementError(HilError, ValueError):
    """A measurement file or record that cannot be read or used as it is."""


class UnstableLoopError(HilError, ValueError):
    """A loop configuration that the model shows unstable; refused before motion."""


class UserError(HilError):
    """A request that cannot be carried out as asked (an option out of range, a refused run)."""


class SupervisorTripped(HilError, RuntimeError):
    """Motion refused: the supervisor tripped and was not reset."""


class RunStopped(HilError):
    """A run that moved and did not complete (a sweep's run, a jog): the exit code says how it
    stopped (:data:`STOP_EXIT_CODES`)."""
    label = "stopped"

    def __init__(self, message: str, status: RunStatus, reason: str, stop: StopKind):
        super().__init__(message)
        self.status, self.reason, self.stop = status, reason, stop
        self.exit_code = stop.exit_code


