"""The objective of the output-error fits: a config's weighted residual vector over a replay's
channels.

Each channel c is weighted by w_c = 1 / max(RMS of its residual under the replay's own config,
its noise floor, 1e-15) (set once, when the replay is made), so that no unit dominates; the
vector is the concatenation of r_c w_c over the channels, and least squares minimises
sum_c w_c^2 ||r_c||^2. ``n`` is its length.

:meth:`Objective.residuals_many` evaluates several configs at once (hil.ident.replay: their loops in
one compiled call), the same numbers as one by one; the environment variable ``HIL_BATCH=0``
selects the one-by-one path (:func:`batched`), the peer that benchmarks/bench_fleet.py times.
"""
from __future__ import annotations

import os

import numpy as np

__all__ = ["Objective", "MaskedObjective", "batched"]


def batched() -> bool:
    """Whether the fits evaluate their Jacobians and grids in one batched call (``HIL_BATCH``: not 0)."""
    return os.environ.get("HIL_BATCH", "1").strip() != "0"


class Objective:
    """Weighted residual vector of a config (the replay's channels)."""

    def __init__(self, replay, weights: dict[str, float], n: int):
        self.replay = replay
        self.weights = weights
        self.n = n          # the vector's length
        # the weighted squared error of configs whose whole error was simulated, by config_key: the
        # starts' grids meet the same points again (the fleet's tracked fit costs the grids the
        # chain's screening costed: 57 of a 6 s record's 1254 single runs), and the loop is deterministic
        self.known_costs: dict = {}

    def residuals(self, cfg) -> dict[str, np.ndarray]:
        return self.replay.residuals(cfg)

    def residuals_many(self, cfgs: list) -> list:
        """Per config its residuals, or the model's error (hil.ident.replay.Replay.residuals_many)."""
        return self.replay.residuals_many(cfgs)

    def vector(self, res: dict) -> np.ndarray:
        return np.concatenate([res[c] * self.weights[c] for c in self.weights])


class MaskedObjective:
    """An objective on some of its replay's samples only (the estimation half of a record): the whole
    record is simulated (the state at a piece's start is the record's), the fit sees the masked
    samples."""

    def __init__(self, obj, mask):
        self.obj, self.weights = obj, obj.weights
        self.sel = np.tile(mask, len(obj.weights))
        self.n = int(self.sel.sum())

    def residuals(self, cfg):
        return self.obj.residuals(cfg)

    def residuals_many(self, cfgs):
        return self.obj.residuals_many(cfgs)

    def vector(self, res):
        return self.obj.vector(res)[self.sel]
