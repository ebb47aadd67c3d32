"""The configuration's loader: a TOML file (or text) read, flattened to dotted keys, converted
by the schema (:mod:`hil.config.schema`) and checked as a whole (:class:`Config`, :func:`load`,
:func:`loads`, ``--set`` values by :func:`parse_assignment`)."""
from __future__ import annotations

import copy
import logging
import math
import re
import tomllib
from pathlib import Path
from typing import Any

from drivers.schema import Field
from hil.config.schema import (
    _CHAIN_KEYS,
    _NUMBERED,
    _NUMBERED_RE,
    MAX_CONFIG_BYTES,
    MAX_CONFIG_DEPTH,
    SCHEMA,
    _convert,
    _flatten,
    _known_in_section,
    _known_sections,
    _short,
    did_you_mean,
    field_for,
)
from hil.errors import ConfigError
from hil.units import SI_UNIT

logger = logging.getLogger("hil.config")      # the name users filter on (--log-level), as before the split


class Config:
    """A validated configuration: SI values by dotted name, and where they came from."""

    def __init__(self, values: dict[str, Any], source: str = "<config>"):
        self.values = values
        self.source = source
        self.overrides: dict[str, Any] = {}     # the --set values it was loaded with, as given
        self.file_keys: frozenset[str] = frozenset()   # the keys its file writes (not defaults, not --set)

    def command_line(self) -> str:
        """``--config FILE --set KEY=VALUE ...``: the options that load this config again, for a
        hint that names a command to run (``hil reset`` after a trip), quoted for a POSIX shell
        with double quotes (the hint itself stands in single quotes)."""
        import re
        words = ["--config", self.source]
        for key, value in self.overrides.items():
            words += ["--set", f"{key}={_assignment_text(value)}"]
        safe = re.compile(r"[\w@%+=:,./-]+")
        return " ".join(w if safe.fullmatch(w) else '"' + re.sub(r'(["\\$`])', r"\\\1", w) + '"' for w in words)

    # -- access ------------------------------------------------------------------------------
    def __getitem__(self, key: str) -> Any:
        if key not in self.values:
            raise KeyError(f"{self.source}: no parameter {key!r}")
        return self.values[key]

    def get(self, key: str, default: Any = None) -> Any:
        v = self.values.get(key, default)
        return default if v is None else v

    def __contains__(self, key: str) -> bool:
        return key in self.values and self.values[key] is not None

    def keys(self):
        return self.values.keys()

    def section(self, prefix: str) -> dict[str, Any]:
        """The keys below ``prefix.``, without the prefix."""
        n = len(prefix) + 1
        return {k[n:]: v for k, v in self.values.items() if k.startswith(prefix + ".")}

    @property
    def n_masses(self) -> int:
        return sum(1 for k in self.values if re.fullmatch(r"plant\.m[0-9]+", k))

    @property
    def rotary(self) -> bool:
        return self.values.get("actuator.type", "rotary") == "rotary"

    # -- change --------------------------------------------------------------------------------
    def with_values(self, changes: dict[str, Any], source: str | None = None) -> "Config":
        """A new config with ``changes`` (raw values, with or without units) applied and validated."""
        raw = {k: v for k, v in self.values.items() if v is not None}
        for k, v in changes.items():
            if v is None:
                raw.pop(k, None)
            else:
                raw[k] = v
        # the values it keeps are validated already: only the changed ones are converted again (the
        # same values: a validated value converts to itself; a kind depends on actuator.type alone)
        known = None if "actuator.type" in changes else self.values
        # the chain's keys unchanged: the chain this config passed is the same
        chain = any(k in _CHAIN_KEYS or _NUMBERED_RE.match(k) for k in changes) or known is None
        return _validate(raw, source or self.source, known, check_chain=chain)

    def without(self, prefix: str) -> "Config":
        raw = {k: v for k, v in self.values.items() if not k.startswith(prefix) and v is not None}
        return _validate(raw, self.source)

    def to_toml(self) -> str:
        """TOML text of this configuration, SI values with their unit written out."""
        sections: dict[str, list[str]] = {}
        for key, value in self.values.items():
            if value is None:
                continue
            sect, _, name = key.rpartition(".")
            f = field_for(key)
            sections.setdefault(sect, []).append(f"{name} = {_toml_value(value, f, self.values)}")
        lines = []
        for sect, rows in sections.items():
            lines.append(f"[{sect}]")
            lines.extend(rows)
            lines.append("")
        return "\n".join(lines)


def _toml_value(value, f: Field | None, values: dict) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, int):
        return str(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v, None, values) for v in value) + "]"
    if isinstance(value, float):
        kind = f.kind_for(values) if f else "dimensionless"
        unit = SI_UNIT.get(kind, "1") if isinstance(kind, str) else "1"
        if math.isinf(value):
            return '"inf"'
        text = repr(value)
        return text if unit == "1" else f'"{text} {unit}"'
    return repr(value)


