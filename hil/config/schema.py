"""The configuration's schema: every key's :class:`~drivers.schema.Field` (:data:`SCHEMA`), the
sections beside it, and the conversion of a value as written to SI (:func:`field_for`, the
checks of each kind). Data and pure functions: the loader (:mod:`hil.config.loader`) and the
documentation (:mod:`hil.config.docs`) read it."""
from __future__ import annotations

import math
import re
from typing import Any, Callable

from drivers.canopen.schema import SECTION as CANOPEN_SECTION
from drivers.schema import Field
from drivers.serial.schema import SECTION as SERIAL_SECTION
from drivers.serial.schema import field as serial_field
from hil.errors import ConfigError
from hil.units import SI_UNIT, UnitError, parse, parse_gain_db


def _rotary(values: dict) -> bool:
    return values.get("actuator.type", "rotary") == "rotary"


def _torque_or_force(values):
    return "torque" if _rotary(values) else "force"


def _rot_or_lin_damping(values):
    return "rot_damping" if _rotary(values) else "damping"


def _output_kind(values):
    return "torque" if _rotary(values) else "voltage"


def _velocity_gain_kind(values):
    return "rot_damping" if _rotary(values) else "volt_per_speed"


# Every number of a configuration, whatever its key, lies within +-MAX_MAGNITUDE (SI): a value
# beyond it is a typo or an attack, never an axis (issue 18: a 1e300 gain, a 10^8-sample delay).
MAX_MAGNITUDE = 1e12

# Every time of a configuration other than 0 (a period, a time constant, a timeout) lies within
# TIME_RANGE (s), unless its key says more narrowly: below a microsecond no host or drive timer
# resolves anything (and a simulated loop period of 1 ns would take 4 million steps a position
# tick: a hang, issue 30); above an hour no period or timeout of a run makes sense. "inf" stays
# accepted where a key allows it (an integral time that switches the integral off).
TIME_RANGE = (1e-6, 3600.0)

# The loop periods (s). A servo drive closes its velocity loop at 8 to 32 kHz (the paper's
# 62.5 us is 16 kHz; the fastest drives reach 62.5 kHz, 16 us): 10 us (100 kHz) is beyond any.
# The host's position loop runs at least as slow as the velocity loop (a whole multiple of it);
# 1 s is a slow serial link's ten times over.
LOOP_PERIOD_RANGE = (10e-6, 1.0)

# Text values: a name, a command template, a pattern; none needs more (a 5 MB meta.name hung
# the plot's title, issue 30).
MAX_STRING_CHARS = 1024
# The configuration file: a few kilobytes in practice; tables nested no deeper than this
# (section.subsection.key, plus an array).
MAX_CONFIG_BYTES = 1 << 20
MAX_CONFIG_DEPTH = 8

# Keys of the chain that are numbered: plant.m1..mN, plant.k1..k(N-1), plant.c1..c(N-1).
_NUMBERED = {"m": ("mass", "mass {i} of the chain (1: motor reflected to the load side)"),
             "k": ("stiffness", "stiffness between mass {i} and mass {j}"),
             "c": ("damping", "damping between mass {i} and mass {j}")}
_NUMBERED_RE = re.compile(r"^plant\.([mkc])([1-9][0-9]*)$")
_CHAIN_KEYS = ("plant.table_mass", "plant.tip_mass")     # the chain's checks read these beside the numbered keys

