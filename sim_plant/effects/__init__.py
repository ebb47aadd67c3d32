"""Physical effects as plug-ins with one interface (sim_plant.effects.base: :class:`Effect`,
its hooks, the :data:`CATALOGUE`), one module per family: friction (and force), transmission
(backlash, stiffness along the travel, lead error), delays, recording (skews, sensor offsets),
structure (an added mode, a mass change), motor (torque ripple), drive (the current loop's lag,
the torque constant), travel (the screw's thermal elongation, a cable carrier's force), flexible (a
flexible transmission at the drive: a 2-mass model), load_friction (a ball screw's preload friction
and its friction growing with the axial load), encoder (an encoder's interpolation error: a
reading, not a motion).

A new effect is one module: a registered subclass of :class:`Effect` (imported once, by the
package here or by its user) with its hooks; nothing in the identification names it.
``from sim_plant.effects import ...`` gives every name of the families.
"""
from __future__ import annotations

from sim_plant.effects.base import (
    ALIASES,
    CATALOGUE,
    ByActuator,
    Combination,
    Effect,
    Param,
    RecordEffect,
    effect,
    register,
)
from sim_plant.effects.delays import ActuatorDelay, FeedbackDelay
from sim_plant.effects.drive import CurrentLoopLag, TorqueConstant
from sim_plant.effects.encoder import EncoderError
from sim_plant.effects.flexible import RING_WINDOW, FlexibleTransmission, edges, ringing
from sim_plant.effects.friction import (
    AsymmetricFriction,
    ConstantForce,
    CoulombFriction,
    StribeckFriction,
    ViscousFriction,
)
from sim_plant.effects.load_friction import LoadDependentFriction
from sim_plant.effects.motor import TorqueRipple
from sim_plant.effects.recording import ChannelSkew, ForceOffset, PositionOffset, TipSkew
from sim_plant.effects.structure import CompliantMode, MassChange
from sim_plant.effects.transmission import Backlash, PitchError, StiffnessAlongTravel, StiffnessFixedFixed
from sim_plant.effects.travel import CableCarrier, ScrewElongation

__all__ = ["Param", "ByActuator", "Effect", "CATALOGUE", "ALIASES", "register", "effect", "Combination",
           "RecordEffect", "CoulombFriction", "ViscousFriction", "StribeckFriction", "AsymmetricFriction",
           "ConstantForce", "Backlash", "StiffnessAlongTravel", "StiffnessFixedFixed", "PitchError",
           "ActuatorDelay", "FeedbackDelay", "ChannelSkew", "TipSkew", "ForceOffset", "PositionOffset",
           "TorqueRipple", "CompliantMode", "MassChange", "CurrentLoopLag", "TorqueConstant", "ScrewElongation",
           "CableCarrier", "FlexibleTransmission", "LoadDependentFriction", "edges", "ringing", "RING_WINDOW",
           "EncoderError"]

# the order the catalogue has always listed its effects in (candidate lists, the diagnosis' ties,
# the docs' table); an effect registered later (a new family, a user's module) follows these
_ORDER = ("coulomb_friction", "viscous_friction", "stribeck_friction", "asymmetric_friction", "constant_force",
          "backlash", "actuator_delay", "feedback_delay", "channel_skew", "tip_skew", "force_offset",
          "position_offset", "stiffness_along_travel", "stiffness_along_travel_fixed_fixed", "pitch_error",
          "torque_ripple", "compliant_mode", "mass_change",
          # the drive engineer's checklist (issue 24, item 3)
          "current_loop_lag", "torque_constant", "screw_elongation", "cable_carrier", "load_dependent_friction",
          # the flexible transmission at the drive (issue 25)
          "flexible_transmission",
          # the checklist's encoder: its interpolation error (issue 24, item 3)
          "encoder_error")


def _in_order() -> None:
    rest = {n: e for n, e in CATALOGUE.items() if n not in _ORDER}
    listed = {n: CATALOGUE[n] for n in _ORDER}
    CATALOGUE.clear()
    CATALOGUE.update(listed)
    CATALOGUE.update(rest)


_in_order()
