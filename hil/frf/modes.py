"""The modes in a measurement, the model's, and the parameter that explains a difference.

:func:`fit_modes` fits each of the model's elastic modes that lies inside the measured band, in the
response where its shape shows most (the motor speed, TF1', or the tip speed), by variable
projection (:func:`fit_mode`: one mode with a rigid-body and background terms); the same fit on
the model's exact response gives the values to compare with (the eigenvalues are reported too).

:func:`discrepancies` turns a difference beyond tolerance into one sentence: the damper or spring
carrying most of the mode's modal damping or strain energy (mass-normalized shapes of the
undamped chain) and the value that would close the gap, in config units.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Mode", "fit_mode", "model_modes", "fit_modes", "discrepancies"]


@dataclass
class Mode:
    f_hz: float
    zeta: float
    response: str
    f_std: float = 0.0
    zeta_std: float = 0.0

    def as_dict(self):
        return {"frequency_hz": self.f_hz, "damping_ratio": self.zeta, "response": self.response,
                "frequency_std_hz": self.f_std, "damping_std": self.zeta_std}


def fit_mode(f, h, f_guess: float, weight=None, rel_band: float = 0.3) -> tuple[float, float, float, float]:
    """Fit one mode around ``f_guess``: H(s) ~ (b1 s + b0) / (s^2 + 2 z w s + w^2) + e_1/s + e0 + e1 s
    (rigid body and the other modes as background), by variable projection: for (w, z) the
    residue and background are a linear least-squares fit, (w, z) by nonlinear least squares.
    Returns (f, zeta, std f, std zeta)."""
    import scipy.optimize
    f = np.asarray(f)
    sel = (f > f_guess * (1 - rel_band)) & (f < f_guess * (1 + rel_band))
    if sel.sum() < 6:
        raise ValueError(f"too few lines near {f_guess:.3g} Hz to fit a mode")
    ff, hh = f[sel], h[sel]
    w = np.ones(ff.size) if weight is None else np.asarray(weight)[sel]
    s = 2j * np.pi * ff
    norm = np.median(np.abs(hh))
    hh = hh / norm

    def basis(theta):
        wn = 2 * np.pi * theta[0]
        zeta = theta[1]
        d = s ** 2 + 2 * zeta * wn * s + wn ** 2
        return np.stack([s / d * wn, wn ** 2 / d, wn / s, np.ones_like(s), s / wn], axis=1)

    def resid(theta):
        B = basis(theta)
        Br = np.vstack([B.real, B.imag]) * np.concatenate([w, w])[:, None]
        y = np.concatenate([hh.real, hh.imag]) * np.concatenate([w, w])
        c, *_ = np.linalg.lstsq(Br, y, rcond=None)
        return Br @ c - y

    # start: the peak of |H| near the guess, damping from a coarse grid
    pk = ff[np.argmax(np.abs(hh) * (np.abs(ff - f_guess) < 0.15 * f_guess))]
    best = None
    for z0 in (0.005, 0.015, 0.04, 0.1, 0.2):
        for f0 in (pk, f_guess):
            r = scipy.optimize.least_squares(resid, [f0, z0], bounds=([ff[0], 1e-4], [ff[-1], 0.9]),
                                             x_scale=[f_guess * 0.01, 0.01])
            if best is None or r.cost < best.cost:
                best = r
    J = best.jac
    dof = max(2 * ff.size - 7, 1)
    s2 = 2 * best.cost / dof
    try:
        cov = np.linalg.inv(J.T @ J) * s2
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        sd = np.array([np.nan, np.nan])
    return float(best.x[0]), float(best.x[1]), float(sd[0]), float(sd[1])


def model_modes(plant):
    """The model's elastic modes: (frequency Hz, damping ratio) from the damped eigenvalues
    (motor viscous friction included), and the undamped mass-normalized shapes."""
    ch = plant.chain
    w, phi = ch.modes()
    wd, zd = ch.damped_modes(include_ground=True)
    if ch.n < 2 or wd.size == 0:        # a rigid axis (one mass): no elastic mode to fit
        return [], w[1:], phi[:, 1:]
    keep = wd > 1e-6 * max(wd.max(), 1.0)
    wd, zd = wd[keep][-(ch.n - 1):], zd[keep][-(ch.n - 1):]
    return [(float(a / 2 / np.pi), float(b)) for a, b in zip(wd, zd)], w[1:], phi[:, 1:]


def _response_for_mode(plant, phi_col, available) -> str:
    """The measured response where a mode shows most: the sensor with the largest mode-shape entry."""
    cand = [("TF1p", abs(phi_col[0]))]
    if "tip" in available:
        cand.append(("tip", abs(phi_col[plant.tip])))
    return max(cand, key=lambda c: c[1])[0]


def fit_modes(responses: dict, plant, model_h: dict | None = None) -> list[dict]:
    """Fit each of the model's modes inside the measured band, in the response where it shows
    most; the same fit on the model's exact response gives the comparison values."""
    mm, _, phi = model_modes(plant)
    out = []
    for i, (fm, zm) in enumerate(mm):
        name = _response_for_mode(plant, phi[:, i], responses)
        r = responses.get(name)
        if r is None or not (r.f[0] * 1.3 < fm < r.f[-1] / 1.3):
            continue
        wgt = np.sqrt(r.coherence) / np.maximum(r.sigma / np.maximum(np.abs(r.h), 1e-300), 1e-3)
        wgt = wgt / wgt.max()
        try:
            f_, z_, sf, sz = fit_mode(r.f, r.h, fm, wgt)
        except ValueError:
            continue
        row = {"mode": i + 2, "response": name, "measured": Mode(f_, z_, name, sf, sz).as_dict(),
               "model_eigen": {"frequency_hz": fm, "damping_ratio": zm}}
        if model_h is not None and name in model_h:
            fm2, zm2, _, _ = fit_mode(r.f, model_h[name], fm)
            row["model"] = {"frequency_hz": fm2, "damping_ratio": zm2}
        else:
            row["model"] = dict(row["model_eigen"])
        out.append(row)
    return out


