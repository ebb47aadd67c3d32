"""Reading a configuration into the plant: the one place where config keys meet sim_plant.

* :func:`plant_from_config`: the chain, actuator, motor friction and sensors of a validated
  :class:`hil.config.Config`, with the effects its ``[effects.<name>]`` sections switch on
  (:func:`apply_effects`). Everything in linear units on the load side: mass 1 is the motor's
  inertia reflected through the pitch, and its torque enters as the force f = tau 2 pi / p
  (Eq. 12, 23).
* An effect switched on in a configuration (:func:`configure`: the ``[effects.<name>]`` section,
  whose keys hil.config takes from the catalogue's parameters), and the ``parameter:<key>``
  effects that re-identify a value the config already has (:class:`ParameterEffect`,
  :func:`candidate`).
* The components file (catalogue data with units, Appendix 2 and 3) read into SI values for
  :func:`sim_plant.components.equivalents` (:func:`load_components`).

sim_plant knows no configuration and raises ValueError or KeyError; here they become
:class:`hil.errors.ConfigError` naming the file and the key.
"""
from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

from hil.config import NOISE_KINDS, Config, field_for, value_range
from hil.errors import ConfigError, UnitError
from hil.units import DIMENSIONS, fmt, parse
from sim_plant.chain import Chain
from sim_plant.components import k_axial, k_flexure, k_nut_table, k_screw_axial, k_torsional
from sim_plant.effects import ByActuator, Combination, Effect, Param, RecordEffect, effect
from sim_plant.plant import Friction, Plant

__all__ = ["plant_from_config", "apply_effects", "record_effects", "measurement_key", "ParameterEffect", "candidate", "effect_values",
           "configure", "default_parameters", "control_bounds", "CONTROL_PARAMETERS", "load_components",
           "components_from_dict", "without_replaced"]


# --- the plant -----------------------------------------------------------------------------------

def plant_from_config(cfg: Config) -> Plant:
    """Build the plant of a validated configuration (effects included)."""
    n = cfg.n_masses
    m = tuple(cfg[f"plant.m{i}"] for i in range(1, n + 1))
    k = tuple(cfg[f"plant.k{i}"] for i in range(1, n))
    c = tuple(cfg[f"plant.c{i}"] for i in range(1, n))
    if cfg.rotary:
        pitch = cfg["plant.pitch"]
        ratio = 2.0 * math.pi / pitch
        force_gain = ratio           # N per N m
        speed_scale = ratio          # rad/s per m/s
        to_linear = ratio            # N m -> N on mass 1
        viscous = cfg.get("friction.viscous", 0.0) * ratio ** 2
    else:
        pitch = None
        force_gain = cfg["actuator.gain"]
        speed_scale = 1.0
        to_linear = 1.0
        viscous = cfg.get("friction.viscous", 0.0)
    fc = cfg.get("friction.coulomb", 0.0) * to_linear
    fs = cfg.get("friction.static", None)
    fs = fc if fs is None else fs * to_linear
    friction = Friction(fc, fc, fs, fs, 0.0)
    table = (cfg.get("plant.table_mass", 0) or min(2, n)) - 1
    tip = (cfg.get("plant.tip_mass", 0) or n) - 1
    plant = Plant(
        chain=Chain(m, k, c, (viscous,) + (0.0,) * (n - 1)),
        force_gain=force_gain, speed_scale=speed_scale, friction=friction,
        table=table, tip=tip,
        table_resolution=cfg.get("sensors.table_resolution", 0.0),
        motor_resolution=cfg.get("sensors.motor_resolution", 0.0),
        pitch=pitch,
        current_loop_time_constant=cfg.get("actuator.current_loop_time_constant", 0.0),
        endless=bool(cfg.get("plant.endless", False)))
    return apply_effects(plant, cfg)


# the sensors' noise section's channels and their kinds (hil.config's [noise]; hil.ident.noise reads them)
_NOISE_KINDS = NOISE_KINDS


