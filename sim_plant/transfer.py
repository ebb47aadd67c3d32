"""Transfer functions of the chain (Eq. 6, Table 1, Eq. 12) as polynomial coefficient arrays.

Two computations of the same functions: a generic one from the matrices of any chain (cofactors of
the dynamic stiffness Z(s) = M s^2 + C s + K, in exact polynomial arithmetic), and the closed
forms of Table 1 for 2 and 3 dof, with the transcription's sign errors corrected (NOTES.md).
Coefficients are highest power first (numpy convention).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TransferFunction", "chain_tfs", "tf_force", "tf_link", "table1_2dof", "table1_3dof",
           "drive_side", "freqresp", "to_control"]


@dataclass(frozen=True)
class TransferFunction:
    """num(s) / den(s), coefficients highest power first."""
    num: np.ndarray
    den: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "num", np.atleast_1d(np.asarray(self.num, float)))
        object.__setattr__(self, "den", np.atleast_1d(np.asarray(self.den, float)))

    def __call__(self, s):
        return np.polyval(self.num, s) / np.polyval(self.den, s)

    def freqresp(self, f_hz) -> np.ndarray:
        return self(2j * np.pi * np.asarray(f_hz, float))

    def normalized(self) -> "TransferFunction":
        """Leading denominator coefficient 1 (to compare coefficient arrays)."""
        return TransferFunction(self.num / self.den[0], self.den / self.den[0])

    def cancel_s(self) -> "TransferFunction":
        """Cancel the factors s common to numerator and denominator (exact zeros only)."""
        num, den = self.num, self.den
        while len(num) > 1 and len(den) > 1 and num[-1] == 0.0 and den[-1] == 0.0:
            num, den = num[:-1], den[:-1]
        return TransferFunction(num, den)


def freqresp(tf: TransferFunction, f_hz) -> np.ndarray:
    """Complex response of ``tf`` at the frequencies ``f_hz`` (Hz)."""
    return tf.freqresp(f_hz)


# --- generic: polynomial cofactors of Z(s) ------------------------------------------------------
# A polynomial is carried with a second one, the same sums taken over absolute values: it says how
# large each coefficient's terms were, so that a coefficient that cancels (the s^2 factor of a free
# chain) is recognised as zero rather than as rounding noise.

def _padd(a, b):
    n = max(len(a), len(b))
    return np.pad(a, (n - len(a), 0)) + np.pad(b, (n - len(b), 0))


def _det(Z, Za):
    """Determinant (and its absolute-value scale) of a square matrix of polynomials, by Laplace
    expansion along the first row: fine for the few masses of a lumped chain."""
    n = len(Z)
    if n == 0:
        return np.array([1.0]), np.array([1.0])
    if n == 1:
        return Z[0][0], Za[0][0]
    det, scale = np.array([0.0]), np.array([0.0])
    for j in range(n):
        if not np.any(Z[0][j]):
            continue
        minor = [row[:j] + row[j + 1:] for row in Z[1:]]
        minora = [row[:j] + row[j + 1:] for row in Za[1:]]
        d, da = _det(minor, minora)
        det = _padd(det, (-1) ** j * np.polymul(Z[0][j], d))
        scale = _padd(scale, np.polymul(Za[0][j], da))
    return det, scale


def _clean(p, scale, rtol=1e-9):
    p = np.where(np.abs(p) <= rtol * scale, 0.0, p)
    return np.trim_zeros(p, "f") if np.any(p) else np.array([0.0])


def _ratio(num, nscale, den, dscale) -> TransferFunction:
    # the factors s shared by both come from the free-body mode
    return TransferFunction(_clean(num, nscale), _clean(den, dscale)).cancel_s()


def _dynamic_stiffness(chain):
    M, C, K = chain.M, chain.C, chain.K
    n = chain.n
    Z = [[np.array([M[i, j], C[i, j], K[i, j]]) for j in range(n)] for i in range(n)]
    Za = [[np.abs(z) for z in row] for row in Z]
    return Z, Za


def tf_force(chain) -> TransferFunction:
    """TF1 = x1 / f (f on mass 1): x1/f = det Z[2:, 2:] / det Z (Cramer's rule)."""
    Z, Za = _dynamic_stiffness(chain)
    num, nscale = _det([row[1:] for row in Z[1:]], [row[1:] for row in Za[1:]])
    den, dscale = _det(Z, Za)
    return _ratio(num, nscale, den, dscale)


def tf_link(chain, i: int) -> TransferFunction:
    """x_(i+1) / x_i (masses numbered from 1): TF2 is ``tf_link(chain, 1)``, TF3 ``tf_link(chain, 2)``.

    The masses after i feel mass i only through their coupling column: Z_d x_d = -Z[d, i] x_i,
    so x_(i+1)/x_i = -(adj(Z_d) Z[d, i])_1 / det Z_d (no common factor to cancel)."""
    n = chain.n
    if not 1 <= i < n:
        raise ValueError(f"link {i}: a chain of {n} masses has links 1..{n - 1}")
    Z, Za = _dynamic_stiffness(chain)
    d = list(range(i, n))                       # 0-based indices of the masses after mass i
    Zd = [[Z[r][c] for c in d] for r in d]
    Zda = [[Za[r][c] for c in d] for r in d]
    num, nscale = np.array([0.0]), np.array([0.0])
    for j, r in enumerate(d):                   # first row of adj(Z_d) = cofactors C_(j,1)
        if not np.any(Z[r][i - 1]):
            continue
        minor = [[Zd[a][b] for b in range(1, len(d))] for a in range(len(d)) if a != j]
        minora = [[Zda[a][b] for b in range(1, len(d))] for a in range(len(d)) if a != j]
        cof, cofa = _det(minor, minora)
        num = _padd(num, -((-1) ** j) * np.polymul(cof, Z[r][i - 1]))
        nscale = _padd(nscale, np.polymul(cofa, Za[r][i - 1]))
    den, dscale = _det(Zd, Zda)
    return _ratio(num, nscale, den, dscale)


def chain_tfs(chain) -> list[TransferFunction]:
    """[TF1, TF2, TF3, ...]: x1/f, then x2/x1, x3/x2, ... (Eq. 6)."""
    return [tf_force(chain)] + [tf_link(chain, i) for i in range(1, chain.n)]


# --- closed forms: Table 1, corrected -------------------------------------------------------------

def table1_2dof(m1, m2, k, c) -> tuple[TransferFunction, TransferFunction]:
    """(TF1, TF2) of the 2-dof chain, Table 1. As in the table, TF1 keeps d0 = d1 = 0 (the free
    body's s^2); ``.cancel_s()`` removes it."""
    tf1 = TransferFunction([m2, c, k], [m1 * m2, (m1 + m2) * c, (m1 + m2) * k, 0.0, 0.0])
    tf2 = TransferFunction([c, k], [m2, c, k])
    return tf1, tf2


def table1_3dof(m1, m2, m3, k1, k2, c1, c2):
    """(TF1, TF2, TF3) of the 3-dof chain, Table 1 with (m2 - m3) read (m2 + m3) and
    (m1 + m2 - m3) read (m1 + m2 + m3) (derived again from Eq. 3; see NOTES.md). TF1 keeps
    d0 = d1 = 0 as in the table."""
    mT = m1 + m2 + m3
    n1 = [m2 * m3, m3 * c1 + (m2 + m3) * c2, m3 * k1 + (m2 + m3) * k2 + c1 * c2, c1 * k2 + c2 * k1, k1 * k2]
    d1 = [m1 * m2 * m3,
          (m1 + m2) * m3 * c1 + (m2 + m3) * m1 * c2,
          (m1 + m2) * m3 * k1 + (m2 + m3) * m1 * k2 + mT * c1 * c2,
          mT * (c1 * k2 + c2 * k1),
          mT * k1 * k2, 0.0, 0.0]
    n2 = [c1 * m3, c1 * c2 + k1 * m3, c1 * k2 + c2 * k1, k1 * k2]
    return (TransferFunction(n1, d1), TransferFunction(n2, n1),
            TransferFunction([c2, k2], [m3, c2, k2]))


def drive_side(tf1: TransferFunction, tf2: TransferFunction, pitch: float):
    """Eq. (12): TF1' = omega_m / tau_m = TF1 (2 pi/p)^2 s and TF2' = x2 / omega_m = TF2 (p/2 pi) / s."""
    r = 2.0 * math.pi / pitch
    tf1p = TransferFunction(np.polymul(tf1.num, [r**2, 0.0]), tf1.den)
    tf2p = TransferFunction(tf2.num / r, np.polymul(tf2.den, [1.0, 0.0]))
    return tf1p.cancel_s(), tf2p.cancel_s()


def to_control(tf: TransferFunction):
    """A python-control ``TransferFunction`` (needs the optional ``control`` package)."""
    try:
        import control
    except ImportError as exc:
        raise ImportError("python-control is not installed: pip install 'compliant-axis-hil[control]'") from exc
    return control.tf(tf.num, tf.den)
