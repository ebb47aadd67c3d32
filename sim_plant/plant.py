"""The simulated plant as the runtime sees it: a chain, its actuator, motor friction, sensors and
effects (built from a configuration by hil.plant_config).

Everything is in linear units on the load side: mass 1 is the motor's inertia reflected through
the pitch, and its torque enters as the force f = tau 2 pi / p (Eq. 12, 23).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim_plant.chain import Chain

__all__ = ["Plant", "Friction"]


@dataclass(frozen=True)
class Friction:
    """Dry friction on the motor, as forces on mass 1 (N): sliding level per direction, break-away
    level per direction, and a Stribeck velocity (m/s; 0 = no Stribeck curve)."""
    coulomb_pos: float = 0.0
    coulomb_neg: float = 0.0
    static_pos: float = 0.0
    static_neg: float = 0.0
    stribeck_velocity: float = 0.0

    def as_tuple(self) -> tuple:
        """The kernel's form: a tuple is a value, so compiled loops keep it in registers."""
        return (self.coulomb_pos, self.coulomb_neg, self.static_pos, self.static_neg, self.stribeck_velocity)

    def as_array(self) -> np.ndarray:
        return np.array([self.coulomb_pos, self.coulomb_neg, self.static_pos, self.static_neg,
                         self.stribeck_velocity], float)

    @property
    def active(self) -> bool:
        return max(self.coulomb_pos, self.coulomb_neg, self.static_pos, self.static_neg) > 0.0


@dataclass(frozen=True)
class Plant:
    """A chain with its actuator and sensors.

    ``force_gain``: force on mass 1 per unit of controller output (2 pi/p for a motor torque,
    the drive gain for a linear actuator). ``speed_scale``: controller speed units per m/s of
    mass 1 (2 pi/p: rad/s of the motor; 1 for a linear actuator). ``table``, ``tip``: 0-based
    mass indices of the linear encoder and the tool tip. ``effects``: kernel terms of the plant
    effects (see :mod:`sim_plant.effects`). ``endless``: the axis turns without end (a motor alone,
    a rotary table): no travel along which a force or a stiffness can change."""
    chain: Chain
    force_gain: float
    speed_scale: float
    friction: Friction = Friction()
    table: int = 1
    tip: int = 2
    table_resolution: float = 0.0
    motor_resolution: float = 0.0
    pitch: float | None = None
    current_loop_time_constant: float = 0.0
    effects: tuple = field(default=())
    endless: bool = False

    @property
    def n(self) -> int:
        return self.chain.n

    @property
    def total_mass(self) -> float:
        return float(sum(self.chain.m))

