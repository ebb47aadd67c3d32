"""Physical effects as plug-ins with one interface.

An :class:`Effect` has a catalogue name (used on the command line, in JSON and as the config
section ``[effects.<name>]``), a physical description, its parameters (with unit kind, bounds and
a starting guess, SI) and :meth:`Effect.apply`, its contribution to the plant in the loop: it
returns a new :class:`~hil.sim_plant.plant.Plant` (changed masses, links or friction, or force terms
for the compiled loop, see hil.sim_plant.kernel).

A configuration switches an effect on by giving its section, e.g.::

    [effects.constant_force]
    force = "-3.2 N"

(read by hil.plant_config, which also holds the ``parameter:<key>`` effects that re-identify a
config value, and switches an effect on in a configuration: ``hil.plant_config.configure``). Some parameters are settings, not strengths (``Param.fit`` False: where a
stiffness is given along the travel): a fit holds them. An effect whose error is not convex in
its parameter (a delay) gives a grid of starting values over the physically possible range
(:meth:`Effect.grid`). A :class:`RecordEffect` is an artefact of the recording (a channel's time
skew): it leaves the plant alone and acts on the recorded channels. Old names keep working
(:data:`ALIASES`: ``time_delay`` is ``actuator_delay``). The physics here knows no configuration: a parameter it cannot take raises
ValueError, which the config layer reports as a configuration error naming the key.
"""
from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

from hil.sim_plant import kernel
from hil.sim_plant.chain import Chain
from hil.sim_plant.plant import Friction, Plant

__all__ = ["Param", "ByActuator", "Effect", "CATALOGUE", "ALIASES", "register", "effect", "Combination",
           "RecordEffect"]


@dataclass(frozen=True)
class ByActuator:
    """A parameter's unit kind that depends on the actuator: ``rotary`` where a motor turns a
    screw (a torque), ``linear`` on a linear motor (a force)."""
    rotary: str
    linear: str


@dataclass(frozen=True)
class Param:
    """One parameter of an effect. ``kind`` is a unit kind of hil.units, or a :class:`ByActuator`
    (:meth:`kind_for` says which); bounds and guess are SI."""
    name: str
    kind: str | ByActuator
    lower: float
    upper: float
    guess: float
    doc: str
    fit: bool = True       # False: a setting of the effect (a place, not a strength), held during a fit

    def kind_for(self, rotary: bool) -> str:
        """The unit kind on a rotary (motor and screw) or a linear actuator."""
        if isinstance(self.kind, ByActuator):
            return self.kind.rotary if rotary else self.kind.linear
        return self.kind


class Effect(ABC):
    """Base class of the catalogue's effects."""
    name: str = ""
    description: str = ""
    params: tuple[Param, ...] = ()

    @abstractmethod
    def apply(self, plant: Plant, values: dict[str, float]) -> Plant:
        """The plant with this effect's contribution (new masses, links, friction or force terms)."""

    nests: tuple = ()          # simpler catalogue effects this one contains (ranking prefers those)
    # combinations of simpler catalogue effects that can do (part of) this effect's work, e.g.
    # asymmetric Coulomb levels = symmetric Coulomb + a constant force while moving: ``diagnose``
    # fits each combination jointly and prefers it when it explains as much by the same BIC score
    mimicked_by: tuple = ()
    periodic: bool = False     # parameters include a period along the travel

    @property
    def fitted_params(self) -> tuple[Param, ...]:
        """The parameters a fit moves (the others are settings: where, not how strong)."""
        return tuple(p for p in self.params if p.fit)

    def applicable(self, plant: Plant) -> bool:
        """Whether the effect can act on this plant (e.g. backlash needs a transmission link)."""
        return True

    def guess(self, plant: Plant, scale: dict) -> dict[str, float]:
        """Starting values for a fit; ``scale`` gives typical magnitudes of the record (force N,
        speed m/s, period s)."""
        return {p.name: p.guess for p in self.params}

    def grid(self, plant: Plant, ctrl, scale: dict) -> list[dict[str, float]]:
        """Starting values on a grid over the physically possible range, for parameters in which
        the error is not convex (a delay): the fitter simulates each point once and refines from
        the best (hil.ident.starts). Empty: the effect's guess and its regressions suffice.
        ``ctrl``: the controller settings (hil.control.ControllerSettings: its periods)."""
        return []

    def _need_link(self, plant: Plant) -> None:
        if plant.n < 2:
            raise ValueError(f"{self.name}: needs a chain of at least 2 masses (a transmission link)")

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)


