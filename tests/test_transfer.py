"""Transfer functions: generic cofactors vs corrected Table 1 vs the state-space frequency response."""
import math

import numpy as np
import pytest

from sim_plant.chain import Chain
from sim_plant.transfer import (
    TransferFunction,
    chain_tfs,
    drive_side,
    freqresp,
    table1_2dof,
    table1_3dof,
    to_control,
)

M3 = (335.57, 392.97, 4.228)
K3 = (5.362e7, 3.7060e4)
C3 = (16789.0, 11.80)
F = np.array([1.0, 5.0, 14.9, 30.0, 86.6, 200.0, 1000.0])


def same_tf(a, b, rtol=1e-9):
    a, b = a.cancel_s().normalized(), b.cancel_s().normalized()
    assert a.num.shape == b.num.shape and a.den.shape == b.den.shape
    np.testing.assert_allclose(a.num, b.num, rtol=rtol)
    np.testing.assert_allclose(a.den, b.den, rtol=rtol)


def ss_positions(chain, f_hz):
    """x_i / f at each frequency from C (sI - A)^-1 B."""
    ss = chain.state_space()
    out = []
    for f in f_hz:
        s = 2j * math.pi * f
        out.append((ss.C @ np.linalg.solve(s * np.eye(len(ss.A)) - ss.A, ss.B))[:, 0])
    return np.array(out)


def test_generic_matches_table1_3dof():
    for g, t in zip(chain_tfs(Chain(M3, K3, C3)), table1_3dof(*M3, *K3, *C3)):
        same_tf(g, t)


def test_generic_matches_table1_2dof():
    m, k, c = (335.57, 397.198), (5.362e7,), (16789.0,)
    for g, t in zip(chain_tfs(Chain(m, k, c)), table1_2dof(*m, *k, *c)):
        same_tf(g, t)


def test_table1_signs_corrected():
    # the transcription's (m2 - m3) would give a different d2; the corrected one is d2 = (m1+m2+m3) k1 k2
    tf1 = table1_3dof(*M3, *K3, *C3)[0]
    assert tf1.den[-3] == pytest.approx(sum(M3) * K3[0] * K3[1])
    assert tf1.den[-2] == 0.0 and tf1.den[-1] == 0.0


@pytest.mark.parametrize("cg", [(0.0, 0.0, 0.0), (0.0076 * (2 * math.pi / 0.01) ** 2, 0.0, 0.0)])
def test_against_state_space_response(cg):
    chain = Chain(M3, K3, C3, cg)
    x = ss_positions(chain, F)
    tf1, tf2, tf3 = chain_tfs(chain)
    np.testing.assert_allclose(freqresp(tf1, F), x[:, 0], rtol=1e-8)
    np.testing.assert_allclose(tf2.freqresp(F), x[:, 1] / x[:, 0], rtol=1e-8)
    np.testing.assert_allclose(tf3.freqresp(F), x[:, 2] / x[:, 1], rtol=1e-8)


def test_ground_damping_leaves_one_integrator():
    cm = 0.0076 * (2 * math.pi / 0.01) ** 2
    tf1 = chain_tfs(Chain(M3, K3, C3, (cm, 0.0, 0.0)))[0]
    assert tf1.den[-1] == 0.0 and tf1.den[-2] != 0.0


def test_four_mass_chain():
    chain = Chain((1.0, 2.0, 0.5, 3.0), (100.0, 50.0, 20.0), (0.3, 0.2, 0.1))
    x = ss_positions(chain, F[:4])
    tfs = chain_tfs(chain)
    np.testing.assert_allclose(tfs[0].freqresp(F[:4]), x[:, 0], rtol=1e-8)
    for i in range(1, 4):
        np.testing.assert_allclose(tfs[i].freqresp(F[:4]), x[:, i] / x[:, i - 1], rtol=1e-8)


def test_drive_side_eq12():
    p = 0.01
    r = 2 * math.pi / p
    tf1, tf2, _ = table1_3dof(*M3, *K3, *C3)
    tf1p, tf2p = drive_side(tf1, tf2, p)
    s = 2j * math.pi * F
    np.testing.assert_allclose(tf1p(s), tf1(s) * r**2 * s, rtol=1e-12)
    np.testing.assert_allclose(tf2p(s), tf2(s) / (r * s), rtol=1e-12)
    # the s of TF1' cancels one of the free body's two integrators
    assert tf1p.den[-1] == 0.0 and tf1p.den[-2] != 0.0


def test_to_control():
    control = pytest.importorskip("control")
    tf3 = table1_3dof(*M3, *K3, *C3)[2]
    sys = to_control(tf3)
    assert isinstance(sys, control.TransferFunction)
    np.testing.assert_allclose(sys(2j * math.pi * 14.9), tf3.freqresp(14.9), rtol=1e-12)


def test_call_evaluates():
    tf = TransferFunction([1.0], [1.0, 1.0])
    assert tf(1j) == pytest.approx(1 / (1 + 1j))
