"""Damping coefficients from damping ratios and back (Section 2.1.1, Eq. 7-10).

Under proportional damping the modal damping matrix Phi^T C Phi is diagonal with entries
2 zeta_i omega_i (Eq. 8). For the 3-dof chain that leaves one free value: Eq. (9) ties c2 to c1,
and Eq. (10) gives both modal ratios from c1, so one chosen ratio fixes c1 and c2.
"""
from __future__ import annotations

import numpy as np

from sim_plant.modal import frequencies_3dof, modal_matrix_2dof, modal_matrix_3dof, omega_2dof

__all__ = ["c_2dof", "c2_from_c1", "modal_ratios_3dof", "c1_c2_from_ratio", "ratios_from_c"]


def c_2dof(zeta: float, m1: float, m2: float, k: float) -> float:
    """Eq. (7): c = 2 zeta omega_2 m1 m2 / (m1 + m2)."""
    return 2.0 * zeta * omega_2dof(m1, m2, k) * m1 * m2 / (m1 + m2)


def c2_from_c1(m, k, c1: float) -> float:
    """Eq. (9): the c2 that makes the damping of the 3-dof chain proportional (Phi^T C Phi diagonal)."""
    f = frequencies_3dof(*m, *k)
    w1, w3r, a, b = f.w1r23**2, f.w3r12**2, f.w2**2, f.w3**2
    return c1 * (-w3r**2 + a * w3r + b * w3r - a * b) / ((a - w1) * (b - w1))


def modal_ratios_3dof(m, k, c1: float) -> np.ndarray:
    """Eq. (10): the damping ratios (zeta_2, zeta_3) of the elastic modes, with c2 from Eq. (9)."""
    m1, m2, m3 = m
    f = frequencies_3dof(*m, *k)
    w1, w3r = f.w1r23**2, f.w3r12**2
    out = []
    for w, other in ((f.w2, f.w3), (f.w3, f.w2)):
        a, b = w**2, other**2
        num = c1 * w**3 * (a - b) * (a - w3r) * (w3r - w1)
        den = 2.0 * (b - w1) * (m3 * w3r**2 * (a - w1)**2 + m1 * (a - w3r)**2 * w1**2
                                + m2 * (a - w3r)**2 * (a - w1)**2)
        out.append(num / den)
    return np.array(out)


def c1_c2_from_ratio(m1: float, m2: float, m3: float, k1: float, k2: float, zeta: float,
                     mode: int = 3) -> tuple[float, float]:
    """(c1, c2) giving the elastic ``mode`` (2: the lower, 3: the upper) the damping ratio ``zeta``
    under proportional damping. Eq. (10) is linear in c1; Eq. (9) then gives c2."""
    if mode not in (2, 3):
        raise ValueError(f"mode: expected 2 or 3 (the elastic modes of a 3-dof chain), got {mode!r}")
    m, k = (m1, m2, m3), (k1, k2)
    c1 = zeta / modal_ratios_3dof(m, k, 1.0)[mode - 2]
    return c1, c2_from_c1(m, k, c1)


def ratios_from_c(m, k, c) -> np.ndarray:
    """Damping ratios of the elastic modes implied by given dampings c (any c, proportional or not):
    diag(Phi^T C Phi) / (2 omega) with the closed-form modal matrix of a 2- or 3-dof chain.

    Exact when the damping is proportional; otherwise the classical (diagonal) approximation."""
    m, k, c = tuple(m), tuple(k), tuple(c)
    if len(m) == 2:
        w, phi = modal_matrix_2dof(*m, *k)
    elif len(m) == 3:
        w, phi = modal_matrix_3dof(*m, *k)
    else:
        raise ValueError(f"closed forms exist for 2 or 3 masses, got {len(m)}")
    # each link i contributes c_i (phi_i - phi_{i+1})^2 to the diagonal
    d = np.diff(phi, axis=0)
    modal = np.einsum("i,ij->j", np.asarray(c, float), d**2)
    return modal[1:] / (2.0 * w[1:])