CATALOGUE: dict[str, Effect] = {}
# old names that keep working (config sections, command line, candidate lists): name -> catalogue name
ALIASES: dict[str, str] = {"time_delay": "actuator_delay"}


def register(cls):
    """Class decorator: add an effect to the catalogue under its name."""
    inst = cls()
    CATALOGUE[inst.name] = inst
    return cls


def effect(name: str) -> Effect:
    try:
        return CATALOGUE[ALIASES.get(name, name)]
    except KeyError:
        import difflib
        close = difflib.get_close_matches(name, list(CATALOGUE) + list(ALIASES), n=1, cutoff=0.6)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise KeyError(f"unknown effect {name!r} ({hint}known: {', '.join(sorted(CATALOGUE))})") from None


# the kinds of a force and of a damping acting on the motor
_motor_force_kind = ByActuator("torque", "force")
_motor_damping_kind = ByActuator("rot_damping", "damping")


def _to_linear(plant: Plant) -> float:
    """Motor-side torque (N m) to force on mass 1 (N): 2 pi / p; 1 for a linear actuator."""
    return plant.speed_scale


def _level_guess(plant: Plant, fallback: float) -> float:
    f = max(plant.friction.coulomb_pos, plant.friction.coulomb_neg)
    return f / _to_linear(plant) if f > 0 else fallback


@register
class CoulombFriction(Effect):
    name = "coulomb_friction"
    description = "Coulomb (dry) friction on the motor, with stiction: tau_fc sign(v) (Eq. 11)"
    params = (Param("level", _motor_force_kind, 0.0, 1e4, 1.0, "sliding friction level on the motor"),)
    nests = ()

    def apply(self, plant, values):
        f = values["level"] * _to_linear(plant)
        return dataclasses.replace(plant, friction=Friction(f, f, f, f, 0.0))

    def guess(self, plant, scale):
        return {"level": scale.get("force", 1.0) / _to_linear(plant)}


@register
class ViscousFriction(Effect):
    name = "viscous_friction"
    description = "viscous friction on the motor, c_m omega (Eq. 11), added to what the config has"
    params = (Param("coefficient", _motor_damping_kind, -1e6, 1e6, 1e-3, "extra viscous coefficient on the motor"),)

    def apply(self, plant, values):
        c = values["coefficient"] * _to_linear(plant) ** 2
        chain = plant.chain
        cg = (chain.c_ground[0] + c,) + tuple(chain.c_ground[1:])
        return dataclasses.replace(plant, chain=dataclasses.replace(chain, c_ground=cg))

    def guess(self, plant, scale):
        return {"coefficient": scale.get("force", 1.0) / max(scale.get("speed", 1.0), 1e-9) / _to_linear(plant) ** 2}


@register
class StribeckFriction(Effect):
    name = "stribeck_friction"
    description = ("dry friction with a Stribeck curve: break-away level at rest falling to the sliding "
                   "level as exp(-(v/v_s)^2)")
    params = (Param("level", _motor_force_kind, 0.0, 1e4, 1.0, "sliding (Coulomb) level on the motor"),
              Param("static", _motor_force_kind, 0.0, 1e4, 1.5, "break-away level at rest"),
              Param("velocity", "speed", 1e-5, 1.0, 2e-3, "Stribeck velocity (load side)"))
    nests = ("coulomb_friction",)

    def apply(self, plant, values):
        r = _to_linear(plant)
        fc, fs = values["level"] * r, max(values["static"], values["level"]) * r
        return dataclasses.replace(plant, friction=Friction(fc, fc, fs, fs, values["velocity"]))

    def guess(self, plant, scale):
        f0 = _level_guess(plant, 0.0)     # the model's Coulomb level, when it has one
        f = f0 or scale.get("force", 1.0) / _to_linear(plant)
        return {"level": f, "static": (1.1 if f0 else 1.5) * f,
                "velocity": max(0.05 * scale.get("speed", 0.04), 1e-4)}


