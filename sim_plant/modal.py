"""Closed-form modes of the 2-dof and 3-dof free chains (Eq. 2, 4, 5 and Appendix 1).

These are the paper's formulas, kept as a second computation next to the generic eigenproblem of
:meth:`sim_plant.chain.Chain.modes`; the tests compare the two.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["omega_2dof", "Frequencies3", "frequencies_3dof", "modal_matrix_2dof", "modal_matrix_3dof",
           "transmission_mode"]


def omega_2dof(m1: float, m2: float, k: float) -> float:
    """Eq. (2): the elastic mode of the 2-dof chain, rad/s."""
    return math.sqrt(k * (m1 + m2) / (m1 * m2))


class Frequencies3(NamedTuple):
    """Eq. (4)-(5), all in rad/s (m_T in kg).

    ``w1r23``: mass 1 alone on k1 (masses 2 and 3 held), ``w2r13``: mass 2 between k1 and k2,
    ``w3r12``: mass 3 on k2; ``w123^2`` is their sum of squares; ``w2``, ``w3`` the elastic modes."""
    w1r23: float
    w2r13: float
    w3r12: float
    w123: float
    m_T: float
    w2: float
    w3: float


def frequencies_3dof(m1: float, m2: float, m3: float, k1: float, k2: float) -> Frequencies3:
    w1 = math.sqrt(k1 / m1)
    w2r = math.sqrt((k1 + k2) / m2)
    w3r = math.sqrt(k2 / m3)
    w123_sq = w1**2 + w2r**2 + w3r**2
    m_T = m1 + m2 + m3
    root = math.sqrt(w123_sq**2 - 4.0 * k1 * k2 * m_T / (m1 * m2 * m3))
    # the lower root by the product of roots: the difference form loses digits when w2 << w3
    w3_sq = 0.5 * (w123_sq + root)
    w2_sq = k1 * k2 * m_T / (m1 * m2 * m3) / w3_sq
    return Frequencies3(w1, w2r, w3r, math.sqrt(w123_sq), m_T, math.sqrt(w2_sq), math.sqrt(w3_sq))


def modal_matrix_2dof(m1: float, m2: float, k: float):
    """(omega [0, w2], Phi) with mass-normalized columns, first row positive."""
    w2 = omega_2dof(m1, m2, k)
    shape = np.array([[1.0, 1.0], [1.0, -m1 / m2]])   # elastic mode: momentum m1 x1 + m2 x2 = 0
    return np.array([0.0, w2]), _normalize(shape, np.array([m1, m2]))


def modal_matrix_3dof(m1: float, m2: float, m3: float, k1: float, k2: float):
    """(omega [0, w2, w3], Phi): Appendix 1, Eq. (17)-(19), re-derived.

    Row 1 of K phi = w^2 M phi gives phi_2 = (1 - w^2/w1r23^2) phi_1; row 3 gives
    phi_3 = phi_2 / (1 - w^2/w3r12^2). With phi_1 = 1 the norm is the paper's a_i of Eq. (19):
    a^2 = m1 + m2 (1 - w^2/w1r23^2)^2 + m3 (1 - w^2/w1r23^2)^2 / (1 - w^2/w3r12^2)^2, so the
    normalized column is [1, 1 - w^2/w1r23^2, (1 - w^2/w1r23^2)/(1 - w^2/w3r12^2)] / a
    (the transcription of Eq. 17-18 scrambles these entries). The rigid mode is 1/sqrt(m_T)."""
    f = frequencies_3dof(m1, m2, m3, k1, k2)
    cols = [np.ones(3)]
    for w in (f.w2, f.w3):
        r1 = 1.0 - w**2 / f.w1r23**2
        cols.append(np.array([1.0, r1, r1 / (1.0 - w**2 / f.w3r12**2)]))
    return np.array([0.0, f.w2, f.w3]), _normalize(np.column_stack(cols), np.array([m1, m2, m3]))


def _normalize(shape: np.ndarray, m: np.ndarray) -> np.ndarray:
    norms = np.sqrt(np.einsum("ij,i,ij->j", shape, m, shape))
    return shape / norms


def transmission_mode(chain, link: int = 0) -> float:
    """Natural frequency (Hz) of the chain's transmission mode: the elastic mode that strains
    ``link`` (0: motor to table, k1) the most, by its share of the mode's strain energy
    k_link (phi_i - phi_i+1)^2 / (phi^T K phi). On the 3-dof bench this is omega_3 of Eq. (5)
    (87 Hz); with a heavier or extra tip mode it stays the k1 mode however the modes are ordered."""
    w, phi = chain.modes()
    K = chain.K
    best, share = 0.0, -1.0
    for j in range(1, len(w)):
        v = phi[:, j]
        total = float(v @ K @ v)
        if total <= 0.0:
            continue
        e = chain.k[link] * (v[link] - v[link + 1]) ** 2 / total
        if e > share:
            best, share = float(w[j]), e
    return best / (2.0 * math.pi)
