"""Quantities written with units (``"100mm"``, ``"7000mm/min"``, ``"8.5e-4 kg*m^2"``) to SI floats.

Parsing is pint's; this module only fixes the project's conventions: every value inside the
program is SI, radians are dimensionless, and ``Nm`` means newton metre (pint would read
nanometre). The common spellings (``_COMMON_UNITS``: mm, ms, 1/s, N*m, ...) are read from a table
that tests hold to pint's reading, so that a command reading a shipped config does not pay pint's
start-up.

The other way, for what a person reads: :func:`fmt` writes an SI value in the unit an engineer of
feed drives reads (um or mm for a position, ms for a time, Hz, N m, N/um for a stiffness), the unit
chosen by the magnitude from a short ladder per kind (:data:`DISPLAY_UNITS`), the conversion
pint's. Every command's text output goes through it; JSON stays SI (the convention is in the
README, "Output: units").
"""
from __future__ import annotations

import math
import re
import unicodedata
from functools import lru_cache

from hil.errors import UnitError

__all__ = ["UnitError", "parse", "parse_option", "parse_list", "parse_bounded", "parse_angle_deg", "parse_gain_db", "DIMENSIONS",
           "fmt", "fmt_uncertain", "round_to_uncertainty", "display_unit", "DISPLAY_UNITS", "SI_UNIT"]