SCHEMA: dict[str, Field] = {
    # --- plant: the lumped chain ---------------------------------------------------------
    "plant.pitch": Field("length", "screw pitch p (lead per motor revolution); required for a rotary actuator",
                         positive=True),
    "plant.m*": Field("mass", "plant.m1 .. plant.mN: masses of the chain, motor first (m1 = J_m (2 pi/p)^2)",
                      positive=True),
    "plant.k*": Field("stiffness", "plant.k1 .. plant.k(N-1): stiffness between mass i and i+1", positive=True),
    "plant.c*": Field("damping", "plant.c1 .. plant.c(N-1): damping between mass i and i+1", nonnegative=True),
    "plant.table_mass": Field("int", "which mass carries the linear encoder (x_table); 0 = mass 2, or mass 1 "
                              "for a 1-dof chain", default=0, nonnegative=True),
    "plant.tolerance": Field("dimensionless", "how well the config knows the chain's masses, stiffnesses and dampings "
                                              "(relative): a record they explain, moved within it, is the config's "
                                              "own plant (hil diagnose names no drift within it); 0: no tolerance",
                             default=0.05, nonnegative=True, maximum=0.5),
    "plant.tip_mass": Field("int", "which mass is the tool tip (x_tip); 0 = the last mass", default=0,
                            nonnegative=True),
    "plant.endless": Field("bool", "true: the axis turns without end (a motor alone on a bench, a rotary table), "
                           "so nothing can change along its travel: hil diagnose tries no cable carrier, no "
                           "stiffness along the travel and no screw elongation (and says so)", default=False),
    # --- friction on the motor (Eq. 11) ----------------------------------------------------
    "friction.viscous": Field(_rot_or_lin_damping, "viscous friction on the motor, c_m (Eq. 11)", default=0.0,
                              nonnegative=True),
    "friction.coulomb": Field(_torque_or_force, "Coulomb (sliding) friction level on the motor, tau_fc",
                              default=0.0, nonnegative=True),
    "friction.static": Field(_torque_or_force, "break-away (stiction) level; default: the Coulomb level",
                             default=None, nonnegative=True),
    # --- actuator ----------------------------------------------------------------------------
    "actuator.type": Field("str", "rotary: a motor turning a screw (the controller outputs torque); "
                           "linear: a force actuator (the controller outputs a command, force = gain x command)",
                           default="rotary", choices=("rotary", "linear")),
    "actuator.gain": Field("force_per_volt", "linear actuator: force per unit of controller output (N/V)",
                           default=None, positive=True),
    "actuator.current_loop_time_constant": Field("time", "first-order lag of the current loop; 0 = ideal",
                                                 default=0.0, nonnegative=True, maximum=1.0),
    # --- control -----------------------------------------------------------------------------
    "control.position_period": Field("time", "position-loop period Tp", required=True, positive=True,
                                     minimum=LOOP_PERIOD_RANGE[0], maximum=LOOP_PERIOD_RANGE[1]),
    "control.velocity_period": Field("time", "velocity-loop period Tv (Tp must be a whole multiple)",
                                     required=True, positive=True, minimum=LOOP_PERIOD_RANGE[0],
                                     maximum=LOOP_PERIOD_RANGE[1]),
    "control.kv": Field("loop_gain", "position-loop P gain Kv (1/s)", required=True, nonnegative=True),
    "control.ffv": Field("dimensionless", "velocity feed-forward, fraction of the interpolator velocity",
                         default=1.0, nonnegative=True),
    "control.position_feedback": Field("str", "position-loop feedback: the linear encoder (table) or the motor "
                                       "encoder", default="table", choices=("table", "motor")),
    "control.kp": Field(_velocity_gain_kind, "velocity-loop proportional gain Kp", required=True,
                        nonnegative=True),
    "control.ti": Field("time", "velocity-loop integral time Ti; \"inf\" = P only", default=math.inf,
                        positive=True, allow_inf=True),
    "control.velocity_feedback": Field("str", "velocity-loop feedback: the measured motor speed, or a backward "
                                       "difference of the filtered motor position", default="motor_speed",
                                       choices=("motor_speed", "position_difference")),
    "control.velocity_filter": Field("floats", "FIR taps on the motor position before the difference "
                                     "(position_difference only), newest first", default=[1.0], max_items=8),
    "control.filters": Field("filters", "second-order filters of the velocity loop, an array of tables "
                             "([[control.filters]]): kind = notch (frequency, width, depth, e.g. \"86.6Hz\", "
                             "\"20Hz\", \"-20dB\"), lowpass (frequency, damping, default 0.707) or biquad (b = [b0, "
                             "b1, b2], a = [1, a1, a2] at the velocity period); at = torque (the velocity "
                             "controller's output, default) or speed (the speed feedback); at most 4 on each",
                             default=None),
    "control.output_delay": Field("int", "computation delay of the velocity-loop output, in velocity periods",
                                  default=0, nonnegative=True, maximum=1000),
    "control.output_limit": Field(_output_kind, "saturation of the velocity-loop output (torque for a rotary "
                                  "actuator, command for a linear one)", required=True, positive=True),
    "control.acc_ff": Field("dimensionless", "acceleration (torque) feed-forward, fraction of the total "
                            "reflected inertia times the commanded acceleration", default=0.0, nonnegative=True),
    # --- axis limits (checked before motion, monitored during it) --------------------------
    "limits.travel_min": Field("length", "lower software travel limit", required=True),
    "limits.travel_max": Field("length", "upper software travel limit", required=True),
    "limits.speed": Field("speed", "largest commanded speed", required=True, positive=True),
    "limits.acceleration": Field("acceleration", "largest commanded acceleration", required=True, positive=True),
    "limits.jerk": Field("jerk", "largest commanded jerk", required=True, positive=True),
    "limits.torque": Field(_output_kind, "largest motor torque (rotary) or controller output (linear)",
                           default=None, positive=True),
    "limits.following_error_table": Field("length", "following-error window at the table; required on a real "
                                          "backend (canopen, serial) unless supervisor.unsupervised = true",
                                          default=None, positive=True),
    "limits.following_error_tip": Field("length", "following-error window at the tool tip (where measured)",
                                        default=None, positive=True),
    "limits.start_window": Field("length", "hardware backends: a move planned from a given start (--start) runs "
                                 "only if the axis stands within this of it", default=1e-4, positive=True),
    # --- NC ------------------------------------------------------------------------------------
    "nc.g0": Field("speed", "rapid (G00) speed, the reference for the acceleration time t_acc", default=None,
                   positive=True),
    "nc.t_acc": Field("time", "NC acceleration time to reach nc.g0, for a move that gives none of --tacc, --amax "
                      "or --jmax (hil tune writes the one it chose)", default=None, positive=True),
    "nc.shaper": Field("str", "input shaper of the command (hil.shaping): KIND@FREQUENCY[:DAMPING] with KIND zv, zvd, "
                       "ei or si (e.g. 'zvd@14.94Hz'), 'auto' (ZVD at the model's lowest mode) or 'none'; hil move "
                       "--shaper overrides it", default="none"),
    # --- sensors (what the controller and the recorder see) ----------------------------------
    "sensors.table_resolution": Field("length", "linear-encoder quantum; 0 = ideal", default=0.0,
                                      nonnegative=True),
    "sensors.motor_resolution": Field("length", "motor-encoder quantum in linear units; 0 = ideal", default=0.0,
                                      nonnegative=True),
    # --- measurement (records compared with the model: hil.ident.replay) -------------------------
    "measurement.output_includes_u_add": Field("bool", "the recorded controller output (torque, force or command) "
                                               "includes the record's u_add channel (the drive's command logged "
                                               "after the addition); false: the controller's own output",
                                               default=True),
    "measurement.torque": Field("str", "which torque a rotary axis's record holds: command (the drive's torque "
                                "command at the sample, before the actuator's delay and current loop) or actual "
                                "(the measured current, after them); not given: actual, and hil diagnose tries "
                                "both and says which the record is", default=None, choices=("command", "actual")),
    "measurement.force": Field("str", "the same for a linear axis's force (or command) channel: command or actual",
                               default=None, choices=("command", "actual")),
    # the recording's artefacts (sim_plant.effects.RecordEffect): how the record was logged, not the plant
    "measurement.channel_skew": Field("time", "the force (torque, command) channel is logged this late against the "
                                      "positions (a logging artefact; + late)", default=None),
    "measurement.tip_skew": Field("time", "the tool-tip channel (another instrument) is logged this late against "
                                  "the drive's channels (a logging artefact; + late)", default=None),
    "measurement.force_offset": Field(_torque_or_force, "the force (torque, current) channel reads this much more "
                                      "than the actuator delivers (a sensor offset, not a load)", default=None),
    "measurement.position_offset": Field("length", "the tool-tip channel reads this much more than the tip's "
                                         "position (a sensor offset, not a motion)", default=None),
    # --- runtime -------------------------------------------------------------------------------
    "runtime.priority": Field("int", "real-time (SCHED_FIFO) priority of the loop's thread on hardware, 1..99 "
                              "(Linux, needs CAP_SYS_NICE); 0 = normal scheduling", default=0, nonnegative=True,
                              maximum=99),
    "runtime.cpu_latency": Field("time", "with runtime.priority: the CPUs' wake-up latency asked of the kernel "
                                 "while the loop runs (Linux PM QoS /dev/cpu_dma_latency, as cyclictest; needs "
                                 "write access to it): 0 keeps idle CPUs polling, so that no wake-up waits for a "
                                 "halted (virtual) CPU; \"inf\" = no request", default=0.0, nonnegative=True,
                                 allow_inf=True),
    "runtime.loop_cpu": Field("int", "the CPU the loop's thread is pinned to while it runs (Linux "
                              "sched_setaffinity; a CPU this process may use), as on a real-time PC: the live "
                              "scope's server then runs on the other CPUs, at a lower priority; not set = any CPU",
                              default=None, nonnegative=True, maximum=4095),
    # --- backend -------------------------------------------------------------------------------
    "backend.type": Field("str", "sim (embedded plant model), canopen, serial", default="sim"),
    "meta.name": Field("str", "a name for the axis", default="", max_length=200),
    "meta.description": Field("str", "free text", default="", max_length=10000),
    # --- fleet (hil fleet) ------------------------------------------------------------------------
    "fleet.track": Field("str", "effects whose strengths hil fleet fits on every record of the axis and tracks "
                                "over time, comma-separated (e.g. \"backlash, coulomb_friction\")", default=None),
    "fleet.thresholds": Field("str", "physical limits of tracked parameters, comma-separated (e.g. "
                                     "\"backlash.gap > 10um\"); a record beyond one is flagged", default=None),
}

