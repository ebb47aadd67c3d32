"""The transmission analysis (the paper's Section 3): masses 2..N driven by a prescribed motor.

The motor x1 follows the sine-square path exactly (an ideal drive); the rest of the chain
responds to it. With d = 2..N, M, K the chain's mass and stiffness matrices and C_l its link
damping (mass 1's ground damping does not act on x2..),

    M_dd x_d'' + C_l,dd x_d' + K_dd x_d = -K_d1 x1 - C_l,d1 v1

so that x2 = TF2 x1 and x3 = TF3 x2 exactly (Table 1). In state form z = [x_d, v_d],
u = [x1, v1]: z' = A z + B u, discretized with a first-order hold (exact for an input that is
linear between samples, as a densely sampled path is):

    z[k+1] = Phi z[k] + G0 u[k] + G1 u[k+1],

Phi = e^(A dt), G0 = Gam1 - Gam2, G1 = Gam2, all from one matrix exponential of the block
[[A dt, B dt, 0], [0, 0, I], [0, 0, 0]] (Van Loan). The matrices are built once per model and
sample time; the recursion is compiled (numba, cached on disk). The chain starts at rest at x1[0].
"""
from __future__ import annotations

import numpy as np
import scipy.linalg
from numba import njit

from hil.sweep.model import fingerprint, model_of

__all__ = ["transmission_response"]

_TRANS: dict = {}


def _transmission_matrices(cfg, dt: float):
    """First-order-hold discretization of masses 2..N with inputs (x1, v1):
    z[k+1] = Phi z[k] + G0 u[k] + G1 u[k+1]."""
    fp = (fingerprint(cfg), dt)
    if fp in _TRANS:
        return _TRANS[fp]
    plant, _ = model_of(cfg)
    ch = plant.chain
    if ch.n < 2:
        raise ValueError("the transmission analysis needs a chain of at least 2 masses")
    M, K = ch.M, ch.K
    Cl = ch._tridiagonal(ch.c, ch.n)       # links only: mass 1's ground damping does not act on x2..
    d = slice(1, ch.n)
    nd = ch.n - 1
    Minv = np.diag(1.0 / np.diag(M)[d])
    A = np.zeros((2 * nd, 2 * nd))
    A[:nd, nd:] = np.eye(nd)
    A[nd:, :nd] = -Minv @ K[d, d]
    A[nd:, nd:] = -Minv @ Cl[d, d]
    B = np.zeros((2 * nd, 2))
    B[nd:, 0] = -Minv @ K[d, 0]
    B[nd:, 1] = -Minv @ Cl[d, 0]
    nx, nu = 2 * nd, 2
    blk = np.zeros((nx + 2 * nu, nx + 2 * nu))
    blk[:nx, :nx] = A * dt
    blk[:nx, nx:nx + nu] = B * dt
    blk[nx:nx + nu, nx + nu:] = np.eye(nu)
    e = scipy.linalg.expm(blk)
    Phi, Gam1, Gam2 = e[:nx, :nx], e[:nx, nx:nx + nu], e[:nx, nx + nu:]
    out = (np.ascontiguousarray(Phi), np.ascontiguousarray(Gam1 - Gam2), np.ascontiguousarray(Gam2),
           plant.table - 1, plant.tip - 1)
    _TRANS[fp] = out
    return out


@njit(cache=True)
def _lti_foh(Phi, G0, G1, z0, U):
    n_steps = U.shape[0]
    nx = Phi.shape[0]
    nu = U.shape[1]
    Z = np.zeros((n_steps, nx))
    z = z0.copy()
    Z[0, :] = z
    zn = np.zeros(nx)
    for k in range(n_steps - 1):
        for r in range(nx):
            acc = 0.0
            for c in range(nx):
                acc += Phi[r, c] * z[c]
            for c in range(nu):
                acc += G0[r, c] * U[k, c] + G1[r, c] * U[k + 1, c]
            zn[r] = acc
        for r in range(nx):
            z[r] = zn[r]
        Z[k + 1, :] = z
    return Z


def transmission_response(cfg, move, t):
    """(x1, x2, x_tip) on the uniform grid ``t`` for the motor following ``move`` exactly."""
    dt = float(t[1] - t[0])
    Phi, G0, G1, itab, itip = _transmission_matrices(cfg, dt)
    x1 = move.position(t)
    U = np.ascontiguousarray(np.column_stack([x1, move.velocity(t)]))
    nd = Phi.shape[0] // 2
    z0 = np.zeros(2 * nd)
    z0[:nd] = x1[0]
    Z = _lti_foh(Phi, G0, G1, z0, U)
    return x1, Z[:, itab], Z[:, itip]
