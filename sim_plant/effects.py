"""Physical effects as plug-ins with one interface.

An :class:`Effect` has a catalogue name (used on the command line, in JSON and as the config
section ``[effects.<name>]``), a physical description, its parameters (with unit kind, bounds and
a starting guess, SI) and :meth:`Effect.apply`, its contribution to the plant in the loop: it
returns a new :class:`~sim_plant.plant.Plant` (changed masses, links or friction, or force terms
for the compiled loop, see sim_plant.kernel).

A configuration switches an effect on by giving its section, e.g.::

    [effects.constant_force]
    force = "-3.2 N"
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from . import kernel
from .plant import Friction, Plant

__all__ = ["Param", "Effect", "CATALOGUE", "register", "apply_effects", "effect"]


@dataclass(frozen=True)
class Param:
    """One parameter of an effect. ``kind`` is a unit kind of hil.units (or a callable of the
    config values, like the config schema's); bounds and guess are SI."""
    name: str
    kind: object
    lower: float
    upper: float
    guess: float
    doc: str


class Effect:
    """Base class of the catalogue's effects."""
    name: str = ""
    description: str = ""
    params: tuple[Param, ...] = ()

    def apply(self, plant: Plant, values: dict[str, float]) -> Plant:  # pragma: no cover - interface
        raise NotImplementedError

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)


CATALOGUE: dict[str, Effect] = {}


def register(cls):
    """Class decorator: add an effect to the catalogue under its name."""
    inst = cls()
    CATALOGUE[inst.name] = inst
    return cls


def effect(name: str) -> Effect:
    try:
        return CATALOGUE[name]
    except KeyError:
        raise KeyError(f"unknown effect {name!r} (known: {', '.join(sorted(CATALOGUE))})") from None


def _motor_force_kind(values):
    return "torque" if values.get("actuator.type", "rotary") == "rotary" else "force"


def _motor_damping_kind(values):
    return "rot_damping" if values.get("actuator.type", "rotary") == "rotary" else "damping"


def _to_linear(plant: Plant) -> float:
    """Motor-side torque (N m) to force on mass 1 (N): 2 pi / p; 1 for a linear actuator."""
    return plant.speed_scale


@register
class CoulombFriction(Effect):
    name = "coulomb_friction"
    description = "Coulomb (dry) friction on the motor, with stiction: tau_fc sign(v) (Eq. 11)"
    params = (Param("level", _motor_force_kind, 0.0, 1e4, 1.0, "sliding friction level on the motor"),)

    def apply(self, plant, values):
        f = values["level"] * _to_linear(plant)
        return dataclasses.replace(plant, friction=Friction(f, f, max(f, plant.friction.static_pos),
                                                            max(f, plant.friction.static_neg),
                                                            plant.friction.stribeck_velocity))


@register
class ViscousFriction(Effect):
    name = "viscous_friction"
    description = "viscous friction on the motor, c_m omega (Eq. 11), added to what the config has"
    params = (Param("coefficient", _motor_damping_kind, 0.0, 1e6, 1e-3, "viscous coefficient on the motor"),)

    def apply(self, plant, values):
        c = values["coefficient"] * _to_linear(plant) ** 2
        chain = plant.chain
        cg = (chain.c_ground[0] + c,) + tuple(chain.c_ground[1:])
        return dataclasses.replace(plant, chain=dataclasses.replace(chain, c_ground=cg))


@register
class ConstantForce(Effect):
    name = "constant_force"
    description = "a constant force on the moving masses (gravity on an inclined axis, a cable, an offset)"
    params = (Param("force", "force", -1e5, 1e5, 0.0, "force on the load side, + in +x"),)

    def apply(self, plant, values):
        return dataclasses.replace(plant, effects=plant.effects + ((kernel.CONSTANT_FORCE, (0.0, values["force"])),))


def _section_lookup(key: str):
    """Config fields of the ``effects.<name>.<param>`` keys."""
    from hil.config import Field
    parts = key.split(".")
    if len(parts) != 3 or parts[1] not in CATALOGUE:
        return None
    eff = CATALOGUE[parts[1]]
    for p in eff.params:
        if p.name == parts[2]:
            return Field(p.kind, f"{eff.name}: {p.doc}", default=None, required=False)
    return None


def apply_effects(plant: Plant, cfg) -> Plant:
    """The plant with every effect the config switches on (sections ``[effects.<name>]``)."""
    names = []
    for key in cfg.keys():
        if key.startswith("effects.") and cfg.values[key] is not None:
            name = key.split(".")[1]
            if name not in names:
                names.append(name)
    for name in names:
        eff = effect(name)
        sect = cfg.section(f"effects.{name}")
        values = {p.name: sect.get(p.name, p.guess) for p in eff.params}
        for p in eff.params:
            v = values[p.name]
            if not (p.lower <= v <= p.upper) or (isinstance(v, float) and math.isnan(v)):
                from hil.config import ConfigError
                raise ConfigError(f"{cfg.source}: effects.{name}.{p.name}: expected {p.lower:g} .. {p.upper:g}, got {v:g}")
        plant = eff.apply(plant, values)
    return plant


def _register_config():
    from hil.config import register_section
    register_section("effects", _section_lookup)


_register_config()
