"""Opening a backend of :mod:`drivers` for a configuration: the one place the runtime and the
commands build one (:func:`open_backend`), with the checks that belong above the drives: the
supervisor's windows of a real axis (:func:`require_supervision`), and the plant of a simulated
backend, read from the configuration here and handed to it (drivers never read a plant from a
configuration themselves: they sit below ``hil``)."""
from __future__ import annotations

from drivers import BACKENDS, REAL_BACKENDS, Backend, backend_class
from hil.errors import ConfigError
from hil.plant_config import plant_from_config

__all__ = ["open_backend", "require_supervision", "SUPERVISOR_WINDOWS"]

# the windows the supervisor (hil.supervisor) needs to stop a real axis that does not follow:
# following error, speed and travel
SUPERVISOR_WINDOWS = ("limits.following_error_table", "limits.speed", "limits.travel_min", "limits.travel_max")


def require_supervision(cfg, name: str) -> None:
    """Refuse a real backend (:data:`drivers.REAL_BACKENDS`) whose configuration lacks one of the
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
    ``with open_backend(cfg) as b:`` opens it and shuts it down (drivers.base) however the block
    ends. A configuration mistake raises :class:`hil.errors.ConfigError` here, before anything
    connects, and so is a real backend without the supervisor's windows (:func:`require_supervision`).
    ``can_log``: a file to trace the CAN bus into (``hil --can-log``), given to a backend on a CAN
    bus (``records_can``), ignored by the others; a backend that ``takes_plant`` (``"required"`` or
    ``"optional"``) is given the configuration's plant; ``options`` go to the backend's class."""
    name = name or cfg.get("backend.type", "sim")
    if name in BACKENDS:
        require_supervision(cfg, name)
    cls = backend_class(name)
    if can_log is not None and getattr(cls, "records_can", False):
        options["can_log"] = can_log
    takes = getattr(cls, "takes_plant", None)
    if takes and "plant" not in options:
        options["plant"] = _plant(cfg, required=takes == "required")
    return cls(cfg, **options)


def _plant(cfg, required: bool):
    """The configuration's plant; ``None`` where it has none and the backend can do without (a
    serial drive's config that only warms its host loop up with it)."""
    if required:
        return plant_from_config(cfg)
    try:
        return plant_from_config(cfg)
    except Exception:       # no plant model in this config: the backend runs without one
        return None
