"""Backends behind one small contract (hil.drivers.base.Backend): the embedded simulated plant (the
default), CANopen CiA 402 drives, serial drives. Which one runs is chosen in configuration
(``backend.type``) or with ``--backend``, never in code."""
from __future__ import annotations

import importlib

from hil.drivers.base import LOOPS, Backend, BackendFault, Feedback, Setpoint
from hil.errors import BackendError, ConfigError

__all__ = ["BACKENDS", "REAL_BACKENDS", "SUPERVISOR_WINDOWS", "open_backend", "require_supervision", "Backend",
           "Feedback", "Setpoint", "LOOPS", "BackendFault", "BackendError"]

# backend type -> "module:class"; each class is built as cls(cfg, **options)
BACKENDS = {
    "sim": "hil.drivers.sim:SimulatedPlant",
    "canopen": "hil.drivers.canopen.backend:CanopenBackend",
    "serial": "hil.drivers.serial.backend:SerialBackend",
}

# backends that move a real axis (a simulated drive behind them is still driven as a real one)
REAL_BACKENDS = ("canopen", "serial")
# the windows the supervisor (hil.supervisor) needs to stop a real axis that does not follow:
# following error, speed and travel
SUPERVISOR_WINDOWS = ("limits.following_error_table", "limits.speed", "limits.travel_min", "limits.travel_max")


def require_supervision(cfg, name: str) -> None:
    """Refuse a real backend (:data:`REAL_BACKENDS`) whose configuration lacks one of the
    supervisor's windows (:data:`SUPERVISOR_WINDOWS`), with one line naming the missing keys,
    unless it says ``supervisor.unsupervised = true``. Called before anything connects."""
    if name not in REAL_BACKENDS or cfg.get("supervisor.unsupervised", False):
        return
    missing = [k for k in SUPERVISOR_WINDOWS if cfg.get(k) is None]
    if missing:
        raise ConfigError(f"{cfg.source}: {', '.join(missing)}: missing; the {name} backend moves a real axis and "
                          f"the supervisor needs its windows to stop one that does not follow (docs/guide/safety.md); "
                          f"set them, or supervisor.unsupervised = true to run without")


def open_backend(cfg, name: str | None = None, can_log: str | None = None, **options) -> Backend:
    """The backend named by ``name`` or by the config's ``backend.type``, built but not yet opened:
    ``with open_backend(cfg) as b:`` opens it and shuts it down (hil.drivers.base) however the block
    ends. A configuration mistake raises :class:`hil.errors.ConfigError` here, before anything
    connects, and so is a real backend without the supervisor's windows (:func:`require_supervision`).
    ``can_log``: a file to trace the CAN bus into (``hil --can-log``), given to a backend on a CAN
    bus (``records_can``), ignored by the others; ``options`` go to the backend's class."""
    name = name or cfg.get("backend.type", "sim")
    if name not in BACKENDS:
        raise BackendError(f"unknown backend {name!r} (known: {', '.join(BACKENDS)})")
    require_supervision(cfg, name)
    modname, _, clsname = BACKENDS[name].partition(":")
    try:
        mod = importlib.import_module(modname)
    except ModuleNotFoundError as exc:
        raise BackendError(f"backend {name!r} is not available in this installation ({exc})") from None
    cls = getattr(mod, clsname)
    if can_log is not None and getattr(cls, "records_can", False):
        options["can_log"] = can_log
    return cls(cfg, **options)