# The [supervisor] section (hil.supervisor reads it)
SUPERVISOR_SECTION = {
    "supervisor.stop": Field("str", "controlled stop on a trip: quick_stop (CiA 402 quick stop) or disable",
                             default="quick_stop", choices=("quick_stop", "disable")),
    "supervisor.tolerance": Field("dimensionless", "relative margin on the speed/acceleration/jerk/torque limits",
                                  default=0.05, nonnegative=True),
    "supervisor.overrun_cycles": Field("dimensionless", "watchdog: a cycle that starts this many periods late "
                                       "trips (real-time clock only)", default=2.0, positive=True),
    "supervisor.frozen_cycles": Field("int", "position reading unchanged this many ticks while commanded to move",
                                      maximum=1_000_000,
                                      default=10, positive=True),
    "supervisor.history": Field("int", "cycles kept for the trip record", default=50, positive=True,
                                maximum=1_000_000),
    "supervisor.unsupervised": Field("bool", "true: let a real backend (canopen, serial) run without the "
                                     "supervisor's windows (limits.following_error_table); default false: refused "
                                     "before anything connects", default=False),
    "supervisor.latch_file": Field("str", "file that keeps a trip across processes until 'hil reset'; default "
                                   "latch.json in $HIL_STATE_DIR, $XDG_STATE_HOME/compliant-axis-hil or "
                                   "~/.local/state/compliant-axis-hil", default=""),
}