def _configured_effects(cfg: Config):
    """(section name, effect, values) of every ``[effects.<name>]`` section of the config, checked
    against the parameters' ranges (an old name, e.g. ``time_delay``, gives its catalogue effect)."""
    names, sections = [], {}
    for key, v in cfg.values.items():     # one pass: each [effects.<name>] section, as Config.section
        if key.startswith("effects."):
            name, _, rest = key[8:].partition(".")
            sections.setdefault(name, {})[rest] = v
            if v is not None and name not in names:
                names.append(name)
    out = []
    for name in names:
        eff = effect(name)
        sect = sections[name]
        values = {p.name: p.number(sect.get(p.name, p.guess)) for p in eff.params}
        for p in eff.params:
            v = values[p.name]
            if not (p.lower <= v <= p.upper) or (isinstance(v, float) and math.isnan(v)):
                raise ConfigError(f"{cfg.source}: effects.{name}.{p.name}: expected {p.lower:g} .. {p.upper:g}, "
                                  f"got {v:g}")
        out.append((name, eff, values))
    out += _measurement_artefacts(cfg, names)
    return out


def measurement_key(eff: Effect) -> str | None:
    """The ``[measurement]`` key of a recording artefact (``measurement.channel_skew``: the value of
    its one parameter), None for plant physics (``[effects.<name>]``)."""
    if isinstance(eff, RecordEffect) and getattr(eff, "section", "") == "measurement" and len(eff.params) == 1:
        return f"measurement.{eff.name}"
    return None


def _measurement_artefacts(cfg: Config, names: list[str]):
    """(key, effect, values) of the recording's artefacts the ``[measurement]`` section gives (an old
    config's ``[effects.channel_skew]`` still reads; both at once is refused by name)."""
    from sim_plant.effects import CATALOGUE
    out = []
    for eff in CATALOGUE.values():
        key = measurement_key(eff)
        if key is None or cfg.get(key) is None:
            continue
        if eff.name in names:
            raise ConfigError(f"{cfg.source}: {key}: the artefact is also given as [effects.{eff.name}]; "
                              f"expected it once, in [measurement]")
        p, v = eff.params[0], float(cfg[key])
        if not (p.lower <= v <= p.upper) or math.isnan(v):
            raise ConfigError(f"{cfg.source}: {key}: expected {p.lower:g} .. {p.upper:g}, got {v:g}")
        out.append((key, eff, {p.name: v}))
    return out


def record_effects(cfg: Config) -> list[tuple[RecordEffect, dict]]:
    """The artefacts of the recording the config switches on (``channel_skew``, ``tip_skew``):
    (effect, values) each, for the replay and the synthesized records to apply to the channels."""
    return [(eff, values) for _, eff, values in _configured_effects(cfg) if isinstance(eff, RecordEffect)]


def without_replaced(cfg: Config) -> Config:
    """The config without the effects that a later one sets anew (``Effect.replaces``: a
    ``coulomb_friction`` before an ``asymmetric_friction`` acts on nothing) and without the plant's
    keys that a configured effect sets anew (``Effect.replaces_keys``: the motor's friction and
    viscous damping under an ``asymmetric_friction``, back to their defaults, none): the same plant,
    and no value left that reads as if it counted."""
    names = [eff.name for _, eff, _ in _configured_effects(cfg)]
    dead = {r for i, n in enumerate(names) for r in effect(n).replaces if r in names[:i]}
    keys = {k for n in names for k in effect(n).replaces_keys if cfg.get(k)}      # set, and not 0
    if not dead and not keys:
        return cfg
    return cfg.with_values({**{k: None for k in cfg.keys()
                               if k.startswith("effects.") and effect(k.split(".")[1]).name in dead},
                            **{k: None for k in keys}})


def apply_effects(plant: Plant, cfg: Config) -> Plant:
    """The plant with every effect the config switches on (sections ``[effects.<name>]``)."""
    for name, eff, values in _configured_effects(cfg):
        if why := eff.unsuited(plant):
            raise ConfigError(f"{cfg.source}: effects.{name}: cannot act on this axis: {why}")
        try:
            plant = eff.apply(plant, values)
        except ValueError as exc:        # the physics names the effect; the key says it here
            raise ConfigError(f"{cfg.source}: effects.{name}: {str(exc).removeprefix(f'{name}: ')}") from None
    return plant


# a controller setting the fit moves by less than this share of its configured value is not a finding
# (ParameterEffect.degenerate): the drive's settings are entered numbers
SETTING_TOLERANCE = 0.01


