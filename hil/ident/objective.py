"""The objective of the output-error fits: a config's weighted residual vector over a replay's
channels.

Each channel c is weighted by w_c = 1 / max(RMS of its residual under the replay's own config,
its noise floor, 1e-15) (set once, when the replay is made), so that no unit dominates; the
vector is the concatenation of r_c w_c over the channels, and least squares minimises
sum_c w_c^2 ||r_c||^2. ``n`` is its length.
"""
from __future__ import annotations

import numpy as np

__all__ = ["Objective"]


class Objective:
    """Weighted residual vector of a config (the replay's channels)."""

    def __init__(self, replay, weights: dict[str, float], n: int):
        self.replay = replay
        self.weights = weights
        self.n = n          # the vector's length

    def residuals(self, cfg) -> dict[str, np.ndarray]:
        return self.replay.residuals(cfg)

    def vector(self, res: dict) -> np.ndarray:
        return np.concatenate([res[c] * self.weights[c] for c in self.weights])