@register
class AsymmetricFriction(Effect):
    name = "asymmetric_friction"
    description = ("friction with different levels per direction: Coulomb and viscous for v > 0 and v < 0 "
                   "(replaces the config's motor friction)")
    params = (Param("level_pos", _motor_force_kind, 0.0, 1e4, 1.0, "Coulomb level moving in +x"),
              Param("level_neg", _motor_force_kind, 0.0, 1e4, 1.0, "Coulomb level moving in -x"),
              Param("viscous_pos", _motor_damping_kind, 0.0, 1e7, 0.0, "viscous coefficient moving in +x"),
              Param("viscous_neg", _motor_damping_kind, 0.0, 1e7, 0.0, "viscous coefficient moving in -x"))
    nests = ("coulomb_friction", "viscous_friction", "constant_force")
    # while moving, (Fc+ + Fc-)/2 sign(v) + (Fc+ - Fc-)/2 is Coulomb friction plus a constant force
    mimicked_by = (("coulomb_friction", "constant_force"),)

    def apply(self, plant, values):
        r = _to_linear(plant)
        fp, fn = values["level_pos"] * r, values["level_neg"] * r
        chain = plant.chain
        cg = (0.0,) + tuple(chain.c_ground[1:])
        return dataclasses.replace(
            plant, chain=dataclasses.replace(chain, c_ground=cg), friction=Friction(fp, fn, fp, fn, 0.0),
            effects=plant.effects + ((kernel.VISCOUS_ASYMMETRIC, (0.0, values["viscous_pos"] * r * r,
                                                                   values["viscous_neg"] * r * r)),))

    def guess(self, plant, scale):
        r = _to_linear(plant)
        f = _level_guess(plant, scale.get("force", 1.0) / r)
        c = plant.chain.c_ground[0] / (r * r)
        return {"level_pos": f, "level_neg": f, "viscous_pos": c, "viscous_neg": c}


@register
class ConstantForce(Effect):
    name = "constant_force"
    description = "a constant force on the moving masses (gravity on an inclined axis, a cable, an offset)"
    params = (Param("force", "force", -1e5, 1e5, 0.0, "force on the load side, + in +x"),)

    def apply(self, plant, values):
        return dataclasses.replace(plant, effects=plant.effects + ((kernel.CONSTANT_FORCE, (0.0, values["force"])),))

    def guess(self, plant, scale):
        return {"force": 0.1 * scale.get("force", 1.0)}


@register
class Backlash(Effect):
    name = "backlash"
    description = "backlash: a dead zone of +-gap/2 in the transmission between motor and table (link 1)"
    params = (Param("gap", "length", 0.0, 2e-3, 5e-6, "total play of the transmission"),)

    def applicable(self, plant):
        return plant.n >= 2

    def apply(self, plant, values):
        self._need_link(plant)
        return dataclasses.replace(plant, effects=plant.effects + (
            (kernel.BACKLASH, (0.0, 0.5 * values["gap"], plant.chain.k[0], plant.chain.c[0])),))


def _delay_grid(lo: float, hi: float, step: float) -> list[float]:
    """Delays from ``lo`` to ``hi``: whole ``step``s up to 4, then about 1.4 times apart (the error
    is not convex in a delay: a grid finds its basin, a local fit refines it)."""
    out, d = [], lo
    while d < hi * (1 + 1e-9):
        out.append(d)
        d = d + step if d < 4 * step - 1e-15 else d * 1.4
    if out[-1] < hi * (1 - 1e-9):
        out.append(hi)
    return out


