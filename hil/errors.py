"""One error tree for the whole project (as python-control's ``control/exception.py`` and
python-can's ``can/exceptions.py`` have one).

Everything the project raises on purpose derives from :class:`HilError`; the command line
catches that root, prints one line and exits with the error's ``exit_code``:

- 2, a mistake the user can fix before anything moves (a configuration, a unit, a limit, a
  measurement file, an unstable loop, a refused request, a latched trip);
- 1, a drive that was lost or faulted (:class:`BackendFault`);
- 130, an interrupt (Ctrl-C; a ``KeyboardInterrupt``, not a HilError).

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

The library never raises the CLI's errors and the CLI adds no classes of its own. The physics
(``sim_plant``) sits below this module and raises plain ``ValueError``; the layer that reads
a configuration into it turns those into :class:`ConfigError` naming the key.
"""
from __future__ import annotations

__all__ = ["HilError", "ConfigError", "BackendError", "UnitError", "LimitError", "MeasurementError",
           "UnstableLoopError", "UserError", "SupervisorTripped", "BackendFault"]


class HilError(Exception):
    """Root of the project's errors. ``exit_code`` and ``label`` say how the CLI reports it."""
    exit_code = 2
    label = "error"


class ConfigError(HilError, ValueError):
    """A configuration key, value or file that cannot be used; the message names the key."""


class BackendError(ConfigError):
    """An unknown backend, or one that is not available in this installation."""


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


class BackendFault(HilError, RuntimeError):
    """The backend lost the drive, or the drive reported a fault. ``reason`` says which."""
    exit_code = 1
    label = "drive fault"

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason
