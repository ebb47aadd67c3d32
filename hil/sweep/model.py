"""The model a sweep runs on: a configuration's plant and controller, built once per process.

A sweep runs the same model hundreds of times, so the plant (``plant_from_config``) and the
controller are built once per configuration and process, keyed by :func:`fingerprint`, and the
chain's exact zero-order-hold discretization at the velocity period is computed then, once per
model, not per run (``Chain.discretize`` caches it). Workers forked from a process pool inherit the parent's
models; Dask workers build their own from the pickled configuration.

:func:`fingerprint` is also the first field of every run's key in ``runs.jsonl``: a short SHA-1
of the configuration's TOML text, so that runs of different models never mix in a store. Its
definition must not change, or old stores stop resuming.
"""
from __future__ import annotations

import hashlib

from drivers.control import controller_from_config
from hil.plant_config import plant_from_config

__all__ = ["fingerprint", "model_of"]


def fingerprint(cfg) -> str:
    """A short hash of a configuration's values: runs of different models never mix in a store."""
    return hashlib.sha1(cfg.to_toml().encode()).hexdigest()[:12]


_MODELS: dict = {}


def model_of(cfg):
    """(plant, controller) of a config, built once per process.

    Parameters
    ----------
    cfg : hil.config.Config
        The axis configuration.

    Returns
    -------
    tuple
        ``(plant, controller)``; the chain's discretization at the velocity period is in its
        cache. Shared by every run of this process: treat both as read-only.
    """
    fp = fingerprint(cfg)
    if fp not in _MODELS:
        plant = plant_from_config(cfg)
        ctrl = controller_from_config(cfg, plant)
        # the exact ZOH of the chain (a matrix exponential) once per model, not once per run: the
        # chain caches its discretization (sim_plant.chain), so this warms that cache
        plant.chain.discretize(ctrl.velocity_period)
        _MODELS[fp] = (plant, ctrl)
    return _MODELS[fp]