def _energy_shares(plant, phi_col):
    """Per damper / spring: its share of the mode's modal damping and stiffness, with the
    parameter's dotted name and the value in config units."""
    ch = plant.chain
    damp, stiff = [], []
    for j, (k, c) in enumerate(zip(ch.k, ch.c)):
        d2 = (phi_col[j] - phi_col[j + 1]) ** 2
        damp.append((f"plant.c{j + 1}", c, d2, 1.0))
        stiff.append((f"plant.k{j + 1}", k, d2))
    if ch.c_ground[0] > 0 or True:
        conv = plant.speed_scale ** 2 if plant.pitch else 1.0      # N s/m per (N m s/rad)
        damp.append(("friction.viscous", ch.c_ground[0], phi_col[0] ** 2, conv))
    return damp, stiff


def discrepancies(modes: list[dict], plant, f_tol: float = 0.02, z_tol: float = 0.2) -> list[dict]:
    """One sentence per mode whose measured frequency or damping differs from the model's by more
    than ``f_tol`` / ``z_tol`` (relative), naming the parameter that dominates it (modal energy of
    each damper or spring) and the value that would close the gap."""
    _, w, phi = model_modes(plant)
    names = {2: "compliant-mass", 3: "drive"} if plant.n == 3 else {}
    out = []
    for row in modes:
        i = row["mode"] - 2
        me, mo = row["measured"], row["model"]
        fr = me["frequency_hz"] / mo["frequency_hz"]
        zr = me["damping_ratio"] / mo["damping_ratio"]
        damp, stiff = _energy_shares(plant, phi[:, i])
        parts = []
        diff = {}
        if abs(zr - 1) > z_tol:
            tot = sum(c * d2 for _, c, d2, _ in damp)
            name, c, d2, conv = max(damp, key=lambda t: t[1] * t[2] if t[1] > 0 else t[2] * 1e-12)
            share = c * d2 / tot if tot > 0 else 1.0
            # modal damping 2 zeta w; change the dominant damper by the missing amount
            need = 2 * w[i] * (me["damping_ratio"] - mo["damping_ratio"])
            new_c = max(c + need / d2, 0.0)
            factor = new_c / c if c > 0 else math.inf
            word = "too low" if factor > 1 else "too high"
            label = {"plant.c1": "transmission damping c1", "plant.c2": "compliant-mass damping c2",
                     "friction.viscous": "motor viscous friction"}.get(name, name)
            parts.append(f"the {label} ({name}, {share:.0%} of the mode's damping) is about "
                         f"{factor if factor >= 1 else 1 / factor:.1f}x {word}: try {name} = {new_c / conv:.4g}")
            diff[name] = (c / conv, new_c / conv)
        if abs(fr - 1) > f_tol:
            tot = sum(k * d2 for _, k, d2 in stiff)
            name, k, d2 = max(stiff, key=lambda t: t[1] * t[2])
            share = k * d2 / tot
            new_k = k * (1 + (fr ** 2 - 1) / share)
            parts.append(f"the stiffness {name} ({share:.0%} of the mode's strain energy) is about "
                         f"{new_k / k:.2f}x the config's: try {name} = {new_k:.4g}")
            diff[name] = (k, new_k)
        if not parts:
            continue
        label = names.get(row["mode"], f"mode {row['mode']}")
        s = (f"{label} mode: measured {me['frequency_hz']:.2f} Hz, damping {me['damping_ratio']:.3f}; "
             f"model {mo['frequency_hz']:.2f} Hz, {mo['damping_ratio']:.3f}: " + "; ".join(parts))
        out.append({"mode": row["mode"], "sentence": s, "changes": {k: list(v) for k, v in diff.items()},
                    "frequency_ratio": fr, "damping_ratio_ratio": zr})
    return out

