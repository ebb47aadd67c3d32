"""Closed-form modes (Eq. 2, 4, 5, Appendix 1) against the generic eigenproblem of Chain.modes()."""
import math

import numpy as np
import pytest

from sim_plant.chain import Chain
from sim_plant.modal import frequencies_3dof, modal_matrix_2dof, modal_matrix_3dof, omega_2dof

M3 = (335.57, 392.97, 4.228)
K3 = (5.362e7, 3.7060e4)


def hz(w):
    return np.asarray(w) / (2 * math.pi)


def test_paper_bench_3dof_frequencies():
    f = frequencies_3dof(*M3, *K3)
    assert hz(f.w2) == pytest.approx(14.94, abs=0.01)
    assert hz(f.w3) == pytest.approx(86.63, abs=0.01)
    assert f.m_T == pytest.approx(sum(M3))
    # Eq. (5): w123^2 is the sum of the three "others held" frequencies
    assert f.w123**2 == pytest.approx(f.w1r23**2 + f.w2r13**2 + f.w3r12**2)
    # the characteristic polynomial's invariants: sum and product of the non-zero roots
    assert f.w2**2 + f.w3**2 == pytest.approx(f.w123**2)
    assert (f.w2 * f.w3)**2 == pytest.approx(K3[0] * K3[1] * f.m_T / math.prod(M3))


def test_paper_bench_2dof_frequency():
    assert hz(omega_2dof(335.57, 392.97 + 4.228, 5.362e7)) == pytest.approx(86.41, abs=0.01)
    assert hz(omega_2dof(335.57, 392.97, 5.362e7)) == pytest.approx(86.62, abs=0.01)


@pytest.mark.parametrize("m,k", [(M3, K3), ((1.0, 2.0, 3.0), (10.0, 40.0)), ((5.0, 0.1, 7.0), (3.0, 1e3))])
def test_modal_matrix_3dof_matches_eigenproblem(m, k):
    w, phi = modal_matrix_3dof(*m, *k)
    w_ref, phi_ref = Chain(m, k, (0.0, 0.0)).modes()
    np.testing.assert_allclose(w, w_ref, rtol=1e-9, atol=1e-6)
    # eigenvectors agree up to sign (both conventions: first entry positive)
    for j in range(3):
        s = np.sign(phi[:, j] @ phi_ref[:, j])
        np.testing.assert_allclose(phi[:, j], s * phi_ref[:, j], atol=1e-9 * np.abs(phi_ref).max())
    M = np.diag(m)
    np.testing.assert_allclose(phi.T @ M @ phi, np.eye(3), atol=1e-12)
    K = Chain(m, k, (0.0, 0.0)).K
    np.testing.assert_allclose(phi.T @ K @ phi, np.diag(w**2), atol=1e-8 * w[-1]**2)
    np.testing.assert_allclose(phi[:, 0], 1 / math.sqrt(sum(m)))


def test_modal_matrix_2dof_matches_eigenproblem():
    m, k = (335.57, 397.198), (5.362e7,)
    w, phi = modal_matrix_2dof(*m, *k)
    w_ref, phi_ref = Chain(m, k, (0.0,)).modes()
    np.testing.assert_allclose(w, w_ref, rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(phi, phi_ref, atol=1e-12)