# the [noise] section: the channels whose sensor noise a configuration may give, and their kinds
NOISE_KINDS = {"x_motor": "length", "x_table": "length", "x_tip": "length", "torque": "torque", "force": "force",
               "command": "voltage", "e_table": "length", "e_tip": "length"}


def _effects_field(key: str) -> Field | None:
    """Fields of the ``effects.<name>.<param>`` keys: the catalogue's parameters (sim_plant,
    the layer below; imported here when first asked: it compiles)."""
    from sim_plant.effects import ALIASES, CATALOGUE, effect
    parts = key.split(".")
    if len(parts) != 3 or ALIASES.get(parts[1], parts[1]) not in CATALOGUE:
        return None
    eff = effect(parts[1])
    for p in eff.params:
        if p.name == parts[2]:
            if p.choices:        # a setting named by a word (an encoder: motor or table)
                return Field("str", f"{eff.name}: {p.doc}", default=None, required=False, choices=p.choices)
            return Field(_param_kind(p), f"{eff.name}: {p.doc}", default=None, required=False)
    return None


def _param_kind(p):
    """The schema's kind of an effect's parameter: its kind, or a callable of the config's values
    where it depends on ``actuator.type`` (:class:`sim_plant.effects.ByActuator`)."""
    if isinstance(p.kind, str):
        return p.kind
    return lambda values: p.kind_for(_rotary(values))