class ParameterEffect(Effect):
    """``parameter:<dotted name>``: re-identify a parameter the config already has (a mass, a
    stiffness, a damping, a friction value). It changes the config, not the plant."""
    rescale = True

    def __init__(self, key: str, cfg: Config | None = None):
        f = field_for(key)
        if f is None or key.startswith("effects."):
            raise KeyError(f"parameter:{key}: not a parameter of the config schema")
        if not callable(f.kind) and f.kind not in DIMENSIONS:
            # a text, a flag, a count or a list (meta.name, measurement.torque): nothing a fit can move
            raise KeyError(f"parameter:{key}: not a physical quantity (a {f.kind} setting); a fit re-identifies "
                           f"numbers with a unit: a mass, a stiffness, a damping, a gain, a friction value")
        self.key = key
        self.name = f"parameter:{key}"
        self.description = f"re-identify {key} ({f.doc})"
        value = cfg.get(key) if cfg is not None else None
        kind = f.kind
        if callable(kind):           # the schema's kind of actuator.type, as the physics' parameters say it
            kind = ByActuator(kind({"actuator.type": "rotary"}), kind({"actuator.type": "linear"}))
        if not (isinstance(value, (int, float)) and not isinstance(value, bool)):
            value = None
        g = float(value) if value else 1.0
        lo = 0.0 if (f.positive or f.nonnegative) else -1e12
        hi = 1e12
        bounds = control_bounds(key, cfg)      # a controller setting: bounds from the loop's physics
        if bounds is not None:
            lo, hi = bounds
            g = min(max(g, lo), hi)
        self.params = (Param("value", kind, lo, hi, g, f"new value of {key}"),)

    def drifted_key(self, plant):
        return self.key

    def apply(self, plant, values):      # pragma: no cover - parameters act on the config
        raise TypeError("parameter effects act on the config: use hil.plant_config.configure()")

    def degenerate(self, values, cfg=None, sample_period=None):
        # a controller setting is a number entered in the drive: one that differs from the config
        # differs by an entry (a unit, a scaling, another tuning), not by a fraction of a percent;
        # a sliver that small is another effect's shadow
        old = cfg.get(self.key) if cfg is not None else None
        if not self.key.startswith("control.") or not isinstance(old, (int, float)) or isinstance(old, bool) \
                or not old:
            return ""
        if values.get("value") is None:
            return ""
        change = values["value"] / old - 1.0
        if abs(change) >= SETTING_TOLERANCE:
            return ""
        return (f"{self.key} moved by {100 * change:+.2g} % of its setting, within the {100 * SETTING_TOLERANCE:.0f} % "
                f"that tells an entry in the drive from another effect's shadow; ")

    def evidence(self, ctx, values):
        """The config value before and after, in its unit (sim_plant.effects.base: the hook)."""
        key, cfg = self.key, ctx.cfg
        old = cfg.get(key)
        f = field_for(key)
        kind = f.kind_for(cfg.values) if f is not None else None
        if isinstance(old, (int, float)) and kind in DIMENSIONS:
            return f"{key} {fmt(old, kind)} -> {fmt(values.get('value', 0), kind)} explains the {ctx.chan} residual; "
        return f"{key} {old:.4g} -> {values.get('value', 0):.4g} explains the {ctx.chan} residual; "


def configure(eff: Effect, cfg: Config, values: dict[str, float]) -> Config:
    """A new config with the effect ``eff`` switched on with ``values``: a catalogue effect's
    section ``[effects.<name>]``, a combination's members one after the other, a
    ``parameter:<key>`` effect's key itself. The one place an effect becomes configuration keys
    (the physics, sim_plant, takes parameters and knows no configuration)."""
    if isinstance(eff, Combination):
        for m, v in zip(eff.members, eff.split(values)):
            cfg = configure(m, cfg, v)
        return cfg
    if isinstance(eff, ParameterEffect):
        return cfg.with_values({eff.key: holdable(eff.key, float(values["value"]), cfg.values)})
    key = measurement_key(eff)
    if key is not None:       # a recording artefact: [measurement], never the plant's [effects.*]
        return cfg.with_values({key: float(values[eff.params[0].name]),
                                **{f"effects.{eff.name}.{p.name}": None for p in eff.params}})
    params = {p.name: p for p in eff.params}
    return cfg.with_values({f"effects.{eff.name}.{k}": holdable(f"effects.{eff.name}.{k}", params[k].written(v)
                                                                if k in params else float(v), cfg.values)
                            for k, v in values.items()})