def _validate(raw: dict[str, Any], where: str, known: dict[str, Any] | None = None,
              check_chain: bool = True) -> Config:
    """The config of the raw values ``raw`` (units as written), converted to SI and checked; ``known``:
    the values of a validated config with the same ``actuator.type``, whose entries that ``raw``
    holds unchanged (the same object) are taken as they are (:meth:`Config.with_values`: a fit
    changes a few keys of a config thousands of times); ``check_chain`` False: the chain's keys are
    those of ``known``'s config, which passed its checks."""
    values: dict[str, Any] = {}
    # actuator.type first: other kinds depend on it
    if "actuator.type" in raw:
        values["actuator.type"] = _convert("actuator.type", raw["actuator.type"], SCHEMA["actuator.type"], {}, where)
    for key, value in raw.items():
        if known is not None and key in known and known[key] is value and key != "actuator.type":
            # validated as it is (a list copied, as its conversion would)
            values[key] = list(value) if isinstance(value, list) else value
            continue
        f = field_for(key)
        if f is None:
            section = key.split(".", 1)[0] if "." in key else ""
            known = _known_in_section(section) if section else ""
            hint = f" (known keys in [{section}]: {known})" if known else \
                f" (known sections: {', '.join(_known_sections())})"
            raise ConfigError(f"{where}: unknown key {key!r}{hint}{did_you_mean(key, raw)}")
        if key == "actuator.type":
            continue
        values[key] = _convert(key, value, f, values, where)
    # defaults and required keys
    for key, f in SCHEMA.items():
        if "*" in key:
            continue
        if key not in values:
            if f.required:
                kind = f.kind_for(values)
                unit = SI_UNIT.get(kind, kind)
                raise ConfigError(f"{where}: missing required key {key!r} ({f.doc}; a {kind.replace('_', ' ')} in {unit})")
            values[key] = copy.deepcopy(f.default)
    if check_chain:
        _check_chain(values, where)
    _check_consistency(values, where)
    return Config(values, where)


def _check_chain(values: dict, where: str) -> None:
    idx = {c: sorted(int(m.group(2)) for k in values if (m := _NUMBERED_RE.match(k)) and m.group(1) == c)
           for c in "mkc"}
    n = len(idx["m"])
    if n == 0:
        raise ConfigError(f"{where}: missing required key 'plant.m1' (the chain needs at least one mass, in kg)")
    for c, count in (("m", n), ("k", n - 1), ("c", n - 1)):
        want = list(range(1, count + 1))
        if idx[c] != want:
            missing = [f"plant.{c}{i}" for i in want if i not in idx[c]]
            extra = [f"plant.{c}{i}" for i in idx[c] if i not in want]
            if missing:
                raise ConfigError(f"{where}: missing required key {missing[0]!r} (a chain of {n} masses needs "
                                  f"{c}1..{c}{count}; {_NUMBERED[c][0]})")
            raise ConfigError(f"{where}: unknown key {extra[0]!r} (a chain of {n} masses has {c}1..{c}{count})")
    for name, key in (("table", "plant.table_mass"), ("tip", "plant.tip_mass")):
        if values[key] > n:
            raise ConfigError(f"{where}: {key}: expected a mass number 1..{n} (or 0 for the default), "
                              f"got {values[key]}")


def _check_consistency(values: dict, where: str) -> None:
    rotary = values["actuator.type"] == "rotary"
    if rotary and values.get("plant.pitch") is None:
        raise ConfigError(f"{where}: missing required key 'plant.pitch' (a rotary actuator needs the screw pitch, "
                          f"a length in m, e.g. \"10 mm\")")
    if not rotary and values.get("actuator.gain") is None:
        raise ConfigError(f"{where}: missing required key 'actuator.gain' (a linear actuator needs its force "
                          f"per unit of controller output, in N/V)")
    tp, tv = values["control.position_period"], values["control.velocity_period"]
    ratio = tp / tv
    if abs(ratio - round(ratio)) > 1e-6 * ratio or round(ratio) < 1:
        raise ConfigError(f"{where}: control.position_period: expected a whole multiple of "
                          f"control.velocity_period ({tv:g} s), got {tp:g} s (ratio {ratio:.6g})")
    for i, flt in enumerate(values.get("control.filters") or (), 1):
        if "frequency" in flt and not flt["frequency"] < 0.5 / tv:
            raise ConfigError(f"{where}: control.filters[{i}].frequency: expected below the velocity loop's Nyquist "
                              f"frequency {0.5 / tv:g} Hz, got {flt['frequency']:g} Hz")
    if values["limits.travel_min"] >= values["limits.travel_max"]:
        raise ConfigError(f"{where}: limits.travel_min: expected less than limits.travel_max "
                          f"({values['limits.travel_max']:g} m), got {values['limits.travel_min']:g} m")
    if values["friction.static"] is not None and values["friction.static"] < values["friction.coulomb"]:
        raise ConfigError(f"{where}: friction.static: expected at least friction.coulomb "
                          f"({values['friction.coulomb']:g}), got {values['friction.static']:g}")


