"""Numbers as an engineer reads them in reports and on figure axes: um, mm, ms, mm/s, N m, never
SI e-notation.

Everything inside the project is SI (``hil.units``); only the display changes here. For a value
(or a set of values that share one column or one axis) :func:`display_unit` picks the unit of
its family in which the largest magnitude reads at least 1 (0.000203 m -> 203.3 um, 0.0103 m ->
10.3 mm, 0.35 s -> 350 ms), and :func:`fmt` writes the number with ``digits`` significant digits
in fixed-point notation. A unit with no family here (%, dB, m/s^3) is kept as it is.
:func:`engineering_text` rewrites the sentences the library writes in SI (the diagnosis's
evidence, "RMS x_motor error 4.51e-05 -> 2.1e-06 m") in the same units, keeping each number's
significant digits.
"""
from __future__ import annotations

import math
import re

__all__ = ["display_unit", "fmt", "eng", "unit_label", "engineering_text"]

# SI unit (as the project writes it) -> its display units, smallest first: (name, SI per unit)
FAMILIES = {
    "m": (("um", 1e-6), ("mm", 1e-3), ("m", 1.0)),
    "s": (("us", 1e-6), ("ms", 1e-3), ("s", 1.0)),
    "m/s": (("um/s", 1e-6), ("mm/s", 1e-3), ("m/s", 1.0)),
    "N*m": (("mN m", 1e-3), ("N m", 1.0)),
    "N": (("mN", 1e-3), ("N", 1.0), ("kN", 1e3)),
    "V": (("mV", 1e-3), ("V", 1.0)),
    "rad": (("mrad", 1e-3), ("rad", 1.0)),
    "rad/s": (("mrad/s", 1e-3), ("rad/s", 1.0)),
    "Hz": (("Hz", 1.0), ("kHz", 1e3)),
    "N/m": (("N/m", 1.0), ("N/mm", 1e3), ("N/um", 1e6)),
}
# other spellings of the same SI units
ALIASES = {"N m": "N*m", "Nm": "N*m", "N.m": "N*m", "m s^-1": "m/s", "1/s": "Hz"}
# how a unit with no family is written
PLAIN = {"m/s^2": "m/s^2", "m/s^3": "m/s^3", "N s/m": "N s/m", "kg": "kg", "": ""}


def _family(unit: str):
    return FAMILIES.get(ALIASES.get(unit, unit))


def display_unit(unit: str, *values) -> tuple[str, float]:
    """(display unit, SI per display unit) for values in the SI ``unit``: the largest unit of the
    family in which the largest finite magnitude of ``values`` reads at least 1 (the smallest
    unit when all are smaller, the SI unit when there is none)."""
    fam = _family(unit)
    if fam is None:
        return unit.replace("*", " "), 1.0
    mags = [abs(float(v)) for v in _flat(values) if v is not None and math.isfinite(float(v)) and v != 0]
    if not mags:
        return next((n, s) for n, s in fam if s == 1.0)
    top = max(mags)
    chosen = fam[0]
    for name, scale in fam:
        if top / scale >= 1.0 - 1e-6:     # 0.000999999 s is 1.000 ms
            chosen = (name, scale)
    return chosen


def _flat(values):
    for v in values:
        if isinstance(v, (list, tuple)):
            yield from _flat(v)
        elif hasattr(v, "ravel"):
            yield from (float(x) for x in v.ravel())
        else:
            yield v


def fmt(value, digits: int = 4, scale: float = 1.0) -> str:
    """``value / scale`` with ``digits`` significant digits in fixed-point notation ("-" for
    None, "nan"/"inf" as such): 203.3, 0.04120, 12500."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    x = float(value) / scale
    if not math.isfinite(x):
        return str(x)
    if abs(x) < 1e-9:                  # below the last decimal shown
        return "0"
    mag = math.floor(math.log10(abs(x)))
    decimals = max(0, min(9, digits - 1 - mag))
    return f"{x:.{decimals}f}"


def eng(value, unit: str, digits: int = 4) -> str:
    """One value with its unit, in the display unit its magnitude asks for: ``eng(2.033e-4, "m")``
    is "203.3 um"."""
    if value is None:
        return "-"
    name, scale = display_unit(unit, value)
    return f"{fmt(value, digits, scale)} {name}".rstrip()


def unit_label(unit: str) -> str:
    """How an SI unit is written on an axis or in a table header (N*m -> N m)."""
    return PLAIN.get(unit, unit.replace("*", " "))


_NUM = r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"
_UNIT = "|".join(sorted((re.escape(u) for u in (*FAMILIES, *ALIASES)), key=len, reverse=True))
_END = r"(?![\w/*^])"                     # not the start of a longer unit (mm, m/s^2, samples)
_PAIR = re.compile(rf"(?<![\w.])({_NUM}) -> ({_NUM}) ({_UNIT}){_END}")
_ONE = re.compile(rf"(?<![\w.])({_NUM}) ({_UNIT}){_END}")
_BARE = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?[eE][-+]?\d+\b")


def _digits(number: str) -> int:
    """Significant digits of a number as written (at least 2, at most 6)."""
    mantissa = re.split("[eE]", number)[0].lstrip("+-").replace(".", "").lstrip("0")
    return min(max(len(mantissa), 2), 6)


def engineering_text(text: str) -> str:
    """``text`` with each SI quantity ("4.51e-05 m", "0.0203 N*m", "a -> b m") written in the
    unit an engineer reads, and any other e-notation as a plain number; the significant digits
    of each number kept."""
    def pair(m):
        a, b, unit = m.group(1), m.group(2), m.group(3)
        name, k = display_unit(unit, float(a), float(b))
        return f"{fmt(float(a), _digits(a), k)} -> {fmt(float(b), _digits(b), k)} {name}"

    def one(m):
        return eng(float(m.group(1)), m.group(2), _digits(m.group(1)))

    text = _PAIR.sub(pair, text)
    text = _ONE.sub(one, text)
    return _BARE.sub(lambda m: fmt(float(m.group(0)), _digits(m.group(0))), text)