def holdable(key: str, value, values: dict):
    """A fitted number as the configuration can hold it: below the smallest magnitude other than 0
    that its key takes (hil.config.value_range: a time under a microsecond, which no timer
    resolves) it is 0 where the key takes 0, else that smallest magnitude. A delay fitted at
    0.75 us on a record without one is zero within its uncertainty and reads so, where the config
    refused it and the fleet's every record ended in that error: the fit and the config share the
    config's bound."""
    if not isinstance(value, float) or value == 0.0 or not math.isfinite(value):
        return value
    f = field_for(key)
    kind = f.kind_for(values) if f is not None else None
    if kind not in DIMENSIONS:
        return value
    low, _ = value_range(f, kind)
    if low is None or abs(value) >= low:
        return value
    return math.copysign(low, value) if f.positive else 0.0


def effect_values(name: str, cfg) -> dict:
    """The fitted values of an effect in a config: {param: value} (SI)."""
    eff = candidate(name, cfg)
    if name.startswith("parameter:"):
        return {"value": float(cfg[eff.key])}
    key = measurement_key(eff)
    if key is not None and cfg.get(key) is not None:      # a recording artefact: [measurement]
        return {eff.params[0].name: float(cfg[key])}
    # an alias (time_delay) configures its effect's own section
    given = {p.name: next((v for v in (cfg.get(f"effects.{n}.{p.name}") for n in (eff.name, name)) if v is not None),
                          None) for p in eff.params}
    if all(v is None for v in given.values()):
        return {p.name: p.number(cfg[f"effects.{name}.{p.name}"]) for p in eff.params}   # not configured
    # a parameter the section does not write has its default, as the plant takes it (a section
    # written before the parameter existed: compliant_mode's origin)
    return {p.name: p.number(v if v is not None else p.guess) for p, v in zip(eff.params, given.values())}


def values_text(name: str, values: dict) -> str:
    """An effect's values as the chain's text writes them: "level 2.2, x0 0.001" (4 digits, SI; a
    setting by its name, as a configuration writes it: "encoder table")."""
    try:
        eff = candidate(name)
    except (KeyError, ValueError):
        eff = None

    def one(k, v):
        try:
            p = eff.param(k) if eff is not None else None
        except KeyError:
            p = None
        return f"{k} {p.written(v)}" if p is not None and p.choices else f"{k} {v:.4g}"
    return ", ".join(one(k, v) for k, v in values.items())


def candidate(name: str, cfg: Config | None = None) -> Effect:
    """The effect of a catalogue name or ``parameter:<dotted name>``, or several joined by ``+``
    (a :class:`~sim_plant.effects.Combination`, fitted together)."""
    if "+" in name:
        names = name.split("+")
        return Combination([candidate(n, cfg) for n in names], [candidate(n, cfg).name if n.startswith("parameter:")
                                                                else n for n in names])
    if name.startswith("parameter:"):
        key = name.split(":", 1)[1]
        if cfg is not None and key not in cfg and "." not in key:
            # short form parameter:c2 -> plant.c2
            for sect in ("plant", "friction", "actuator", "control"):
                if f"{sect}.{key}" in cfg:
                    key = f"{sect}.{key}"
                    break
        try:
            return ParameterEffect(key, cfg)
        except KeyError as exc:
            raise KeyError(str(exc).strip("'\"")) from None
    return effect(name)


def default_parameters(cfg: Config, closed_loop: bool = True) -> list[str]:
    """The config parameters ``diagnose`` tries to re-identify by default: the chain's masses,
    stiffnesses and dampings, the actuator gain of a linear actuator, and on a closed-loop record
    the controller's own settings (:data:`CONTROL_PARAMETERS`: a drive engineer suspects the
    drive's parameters first, "someone changed them on the drive"), those the config has: the
    gains where not 0, Ti where finite, the current loop's time constant where given. An open-loop
    record replays the recorded actuator and never runs the loops: no controller parameter."""
    out = [k for k in cfg.keys() if re.fullmatch(r"plant\.[mkc][0-9]+", k) and cfg.get(k)]
    if not cfg.rotary and cfg.get("actuator.gain"):
        out.append("actuator.gain")
    if closed_loop:
        for key in CONTROL_PARAMETERS:
            v = cfg.get(key)
            if key == "control.ffv" or (isinstance(v, (int, float)) and 0 < v < math.inf):
                out.append(key)
    return [f"parameter:{k}" for k in out]


