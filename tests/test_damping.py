"""Damping closed forms (Eq. 7, 9, 10) against Phi^T C Phi of the generic eigenvectors and against
the eigenvalues of the damped state matrix."""
import math

import numpy as np
import pytest

from sim_plant.chain import Chain
from sim_plant.damping import c1_c2_from_ratio, c2_from_c1, c_2dof, modal_ratios_3dof, ratios_from_c

M3 = (335.57, 392.97, 4.228)
K3 = (5.362e7, 3.7060e4)
C1 = 16789.0


def test_eq9_gives_c2_11_6():
    # the paper prints 11.80; its own Eq. 9 with its own c1 gives 11.6 (NOTES.md)
    assert c2_from_c1(M3, K3, C1) == pytest.approx(11.6, abs=0.05)


def test_eq9_makes_modal_damping_diagonal():
    chain = Chain(M3, K3, (C1, c2_from_c1(M3, K3, C1)))
    _, phi = chain.modes()
    modal = phi.T @ chain.C @ phi
    off = modal - np.diag(np.diag(modal))
    assert np.abs(off).max() < 1e-12 * np.abs(modal).max()


def test_paper_ratios_mode3_about_0085_mode2_about_0015():
    z = ratios_from_c(M3, K3, (C1, 11.80))
    assert z[0] == pytest.approx(0.015, abs=0.0005)
    assert z[1] == pytest.approx(0.085, abs=0.0005)
    np.testing.assert_allclose(z, Chain(M3, K3, (C1, 11.80)).modal_damping_ratios(), rtol=1e-9)


def test_viscous_friction_moves_mode3_to_0090():
    cm = 0.0076 * (2 * math.pi / 0.01) ** 2     # N m s/rad reflected to N s/m
    z = Chain(M3, K3, (C1, 11.80), (cm, 0.0, 0.0)).modal_damping_ratios(include_ground=True)
    assert z[1] == pytest.approx(0.090, abs=0.0005)


def test_eq10_against_phi_c_phi_and_damped_eigenvalues():
    c2 = c2_from_c1(M3, K3, C1)
    z10 = modal_ratios_3dof(M3, K3, C1)
    np.testing.assert_allclose(z10, ratios_from_c(M3, K3, (C1, c2)), rtol=1e-9)
    np.testing.assert_allclose(z10, Chain(M3, K3, (C1, c2)).modal_damping_ratios(), rtol=1e-9)
    # proportional damping: the ratios are exact, the state matrix's eigenvalues agree
    _, zd = Chain(M3, K3, (C1, c2)).damped_modes(include_ground=False)
    np.testing.assert_allclose(zd[-2:], z10, rtol=1e-6)


@pytest.mark.parametrize("mode", [2, 3])
def test_c1_c2_from_ratio_round_trip(mode):
    c1, c2 = c1_c2_from_ratio(*M3, *K3, 0.0839, mode=mode)
    assert c2 == pytest.approx(c2_from_c1(M3, K3, c1))
    assert ratios_from_c(M3, K3, (c1, c2))[mode - 2] == pytest.approx(0.0839, rel=1e-9)


def test_paper_c1_from_0839_on_mode3():
    # 0.0839 given to the 87 Hz mode gives c1 within 2 % of the paper's 16 789
    c1, c2 = c1_c2_from_ratio(*M3, *K3, 0.0839, mode=3)
    assert c1 == pytest.approx(16530, rel=1e-3)
    assert c1 == pytest.approx(C1, rel=0.02)


def test_c1_c2_from_ratio_rejects_bad_mode():
    with pytest.raises(ValueError, match="mode"):
        c1_c2_from_ratio(*M3, *K3, 0.05, mode=1)


def test_eq7_two_dof():
    m1, m2, k = 335.57, 397.198, 5.362e7
    c = c_2dof(0.05, m1, m2, k)
    assert ratios_from_c((m1, m2), (k,), (c,))[0] == pytest.approx(0.05, rel=1e-12)
    _, zd = Chain((m1, m2), (k,), (c,)).damped_modes(include_ground=False)
    assert zd[-1] == pytest.approx(0.05, rel=1e-9)
