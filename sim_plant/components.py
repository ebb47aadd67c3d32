"""Equivalent stiffness and masses of the 3-dof model from catalogue data (Appendix 2 and 3,
Eq. 13, 14, 20-25).

Rotary elements (motor shaft, coupling, screw torsion, inertias) are reflected to the linear
side through the pitch p: a torsional stiffness or inertia is multiplied by (2 pi/p)^2.
A components file (TOML, units written out; see ``config/paper_bench_components.toml`` for the
layout) is read into SI values by :func:`hil.plant_config.load_components`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["k_torsional", "k_axial", "k_flexure", "k_screw_axial", "k_nut_table", "k1_equivalent",
           "m1_equivalent", "m2_equivalent", "Equivalents", "equivalents", "k_screw_fixed_free",
           "k_screw_fixed_fixed", "k1_along_travel"]


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


# --- the screw's axial stiffness with the nut at a distance from the bearings (Eq. 13, 20) ------------

def k_screw_fixed_free(E: float, A: float, L: float) -> float:
    """A screw held axially at one end only (fixed-free): the nut at a distance ``L`` from the fixed
    bearing sees the screw length L in tension or compression, E A / L (Eq. 20), N/m."""
    return k_axial(E, A, L)


def k_screw_fixed_fixed(E: float, A: float, L: float, a: float) -> float:
    """A screw held axially at both ends (fixed-fixed), bearings ``L`` apart, the nut at ``a``
    from one of them: the two lengths act in parallel on the nut (Eq. 13 with rigid bearings),
    E A / a + E A / (L - a) = E A L / (a (L - a)), N/m; least, 4 E A / L, in the middle."""
    if not 0.0 < a < L:
        raise ValueError(f"k_screw_fixed_fixed: the nut must lie between the bearings (0 < a < L), got a={a:g}, "
                         f"L={L:g}")
    return E * A * L / (a * (L - a))


def k1_along_travel(k_screw: float, k_rest: float) -> float:
    """The transmission stiffness with the screw's axial term ``k_screw`` in series with the
    compliances that do not move with the nut (motor shaft, coupling, bearings, nut, nut-table
    link: Eq. 21 with the screw's torsion left in ``k_rest``), N/m."""
    return _series(k_screw, k_rest)


def m1_equivalent(pitch, J_m) -> float:
    """Eq. (23): motor inertia reflected to the linear side."""
    return J_m * (2.0 * math.pi / pitch) ** 2


def m2_equivalent(pitch, J_AF1, J_AF2, J_H, m_T, m_M, extra=0.0) -> float:
    """Eq. (24)-(25): coupling halves, screw, nut and table, plus ``extra`` mass carried by the
    table (on the paper's bench a 9.15 kg block holding the compliant mass)."""
    r2 = (2.0 * math.pi / pitch) ** 2
    return (J_AF1 + J_AF2 + J_H) * r2 + m_T + m_M + extra


# --- the 3-dof model ---------------------------------------------------------------------------

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
    """Eq. (21)-(25) on component values in SI by dotted key (``drive.pitch``, ``stiffness.k_em``,
    ..., as :func:`hil.plant_config.load_components` returns them)."""
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