# the controller's settings among the default candidates (a feed-forward of 0 is a setting too)
CONTROL_PARAMETERS = ("control.kv", "control.ffv", "control.kp", "control.ti", "actuator.current_loop_time_constant")
FFV_RANGE = (0.0, 1.2)       # a velocity feed-forward beyond 1.2 of the command's speed is not a drive's setting
TI_MAX = 3600.0              # s: an integral time beyond an hour is a P loop


def control_bounds(key: str, cfg: Config | None) -> tuple[float, float] | None:
    """(lower, upper) of a controller setting as a re-identified parameter, from the loop's physics
    (SI); None for any other key. Closed forms of the sampled loops, each an upper limit of the
    real one (the loops' lags and delays only lower it; a fit that crosses the real limit simulates
    an unstable loop, whose error the fit rejects):

    * ``control.kv``: 0 .. 2 / Tp. Around an ideal velocity loop the position loop sampled every Tp
      is x[k+1] = x[k] + Tp kv (x_cmd - x[k]), stable for |1 - kv Tp| < 1.
    * ``control.kp``: 0 .. 2 M / (g R Tv), with M the chain's total mass (load side), g the force
      per unit of the loop's output and R the speed scale (rad/s per m/s; 1 on a linear
      actuator): the velocity P loop sampled every Tv on the rigid axis is
      v[k+1] = v[k] - (Tv g kp R / M) v[k] + ..., stable for Tv g kp R / M < 2.
    * ``control.ti``: Tv .. :data:`TI_MAX`: an integral time shorter than the loop's period adds more
      than the whole error each period.
    * ``control.ffv``: :data:`FFV_RANGE`.
    * ``actuator.current_loop_time_constant``: 0 .. 1 s (the schema's bound).
    """
    if key == "control.ffv":
        return FFV_RANGE
    if key == "actuator.current_loop_time_constant":
        return 0.0, 1.0
    if key not in CONTROL_PARAMETERS:
        return None
    if cfg is None:
        return 0.0, 1e12
    tp, tv = cfg.get("control.position_period"), cfg.get("control.velocity_period")
    if key == "control.kv":
        return 0.0, 2.0 / tp
    if key == "control.ti":
        return tv, TI_MAX
    mass = sum(cfg.get(f"plant.m{i}") for i in range(1, cfg.n_masses + 1))
    if cfg.rotary:
        ratio = 2.0 * math.pi / cfg["plant.pitch"]
        gain, speed = ratio, ratio
    else:
        gain, speed = cfg["actuator.gain"], 1.0
    return 0.0, 2.0 * mass / (gain * speed * tv)


# --- the components file -------------------------------------------------------------------------

# key -> (kind, meaning); a stiffness may also be an element {G, J, L} / {E, A, L} / {E, I, L} (Eq. 20)
_KEYS = {
    "drive.pitch": ("length", "screw pitch p"),
    "stiffness.k_em": ("rot_stiffness", "motor shaft, torsion"),
    "stiffness.k_AF": ("rot_stiffness", "flexible coupling, torsion"),
    "stiffness.k_Ht": ("rot_stiffness", "ball screw, torsion"),
    "stiffness.k_Ha": ("stiffness", "ball screw, axial (or its parts k_tb, k_Ha1, k_b, k_Ha2, Eq. 13)"),
    "stiffness.k_T": ("stiffness", "nut, axial"),
    "stiffness.k_M": ("stiffness", "nut-table link (or its parts k_aT, k_aS, k_ft, Eq. 14)"),
    "stiffness.k_c": ("stiffness", "compliant structure (column), k2"),
    "inertia.J_m": ("inertia", "motor"),
    "inertia.J_AF1": ("inertia", "coupling, first half"),
    "inertia.J_AF2": ("inertia", "coupling, second half"),
    "inertia.J_H": ("inertia", "ball screw"),
    "mass.m_T": ("mass", "nut"),
    "mass.m_M": ("mass", "table"),
    "mass.extra_table": ("mass", "extra mass carried by the table"),
    "mass.m_c": ("mass", "compliant structure (column), m3"),
}
_OPTIONAL = {"mass.extra_table": 0.0}
_PARTS = {
    "stiffness.k_Ha": (k_screw_axial, ("k_tb", "k_Ha1", "k_b", "k_Ha2"), "stiffness"),
    "stiffness.k_M": (k_nut_table, ("k_aT", "k_aS", "k_ft"), "stiffness"),
}
_ELEMENTS = {   # Eq. (20): which keys make which element
    frozenset("GJL"): (k_torsional, (("G", "pressure"), ("J", "area_moment"), ("L", "length")), "rot_stiffness"),
    frozenset("EAL"): (k_axial, (("E", "pressure"), ("A", "area"), ("L", "length")), "stiffness"),
    frozenset("EIL"): (k_flexure, (("E", "pressure"), ("I", "area_moment"), ("L", "length")), "stiffness"),
}


