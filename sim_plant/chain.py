"""Lumped-parameter chains: N masses joined by N-1 spring-damper pairs (Eq. 1 and 3).

Mass 1 is the motor (its inertia reflected to the load side through the pitch), the force f acts
on it. The 2-dof and 3-dof models of the paper are the chains of 2 and 3 masses; N is free.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import scipy.linalg

from sim_plant.blas_threads import one_blas_thread

__all__ = ["Chain", "StateSpace", "zoh"]


@dataclass(frozen=True)
class StateSpace:
    """x' = A x + B u, y = C x + D u (or the discrete x[k+1] = A x[k] + B u[k] with sample time dt)."""
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float = 0.0      # 0: continuous time

    def to_control(self):
        """A python-control ``StateSpace`` (needs the optional ``control`` package)."""
        try:
            import control
        except ImportError as exc:  # pragma: no cover - depends on the optional extra
            raise ImportError("python-control is not installed: pip install 'compliant-axis-hil[control]'") from exc
        return control.ss(self.A, self.B, self.C, self.D, self.dt if self.dt else 0)


def zoh(ss: StateSpace, dt: float) -> StateSpace:
    """Exact zero-order-hold discretization: Ad = e^(A dt), Bd = int_0^dt e^(A s) ds B.

    Computed with one matrix exponential of the block matrix [[A, B], [0, 0]] (Van Loan), which
    stays exact for the singular A of a free chain (rigid-body mode)."""
    n, m = ss.B.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = ss.A
    block[:n, n:] = ss.B
    with one_blas_thread():         # a 10 x 10 exponential: threads cost 1000 x its work (blas_threads)
        e = scipy.linalg.expm(block * dt)
    return StateSpace(np.ascontiguousarray(e[:n, :n]), np.ascontiguousarray(e[:n, n:]), ss.C.copy(), ss.D.copy(), dt)


@lru_cache(maxsize=64)
def _discretize_cached(chain: "Chain", dt: float, inputs: str) -> StateSpace:
    d = zoh(chain.state_space(inputs), dt)
    for a in (d.A, d.B, d.C, d.D):
        a.setflags(write=False)
    return d


@dataclass(frozen=True)
class Chain:
    """A free chain of masses ``m`` joined by springs ``k`` and dampers ``c`` (SI units, linear).

    ``c_ground`` is an extra viscous damping from each mass to the ground (the motor's viscous
    friction of Eq. 11 sits on mass 1)."""
    m: tuple[float, ...]
    k: tuple[float, ...]
    c: tuple[float, ...]
    c_ground: tuple[float, ...] = field(default=())

    def __post_init__(self):
        n = len(self.m)
        if n < 1 or len(self.k) != n - 1 or len(self.c) != n - 1:
            raise ValueError(f"a chain of {n} masses needs {n - 1} stiffnesses and dampings, got "
                             f"{len(self.k)} and {len(self.c)}")
        if not self.c_ground:
            object.__setattr__(self, "c_ground", (0.0,) * n)
        if len(self.c_ground) != n:
            raise ValueError(f"c_ground needs {n} values, got {len(self.c_ground)}")

    @property
    def n(self) -> int:
        return len(self.m)

    @staticmethod
    def _tridiagonal(links, n) -> np.ndarray:
        K = np.zeros((n, n))
        for i, ki in enumerate(links):
            K[i, i] += ki
            K[i + 1, i + 1] += ki
            K[i, i + 1] -= ki
            K[i + 1, i] -= ki
        return K

    @property
    def M(self) -> np.ndarray:
        return np.diag(np.asarray(self.m, float))

    @property
    def K(self) -> np.ndarray:
        return self._tridiagonal(self.k, self.n)

    @property
    def C(self) -> np.ndarray:
        """Damping matrix of the links, plus ``c_ground`` on the diagonal."""
        return self._tridiagonal(self.c, self.n) + np.diag(np.asarray(self.c_ground, float))

    def state_space(self, inputs: str = "motor") -> StateSpace:
        """States [x_1..x_N, v_1..v_N]; outputs the positions x_1..x_N.

        ``inputs="motor"``: one input, the force on mass 1. ``inputs="all"``: one force input per
        mass (what the simulator uses: drive force, friction and plant effects enter as forces)."""
        n = self.n
        Minv = np.diag(1.0 / np.asarray(self.m, float))
        A = np.zeros((2 * n, 2 * n))
        A[:n, n:] = np.eye(n)
        A[n:, :n] = -Minv @ self.K
        A[n:, n:] = -Minv @ self.C
        Ball = np.zeros((2 * n, n))
        Ball[n:, :] = Minv
        B = Ball[:, :1] if inputs == "motor" else Ball
        C = np.hstack([np.eye(n), np.zeros((n, n))])
        return StateSpace(A, B, C, np.zeros((n, B.shape[1])))

    def discretize(self, dt: float, inputs: str = "all") -> StateSpace:
        """Exact ZOH discretization (cached: sweeps and fits discretize the same chain many times;
        treat the returned matrices as read-only)."""
        return _discretize_cached(self, float(dt), inputs)

    def modes(self):
        """Undamped modes by the generalized eigenproblem K phi = w^2 M phi.

        Returns (omega [rad/s] ascending, Phi) with mass-normalized columns (Phi^T M Phi = I);
        the first mode of a free chain is the rigid-body mode (omega = 0)."""
        w2, phi = scipy.linalg.eigh(self.K, self.M)
        w2 = np.clip(w2, 0.0, None)
        order = np.argsort(w2)
        w2, phi = w2[order], phi[:, order]
        # sign convention: first entry (motor) positive, so shapes compare across methods
        for j in range(phi.shape[1]):
            if phi[0, j] < 0:
                phi[:, j] = -phi[:, j]
        return np.sqrt(w2), phi

    def modal_damping_ratios(self, include_ground: bool = False) -> np.ndarray:
        """Damping ratios of the elastic modes: zeta_i = (Phi^T C Phi)_ii / (2 omega_i).

        Exact under proportional damping; otherwise the diagonal (classical) approximation.
        ``include_ground`` adds the motor's viscous friction to C."""
        w, phi = self.modes()
        C = self.C if include_ground else self._tridiagonal(self.c, self.n)
        modal = phi.T @ C @ phi
        zeta = np.diag(modal)[1:] / (2.0 * w[1:])
        return zeta

    def damped_modes(self, include_ground: bool = True):
        """Natural frequencies [rad/s] and damping ratios of the elastic modes from the eigenvalues of
        the damped state matrix (no proportional-damping assumption)."""
        C = self.C if include_ground else self._tridiagonal(self.c, self.n)
        ss = Chain(self.m, self.k, self.c, tuple(np.diag(C) - np.diag(self._tridiagonal(self.c, self.n)))).state_space()
        lam = np.linalg.eigvals(ss.A)
        lam = lam[lam.imag > 1e-9]
        wn = np.abs(lam)
        zeta = -lam.real / wn
        order = np.argsort(wn)
        return wn[order], zeta[order]