def _effects_keys() -> list[str]:
    from sim_plant.effects import CATALOGUE
    return [f"effects.{n}.{p.name}" for n, e in CATALOGUE.items() for p in e.params]


def _noise_field(key: str) -> Field | None:
    parts = key.split(".")
    if len(parts) != 2 or parts[1] not in NOISE_KINDS:
        return None
    return Field(NOISE_KINDS[parts[1]], f"RMS noise of the {parts[1]} sensor (before quantization): the "
                 f"noise floor of hil diagnose", default=None, nonnegative=True)


# The sections beside SCHEMA, explicitly: name -> field of a key (None: not one of its keys).
_SECTIONS: dict[str, Callable[[str], Field | None]] = {
    "supervisor": SUPERVISOR_SECTION.get,
    "effects": _effects_field,
    "noise": _noise_field,
    "canopen": CANOPEN_SECTION.get,
    "serial": serial_field,
}
# The keys each such section knows (for "did you mean").
_SECTION_KEYS: dict[str, Callable[[], list[str]]] = {
    "supervisor": lambda: list(SUPERVISOR_SECTION),
    "effects": _effects_keys,
    "noise": lambda: [f"noise.{c}" for c in NOISE_KINDS],
    "canopen": lambda: list(CANOPEN_SECTION),
    "serial": lambda: list(SERIAL_SECTION),
}
# every section beside SCHEMA's
SECTION_NAMES = tuple(_SECTIONS)


def did_you_mean(key: str, present=()) -> str:
    """``"; did you mean 'plant.c2'?"`` for a mistyped key, or ``""`` when nothing is close
    (difflib, over the schema's keys and the keys the sections beside it list). ``present``: the
    keys the configuration has; its chain's numbered keys are offered as far as its chain goes
    (``plant.kl`` on a chain of k1..k2 is ``plant.k1``, not ``plant.k9``)."""
    import difflib
    names = [k for k in SCHEMA if "*" not in k]
    masses = [int(m.group(2)) for k in present if (m := _NUMBERED_RE.match(k)) and m.group(1) == "m"]
    n = max(masses) if masses else 9
    names += [f"plant.m{i}" for i in range(1, n + 1)] + [f"plant.{c}{i}" for c in "kc" for i in range(1, max(n, 2))]
    for known in _SECTION_KEYS.values():
        try:
            names += list(known())
        except Exception:       # a section that cannot list its keys now: no suggestion from it
            continue
    # a letter typed for the digit it looks like (plant.kl, plant.cO) before any other closeness
    section, _, name = key.partition(".")
    lookalike = f"{section}.{name[:1]}{name[1:].translate(str.maketrans('lIOo', '1100'))}"
    if lookalike != key and lookalike in names:
        return f"; did you mean {lookalike!r}?"
    close = difflib.get_close_matches(key, names, n=1, cutoff=0.75)
    return f"; did you mean {close[0]!r}?" if close else ""


def field_for(key: str) -> Field | None:
    """The schema field of a dotted key (a section's beside the schema included), or None if unknown."""
    if key in SCHEMA:
        return SCHEMA[key]
    m = _NUMBERED_RE.match(key)
    if m:
        return SCHEMA[f"plant.{m.group(1)}*"]
    head = key.split(".", 1)[0]
    if head in _SECTIONS:
        return _SECTIONS[head](key)
    return None