def _quantity(value, kind, what, zero_ok=False):
    try:
        out = parse(value, kind, what)
    except UnitError as exc:
        raise ConfigError(str(exc)) from None
    if not (out >= 0 if zero_ok else out > 0) or math.isinf(out):
        raise ConfigError(f"{what}: expected a {'' if zero_ok else 'positive '}finite {kind}"
                          f"{' >= 0' if zero_ok else ''}, got {value!r}")
    return out


def _element(value: dict, kind: str, what: str) -> float:
    fn, args, ekind = _ELEMENTS.get(frozenset(value), (None, None, None))
    if fn is None:
        raise ConfigError(f"{what}: expected an element {{G, J, L}} (torsion), {{E, A, L}} (axial) or "
                          f"{{E, I, L}} (flexure), got keys {', '.join(sorted(value))}")
    if ekind != kind:
        raise ConfigError(f"{what}: an element {{{', '.join(sorted(value))}}} gives a {ekind}, expected a {kind}")
    return fn(*(_quantity(value[a], k, f"{what}.{a}") for a, k in args))


def _stiffness(value, kind, what):
    return _element(value, kind, what) if isinstance(value, dict) else _quantity(value, kind, what)


def components_from_dict(table: dict, source: str = "<components>") -> dict[str, float]:
    """Validate a components table (as read from TOML) and return SI values by dotted key; parts
    (Eq. 13, 14) and elements (Eq. 20) are reduced to the stiffness they stand for."""
    flat = {}
    for sect, body in table.items():
        if sect == "meta":
            continue
        if not isinstance(body, dict):
            raise ConfigError(f"{source}: {sect}: expected a section [{sect}], got {body!r}")
        for name, value in body.items():
            flat[f"{sect}.{name}"] = value
    for key in flat:
        if key not in _KEYS:
            raise ConfigError(f"{source}: unknown key {key!r} (known: {', '.join(_KEYS)})")
    out = {}
    for key, (kind, doc) in _KEYS.items():
        what = f"{source}: {key}"
        if key not in flat:
            if key in _OPTIONAL:
                out[key] = _OPTIONAL[key]
                continue
            raise ConfigError(f"{what}: missing ({doc}, a {kind})")
        value = flat[key]
        if key in _PARTS and isinstance(value, dict) and not frozenset(value) in _ELEMENTS:
            fn, names, pkind = _PARTS[key]
            missing = [n for n in names if n not in value]
            extra = [n for n in value if n not in names]
            if missing or extra:
                raise ConfigError(f"{what}: expected the parts {', '.join(names)}"
                                  + (f"; missing {', '.join(missing)}" if missing else "")
                                  + (f"; unknown {', '.join(extra)}" if extra else ""))
            out[key] = fn(*(_stiffness(value[n], pkind, f"{what}.{n}") for n in names))
        elif key.startswith("stiffness."):
            out[key] = _stiffness(value, kind, what)
        elif key == "mass.extra_table":
            out[key] = _quantity(value, kind, what, zero_ok=True)
        else:
            out[key] = _quantity(value, kind, what)
    return out


def load_components(path: str | Path) -> dict[str, float]:
    """Read and validate a components TOML file (see :func:`components_from_dict`)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such components file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return components_from_dict(table, str(path))
