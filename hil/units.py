"""Quantities written with units (``"100mm"``, ``"7000mm/min"``, ``"8.5e-4 kg*m^2"``) to SI floats.

Parsing is pint's; this module only fixes the project's conventions: every value inside the
program is SI, radians are dimensionless, and ``Nm`` means newton metre (pint would read
nanometre).
"""
from __future__ import annotations

import math
import re
from functools import lru_cache

from hil.errors import UnitError

__all__ = ["UnitError", "parse", "parse_list", "parse_bounded", "DIMENSIONS"]


# Expected kinds of quantity, by name, as pint dimensionalities written as strings.
DIMENSIONS = {
    "dimensionless": "",
    "length": "[length]",
    "time": "[time]",
    "frequency": "1 / [time]",
    "speed": "[length] / [time]",
    "acceleration": "[length] / [time] ** 2",
    "jerk": "[length] / [time] ** 3",
    "mass": "[mass]",
    "inertia": "[length] ** 2 * [mass]",
    "stiffness": "[mass] / [time] ** 2",
    "damping": "[mass] / [time]",
    "force": "[length] * [mass] / [time] ** 2",
    "torque": "[length] ** 2 * [mass] / [time] ** 2",
    "rot_stiffness": "[length] ** 2 * [mass] / [time] ** 2",
    "rot_damping": "[length] ** 2 * [mass] / [time]",
    "angular_speed": "1 / [time]",
    "voltage": "[length] ** 2 * [mass] / [current] / [time] ** 3",
    "force_per_volt": "[current] * [time] / [length]",
    "pressure": "[mass] / [length] / [time] ** 2",
    "area": "[length] ** 2",
    "area_moment": "[length] ** 4",
    "density": "[mass] / [length] ** 3",
    "volt_per_speed": "[length] * [mass] / [current] / [time] ** 2",
}

# What a bare number means for each kind (the SI unit), for messages.
SI_UNIT = {
    "dimensionless": "1", "length": "m", "time": "s", "frequency": "1/s", "speed": "m/s",
    "acceleration": "m/s^2", "jerk": "m/s^3", "mass": "kg", "inertia": "kg*m^2",
    "stiffness": "N/m", "damping": "N*s/m", "force": "N", "torque": "N*m",
    "rot_stiffness": "N*m/rad", "rot_damping": "N*m*s/rad", "angular_speed": "rad/s",
    "voltage": "V", "force_per_volt": "N/V", "pressure": "Pa", "area": "m^2",
    "area_moment": "m^4", "density": "kg/m^3", "volt_per_speed": "V*s/m",
}


def _finite_or_nan(value: float, what: str, kind: str) -> float:
    if math.isnan(value):
        raise UnitError(f"{what}: NaN is not a {kind}")
    return value


@lru_cache(maxsize=1)
def _registry():
    import pint

    try:
        # pint's parsed definitions cached on disk (the user's cache folder): a tenth of the time
        # of building the registry, which every command that reads a config pays at start-up
        return pint.UnitRegistry(autoconvert_offset_to_baseunit=True, cache_folder=":auto:")
    except OSError:         # no writable cache folder: build it from the definitions
        return pint.UnitRegistry(autoconvert_offset_to_baseunit=True)


_DIGIT_GROUPS = re.compile(r"[0-9]_[0-9]")
_NM = re.compile(r"(?<![A-Za-z])Nm(?![A-Za-z])")


def _normalise(text: str) -> str:
    text = text.strip().replace("µ", "u").replace("μ", "u")
    text = _NM.sub("N*m", text)
    text = text.replace("N m", "N*m")
    return text