@register
class ActuatorDelay(Effect):
    """The drive's computation and transport: the torque (force) command reaches the motor late.
    Also known by its old name ``time_delay`` (config section ``[effects.time_delay]``)."""
    name = "actuator_delay"
    description = ("the torque (force) command reaches the motor late: a drive's computation and transport "
                   "delay, from one velocity-loop period upward")
    params = (Param("delay", "time", 0.0, 0.05, 5e-4, "delay of the command reaching the motor"),)
    MAX = 0.02           # the grid's upper end, s: a drive delays by a few velocity periods, a fieldbus by ms

    def apply(self, plant, values):
        return dataclasses.replace(plant, effects=plant.effects + ((kernel.TIME_DELAY, (values["delay"],)),))

    def guess(self, plant, scale):
        return {"delay": 0.25 * scale.get("period", 2e-3)}

    def grid(self, plant, ctrl, scale):
        tv = ctrl.velocity_period
        return [{"delay": d} for d in _delay_grid(tv, self.MAX, tv)]


@register
class FeedbackDelay(Effect):
    """The position the position loop uses (table or motor, as the config says) is late: a linear
    scale read over a fieldbus. Only the loop's feedback: the recorded positions are the true ones."""
    name = "feedback_delay"
    description = ("the position the position loop uses is late (a scale read over a fieldbus): from a "
                   "fraction of a position period to several; the recorded positions are the true ones")
    params = (Param("delay", "time", 0.0, 0.05, 1e-3, "delay of the position loop's feedback"),)
    MAX_PERIODS = 5      # the grid's upper end, position periods

    def apply(self, plant, values):
        return dataclasses.replace(plant, effects=plant.effects + ((kernel.FEEDBACK_DELAY, (values["delay"],)),))

    def guess(self, plant, scale):
        return {"delay": 0.25 * scale.get("period", 4e-3)}

    def grid(self, plant, ctrl, scale):
        tp = ctrl.position_period
        return [{"delay": d} for d in _delay_grid(tp / 8, min(self.MAX_PERIODS * tp, 0.05), tp / 8)]


class RecordEffect(Effect):
    """An artefact of the recording, not of the plant: it acts on the channels as recorded
    (hil.ident.replay applies it to the simulated channels read back, hil.ident.synth to the
    record it writes), never on the loop. A configuration gives it in ``[measurement]`` (the key
    ``measurement.<name>``, the value of its one parameter), not among the plant's effects."""
    channels: tuple = ()
    section = "measurement"

    def apply(self, plant, values):
        return plant

    @abstractmethod
    def apply_record(self, t, channels: dict, values: dict[str, float]) -> dict:
        """The recorded channels (SI, on the times ``t``) with the artefact: a new dict."""


def _skewed(t, y, skew):
    """``y`` recorded ``skew`` seconds late: y(t - skew), linear between samples, held at the ends."""
    import numpy as np
    return np.interp(t - skew, t, y)


@register
class ChannelSkew(RecordEffect):
    """The force channel (torque, force or command) is logged out of step with the positions."""
    name = "channel_skew"
    description = ("a logging artefact, not physics: the force (torque) channel is recorded out of step with "
                   "the positions, by a signed skew (+: recorded late)")
    params = (Param("skew", "time", -0.2, 0.2, 0.0, "time skew of the force channel against the positions"),)
    channels = ("torque", "force", "command")
    MAX_SAMPLES = 12     # the grid's range, samples either way

    def apply_record(self, t, channels, values):
        out = dict(channels)
        for c in self.channels:
            if c in out:
                out[c] = _skewed(t, out[c], values["skew"])
        return out

    def guess(self, plant, scale):
        return {"skew": 0.0}

    def grid(self, plant, ctrl, scale):
        ts = scale.get("period", ctrl.position_period)
        n = self.MAX_SAMPLES
        return [{"skew": 0.5 * i * ts} for i in range(-2 * n, 2 * n + 1)]


