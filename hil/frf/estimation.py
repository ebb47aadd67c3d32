"""Frequency responses estimated from a recorded run, with coherence and uncertainty.

Estimates use the excitation as instrumental variable: H_yu = S_ry / S_ru, cross spectra with the
injected signal r averaged over whole periods (Welch with a boxcar window of one period, no
overlap: no leakage for a periodic excitation in steady state). In closed loop this removes the
bias of the plain H1 = S_uy / S_uu. Coherence gamma^2 of r with each channel, and the standard
deviation of |H|: from the scatter of the periods (the coherence formula
sigma ~ |H| sqrt((1 - g^2) / (2 n g^2)) generalised to noise correlated between the channels of the
ratio, as it is in closed loop); with fewer than 3 periods, the coherence formula.

Responses (names used everywhere, JSON included; :data:`RESPONSES`, :data:`UNITS`, :data:`TITLES`):

* ``TF1p``  torque -> measured motor speed (rad/s per N m; Eq. 12's TF1')
* ``TF2``   table / motor position, ``TF3`` tip / table (where the tip is measured)
* ``Lv``    open velocity loop (controller x plant), ``Tv`` closed velocity loop
* ``Lp``    open position loop, ``Tp`` closed position loop x_table / x_cmd (below the position
            loop's Nyquist frequency; derived from the measured x_table / speed reference)
* ``tip``   torque -> tip speed (where the tip is measured; used for the modal fit)

A response computed from others rather than estimated directly is marked ``derived``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hil.frf.model import position_hold
from hil.frf.run import CH, FrfRecord

__all__ = ["RESPONSES", "UNITS", "TITLES", "Response", "estimate"]

RESPONSES = ("TF1p", "TF2", "TF3", "tip", "Lv", "Tv", "Lp", "Tp")
UNITS = {"TF1p": "rad/s per N m", "TF2": "1", "TF3": "1", "tip": "m/s per N m", "Lv": "1", "Tv": "1",
         "Lp": "1", "Tp": "1"}
TITLES = {"TF1p": "TF1' torque -> motor speed", "TF2": "TF2 table / motor", "TF3": "TF3 tip / table",
          "tip": "torque -> tip speed", "Lv": "open velocity loop", "Tv": "closed velocity loop",
          "Lp": "open position loop", "Tp": "closed position loop"}


@dataclass
class Response:
    """One frequency response: complex values, coherence, standard deviation of |H|."""
    f: np.ndarray
    h: np.ndarray
    coherence: np.ndarray
    sigma: np.ndarray
    derived: bool = False

    def as_dict(self) -> dict:
        return {"frequency_hz": self.f.tolist(), "magnitude": np.abs(self.h).tolist(),
                "phase_deg": np.degrees(np.angle(self.h)).tolist(), "coherence": self.coherence.tolist(),
                "magnitude_std": self.sigma.tolist(), "derived": self.derived}


def _spectra(rec: FrfRecord):
    """Per-period DFTs at the excitation lines: dict channel -> (periods x lines) complex."""
    n = rec.excitation.n
    seg = rec.data[rec.start:rec.start + rec.periods * n]
    if seg.shape[0] < rec.periods * n:
        raise ValueError("record shorter than the averaged periods")
    seg = seg.copy()
    # positions move at the working speed: remove that trend (for a periodic response plus a
    # ramp, x[i + n] - x[i] is the ramp's rise over one period, whatever the periodic part)
    t = np.arange(seg.shape[0]) * rec.dt
    for c in ("x_motor", "x_table", "x_tip"):
        i = CH.index(c)
        if rec.periods > 1:
            slope = np.mean(seg[n:, i] - seg[:-n, i]) / (n * rec.dt)
        else:
            slope = (seg[-1, i] - seg[0, i]) / (t[-1] + rec.dt)
        seg[:, i] -= slope * t
    F = np.fft.rfft(seg.reshape(rec.periods, n, len(CH)), axis=1)[:, rec.excitation.lines, :]
    return {c: F[:, :, i] for i, c in enumerate(CH)}


def _iv(F, y: str, u: str, pre=None):
    """H = S_ry / S_ru with its coherence-based standard deviation."""
    R = F["r"]
    Y = F[y] if pre is None else pre(F[y])
    U = F[u]
    n = R.shape[0]
    Sry, Sru = np.mean(np.conj(R) * Y, 0), np.mean(np.conj(R) * U, 0)
    Srr = np.mean(np.abs(R) ** 2, 0)
    g_y = np.abs(Sry) ** 2 / (Srr * np.mean(np.abs(Y) ** 2, 0) + 1e-300)
    g_u = np.abs(Sru) ** 2 / (Srr * np.mean(np.abs(U) ** 2, 0) + 1e-300)
    g_y, g_u = np.clip(g_y, 1e-12, 1.0), np.clip(g_u, 1e-12, 1.0)
    h = Sry / Sru
    q = (1 - g_y) / g_y + (1 - g_u) / g_u
    coh = 1.0 / (1.0 + q)
    if n > 2:
        # noise of the ratio from the scatter over periods (the coherence formula generalised to
        # noise correlated between the two channels, as a closed loop makes it): per period the
        # residual of Y = H U, its variance over the periods; std of |H| = that / sqrt 2
        # (half the complex variance lies along H)
        Ym, Um = Y.mean(0), U.mean(0)
        D = (Y - Ym) - h * (U - Um)
        var = np.sum(np.abs(D) ** 2, 0) / ((n - 1) * n * np.abs(Um) ** 2)
        sigma = np.sqrt(var / 2)
    else:
        sigma = np.abs(h) * np.sqrt(q / (2 * max(n, 1)))      # Bendat & Piersol, from the coherence
    return h, coh, sigma


def estimate(rec: FrfRecord, ctrl) -> dict[str, Response]:
    """The responses a drive engineer reads, estimated from the record (instrumental variable:
    the injected excitation)."""
    F = _spectra(rec)
    f = rec.excitation.freqs
    jw = 2j * np.pi * f
    # speeds from positions: the DFT of a periodic steady state, d/dt -> j w (exact for the lines)
    scale = ctrl.speed_scale
    out: dict[str, Response] = {}
    if rec.input == "torque":
        h, c, s = _iv(F, "w", "u")
        out["TF1p"] = Response(f, h, c, s)
        h, c, s = _iv(F, "x_tip", "u", pre=lambda X: X * jw)
        if rec.tip_measured:
            out["tip"] = Response(f, h, c, s)
        # open velocity loop: controller (u_ctrl / e) x plant (w / u)
        hc, cc, sc = _iv(F, "u_ctrl", "e")
        lv = hc * out["TF1p"].h
        out["Lv"] = Response(f, lv, np.minimum(cc, out["TF1p"].coherence),
                             np.abs(lv) * np.hypot(sc / np.maximum(np.abs(hc), 1e-300),
                                                   out["TF1p"].sigma / np.maximum(np.abs(out["TF1p"].h), 1e-300)))
        tv = lv / (1 + lv)
        out["Tv"] = Response(f, tv, out["Lv"].coherence, np.abs(tv) * out["Lv"].sigma / np.maximum(np.abs(lv), 1e-300)
                             / np.maximum(np.abs(1 + lv), 1e-300), derived=True)
        # table position per speed reference: x_table/u x C / (1 + Lv)
        hx, cx, sx = _iv(F, "x_table", "u")
        P = hx * hc / (1 + lv)
        rel_lv = out["Lv"].sigma / np.maximum(np.abs(lv), 1e-300)
        sP = np.abs(P) * np.sqrt((sx / np.maximum(np.abs(hx), 1e-300)) ** 2 + (sc / np.maximum(np.abs(hc), 1e-300)) ** 2
                                 + (np.abs(lv) / np.maximum(np.abs(1 + lv), 1e-300) * rel_lv) ** 2)
        cP = cx
    else:
        h, c, s = _iv(F, "w", "w_ref")
        out["Tv"] = Response(f, h, c, s)
        lv = h / (1 - h)
        out["Lv"] = Response(f, lv, c, np.abs(lv) * s / np.maximum(np.abs(h * (1 - h)), 1e-300), derived=True)
        hw, cw, sw = _iv(F, "w", "u")
        out["TF1p"] = Response(f, hw, cw, sw)
        if rec.tip_measured:
            out["tip"] = Response(f, *_iv(F, "x_tip", "u", pre=lambda X: X * jw))
        P, cP, sP = _iv(F, "x_table", "w_ref")
        # the measured open position loop, broken at the speed reference (sampled at Tp)
        hl, cl, sl = _iv(F, "w_ref_pos", "w_ref")
        lp_meas = -hl
    h2, c2, s2 = _iv(F, "x_table", "x_motor")
    out["TF2"] = Response(f, h2, c2, s2)
    if rec.tip_measured:
        out["TF3"] = Response(f, *_iv(F, "x_tip", "x_table"))
    # position loop (below its Nyquist frequency)
    tp = ctrl.position_period
    keep = f < 0.5 / tp
    hold = position_hold(f, tp)
    lp = ctrl.kv * scale * P * hold
    if rec.input == "velocity":
        out["Lp"] = Response(f[keep], lp_meas[keep], cl[keep], sl[keep])
    else:
        out["Lp"] = Response(f[keep], lp[keep], cP[keep], (np.abs(lp) * sP / np.maximum(np.abs(P), 1e-300))[keep],
                             derived=True)
    lpv = out["Lp"].h
    ff = ctrl.ffv * (np.exp(jw * tp) - 1) / tp
    tpos = (ctrl.kv + ff[keep]) * scale * P[keep] * hold[keep] / (1 + lpv)
    out["Tp"] = Response(f[keep], tpos, out["Lp"].coherence,
                         np.abs(tpos) * out["Lp"].sigma / np.maximum(np.abs(lpv), 1e-300), derived=True)
    return out