def parse(value, kind: str, what: str = "value") -> float:
    """Return ``value`` in SI units, checking that it is a quantity of ``kind``.

    Numbers are taken as already SI. Strings may carry a unit; a string without one is taken as
    SI too. ``"inf"`` is accepted (e.g. an integral time that disables the integral action).
    """
    if kind not in DIMENSIONS:
        raise KeyError(f"unknown kind of quantity {kind!r}")
    if isinstance(value, bool):
        raise UnitError(f"{what}: expected a {kind} ({SI_UNIT[kind]}), got a boolean {value!r}")
    if isinstance(value, (int, float)):
        out = float(value)
    elif isinstance(value, str):
        text = _normalise(value)
        if not text:
            raise UnitError(f"{what}: empty string, expected a {kind} ({SI_UNIT[kind]})")
        if text.lower() in ("inf", "+inf", "infinity"):
            return math.inf
        if _DIGIT_GROUPS.search(text):
            # Python's float() reads "1_000" as 1000: a written quantity means what it shows
            raise UnitError(f"{what}: cannot read {value!r} as a {kind}: '_' inside a number")
        try:
            return _finite_or_nan(float(text), what, kind)      # a bare number: SI already
        except ValueError:
            pass
        ureg = _registry()
        try:
            q = ureg.Quantity(text)
        except Exception as exc:  # pint raises several kinds; all mean "cannot read this"
            raise UnitError(f"{what}: cannot read {value!r} as a {kind} ({exc.__class__.__name__}: {exc})") from None
        if not hasattr(q, "dimensionality"):
            out = float(q)
        else:
            want = ureg.get_dimensionality(DIMENSIONS[kind]) if DIMENSIONS[kind] else {}
            if dict(q.dimensionality) != dict(want):
                got = str(q.dimensionality) if q.dimensionality else "none (a plain number)"
                raise UnitError(
                    f"{what}: {value!r} is not a {kind}: its unit has dimension {got}, expected "
                    f"{DIMENSIONS[kind] or 'none'} (e.g. {SI_UNIT[kind]})")
            out = float(q.to_base_units().magnitude)
    else:
        raise UnitError(f"{what}: expected a number or a string with a unit, got {type(value).__name__}")
    if math.isnan(out):
        raise UnitError(f"{what}: NaN is not a {kind}")
    # Quantities like "10 um" come back as 9.999999999999999e-06: round to 15 significant digits.
    if out != 0.0 and math.isfinite(out):
        out = float(f"{out:.15g}")
    return out


def parse_list(text: str, kind: str, what: str = "value") -> list[float]:
    """Comma-separated quantities, e.g. ``"60ms,80ms,90ms"``; a unit on the last one applies to
    the bare numbers before it (``"60,80,90ms"``)."""
    parts = [p.strip() for p in str(text).split(",") if p.strip()]
    if not parts:
        raise UnitError(f"{what}: empty list")
    unit = re.sub(r"^[\s+\-0-9.eE]*", "", parts[-1])
    out = []
    for p in parts:
        if unit and re.fullmatch(r"[+\-]?[0-9.]+([eE][+\-]?[0-9]+)?", p):
            p = p + " " + unit
        out.append(parse(p, kind, what))
    return out


def parse_bounded(value, kind: str, what: str, *, positive: bool = False, nonnegative: bool = False,
                  minimum: float | None = None, maximum: float | None = None) -> float:
    """:func:`parse` for a command-line option that must be a finite number within bounds
    (SI): one clear line (a UnitError) for inf, a sign that does not fit, or a value out of range.

    Parameters
    ----------
    value, kind, what
        As for :func:`parse`; ``what`` names the option in the message (e.g. ``"--dwell"``).
    positive, nonnegative : bool
        Require > 0 or >= 0.
    minimum, maximum : float, optional
        Bounds, SI (inclusive); the message shows them in SI units.
    """
    x = parse(value, kind, what)
    unit = SI_UNIT[kind]
    if not math.isfinite(x):
        raise UnitError(f"{what}: expected a finite {kind} ({unit}), got {value!r}")
    if positive and not x > 0:
        raise UnitError(f"{what}: expected a positive {kind} ({unit}), got {value!r}")
    if nonnegative and not x >= 0:
        raise UnitError(f"{what}: expected a {kind} >= 0 ({unit}), got {value!r}")
    if minimum is not None and x < minimum:
        raise UnitError(f"{what}: expected a {kind} of at least {minimum:g} {unit}, got {value!r}")
    if maximum is not None and x > maximum:
        raise UnitError(f"{what}: expected a {kind} of at most {maximum:g} {unit}, got {value!r}")
    return x