@register
class TipSkew(ChannelSkew):
    """The tool-tip channel is logged by another instrument (an interferometer with its own clock)."""
    name = "tip_skew"
    description = ("a logging artefact, not physics: the tool-tip channel (another instrument) is recorded out "
                   "of step with the drive's channels, by a signed skew (+: recorded late)")
    params = (Param("skew", "time", -0.2, 0.2, 0.0, "time skew of the x_tip channel against the others"),)
    channels = ("x_tip",)

    def applicable(self, plant):
        return plant.tip != plant.table


@register
class ForceOffset(RecordEffect):
    """A constant offset of the force sensor (a current or torque reading, a load cell): the
    recorded torque (rotary) or force (linear) reads ``offset`` more than the actuator delivered.
    A sensor offset, not a load: it changes the recorded channel alone, the same at standstill
    and in motion, and never the positions; a constant load force (``constant_force``) moves the
    axis, and on a P-I loop the torque shows it only as the integrator takes it up (not while dry
    friction holds the axis at rest)."""
    name = "force_offset"
    description = ("a sensor offset, not a load: the force (torque, current) channel reads a constant offset, the "
                   "same at rest and in motion, and the positions are unchanged")
    params = (Param("offset", _motor_force_kind, -1e5, 1e5, 0.0, "offset of the recorded torque (force) channel"),)
    channels = ("torque", "force")

    def apply_record(self, t, channels, values):
        out = dict(channels)
        for c in self.channels:
            if c in out:
                out[c] = out[c] + values["offset"]
        return out

    def guess(self, plant, scale):
        # (linear in the offset: any start of the residual's size converges; 0 gives no scale)
        return {"offset": 0.1 * scale.get("force", 1.0) / _to_linear(plant)}


@register
class PositionOffset(RecordEffect):
    """A constant offset of the tool-tip channel (another instrument: a laser interferometer or
    a probe whose zero is not the scale's): a sensor offset, not a motion of the tip."""
    name = "position_offset"
    description = ("a sensor offset, not a motion: the tool-tip position channel (another instrument) reads a "
                   "constant offset from the drive's positions")
    params = (Param("offset", "length", -1.0, 1.0, 0.0, "offset of the recorded x_tip channel"),)
    channels = ("x_tip",)

    def applicable(self, plant):
        return plant.tip != plant.table

    def apply_record(self, t, channels, values):
        out = dict(channels)
        if "x_tip" in out:
            out["x_tip"] = out["x_tip"] + values["offset"]
        return out

    def guess(self, plant, scale):
        return {"offset": 1e-6}