def _flatten(table: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in table.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, name + "."))
        else:
            out[name] = v
    return out


def _known_sections() -> list[str]:
    return sorted({k.split(".", 1)[0] for k in SCHEMA} | set(SECTION_NAMES))


def _known_in_section(section: str) -> str:
    names = sorted(k for k in SCHEMA if k.startswith(section + "."))
    return ", ".join(n.replace("*", "N") for n in names)


def _convert(key: str, raw: Any, f: Field, values: dict, where: str) -> Any:
    kind = f.kind_for(values)
    what = f"{where}: {key}"
    if kind == "str":
        if not isinstance(raw, str):
            raise ConfigError(f"{what}: expected a string, got {_short(raw)}")
        if len(raw) > f.max_length:
            raise ConfigError(f"{what}: expected a text of at most {f.max_length} characters, got {len(raw)} "
                              f"({_short(raw)})")
        if f.choices and raw not in f.choices:
            raise ConfigError(f"{what}: expected one of {', '.join(f.choices)}, got {_short(raw)}")
        return raw
    if kind == "bool":
        if not isinstance(raw, bool):
            raise ConfigError(f"{what}: expected true or false, got {_short(raw)}")
        return raw
    if kind == "int":
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise ConfigError(f"{what}: expected a whole number, got {_short(raw)}")
        if f.nonnegative and raw < 0:
            raise ConfigError(f"{what}: expected a whole number >= 0, got {raw!r}")
        if f.positive and raw <= 0:
            raise ConfigError(f"{what}: expected a whole number >= 1, got {raw!r}")
        top = f.maximum if f.maximum is not None else MAX_MAGNITUDE
        if raw > top or raw < -MAX_MAGNITUDE:
            raise ConfigError(f"{what}: expected a whole number of at most {top:g}, got {_short(raw)}")
        if f.minimum is not None and raw != 0 and raw < f.minimum:
            raise ConfigError(f"{what}: expected a whole number of at least {f.minimum:g}, got {raw!r}")
        return raw
    if kind == "filters":
        return _filters(raw, what)
    if kind == "floats":
        if not isinstance(raw, list) or not raw or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                and abs(x) <= MAX_MAGNITUDE for x in raw):
            raise ConfigError(f"{what}: expected a non-empty list of numbers, got {_short(raw)}")
        if len(raw) > f.max_items:
            raise ConfigError(f"{what}: expected at most {f.max_items} numbers, got {len(raw)}")
        return [float(x) for x in raw]
    try:
        value = parse(raw, kind, what)
    except UnitError as exc:
        raise ConfigError(str(exc)) from None
    unit = SI_UNIT[kind]
    if math.isinf(value) and not f.allow_inf:
        raise ConfigError(f"{what}: expected a finite {kind} ({unit}), got {raw!r}")
    if f.positive and not value > 0:
        raise ConfigError(f"{what}: expected a positive {kind} ({unit}), got {raw!r}")
    if f.nonnegative and not value >= 0:
        raise ConfigError(f"{what}: expected a {kind} >= 0 ({unit}), got {raw!r}")
    if not math.isinf(value):
        low, top = value_range(f, kind)
        if value > top or value < -MAX_MAGNITUDE:
            raise ConfigError(f"{what}: expected a {kind} of at most {top:g} {unit}, got {_short(raw)}")
        if low is not None and value != 0 and abs(value) < low:
            zero = " (or 0)" if not f.positive else ""
            raise ConfigError(f"{what}: expected a {kind} of at least {low:g} {unit}{zero}, got {_short(raw)}")
    return value


_FILTER_KEYS = {"notch": ("frequency", "width", "depth"), "lowpass": ("frequency", "damping"), "biquad": ("b", "a")}


