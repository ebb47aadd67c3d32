"""The base of the effects' plug-ins: :class:`Param`, :class:`ByActuator`, :class:`Effect`,
:class:`RecordEffect`, :class:`Combination`, the :data:`CATALOGUE` and :func:`register`.

An :class:`Effect` has a catalogue name (used on the command line, in JSON and as the config
section ``[effects.<name>]``), a physical description, its parameters (with unit kind, bounds and
a starting guess, SI) and :meth:`Effect.apply`, its contribution to the plant in the loop: it
returns a new :class:`~sim_plant.plant.Plant` (changed masses, links or friction, or force terms
for the compiled loop, see sim_plant.kernel).

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

A new effect is one module (and its test): a subclass of :class:`Effect` decorated with
:func:`register`; the identification asks the effect itself through its hooks, never its name:

* :meth:`Effect.evidence` ``(ctx, values) -> str``: what in the residual before the fit points at
  the effect, as the head of its evidence line ("" : the fall of the error alone);
* :meth:`Effect.starts` ``(ctx, guess) -> list[dict]``: the starting values of its fit (the base:
  the points of :meth:`Effect.grid` costed by ``ctx.grid_starts``, else
  :meth:`Effect.regression_start` and the guess);
* :meth:`Effect.regression_start` ``(ctx) -> dict | None``: a start from the linear regression
  of the force residual while moving (``ctx.force_residual`` on ``ctx.moving``; the friction
  module's ``force_levels``);
* :attr:`Effect.synth_strength`: the values ``hil synth`` hides by default (for the paper bench);
* :attr:`Effect.linear_param` and :meth:`Effect.linear_column` ``(ctx) -> (column, value now)``:
  an effect linear in that one parameter through the inverse model of a rigid axis, screened in
  pairs (hil.ident.joint);
* :attr:`Effect.lags_the_torque`: the effect delays or lags the torque after the controller, so
  that a record's torque command and its current differ (hil.ident.sampling);
* :attr:`Effect.non_smooth`: the error jumps with the effect's gridded parameter (a contact's
  timing): the diagnosis chain refits it on the night's plant (hil.ident.chain);
* :attr:`Effect.screen_starts`: starts of the brief screening fit (2 where two basins lie apart);
  :attr:`Effect.cost_factor`: how costly its fit is, for the scheduling of the candidates.

The context ``ctx`` is built by hil.ident (hil.ident.context.EffectContext) and used duck-typed:
the physics imports nothing of the identification. It carries the replay's record and residual
before the fit (``meas``, ``res0``, ``v_cmd``, ``moving``, ``force_channel``,
``force_residual``, ``force_unit``, ``unit()``, ``sample_period``; ``motion``, the measured
velocity and acceleration as the inverse model has them), the model (``plant``,
``controller``, ``scale``; what the config has: ``configured(effect, param)`` (0 where it has
none), ``given(effect, param)`` (None where it has none), ``rotary``,
``velocity_period``, ``position_period``, ``position_feedback``), for evidence the channel and modes (``chan``,
``base_modes``), ``fmt_si`` (hil.units.fmt_si), and the helpers that simulate (``grid_starts``, ``prefilter``,
``periodic_starts``, ``mode_targets``, ``residuals_with``, ``cost``, ``pays``). Hooks use numpy.
"""
from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass

from sim_plant.plant import Plant

