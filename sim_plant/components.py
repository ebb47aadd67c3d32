"""Equivalent stiffness and masses of the 3-dof model from catalogue data (Appendix 2 and 3,
Eq. 13, 14, 20-25).

Rotary elements (motor shaft, coupling, screw torsion, inertias) are reflected to the linear
side through the pitch p: a torsional stiffness or inertia is multiplied by (2 pi/p)^2.
A components file (TOML, units written out) is read by :func:`load_components`; see
``config/paper_bench_components.toml`` for the layout.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from hil.config import ConfigError
from hil.units import UnitError, parse

__all__ = ["k_torsional", "k_axial", "k_flexure", "k_screw_axial", "k_nut_table", "k1_equivalent",
           "m1_equivalent", "m2_equivalent", "Equivalents", "equivalents", "load_components",
           "components_from_dict"]


# --- Eq. (20): elements ------------------------------------------------------------------------

def k_torsional(G: float, J: float, L: float) -> float:
    """G J / L, N m/rad (J: polar second moment of area)."""
    return G * J / L


def k_axial(E: float, A: float, L: float) -> float:
    """E A / L, N/m."""
    return E * A / L


def k_flexure(E: float, I: float, L: float) -> float:
    """3 E I / L^3, N/m: a cantilever loaded at its end."""
    return 3.0 * E * I / L**3


# --- Eq. (13), (14), (21)-(25) -----------------------------------------------------------------

def _series(*k: float) -> float:
    return 1.0 / sum(1.0 / x for x in k)


def k_screw_axial(k_tb: float, k_Ha1: float, k_b: float, k_Ha2: float) -> float:
    """Eq. (13): the screw side towards the thrust bearing and the side towards the other
    bearing act in parallel on the nut, each in series with its bearing."""
    return _series(k_tb, k_Ha1) + _series(k_b, k_Ha2)


def k_nut_table(k_aT: float, k_aS: float, k_ft: float) -> float:
    """Eq. (14): nut, nut support and the four bending screws to the table, in series."""
    return _series(k_aT, k_aS, 4.0 * k_ft)


def k1_equivalent(pitch, k_em, k_AF, k_Ht, k_Ha, k_T, k_M) -> float:
    """Eq. (21)-(22): the transmission, motor to table, as springs in series; the screw's torsion
    and axial stiffness act in parallel."""
    r2 = (2.0 * math.pi / pitch) ** 2
    return _series(k_em * r2, k_AF * r2, k_Ht * r2 + k_Ha, k_T, k_M)


def m1_equivalent(pitch, J_m) -> float:
    """Eq. (23): motor inertia reflected to the linear side."""
    return J_m * (2.0 * math.pi / pitch) ** 2


def m2_equivalent(pitch, J_AF1, J_AF2, J_H, m_T, m_M, extra=0.0) -> float:
    """Eq. (24)-(25): coupling halves, screw, nut and table, plus ``extra`` mass carried by the
    table (on the paper's bench a 9.15 kg block holding the compliant mass)."""
    r2 = (2.0 * math.pi / pitch) ** 2
    return (J_AF1 + J_AF2 + J_H) * r2 + m_T + m_M + extra


# --- the components file -----------------------------------------------------------------------

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


@dataclass(frozen=True)
class Equivalents:
    """The 3-dof model's k1, m1, m2 (and k2, m3 of the compliant structure), SI units.

    ``compliance`` is each element's share of 1/k1 (they sum to 1): where the transmission gives."""
    k1: float
    m1: float
    m2: float
    k2: float
    m3: float
    compliance: dict = field(default_factory=dict)


def equivalents(c: dict[str, float]) -> Equivalents:
    """Eq. (21)-(25) on validated component values (from :func:`load_components`)."""
    p = c["drive.pitch"]
    r2 = (2.0 * math.pi / p) ** 2
    springs = {"k_em": c["stiffness.k_em"] * r2, "k_AF": c["stiffness.k_AF"] * r2,
               "k_Ht+k_Ha": c["stiffness.k_Ht"] * r2 + c["stiffness.k_Ha"],
               "k_T": c["stiffness.k_T"], "k_M": c["stiffness.k_M"]}
    k1 = k1_equivalent(p, c["stiffness.k_em"], c["stiffness.k_AF"], c["stiffness.k_Ht"], c["stiffness.k_Ha"],
                       c["stiffness.k_T"], c["stiffness.k_M"])
    return Equivalents(
        k1=k1,
        m1=m1_equivalent(p, c["inertia.J_m"]),
        m2=m2_equivalent(p, c["inertia.J_AF1"], c["inertia.J_AF2"], c["inertia.J_H"], c["mass.m_T"],
                         c["mass.m_M"], c["mass.extra_table"]),
        k2=c["stiffness.k_c"], m3=c["mass.m_c"],
        compliance={name: k1 / k for name, k in springs.items()})
