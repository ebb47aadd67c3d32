"""Backends behind one small contract (drivers.base.Backend): the embedded simulated plant (the
default), CANopen CiA 402 drives, serial drives. Which one runs is chosen in configuration
(``backend.type``) or with ``--backend``, never in code; ``hil.backends.open_backend`` builds it.

The middle of the three top-level packages: ``drivers`` imports ``sim_plant`` (the physics) and
never ``hil`` (the runtime and the tools on top); what a backend needs of a configuration it reads
through the config object handed to it, and the simulated ones are handed their plant."""
from __future__ import annotations

import importlib

from drivers.base import LOOPS, Backend, BackendFault, Fault, Feedback, Setpoint
from drivers.errors import BackendError

__all__ = ["BACKENDS", "REAL_BACKENDS", "backend_class", "Backend", "Feedback", "Fault", "Setpoint", "LOOPS", "BackendFault",
           "BackendError"]

# backend type -> "module:class"; each class is built as cls(cfg, **options) (with plant= where the
# class says ``takes_plant``)
BACKENDS = {
    "sim": "drivers.sim:SimulatedPlant",
    "canopen": "drivers.canopen.backend:CanopenBackend",
    "serial": "drivers.serial.backend:SerialBackend",
}

# backends that move a real axis (a simulated drive behind them is still driven as a real one)
REAL_BACKENDS = ("canopen", "serial")


def backend_class(name: str) -> type[Backend]:
    """The class of the backend ``name`` (:data:`BACKENDS`), imported now; :class:`BackendError`
    for an unknown name or one this installation cannot import."""
    if name not in BACKENDS:
        raise BackendError(f"unknown backend {name!r} (known: {', '.join(BACKENDS)})")
    modname, _, clsname = BACKENDS[name].partition(":")
    try:
        mod = importlib.import_module(modname)
    except ModuleNotFoundError as exc:
        raise BackendError(f"backend {name!r} is not available in this installation ({exc})") from None
    return getattr(mod, clsname)