__all__ = ["Param", "ByActuator", "Effect", "CATALOGUE", "ALIASES", "register", "effect", "Combination",
           "RecordEffect", "motor_force_kind", "motor_damping_kind", "to_linear", "level_guess"]


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
    # names of a setting's whole values 0, 1, ... (``encoder``: "motor", "table"): a configuration
    # writes the name, the physics takes the number (:meth:`number`, :meth:`written`)
    choices: tuple = ()

    def kind_for(self, rotary: bool) -> str:
        """The unit kind on a rotary (motor and screw) or a linear actuator."""
        if isinstance(self.kind, ByActuator):
            return self.kind.rotary if rotary else self.kind.linear
        return self.kind

    def number(self, value) -> float:
        """The value as the physics takes it: a choice's name as its number (ValueError: not one of them)."""
        if isinstance(value, str):
            if value not in self.choices:
                raise ValueError(f"{self.name}: expected one of {', '.join(self.choices) or 'a number'}, got {value!r}")
            return float(self.choices.index(value))
        return float(value)

    def written(self, value):
        """The value as a configuration writes it: a choice's name, else the number (SI)."""
        if self.choices:
            i = int(round(float(value)))
            if not 0 <= i < len(self.choices):
                raise ValueError(f"{self.name}: expected one of {', '.join(self.choices)}, got {value!r}")
            return self.choices[i]
        return float(value)


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
    # effects whose action this one sets anew when it comes after them (asymmetric friction sets the
    # friction and the motor's viscous damping): before it in a configuration they act on nothing
    replaces: tuple = ()
    # the plant's own config keys this one sets anew wherever it is configured (the plant's friction
    # is built before every effect): with it they act on nothing
    replaces_keys: tuple = ()
    periodic: bool = False     # parameters include a period along the travel

    @property
    def fitted_params(self) -> tuple[Param, ...]:
        """The parameters a fit moves (the others are settings: where, not how strong)."""
        return tuple(p for p in self.params if p.fit)

    def drifted_key(self, plant: Plant) -> str | None:
        """The config key this effect is a change of (a mass on the table is the table mass), or
        None: a physical effect of its own. A change within the config's tolerance is no finding
        (hil.ident.tolerance)."""
        return None

    def unsuited(self, plant: Plant) -> str:
        """Why the effect cannot act on this plant (backlash needs a transmission link; a cable
        carrier needs a travel with ends), or "" where it can. The one hook subclasses implement."""
        return ""

    def applicable(self, plant: Plant) -> bool:
        """Whether the effect can act on this plant (:meth:`unsuited` gives no reason against it)."""
        return not self.unsuited(plant)

    def guess(self, plant: Plant, scale: dict) -> dict[str, float]:
        """Starting values for a fit; ``scale`` gives typical magnitudes of the record (force N,
        speed m/s, period s)."""
        return {p.name: p.guess for p in self.params}

    def grid(self, plant: Plant, ctrl, scale: dict) -> list[dict[str, float]]:
        """Starting values on a grid over the physically possible range, for parameters in which
        the error is not convex (a delay): the fitter simulates each point once and refines from
        the best (hil.ident.starts). Empty: the effect's guess and its regressions suffice.
        ``ctrl``: the controller settings (drivers.control.ControllerSettings: its periods)."""
        return []

    def _need_link(self, plant: Plant) -> None:
        if why := no_link(plant):
            raise ValueError(f"{self.name}: cannot act on this axis: {why}")

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)

    # --- the identification's hooks (the module's docstring; ``ctx``: hil.ident.context.EffectContext)

    synth_strength: dict | None = None      # the values ``hil synth`` hides by default (paper bench, SI)
    linear_param: str | None = None         # the parameter linear through the inverse model (hil.ident.joint)
    screen_starts: int = 1                  # starts of the brief screening fit
    lags_the_torque: bool = False           # makes the torque command and the current differ at the sample
    non_smooth: bool = False                # the error jumps with its gridded parameter (a contact's timing)

    @property
    def cost_factor(self) -> int:
        """How costly a fit of this effect is against a plain one (a periodic effect's starts
        simulate its orders): the candidates are scheduled costliest first."""
        return 3 if self.periodic else 1

    def evidence(self, ctx, values: dict[str, float]) -> str:
        """The head of the evidence line (ending in "; "): what in the residual before the fit
        points at this effect, with the fitted ``values``; "": the error's fall says it all."""
        return ""

    def starts(self, ctx, guess: dict[str, float]) -> list[dict[str, float]]:
        """Starting values of a fit, best first: the points of :meth:`grid` costed by one
        simulation each (``ctx.grid_starts``), else the regression's start and the ``guess``."""
        grid = self.grid(ctx.plant, ctx.controller, ctx.scale)
        if grid:
            return ctx.grid_starts(self, [dict(guess, **pt) for pt in grid])
        reg = self.regression_start(ctx)
        return [reg, guess] if reg else [guess]

    def regression_start(self, ctx) -> dict[str, float] | None:
        """A start from the linear regression of the force residual while moving (a friction or
        force effect: ``ctx.force_residual`` on ``ctx.moving``); None: the effect has none."""
        return None

    def linear_column(self, ctx):
        """(regressor per unit of :attr:`linear_param`, the value the model has now) on the
        inverse model's motion (``ctx.v``, ``ctx.a``; hil.ident.joint); None: not linear."""
        return None

    def degenerate(self, values: dict[str, float], cfg=None, sample_period: float | None = None) -> str:
        """Why the fitted ``values`` are not this effect's own finding, "" when they are: a fit that
        ends where the effect turns into another (a mode at its frequency bound or critically
        damped: a rigid mass, a damper) names the wrong thing. The diagnosis never calls such a
        fit significant, and says why in its evidence. ``cfg``: the model's config the fit
        started from; ``sample_period``: the record's (s)."""
        return ""

    def _at_bound(self, values: dict[str, float], names: tuple, rel: float = 0.01) -> list[str]:
        """Those of ``names`` whose fitted value lies within ``rel`` of the range's span of a bound."""
        out = []
        for n in names:
            p, v = self.param(n), values.get(n)
            if v is not None and (v >= p.upper - rel * (p.upper - p.lower) or v <= p.lower + rel * (p.upper - p.lower)):
                out.append(n)
        return out


