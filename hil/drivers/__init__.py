"""Backends behind one small contract (hil.drivers.base.Backend): the embedded simulated plant (the
default), CANopen CiA 402 drives, serial drives. Which one runs is chosen in configuration
(``backend.type``) or with ``--backend``, never in code."""
from __future__ import annotations

import importlib

from hil.drivers.base import LOOPS, Backend, BackendFault, Feedback, Setpoint
from hil.errors import BackendError

__all__ = ["BACKENDS", "open_backend", "Backend", "Feedback", "Setpoint", "LOOPS", "BackendFault", "BackendError"]

# backend type -> "module:class"; each class is built as cls(cfg, **options)
BACKENDS = {
    "sim": "hil.drivers.sim:SimulatedPlant",
    "canopen": "hil.drivers.canopen.backend:CanopenBackend",
    "serial": "hil.drivers.serial.backend:SerialBackend",
}


def open_backend(cfg, name: str | None = None, **options) -> Backend:
    """The backend named by ``name`` or by the config's ``backend.type``, built but not yet opened:
    ``with open_backend(cfg) as b:`` opens it and shuts it down (hil.drivers.base) however the block
    ends. A configuration mistake raises :class:`hil.errors.ConfigError` here, before anything
    connects."""
    name = name or cfg.get("backend.type", "sim")
    if name not in BACKENDS:
        raise BackendError(f"unknown backend {name!r} (known: {', '.join(BACKENDS)})")
    modname, _, clsname = BACKENDS[name].partition(":")
    try:
        mod = importlib.import_module(modname)
    except ModuleNotFoundError as exc:
        raise BackendError(f"backend {name!r} is not available in this installation ({exc})") from None
    return getattr(mod, clsname)(cfg, **options)