def _filters(raw: Any, what: str) -> list[dict]:
    """``control.filters``: each table checked and in SI (frequencies in Hz, the depth in dB), in
    the form :func:`drivers.control.filter_sections` designs from; one line naming the entry and
    its key for anything else."""
    if not isinstance(raw, list) or not all(isinstance(t, dict) for t in raw):
        raise ConfigError(f"{what}: expected an array of tables ([[control.filters]] with kind = \"notch\", ...), "
                          f"got {_short(raw)}")
    out = []
    for i, t in enumerate(raw, 1):
        at = f"{what}[{i}]"
        kind = t.get("kind")
        if not isinstance(kind, str) or kind not in _FILTER_KEYS:
            raise ConfigError(f"{at}.kind: expected one of {', '.join(_FILTER_KEYS)}, got {_short(kind)}")
        place = t.get("at", "torque")
        if place not in ("torque", "speed"):
            raise ConfigError(f"{at}.at: expected torque or speed, got {_short(place)}")
        extra = set(t) - set(_FILTER_KEYS[kind]) - {"kind", "at"}
        if extra:
            raise ConfigError(f"{at}: {', '.join(sorted(extra))}: not a key of a {kind} (its keys: kind, at, "
                              f"{', '.join(_FILTER_KEYS[kind])})")
        entry = {"kind": kind, "at": place}
        for key in _FILTER_KEYS[kind]:
            if key not in t and not (kind == "lowpass" and key == "damping"):
                raise ConfigError(f"{at}.{key}: missing (a {kind} needs {', '.join(_FILTER_KEYS[kind])})")
        try:
            if kind == "biquad":
                for key in ("b", "a"):
                    v = t[key]
                    if not (isinstance(v, list) and len(v) == 3 and all(
                            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
                        raise ConfigError(f"{at}.{key}: expected three numbers, got {_short(v)}")
                    entry[key] = [float(x) for x in v]
                if entry["a"][0] == 0:
                    raise ConfigError(f"{at}.a: the first coefficient must not be 0")
            else:
                entry["frequency"] = parse(t["frequency"], "frequency", f"{at}.frequency")
                if not entry["frequency"] > 0:
                    raise ConfigError(f"{at}.frequency: expected a positive frequency, got {_short(t['frequency'])}")
            if kind == "notch":
                entry["width"] = parse(t["width"], "frequency", f"{at}.width")
                if not 0 < entry["width"] < 2 * entry["frequency"]:
                    raise ConfigError(f"{at}.width: expected a width between 0 and twice the frequency, got "
                                      f"{_short(t['width'])}")
                entry["depth"] = parse_gain_db(t["depth"], f"{at}.depth")
                if not -120.0 <= entry["depth"] <= 0.0:
                    raise ConfigError(f"{at}.depth: expected a depth from -120 dB to 0 dB, got {_short(t['depth'])}")
            if kind == "lowpass":
                entry["damping"] = float(parse(t.get("damping", math.sqrt(0.5)), "dimensionless", f"{at}.damping"))
                if not 0 < entry["damping"] <= 10:
                    raise ConfigError(f"{at}.damping: expected a damping ratio above 0 and at most 10, got "
                                      f"{_short(t['damping'])}")
        except UnitError as exc:
            raise ConfigError(str(exc)) from None
        out.append(entry)
    for place in ("torque", "speed"):
        if sum(e["at"] == place for e in out) > 4:
            raise ConfigError(f"{what}: at most 4 filters on the {place} path")
    return out


def value_range(f: Field, kind: str) -> tuple[float | None, float]:
    """The smallest magnitude other than 0 and the largest value a number of field ``f`` (of
    ``kind``) may have, SI: the field's own bounds, else a time's :data:`TIME_RANGE`, else only
    :data:`MAX_MAGNITUDE`."""
    low = f.minimum if f.minimum is not None else (TIME_RANGE[0] if kind == "time" else None)
    top = f.maximum if f.maximum is not None else (TIME_RANGE[1] if kind == "time" else MAX_MAGNITUDE)
    return low, top


def _short(raw: Any, n: int = 60) -> str:
    """A value as written, cut for a one-line message."""
    r = repr(raw)
    return r if len(r) <= n else r[:n] + "..."