CATALOGUE: dict[str, Effect] = {}
# old names that keep working (config sections, command line, candidate lists): name -> catalogue name
ALIASES: dict[str, str] = {"time_delay": "actuator_delay"}


def no_link(plant: Plant) -> str:
    """Why an effect of the transmission (link 1) cannot act on ``plant``, or ""."""
    return "" if plant.n >= 2 else f"no transmission link: the chain has {plant.n} mass"


def no_travel(plant: Plant) -> str:
    """Why an effect that changes along the travel cannot act on ``plant``, or ""."""
    return ("the axis turns without end (plant.endless): no travel for it to change along"
            if plant.endless else "")


def no_tip(plant: Plant) -> str:
    """Why an artefact of the tool tip's own instrument cannot act on ``plant``, or ""."""
    return "" if plant.tip != plant.table else "no tool tip apart from the table: x_tip is x_table"


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
motor_force_kind = ByActuator("torque", "force")
motor_damping_kind = ByActuator("rot_damping", "damping")


def to_linear(plant: Plant) -> float:
    """Motor-side torque (N m) to force on mass 1 (N): 2 pi / p; 1 for a linear actuator."""
    return plant.speed_scale


def level_guess(plant: Plant, fallback: float) -> float:
    """The model's Coulomb level in motor units, ``fallback`` where it has none."""
    f = max(plant.friction.coulomb_pos, plant.friction.coulomb_neg)
    return f / to_linear(plant) if f > 0 else fallback


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
        """Each member's values (a setting ``values`` does not give is left to the configuration)."""
        return [{p.name: values[f"{n}.{p.name}"] for p in m.params if f"{n}.{p.name}" in values}
                for n, m in zip(self.names, self.members)]

    def unsuited(self, plant):
        return next((why for why in (m.unsuited(plant) for m in self.members) if why), "")

    def apply(self, plant, values):
        for m, v in zip(self.members, self.split(values)):
            plant = m.apply(plant, v)
        return plant

    def guess(self, plant, scale):
        return {f"{n}.{k}": v for n, m in zip(self.names, self.members) for k, v in m.guess(plant, scale).items()}

    def degenerate(self, values, cfg=None, sample_period=None):
        return "".join(m.degenerate(v, cfg, sample_period) for m, v in zip(self.members, self.split(values)))

    def regression_start(self, ctx):
        """The members' regression starts together; None unless every member has one."""
        parts = [m.regression_start(ctx) for m in self.members]
        if any(p is None for p in parts):
            return None
        return {f"{m.name}.{k}": v for m, p in zip(self.members, parts) for k, v in p.items()}