def _toml(text: str, source: str) -> dict:
    """The TOML document ``text``, within :data:`MAX_CONFIG_BYTES` and :data:`MAX_CONFIG_DEPTH`;
    anything else is one ConfigError naming ``source``."""
    if len(text) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{source}: {len(text)} characters, expected a configuration of at most "
                          f"{MAX_CONFIG_BYTES // 1024} KiB")
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    except RecursionError:            # arrays or inline tables nested some thousand deep
        raise ConfigError(f"{source}: arrays or tables nested too deeply (expected at most "
                          f"{MAX_CONFIG_DEPTH} levels)") from None
    if _depth(table) > MAX_CONFIG_DEPTH:
        raise ConfigError(f"{source}: arrays or tables nested too deeply (expected at most "
                          f"{MAX_CONFIG_DEPTH} levels)")
    return table


def _depth(value) -> int:
    """How deeply tables and arrays nest in ``value`` (a scalar: 0), without recursion."""
    deepest, todo = 0, [(value, 1)]
    while todo:
        v, d = todo.pop()
        items = v.values() if isinstance(v, dict) else v if isinstance(v, list) else None
        if items is None:
            continue
        deepest = max(deepest, d)
        if d <= MAX_CONFIG_DEPTH:
            todo.extend((x, d + 1) for x in items)
    return deepest


def loads(text: str, source: str = "<string>", overrides: dict[str, Any] | None = None) -> Config:
    table = _toml(text, source)
    raw = _flatten(table)
    written = frozenset(raw)
    if overrides:
        for k, v in overrides.items():
            if field_for(k) is None:
                raise ConfigError(f"--set {k}: unknown key {k!r} (not a parameter of {source})"
                                  f"{did_you_mean(k)}")
            raw[k] = v
    cfg = _validate(raw, source)
    cfg.overrides = dict(overrides or {})
    cfg.file_keys = written
    return cfg


def _assignment_text(value: Any) -> str:
    """The VALUE of ``--set KEY=VALUE`` that :func:`parse_assignment` reads back as ``value``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        try:
            tomllib.loads(f"v = {value}")
        except tomllib.TOMLDecodeError:
            return value                      # read back as the same string
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    import json
    return json.dumps(value)


def examples_dir() -> Path:
    """The folder of the example configurations and ``SCHEMA.md``: ``hil/examples`` in an installed
    wheel (pyproject.toml maps ``config/`` there), ``config/`` of a source tree."""
    here = Path(__file__).resolve().parents[1]          # the hil package
    shipped = here / "examples"
    return shipped if shipped.is_dir() else here.parent / "config"


def example_names() -> list[str]:
    """The file names of the shipped example configurations, sorted."""
    folder = examples_dir()
    return sorted(p.name for p in folder.glob("*.toml")) if folder.is_dir() else []


def shipped_example(path: Path) -> Path | None:
    """The shipped example that a missing ``path`` names: ``NAME.toml`` or ``config/NAME.toml``."""
    if path.is_absolute() or path.parent not in (Path("."), Path("config")) or path.suffix != ".toml":
        return None
    shipped = examples_dir() / path.name
    return shipped if shipped.is_file() else None


def load(path: str | Path, overrides: dict[str, Any] | None = None) -> Config:
    """Read and validate a TOML configuration file; ``overrides`` are ``--set`` values.

    A relative ``NAME.toml`` or ``config/NAME.toml`` that is not a file is read from the shipped
    examples (:func:`examples_dir`), so that an installed package runs the README's commands.
    """
    p = Path(path)
    if not p.exists() and (shipped := shipped_example(p)) is not None:
        p = path = shipped
    try:
        if p.exists() and not p.is_file():
            raise ConfigError(f"{path}: is not a file, expected a configuration file (TOML)")
        if p.exists() and p.stat().st_size > MAX_CONFIG_BYTES:
            raise ConfigError(f"{path}: {p.stat().st_size} bytes, expected a configuration of at most "
                              f"{MAX_CONFIG_BYTES // 1024} KiB")
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such configuration file (shipped examples, by name: "
                          f"{', '.join(example_names()) or 'none'})") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file") from None
    logger.debug("reading the configuration %s (overrides: %s)", p, overrides or "none")
    return loads(text, str(path), overrides)


def parse_assignment(text: str) -> tuple[str, Any]:
    """``"plant.c2=33"`` or ``"plant.c2=33 N*s/m"`` -> ("plant.c2", value)."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected KEY=VALUE, e.g. plant.c2=33")
    key, _, value = text.partition("=")
    key, value = key.strip(), value.strip()
    try:
        parsed = _toml(f"v = {value}", f"--set {_short(key, 60)}")["v"]
    except ConfigError as exc:
        if "nested too deeply" in str(exc) or "KiB" in str(exc):
            raise
        parsed = value
    return key, parsed


