"""The context an effect's hooks see (sim_plant.effects.base: ``evidence``, ``starts``): the
replay's record and its residual before the fit, the model, and the identification's helpers
that simulate, so that the physics' plug-ins ask for them without importing this layer (the
starts' own helpers, ``grid_starts``, ``prefilter``, ``periodic_starts``, ``mode_targets``, are
added by hil.ident.starts.StartContext).

Conventions as the callers had them: ``v_cmd`` the commanded velocity (np.gradient of x_cmd on
the record's times), ``moving`` |v_cmd| > 2 % of max|v_cmd|; the force residual in the force
channel's units (motor torque on a rotary axis), None without a force channel; ``motion`` the
measured velocity and acceleration as the inverse model has them (hil.ident.joint: the motor's
position, else the table's, else the command, filtered forward and backward below
min(100 Hz, 0.2 / sample period) and differentiated, hil.ident.inverse.motion), record by record.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np

from hil.ident.inverse import motion
from hil.ident.scores import MIN_SCORE, bic_score
from hil.plant_config import candidate, configure
from hil.units import fmt_si

__all__ = ["EffectContext", "configured_value"]


def configured_value(cfg, effect: str, param: str) -> float:
    """The value ``cfg`` gives ``param`` of ``effect`` now (0 where it gives none; a setting named by
    a word, its number)."""
    v = cfg.get(f"effects.{effect}.{param}", 0.0) or 0.0
    return candidate(effect, cfg).param(param).number(v) if isinstance(v, str) else float(v)


class EffectContext:
    """What an effect's hooks read of one replay (see the module's docstring).

    Parameters
    ----------
    replay : hil.ident.replay.Replay
        The record replayed through the model.
    res0 : dict
        Its residuals before the fit (measured - simulated, per channel, SI).
    cfg : Config, optional
        The model's config the fit starts from (default: the replay's).
    scale : dict, optional
        The record's typical magnitudes (hil.ident.starts.record_scales).
    chan : str, optional
        The channel where the fit shows (evidence).
    base_modes : sequence of float
        The model's natural frequencies, Hz (evidence of an added mode).
    """

    def __init__(self, replay, res0: dict, cfg=None, scale: dict | None = None, chan: str | None = None,
                 base_modes=()):
        self.replay = replay
        self.res0 = res0
        self.cfg = cfg if cfg is not None else replay.cfg
        self.scale = scale or {}
        self.chan = chan
        self.base_modes = base_modes
        self.plant = replay.plant
        self.meas = replay.meas
        self.sample_period = replay.sample_period
        self.force_to_load = replay.force_to_load
        self.force_channel = replay.force_channel

    def configured(self, effect: str, param: str) -> float:
        """The value the model's config gives ``param`` of ``effect`` now (0 where it gives none)."""
        return configured_value(self.cfg, effect, param)

    def given(self, effect: str, param: str) -> float | None:
        """The value the model's config gives ``param`` of ``effect`` (a setting the user states: an
        encoder's signal period), None where it gives none."""
        if self.cfg.get(f"effects.{effect}.{param}") is None:
            return None
        return configured_value(self.cfg, effect, param)

    @property
    def rotary(self) -> bool:
        return self.cfg.rotary

    @property
    def velocity_period(self) -> float:
        return self.cfg["control.velocity_period"]

    @property
    def position_period(self) -> float:
        return self.cfg["control.position_period"]

    @property
    def position_feedback(self) -> str | None:
        return self.cfg.get("control.position_feedback")

    fmt_si = staticmethod(fmt_si)     # a figure in its engineering unit (hil.units: the physics imports none)

    def unit(self, channel: str) -> str:
        return self.replay.unit(channel)

    @cached_property
    def v_cmd(self) -> np.ndarray:
        return np.gradient(self.meas["x_cmd"], self.meas.t)

    @cached_property
    def moving(self) -> np.ndarray:
        v = self.v_cmd
        return np.abs(v) > 0.02 * max(float(np.max(np.abs(v))), 1e-12)

    @cached_property
    def motion(self) -> tuple[np.ndarray, np.ndarray]:
        """(v, a) of the measured motion (m/s, m/s^2; the module's definition), on the record's
        samples (several records: each its own, joined)."""
        va = []
        for p in getattr(self.replay, "parts", [self.replay]):
            x = next(p.meas[c] for c in ("x_motor", "x_table", "x_cmd") if c in p.meas)
            va.append(motion(p.meas.t, x, cutoff=min(100.0, 0.2 / p.sample_period)))
        return np.concatenate([v for v, _ in va]), np.concatenate([a for _, a in va])

    @cached_property
    def force_residual(self):
        return self.res0.get(self.force_channel) if self.force_channel else None

    @property
    def force_unit(self) -> str:
        return self.replay.unit(self.force_channel) if self.force_channel else ""

    @cached_property
    def controller(self):
        from drivers.control import controller_from_config
        return controller_from_config(self.cfg, self.plant)

    # --- helpers that simulate (the starts' helpers: hil.ident.starts.StartContext)

    def residuals_with(self, eff, values: dict) -> dict:
        """The replay's residuals with ``eff`` at ``values`` in the model (ValueError: not simulable)."""
        return self.replay.residuals(configure(eff, self.cfg, values))

    def cost(self, res: dict) -> float:
        """The weighted squared error of residuals ``res`` (the fit's objective)."""
        return float(np.sum(self.replay.objective.vector(res) ** 2))

    def pays(self, res_without: dict, res_with: dict, n_params: int) -> bool:
        """Whether ``n_params`` more parameters pay for the fall from ``res_without`` to ``res_with``
        (BIC score above MIN_SCORE, hil.ident.scores)."""
        chans = list(self.replay.objective.weights)
        return bic_score(res_without, res_with, chans, n_params, self.replay.noise) > MIN_SCORE
