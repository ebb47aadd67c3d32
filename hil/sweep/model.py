"""The model a sweep runs on: a configuration's plant and controller, built once per process.

A sweep runs the same model hundreds of times, so the plant (``plant_from_config``) and the
controller are built once per configuration and process, keyed by :func:`fingerprint`, and the
chain carries its exact zero-order-hold discretization at the velocity period (one matrix
exponential per model, not per run). Workers forked from a process pool inherit the parent's
models; Dask workers build their own from the pickled configuration.

:func:`fingerprint` is also the first field of every run's key in ``runs.jsonl``: a short SHA-1
of the configuration's TOML text, so that runs of different models never mix in a store. Its
definition must not change, or old stores stop resuming.
"""
from __future__ import annotations

import hashlib
from dataclasses import replace

from hil.control import controller_from_config
from hil.plant_config import plant_from_config
from sim_plant.chain import Chain

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
        ``(plant, controller)``; the plant's chain keeps its discretization at the velocity
        period. Shared by every run of this process: treat both as read-only.
    """
    fp = fingerprint(cfg)
    if fp not in _MODELS:
        plant = plant_from_config(cfg)
        ctrl = controller_from_config(cfg, plant)
        # the exact ZOH of the chain (a matrix exponential) once per model, not once per run
        plant = replace(plant, chain=_DiscretizedChain.of(plant.chain, ctrl.velocity_period))
        _MODELS[fp] = (plant, ctrl)
    return _MODELS[fp]


class _DiscretizedChain(Chain):
    """A chain that keeps its discretization at one sample time (the simulator asks for it every run)."""

    @classmethod
    def of(cls, chain: Chain, dt: float) -> "_DiscretizedChain":
        out = cls(chain.m, chain.k, chain.c, chain.c_ground)
        object.__setattr__(out, "_cache", {("all", dt): Chain.discretize(chain, dt, inputs="all")})
        return out

    def discretize(self, dt: float, inputs: str = "all"):
        cache = self.__dict__.setdefault("_cache", {})
        if (inputs, dt) not in cache:
            cache[(inputs, dt)] = Chain.discretize(self, dt, inputs=inputs)
        return cache[(inputs, dt)]
