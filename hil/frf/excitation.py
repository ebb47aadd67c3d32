"""Periodic excitation signals for frequency-response measurements.

One period of a multisine (flat amplitude, Schroeder phases), a periodic linear chirp or a PRBS
(maximum-length sequence), sampled at the velocity period and scaled to a peak amplitude. The
record averages whole periods, so every estimate sits on a DFT line of one period (``lines``:
the bins, of one period, that carry the signal's energy in the band); no window, no leakage.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Excitation", "make_excitation"]


@dataclass
class Excitation:
    """One period of a periodic excitation sampled every ``dt`` (``n`` samples), peak ``amplitude``;
    ``lines``: the DFT bins (of one period) that carry energy in the band."""
    kind: str
    signal: np.ndarray
    dt: float
    lines: np.ndarray

    @property
    def n(self) -> int:
        return self.signal.size

    @property
    def period(self) -> float:
        return self.n * self.dt

    @property
    def freqs(self) -> np.ndarray:
        return self.lines / self.period


def make_excitation(kind: str, dt: float, period: float, band: tuple[float, float], amplitude: float,
                    seed: int = 0) -> Excitation:
    """Periodic excitation of one ``period`` (s) at sample time ``dt``: ``multisine`` (flat
    amplitude, Schroeder phases, lines from band[0] to band[1]), ``chirp`` (linear sweep over the
    band within the period) or ``prbs`` (maximum-length sequence clocked at ~2.5 band[1]; its
    period replaces ``period``). Scaled to a peak of ``amplitude``."""
    f_lo, f_hi = band
    if not 0 < f_lo < f_hi < 0.5 / dt:
        raise ValueError(f"band {f_lo:g}..{f_hi:g} Hz: needs 0 < low < high < {0.5 / dt:g} Hz")
    if kind == "prbs":
        hold = max(1, int(round(1.0 / (2.5 * f_hi * dt))))
        nbits = max(5, int(math.ceil(math.log2(period / (hold * dt) + 1))))
        import scipy.signal
        seq = scipy.signal.max_len_seq(nbits, state=np.ones(nbits, int) if seed == 0 else
                                       (np.random.default_rng(seed).integers(0, 2, nbits) | np.eye(1, nbits, 0, int)[0]))[0]
        x = np.repeat(2.0 * seq - 1.0, hold)
        n = x.size
    else:
        n = int(round(period / dt))
        x = None
    T = n * dt
    k_lo, k_hi = max(1, int(math.ceil(f_lo * T - 1e-9))), int(math.floor(f_hi * T + 1e-9))
    if k_hi < k_lo:
        raise ValueError(f"band {f_lo:g}..{f_hi:g} Hz holds no line of a {T:g} s period")
    lines = np.arange(k_lo, k_hi + 1)
    if kind == "multisine":
        K = lines.size
        phase = -np.pi * np.arange(K) * (np.arange(K) + 1) / K        # Schroeder
        t = np.arange(n) * dt
        x = np.zeros(n)
        for k, ph in zip(lines, phase):
            x += np.cos(2 * np.pi * k / T * t + ph)
    elif kind == "chirp":
        t = np.arange(n) * dt
        # linear sweep f_lo -> f_hi over the period, tapered at both ends
        f0, f1 = lines[0] / T, lines[-1] / T
        ph = 2 * np.pi * (f0 * t + 0.5 * (f1 - f0) / T * t ** 2)
        x = np.sin(ph)
        taper = np.clip(np.minimum(t, T - t) / (0.02 * T), 0, 1)
        x = x * (0.5 - 0.5 * np.cos(np.pi * taper))
    elif kind != "prbs":
        raise ValueError(f"unknown signal {kind!r} (multisine, chirp, prbs)")
    x = x - x.mean()
    x *= amplitude / np.max(np.abs(x))
    X = np.fft.rfft(x)
    # keep the lines that carry energy (a chirp's or PRBS's spectrum is not flat)
    strong = np.abs(X[lines]) > 1e-3 * np.abs(X[lines]).max()
    return Excitation(kind, x, dt, lines[strong])