# Expected kinds of quantity, by name, as pint dimensionalities written as strings.
DIMENSIONS = {
    "dimensionless": "",
    "length": "[length]",
    "time": "[time]",
    "frequency": "1 / [time]",
    "loop_gain": "1 / [time]",
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
    "dimensionless": "1", "length": "m", "time": "s", "frequency": "1/s", "loop_gain": "1/s", "speed": "m/s",
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


def _import_pint():
    """pint, without the dask import its compatibility module does when dask is installed (0.14 s
    of every command's start, only to recognise dask arrays, which no quantity here is); dask itself
    stays importable (the fleet's scheduler imports it later)."""
    import sys
    if "pint" in sys.modules or "dask" in sys.modules:
        import pint
        return pint
    sys.modules["dask"] = None            # find_spec sees no dask: pint.compat leaves it alone
    try:
        import pint
    finally:
        if sys.modules.get("dask", 0) is None:
            del sys.modules["dask"]
    return pint


@lru_cache(maxsize=1)
def _registry():
    pint = _import_pint()

    try:
        # pint's parsed definitions cached on disk (the user's cache folder): a tenth of the time
        # of building the registry, which every command that reads a config pays at start-up
        return pint.UnitRegistry(autoconvert_offset_to_baseunit=True, cache_folder=":auto:")
    except OSError:         # no writable cache folder: build it from the definitions
        return pint.UnitRegistry(autoconvert_offset_to_baseunit=True)


# The spellings most quantities are written in (the shipped configs, the options' usual units),
# read without pint: its import and registry cost 0.25 s, a quarter of a short command such as
# `hil model`. Each is the unit's kind (its dimension, DIMENSIONS) and its exact SI factor;
# tests/test_units_common.py holds every entry, with the display units, to pint's own reading,
# and any other spelling goes to pint.
_COMMON_UNITS: dict[str, tuple[str, tuple[int, int]]] = {
    **{u: ("length", f) for u, f in (("m", (1, 1)), ("mm", (1, 10**3)), ("um", (1, 10**6)), ("nm", (1, 10**9)),
                                      ("cm", (1, 100)), ("km", (1000, 1)))},
    **{u: ("time", f) for u, f in (("s", (1, 1)), ("ms", (1, 10**3)), ("us", (1, 10**6)), ("min", (60, 1)))},
    **{u: ("frequency", f) for u, f in (("Hz", (1, 1)), ("kHz", (1000, 1)), ("1/s", (1, 1)), ("/s", (1, 1)),
                                         ("rad/s", (1, 1)))},
    **{u: ("speed", f) for u, f in (("m/s", (1, 1)), ("mm/s", (1, 10**3)), ("um/s", (1, 10**6)),
                                     ("m/min", (1, 60)), ("mm/min", (1, 60000)))},
    **{u: ("acceleration", f) for u, f in (("m/s^2", (1, 1)), ("m/s**2", (1, 1)), ("mm/s^2", (1, 10**3)),
                                            ("mm/s**2", (1, 10**3)))},
    **{u: ("jerk", f) for u, f in (("m/s^3", (1, 1)), ("m/s**3", (1, 1)), ("mm/s^3", (1, 10**3)),
                                    ("mm/s**3", (1, 10**3)))},
    **{u: ("mass", f) for u, f in (("kg", (1, 1)), ("g", (1, 10**3)))},
    **{u: ("inertia", (1, 1)) for u in ("kg*m^2", "kg*m**2")},
    **{u: ("stiffness", f) for u, f in (("N/m", (1, 1)), ("N/mm", (10**3, 1)), ("N/um", (10**6, 1)))},
    "N*s/m": ("damping", (1, 1)),
    **{u: ("force", f) for u, f in (("N", (1, 1)), ("kN", (1000, 1)))},
    **{u: ("torque", (1, 1)) for u in ("N*m", "N*m/rad")},
    **{u: ("rot_damping", (1, 1)) for u in ("N*m*s/rad", "N*m*s")},
    **{u: ("voltage", f) for u, f in (("V", (1, 1)), ("mV", (1, 10**3)))},
    "N/V": ("force_per_volt", (1, 1)),
    "V*s/m": ("volt_per_speed", (1, 1)),
    **{u: ("pressure", f) for u, f in (("Pa", (1, 1)), ("kPa", (10**3, 1)), ("MPa", (10**6, 1)),
                                        ("GPa", (10**9, 1)))},
    **{u: ("area", f) for u, f in (("m^2", (1, 1)), ("mm^2", (1, 10**6)))},
    "m^4": ("area_moment", (1, 1)),     # (not mm^4: pint's factor is (1e-3)**4, not 1e-12)
    "kg/m^3": ("density", (1, 1)),
}
# a number, then a unit that starts with a letter or "/" ("501/s" is 501 per second), or "1/s"
# after a space ("50 1/s")
_COMMON = re.compile(r"([+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)(?:\s*([A-Za-z/][A-Za-z0-9*/^]*)|\s+(1/s))")


def _common(text: str, kind: str) -> float | None:
    """``text`` (normalised) in SI where it is a number and one of :data:`_COMMON_UNITS` of the
    dimension of ``kind``, computed exactly and rounded once; None for pint to read."""
    m = _COMMON.fullmatch(text)
    if m is None:
        return None
    entry = _COMMON_UNITS.get(m.group(2) or m.group(3))
    if entry is None or DIMENSIONS[entry[0]] != DIMENSIONS[kind]:
        return None
    number = float(m.group(1))
    if not abs(number) < 1e200:         # near the float range's end: pint's own arithmetic decides
        return None
    from fractions import Fraction
    num, den = entry[1]
    return float(Fraction(m.group(1)) * num / den)


_DIGIT_GROUPS = re.compile(r"[0-9]_[0-9]")
_NM = re.compile(r"(?<![A-Za-z])Nm(?![A-Za-z])")


# Text copied from a datasheet, a PDF or a web page writes its signs and spaces with other
# characters than the keyboard's: the minus sign (U+2212) and the dashes, the non-breaking and thin
# spaces. pint drops a character it does not know, so "−10mm" read +10 mm: a sign lost is motion the
# wrong way. Every one is mapped to its ASCII meaning once, here, for the CLI, the config and --set.
_SIGNS = {"\u2212": "-", "\u2796": "-", "\ufe63": "-", "\uff0d": "-", "\u02d7": "-",
          "\ufe62": "+", "\uff0b": "+", "\u2795": "+"}
# (a soft hyphen, U+00AD, is not among them: pasted where a minus was meant, it is refused, not dropped)
_INVISIBLE = {"\u200b", "\u200c", "\u200d", "\u2060", "\ufeff"}
# what pint reads beyond ASCII: the micro sign, the degree, a dot or cross as a product, the ohm, pi,
# the angstrom, per mille, superscript exponents (m², s⁻¹); any other character is refused, never dropped
_KNOWN = set("µμ°·⋅×ΩπÅå‰⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁺")
# "1 000 mm", "1 500/s": a group of three digits after a space (the 1 of a unit "1/s" is one digit: "50 1/s")
_DIGITS_SPACED = re.compile(r"[0-9]\s+[0-9]{3}(?![0-9])")
_DECIMAL_COMMA = re.compile(r"[0-9],[0-9]")
_THOUSANDS_COMMA = re.compile(r"[0-9],[0-9]{3}(?![0-9])")


def _plain_character(ch: str) -> str:
    """The ASCII meaning of one character of a quantity text: a dash or a minus sign is ``-``, every
    space is ``' '``, an invisible character is nothing; any other character as it is."""
    if ch.isascii():
        return ch
    if ch in _SIGNS:
        return _SIGNS[ch]
    if ch in _INVISIBLE:
        return ""
    category = unicodedata.category(ch)
    if category == "Pd":                     # hyphen, figure dash, en dash, em dash, ...
        return "-"
    if category == "Zs":                     # no-break, thin, narrow no-break, figure space, ...
        return " "
    return ch


def plain_text(text: str) -> str:
    """``text`` with its Unicode signs and spaces written in ASCII (:func:`_plain_character`):
    ``"−10 mm"`` (a minus sign, a thin space) is ``"-10 mm"``."""
    if text.isascii():
        return text
    return "".join(_plain_character(ch) for ch in text)


def _cut(text: str, n: int = 40) -> str:
    """A text as a one-line message quotes it: its first ``n`` characters, "..." after a longer one."""
    return text if len(text) <= n else text[:n] + "..."


def _check_characters(text: str, original: str, what: str) -> None:
    """Refuse, in one line, what pint would read wrongly rather than not at all: a character it
    does not know (it drops it), digits apart (``1 000 mm`` is 1 x 000 mm to it) and a decimal
    comma (``1,5mm``)."""
    for ch in text:
        if not ch.isascii() and ch not in _KNOWN:
            name = unicodedata.name(ch, "unnamed")
            raise UnitError(f"{what}: cannot read {_cut(original)!r}: the character {ch!r} (U+{ord(ch):04X} {name}) "
                            f"is not part of a quantity, expected {_QUANTITY_EXAMPLE}")
    if _THOUSANDS_COMMA.search(text):          # "1,000 mm": a thousand, or one with a decimal comma?
        whole = _THOUSANDS_COMMA.sub(lambda m: m.group(0).replace(",", ""), text)
        point = _THOUSANDS_COMMA.sub(lambda m: m.group(0).replace(",", "."), text)
        raise UnitError(f"{what}: cannot read {_cut(original)!r}: a comma between digits is a thousands separator "
                        f"({whole!r}) or a decimal comma ({point!r}); write the one meant, with a point for decimals")
    if _DECIMAL_COMMA.search(text):
        hint = _DECIMAL_COMMA.sub(lambda m: m.group(0).replace(",", "."), text)
        raise UnitError(f"{what}: cannot read {_cut(original)!r}: a decimal comma; write a point ({hint!r})")
    if "," in text:
        raise UnitError(f"{what}: cannot read {_cut(original)!r}: a comma inside one quantity, expected "
                        f"{_QUANTITY_EXAMPLE}")
    if _DIGITS_SPACED.search(text):
        raise UnitError(f"{what}: cannot read {_cut(original)!r}: digits separated by a space (a thousands "
                        f"separator?); write the number whole, e.g. 1000 mm")


def _normalise(text: str) -> str:
    text = plain_text(text).strip().replace("µ", "u").replace("μ", "u")
    text = _NM.sub("N*m", text)
    text = text.replace("N m", "N*m")
    return text


# Bounds on a quantity written as text, checked before pint reads it: pint evaluates the
# arithmetic of the text (Python integers), so "10**10**10 mm" would compute a number of ten
# billion digits, and a long text costs in proportion. No quantity of an axis needs a power of a
# power, an exponent beyond MAX_EXPONENT or more than MAX_QUANTITY_CHARS characters.
MAX_QUANTITY_CHARS = 100
MAX_EXPONENT = 30
_POWER_OP = re.compile(r"\*\*|\^")
# an exponent: a plain number, signed, or a fraction of whole numbers in parentheses: m^2, s**-1, m^(1/2)
_EXPONENT = re.compile(r"\s*(?:\(\s*([+-]?\s*[0-9]+(?:\.[0-9]*)?)(?:\s*/\s*([0-9]+))?\s*\)|([+-]?\s*[0-9]+(?:\.[0-9]*)?))")
_QUANTITY_EXAMPLE = "a number and a unit, e.g. 10 mm or 8.5e-4 kg*m^2"


def check_quantity_text(text: str, kind: str, what: str = "value") -> None:
    """Refuse, in one line (a UnitError naming ``what``), a quantity text that would cost pint
    more than a quantity may: longer than :data:`MAX_QUANTITY_CHARS`, a power of a power
    (``10**10**10``, ``(2^3)^4``), an exponent that is not a plain number or beyond
    :data:`MAX_EXPONENT` in size."""
    shown = _cut(text)
    if len(text) > MAX_QUANTITY_CHARS:
        raise UnitError(f"{what}: {shown!r} ({len(text)} characters): expected a {kind} of at most "
                        f"{MAX_QUANTITY_CHARS} characters, {_QUANTITY_EXAMPLE}")
    for op in _POWER_OP.finditer(text):
        m = _EXPONENT.match(text, op.end())
        if m is None:
            raise UnitError(f"{what}: cannot read {shown!r} as a {kind}: an exponent must be a number (e.g. m^2, "
                            f"s**-1), expected {_QUANTITY_EXAMPLE}")
        num = float(re.sub(r"\s", "", m.group(1) or m.group(3)))
        size = abs(num / int(m.group(2))) if m.group(2) and int(m.group(2)) else abs(num)
        if size > MAX_EXPONENT:
            raise UnitError(f"{what}: cannot read {shown!r} as a {kind}: exponent {size:g} beyond "
                            f"{MAX_EXPONENT}, expected {_QUANTITY_EXAMPLE}")
        nested = _POWER_OP.match(text[m.end():].lstrip()) is not None
        base = text[:op.start()].rstrip()
        if not nested and base.endswith(")"):
            depth, i = 0, len(base) - 1
            while i >= 0:                          # the parenthesised base: does it hold a power?
                depth += {")": 1, "(": -1}.get(base[i], 0)
                if depth == 0:
                    break
                i -= 1
            nested = _POWER_OP.search(base[max(i, 0):]) is not None
        if nested:
            raise UnitError(f"{what}: cannot read {shown!r} as a {kind}: a power of a power is not allowed, "
                            f"expected {_QUANTITY_EXAMPLE}")


def _quiet_overflow():
    """numpy's overflow warning off: a huge logarithmic quantity ("1e300 dB") overflows inside pint
    to inf, which the keys and options that need a finite value refuse in one line; the warning
    would be a second line on stderr."""
    import numpy as np  # loaded with pint already
    return np.errstate(over="ignore")


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
        if len(value) > MAX_QUANTITY_CHARS:
            check_quantity_text(value, kind, what)           # one line, the text cut
        text = _normalise(value)
        if not text:
            raise UnitError(f"{what}: empty string, expected a {kind} ({SI_UNIT[kind]})")
        _check_characters(text, value, what)
        if text.lower() in ("inf", "+inf", "infinity"):
            return math.inf
        if _DIGIT_GROUPS.search(text):
            # Python's float() reads "1_000" as 1000: a written quantity means what it shows
            raise UnitError(f"{what}: cannot read {value!r} as a {kind}: '_' inside a number")
        try:
            return _finite_or_nan(float(text), what, kind)      # a bare number: SI already
        except ValueError:
            pass
        check_quantity_text(text, kind, what)
        out = _common(text, kind)
        if out is not None:
            return _rounded(out)
        ureg = _registry()
        try:
            with _quiet_overflow():
                q = ureg.Quantity(text)
        except Exception as exc:  # pint raises several kinds; all mean "cannot read this"
            # one line of bounded length: a long text of wide characters repr'd is ten times its length
            shown, why = repr(value), str(exc)
            shown = shown if len(shown) <= 80 else shown[:77] + "..."
            why = why if len(why) <= 120 else why[:117] + "..."
            raise UnitError(f"{what}: cannot read {shown} as a {kind} ({exc.__class__.__name__}: {why})") from None
        if not hasattr(q, "dimensionality"):
            out = float(q)
        else:
            want = ureg.get_dimensionality(DIMENSIONS[kind]) if DIMENSIONS[kind] else {}
            if dict(q.dimensionality) != dict(want):
                got = str(q.dimensionality) if q.dimensionality else "none (a plain number)"
                raise UnitError(
                    f"{what}: {value!r} is not a {kind}: its unit has dimension {got}, expected "
                    f"{DIMENSIONS[kind] or 'none'} (e.g. {SI_UNIT[kind]})")
            with _quiet_overflow():
                out = float(q.to_base_units().magnitude)
    else:
        raise UnitError(f"{what}: expected a number or a string with a unit, got {type(value).__name__}")
    if math.isnan(out):
        raise UnitError(f"{what}: NaN is not a {kind}")
    return _rounded(out)


def _rounded(out: float) -> float:
    """Quantities like "10 um" come back from pint as 9.999999999999999e-06: rounded to 15
    significant digits (the exact reading of a common unit too, so both read alike)."""
    if out != 0.0 and math.isfinite(out):
        out = float(f"{out:.15g}")
    return out


# The units a command-line option of each kind is usually written in, for the message that asks for
# one (the first few of each kind; pint reads any other unit of the dimension as well).
OPTION_UNITS = {
    "length": "mm, um, m", "time": "s, ms, us", "frequency": "Hz, kHz", "loop_gain": "1/s",
    "speed": "mm/min, m/min, mm/s, m/s", "acceleration": "m/s^2, mm/s^2", "jerk": "m/s^3, mm/s^3",
    "angular_speed": "rad/s, rpm", "force": "N, kN", "torque": "N*m", "voltage": "V, mV",
}

_BARE_NUMBER = re.compile(r"[+\-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+\-]?[0-9]+)?")


def option_units(kind: str) -> str:
    """The units named in the message for a bare number given for ``kind`` (``"s, ms, us"``)."""
    if kind in OPTION_UNITS:
        return OPTION_UNITS[kind]
    return ", ".join(dict.fromkeys([shown for shown, _, _ in DISPLAY_UNITS.get(kind, [])] + [SI_UNIT[kind]]))


def parse_option(value, kind: str, what: str) -> float:
    """:func:`parse` for a command-line option: the one rule of the command line is that a quantity
    carries its unit, so a bare number is refused with one line naming the units it takes
    (``--tacc 200: a time needs its unit (s, ms, us)``), where :func:`parse` (the config's rule,
    config/SCHEMA.md) would read it as SI. Numbers whose meaning no unit changes stay bare: a
    dimensionless kind, zero and ``inf``.
    """
    text = _normalise(value) if isinstance(value, str) else value
    if kind != "dimensionless" and isinstance(text, str) and _BARE_NUMBER.fullmatch(text) and float(text) != 0.0:
        noun = kind.replace("_", " ")
        article = "an" if noun[0] in "aeiou" else "a"
        raise UnitError(f"{what} {value}: {article} {noun} needs its unit ({option_units(kind)})")
    return parse(value, kind, what)


def parse_list(text: str, kind: str, what: str = "value", *, option: bool = False) -> list[float]:
    """Comma-separated quantities, e.g. ``"60ms,80ms,90ms"``; a unit on the last one applies to
    the bare numbers before it (``"60,80,90ms"``). ``option``: a command-line option's list, whose
    numbers need a unit (:func:`parse_option`): on the last one at least."""
    parts = [p.strip() for p in plain_text(str(text)).split(",") if p.strip()]
    if not parts:
        raise UnitError(f"{what}: empty list")
    unit = re.sub(r"^[\s+\-0-9.eE]*", "", parts[-1])
    out = []
    for p in parts:
        if unit and re.fullmatch(r"[+\-]?[0-9.]+([eE][+\-]?[0-9]+)?", p):
            p = p + " " + unit
        out.append(parse_option(p, kind, what) if option else parse(p, kind, what))
    return out


def parse_bounded(value, kind: str, what: str, *, positive: bool = False, nonnegative: bool = False,
                  minimum: float | None = None, maximum: float | None = None) -> float:
    """:func:`parse_option` for a command-line option that must be a finite number within bounds
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
    x = parse_option(value, kind, what)
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



def parse_angle_deg(value, what: str = "value") -> float:
    """An angle in degrees, for the options that are read in degrees (a phase margin): ``"45deg"``,
    ``"45 °"``, ``"0.785rad"``; a bare number is taken in degrees (the unit such a figure is always
    quoted in, not radians). One clear line (a UnitError) for anything else, inf or NaN."""
    text = _normalise(str(value)).replace("°", " deg")
    try:
        deg = float(text)
    except ValueError:
        check_quantity_text(text, "angle", what)
        try:
            with _quiet_overflow():
                deg = float(_registry().Quantity(text).to("deg").magnitude)
        except Exception:      # pint: not readable, or not an angle
            raise UnitError(f"{what}: expected an angle (e.g. 45deg or 0.785rad), got {value!r}") from None
        if not re.search(r"[A-Za-z]", text):          # "2*3": a number, not an angle
            raise UnitError(f"{what}: expected an angle (e.g. 45deg or 0.785rad), got {value!r}")
    if not math.isfinite(deg):
        raise UnitError(f"{what}: expected a finite angle (e.g. 45deg), got {value!r}")
    return float(f"{deg:.15g}")


_DB = re.compile(r"^\s*([+\-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+\-]?[0-9]+)?)\s*(dB|db|)\s*$")


def parse_gain_db(value, what: str = "value") -> float:
    """A gain in decibels, for the options that are read in dB (a gain margin): ``"6dB"``,
    ``"6 dB"``; a bare number is taken in dB. One clear line (a UnitError) for anything else."""
    m = _DB.match(plain_text(str(value)))
    if m is None:
        raise UnitError(f"{what}: expected a gain in dB (e.g. 6dB), got {value!r}")
    return float(m.group(1))

# The units a person reads, per kind: (unit as printed, as pint reads it, the largest |SI value| it
# is used up to). The first rung whose limit the magnitude stays below is taken; the last is the
# fallback. Printed spellings are ASCII (um, not the micro sign; "N m", as in the config files).
DISPLAY_UNITS: dict[str, list[tuple[str, str, float]]] = {
    "length": [("nm", "nm", 1e-6), ("um", "um", 1e-3), ("mm", "mm", 10.0), ("m", "m", math.inf)],
    "time": [("us", "us", 1e-3), ("ms", "ms", 1.0), ("s", "s", math.inf)],
    "frequency": [("Hz", "Hz", 1e4), ("kHz", "kHz", math.inf)],
    # a position loop's gain Kv: a speed per following error, 1/s (never Hz: it is no frequency of a cycle)
    "loop_gain": [("1/s", "1/s", math.inf)],
    "speed": [("mm/s", "mm/s", 0.1), ("m/s", "m/s", math.inf)],
    "acceleration": [("m/s^2", "m/s^2", math.inf)],
    "jerk": [("m/s^3", "m/s^3", math.inf)],
    "mass": [("g", "g", 0.1), ("kg", "kg", math.inf)],
    "inertia": [("kg m^2", "kg*m^2", math.inf)],
    "stiffness": [("N/m", "N/m", 1e3), ("N/mm", "N/mm", 1e6), ("N/um", "N/um", math.inf)],
    "damping": [("N s/m", "N*s/m", math.inf)],
    "force": [("N", "N", 1e4), ("kN", "kN", math.inf)],
    "torque": [("N m", "N*m", math.inf)],
    "rot_stiffness": [("N m/rad", "N*m", math.inf)],
    "rot_damping": [("N m s/rad", "N*m*s", math.inf)],
    "angular_speed": [("rad/s", "1/s", math.inf)],
    "voltage": [("mV", "mV", 1.0), ("V", "V", math.inf)],
    "force_per_volt": [("N/V", "N/V", math.inf)],
    "pressure": [("Pa", "Pa", 1e3), ("kPa", "kPa", 1e6), ("MPa", "MPa", math.inf)],
    "area": [("mm^2", "mm^2", 1e-2), ("m^2", "m^2", math.inf)],
    "area_moment": [("mm^4", "mm^4", 1e-4), ("m^4", "m^4", math.inf)],
    "density": [("kg/m^3", "kg/m^3", math.inf)],
    "volt_per_speed": [("V s/m", "V*s/m", math.inf)],
    "dimensionless": [("", "", math.inf)],
}


@lru_cache(maxsize=None)
def _factor(kind: str, pint_unit: str) -> float:
    """SI value * factor = value in ``pint_unit`` (pint's conversion, cached per unit; a common
    unit's is the same number, had without pint)."""
    if not pint_unit:
        return 1.0
    entry = _COMMON_UNITS.get(pint_unit)
    if entry is not None and DIMENSIONS[entry[0]] == DIMENSIONS[kind]:
        num, den = entry[1]
        return 1.0 / (num / den)        # as pint divides: 1 / 1e-9 is 999999999.9999999
    ureg = _registry()
    si = ureg.Quantity(1.0, _normalise(SI_UNIT[kind]).replace("^", "**"))
    return float(si.to(pint_unit.replace("^", "**")).magnitude)


def display_unit(value: float, kind: str, unit: str | None = None) -> tuple[str, float]:
    """The unit :func:`fmt` prints ``value`` (SI) in, and the factor from SI to it.

    ``unit``: a fixed unit (printed as given, e.g. ``"um"`` for a column of figures that should
    share one unit); default: chosen by the magnitude from :data:`DISPLAY_UNITS`.
    """
    if kind not in DIMENSIONS:
        raise KeyError(f"unknown kind of quantity {kind!r}")
    if unit is not None:
        return unit, _factor(kind, _normalise(unit))
    ladder = DISPLAY_UNITS.get(kind) or [(SI_UNIT[kind], SI_UNIT[kind], math.inf)]
    mag = abs(value) if isinstance(value, (int, float)) and math.isfinite(value) else 0.0
    for shown, pint_unit, limit in ladder:
        if mag < limit:
            return shown, _factor(kind, pint_unit)
    shown, pint_unit, _ = ladder[-1]
    return shown, _factor(kind, pint_unit)


def fmt(value, kind: str, digits: int = 4, unit: str | None = None) -> str:
    """``value`` (SI) as text in an engineering unit: ``fmt(2.033e-4, "length")`` -> ``"203.3 um"``,
    ``fmt(8.94, "torque")`` -> ``"8.94 N m"``, ``fmt(0.012, "time")`` -> ``"12 ms"``.

    Parameters
    ----------
    value : float or None
        SI value; None and NaN are written ``n/a``.
    kind : str
        A key of :data:`DIMENSIONS`.
    digits : int
        Significant digits (``g`` format: no trailing zeros, no e-notation for 1e-4 .. 1e6).
    unit : str, optional
        Print in this unit instead of the one chosen by the magnitude.
    """
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    value = float(value)
    if math.isinf(value):
        return ("-" if value < 0 else "") + "inf"
    shown, factor = display_unit(value, kind, unit)
    x = value * factor
    text = f"{x:.{digits}g}"
    if "e" in text and abs(x) >= 1:          # 12345 m/s^3, not 1.234e+04
        text = f"{x:.0f}"
    return f"{text} {shown}" if shown else text


def round_to_uncertainty(value: float, sigma: float | None, sig: int = 2) -> tuple[float, int | None]:
    """``value`` rounded to the last digit that its standard error ``sigma`` leaves meaningful
    (``sig`` significant digits of sigma): ``(40.0912, 0.0374)`` -> ``(40.091, 3)``; returns the
    rounded value and the number of decimals kept (None: sigma unknown or zero, value kept to 6
    significant digits)."""
    if sigma is None or not math.isfinite(sigma) or sigma <= 0 or not math.isfinite(value):
        return (float(f"{value:.6g}") if math.isfinite(value) else value), None
    decimals = sig - 1 - int(math.floor(math.log10(sigma)))
    return round(value, decimals), decimals


def fmt_uncertain(value: float, sigma: float | None, kind: str, unit: str | None = None) -> str:
    """``value +- sigma`` in one engineering unit, the value rounded to its uncertainty:
    ``fmt_uncertain(40.0912, 0.0374, "damping")`` -> ``"40.091 +- 0.037 N s/m"``."""
    shown, factor = display_unit(value, kind, unit)
    v = value * factor
    s = None if sigma is None or not math.isfinite(sigma) else abs(sigma) * factor
    r, dec = round_to_uncertainty(v, s)
    tail = f" {shown}" if shown else ""
    if dec is None:
        return f"{r:.6g}{tail}" if math.isfinite(v) else f"{v}{tail}"
    d = max(dec, 0)
    return f"{r:.{d}f} +- {s:.{d}f}{tail}" if dec >= 0 else f"{r:.0f} +- {round(s, dec):.0f}{tail}"


def kind_of(si_unit: str) -> str | None:
    """The kind of quantity whose SI unit is ``si_unit`` (``"m"`` -> ``"length"``, ``"N*m"`` ->
    ``"torque"``), None when no kind has it; for channels that carry their unit, not their kind."""
    want = si_unit.replace("*", " ").strip()
    for kind in ("length", "time", "torque", "force", "speed", "acceleration", "voltage", "frequency", "mass"):
        if SI_UNIT[kind].replace("*", " ") == want:
            return kind
    return None


def fmt_si(value, si_unit: str, digits: int = 4) -> str:
    """:func:`fmt` for a value known by its SI unit (a record's channel): ``fmt_si(2.03e-4, "m")``
    -> ``"203 um"``; a unit of no known kind is written as given."""
    kind = kind_of(si_unit)
    if kind is None and si_unit in ANGLE_LADDER and value is not None and math.isfinite(float(value)):
        # an angle (a motor's position on a record without a screw): urad, mrad or rad by magnitude
        shown, scale = next(((n, k) for n, k in ANGLE_LADDER[si_unit] if abs(float(value)) >= k),
                            ANGLE_LADDER[si_unit][-1])
        text = f"{float(value) / scale:.{digits}g}"
        return f"{float(value) / scale:.0f} {shown}" if "e" in text and abs(float(value)) >= 1 else f"{text} {shown}"
    if kind is None:
        return "n/a" if value is None else f"{float(value):.{digits}g} {si_unit}".rstrip()
    return fmt(value, kind, digits)


# the displayed units of an angle and an angular speed, largest first
ANGLE_LADDER = {"rad": (("rad", 1.0), ("mrad", 1e-3), ("urad", 1e-6)),
                "rad/s": (("rad/s", 1.0), ("mrad/s", 1e-3), ("urad/s", 1e-6))}