@register
class StiffnessAlongTravel(Effect):
    """The transmission stiffness k1 changes with the nut position: the screw's axial compliance
    grows with the length of screw between the fixed bearing and the nut (EA/L, Eq. 20, for a
    screw held at one end), in series with the compliances that do not move (motor shaft,
    coupling, bearings, nut, nut-table link; Eq. 21). Its compliance 1/k1 is then linear in the
    nut position: the effect is fitted as k1 at the two ends of a stretch of travel
    (``x_start``, ``x_end``: settings, by default the stroke the record covers), and the kernel
    evaluates k1(x_nut) = 1 / (1/k_start + (x - x_start)/(x_end - x_start) (1/k_end - 1/k_start))
    every step (hil.sim_plant.components.k1_along_travel)."""
    name = "stiffness_along_travel"
    description = ("the transmission stiffness k1 changes with the nut position (screw held at one end: EA/L "
                   "in series with the fixed compliances), given at both ends of the travel")
    params = (Param("k_start", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut at x_start"),
              Param("k_end", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut at x_end"),
              Param("x_start", "length", -1e3, 1e3, 0.0, "one end of the travel (a setting, not fitted)", fit=False),
              Param("x_end", "length", -1e3, 1e3, 0.1, "the other end of the travel (a setting, not fitted)",
                    fit=False))

    def applicable(self, plant):
        return plant.n >= 2

    def apply(self, plant, values):
        self._need_link(plant)
        x0, x1 = values["x_start"], values["x_end"]
        if not x1 > x0:
            raise ValueError(f"{self.name}: x_end must lie beyond x_start (got {x0:g} .. {x1:g} m)")
        c0, c1 = 1.0 / values["k_start"], 1.0 / values["k_end"]
        return dataclasses.replace(plant, effects=plant.effects + (
            (kernel.STIFFNESS_ALONG_TRAVEL, (0.0, plant.chain.k[0], x0, x1, c0, 0.5 * (c0 + c1), c1)),))

    def guess(self, plant, scale):
        k = plant.chain.k[0] if plant.n >= 2 else 5e7
        lo, hi = scale.get("x_min", 0.0), scale.get("x_max", 0.1)
        if not hi > lo:
            hi = lo + 1e-3
        return {"k_start": k, "k_end": k, "x_start": lo, "x_end": hi}


@register
class StiffnessFixedFixed(StiffnessAlongTravel):
    """k1 along the travel of a screw held axially at both ends (fixed-fixed): the nut at ``a`` from
    one bearing of ``L`` sees the two screw lengths in parallel, E A L / (a (L - a)) (Eq. 13 with
    rigid bearings, hil.sim_plant.components.k_screw_fixed_fixed), least in the middle. Its compliance
    a (L - a) / (E A L), in series with the fixed ones, is quadratic in the nut position: fitted as
    k1 at both ends of the stretch and midway, wherever the bearings sit. A screw held at one end
    is the special case of a compliance linear along the travel (``stiffness_along_travel``)."""
    name = "stiffness_along_travel_fixed_fixed"
    description = ("the transmission stiffness k1 changes with the nut position as for a screw held at both ends "
                   "(softest between the bearings), given at both ends of the travel and midway")
    params = (Param("k_start", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut at x_start"),
              Param("k_middle", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut midway between x_start and x_end"),
              Param("k_end", "stiffness", 1e3, 1e12, 5e7, "k1 with the nut at x_end"),
              Param("x_start", "length", -1e3, 1e3, 0.0, "one end of the travel (a setting, not fitted)", fit=False),
              Param("x_end", "length", -1e3, 1e3, 0.1, "the other end of the travel (a setting, not fitted)",
                    fit=False))
    nests = ("stiffness_along_travel",)

    def apply(self, plant, values):
        self._need_link(plant)
        x0, x1 = values["x_start"], values["x_end"]
        if not x1 > x0:
            raise ValueError(f"{self.name}: x_end must lie beyond x_start (got {x0:g} .. {x1:g} m)")
        return dataclasses.replace(plant, effects=plant.effects + (
            (kernel.STIFFNESS_ALONG_TRAVEL, (0.0, plant.chain.k[0], x0, x1, 1.0 / values["k_start"],
                                             1.0 / values["k_middle"], 1.0 / values["k_end"])),))

    def guess(self, plant, scale):
        g = super().guess(plant, scale)
        return dict(g, k_middle=g["k_start"])


@register
class PitchError(Effect):
    name = "pitch_error"
    description = ("periodic lead error of the screw: the nut sits at x1 + a sin(2 pi x1 / period + phase), "
                   "seen as x_motor - x_table periodic in position")
    params = (Param("amplitude", "length", 0.0, 1e-3, 1e-6, "amplitude of the lead error"),
              Param("period", "length", 1e-4, 1.0, 0.01, "period of the error along the travel (often the pitch)"),
              Param("phase", "dimensionless", -4 * math.pi, 4 * math.pi, 0.0, "phase at x1 = 0 (rad)"))
    periodic = True

    def applicable(self, plant):
        return plant.n >= 2

    def apply(self, plant, values):
        self._need_link(plant)
        return dataclasses.replace(plant, effects=plant.effects + (
            (kernel.PITCH_ERROR, (0.0, values["amplitude"], values["period"], values["phase"], plant.chain.k[0])),))

    def guess(self, plant, scale):
        return {"amplitude": 1e-6, "period": plant.pitch or 0.01, "phase": 0.0}


@register
class TorqueRipple(Effect):
    name = "torque_ripple"
    description = "cogging / torque ripple: a motor torque periodic in the motor angle"
    params = (Param("amplitude", _motor_force_kind, 0.0, 1e4, 0.1, "ripple amplitude on the motor"),
              Param("period", "length", 1e-5, 1.0, 1e-3, "period along the travel (pitch / ripples per turn)"),
              Param("phase", "dimensionless", -4 * math.pi, 4 * math.pi, 0.0, "phase at x1 = 0 (rad)"))
    periodic = True

    def apply(self, plant, values):
        return dataclasses.replace(plant, effects=plant.effects + (
            (kernel.TORQUE_RIPPLE, (values["amplitude"] * _to_linear(plant), values["period"], values["phase"])),))

    def guess(self, plant, scale):
        return {"amplitude": 0.05 * scale.get("force", 1.0) / _to_linear(plant),
                "period": (plant.pitch or 0.01) / 6, "phase": 0.0}


@register
class CompliantMode(Effect):
    name = "compliant_mode"
    description = ("an extra mass-spring-damper at the tool tip (a structural mode the model lacks); the "
                   "new mass becomes the tool tip")
    params = (Param("mass", "mass", 1e-3, 1e4, 5.0, "modal mass of the extra mode"),
              Param("frequency", "frequency", 0.5, 1e3, 20.0, "natural frequency of the extra mode (Hz)"),
              Param("damping_ratio", "dimensionless", 1e-4, 1.0, 0.02, "its damping ratio"))

    def apply(self, plant, values):
        m, f, z = values["mass"], values["frequency"], values["damping_ratio"]
        w = 2 * math.pi * f
        k, c = m * w * w, 2 * z * m * w
        ch = plant.chain
        chain = Chain(ch.m + (m,), ch.k + (k,), ch.c + (c,), ch.c_ground + (0.0,))
        return dataclasses.replace(plant, chain=chain, tip=ch.n)


@register
class MassChange(Effect):
    name = "mass_change"
    description = "a change of the moving mass (payload, workpiece) on the table"
    params = (Param("mass", "mass", -1e4, 1e5, 0.0, "mass added to the table (negative: removed)"),)

    def apply(self, plant, values):
        ch = plant.chain
        m = list(ch.m)
        m[plant.table] += values["mass"]
        if m[plant.table] <= 0:
            raise ValueError(f"mass_change: the table mass would be {m[plant.table]:g} kg")
        return dataclasses.replace(plant, chain=dataclasses.replace(ch, m=tuple(m)))

    def guess(self, plant, scale):
        return {"mass": 0.05 * plant.chain.m[plant.table]}


class Combination(Effect):
    """Several effects fitted together: parameters named ``<effect>.<param>``; the name is the
    members' names joined by ``+`` (``coulomb_friction+constant_force``)."""

    def __init__(self, members, names=None):
        self.members = tuple(members)
        # the names as the user wrote them (an old name such as time_delay keeps its parameters' prefix)
        self.names = tuple(names) if names else tuple(m.name for m in self.members)
        self.name = "+".join(self.names)
        self.description = " and ".join(m.description for m in self.members)
        self.params = tuple(dataclasses.replace(p, name=f"{n}.{p.name}") for n, m in zip(self.names, self.members)
                            for p in m.params)
        self.periodic = any(m.periodic for m in self.members)

    def split(self, values: dict) -> list[dict]:
        return [{p.name: values[f"{n}.{p.name}"] for p in m.params} for n, m in zip(self.names, self.members)]

    def applicable(self, plant):
        return all(m.applicable(plant) for m in self.members)

    def apply(self, plant, values):
        for m, v in zip(self.members, self.split(values)):
            plant = m.apply(plant, v)
        return plant

    def guess(self, plant, scale):
        return {f"{n}.{k}": v for n, m in zip(self.names, self.members) for k, v in m.guess(plant, scale).items()}

