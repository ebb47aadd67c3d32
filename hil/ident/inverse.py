"""The inverse dynamic model of a rigid axis, identified by least squares (IDIM-LS, Gautier).

force = M a + Fv v + Fc sign(v) + offset, or with separate levels per direction (Fv+, Fv-,
Fc+, Fc-, no offset), regressed on the velocity and acceleration differentiated from the measured
position (SI units). A linear regression on the force channel: it gives the EMPS benchmark's
published model and starting values for the output-error fits (hil.ident.fit).
"""
from __future__ import annotations

import numpy as np
from scipy.signal import butter, decimate, filtfilt

__all__ = ["idim_ls", "motion"]


def motion(t, x, cutoff: float = 100.0, order: int = 4):
    """Velocity and acceleration of a measured position: low-pass filtered forward and backward
    (Butterworth, ``order``, ``cutoff`` Hz), then central differences (the IDIM recipe)."""
    t, x = np.asarray(t, float), np.asarray(x, float)
    dt = float(np.median(np.diff(t)))
    b, a = butter(order, cutoff / (0.5 / dt))
    xf = filtfilt(b, a, x)
    v = np.gradient(xf, dt)
    return v, np.gradient(v, dt)


def idim_ls(t, x, force, *, cutoff: float = 100.0, order: int = 4, decimation: int = 10,
            asymmetric: bool = False) -> dict:
    """Inverse dynamic model, least squares (IDIM-LS, Gautier): the force of a rigid axis,
    ``force = M a + Fv v + Fc sign(v) + offset`` (or with separate levels per direction,
    ``asymmetric``: Fv+, Fv-, Fc+, Fc-, no offset), regressed on the measured position.

    The position is low-pass filtered forward and backward (Butterworth, ``order``, ``cutoff``
    Hz), differentiated by central differences, and the regressors and the force are decimated by
    ``decimation`` (each through scipy.signal.decimate's anti-aliasing filter, zero phase), as in
    the EMPS benchmark's reference recipe. Returns the parameters (SI), the relative 2-norm force
    error % and the condition number of the column-scaled regressor."""
    t, x, force = (np.asarray(a, float) for a in (t, x, force))
    v, acc = motion(t, x, cutoff, order)
    if asymmetric:
        pos = v > 0
        cols = {"M": acc, "Fv+": v * pos, "Fv-": v * ~pos, "Fc+": pos * 1.0, "Fc-": -1.0 * (v < 0)}
    else:
        cols = {"M": acc, "Fv": v, "Fc": np.sign(v), "offset": np.ones_like(v)}

    def dec(y):
        return decimate(y, decimation, zero_phase=True) if decimation > 1 else y
    X = np.column_stack([dec(c) for c in cols.values()])
    y = dec(force)
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    err = 100.0 * float(np.linalg.norm(y - X @ theta) / np.linalg.norm(y))
    cond = float(np.linalg.cond(X / np.linalg.norm(X, axis=0)))
    return {"params": dict(zip(cols, theta.tolist())), "relative_error": err, "condition": cond}
