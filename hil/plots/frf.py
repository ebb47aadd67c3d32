"""Figures of ``hil frf``: measured against modelled frequency responses (Bode, one column per
response, with the measurement's uncertainty band) and the coherence.

Plotting only; the numbers come from :mod:`hil.frf`.
"""
from __future__ import annotations

import numpy as np

from hil.frf import TITLES, UNITS

__all__ = ["bode_measured_vs_model", "coherence_figure"]


def bode_measured_vs_model(result, names=None, title: str = ""):
    """Magnitude (dB, with a +-2 sigma band), phase (deg) of each response: measured (dots) and
    model (line); fitted modes marked."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in (names or result.responses) if n in result.responses]
    fig, axes = plt.subplots(2, len(names), figsize=(3.6 * len(names), 6.0), squeeze=False)
    for j, name in enumerate(names):
        r = result.responses[name]
        mag, ph = axes[0, j], axes[1, j]
        m_db = 20 * np.log10(np.abs(r.h))
        rel = np.clip(r.sigma / np.maximum(np.abs(r.h), 1e-300), 0, 0.99)
        mag.fill_between(r.f, m_db + 20 * np.log10(1 - np.minimum(2 * rel, 0.9)), m_db + 20 * np.log10(1 + 2 * rel),
                         color="C0", alpha=0.25, linewidth=0, label="measured +-2 sigma")
        mag.semilogx(r.f, m_db, ".", color="C0", markersize=2.5, label="measured")
        ph.semilogx(r.f, np.degrees(np.unwrap(np.angle(r.h))), ".", color="C0", markersize=2.5)
        if name in result.model:
            hm = result.model[name][:r.f.size]
            mag.semilogx(r.f, 20 * np.log10(np.abs(hm)), "-", color="C3", linewidth=1.0, label="model")
            phm = np.degrees(np.unwrap(np.angle(hm)))
            phm_meas = np.degrees(np.unwrap(np.angle(r.h)))
            # same branch as the measured phase
            phm += 360 * np.round((phm_meas[0] - phm[0]) / 360)
            ph.semilogx(r.f, phm, "-", color="C3", linewidth=1.0)
        mag.set_title(TITLES[name] + (" (derived)" if r.derived else ""), fontsize=9)
        mag.set_ylabel(f"dB re {UNITS[name]}", fontsize=8)
        ph.set_ylabel("phase (deg)", fontsize=8)
        ph.set_xlabel("frequency (Hz)")
        for ax in (mag, ph):
            ax.set_xscale("log")
            ax.grid(True, which="both", alpha=0.3)
            for row in result.modes:
                ax.axvline(row["measured"]["frequency_hz"], color="0.5", linestyle=":", linewidth=0.8)
        if j == 0:
            mag.legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def coherence_figure(result, title: str = ""):
    """Coherence of the excitation with each estimated (not derived) response."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    for name, r in result.responses.items():
        if r.derived:
            continue
        ax.semilogx(r.f, r.coherence, label=TITLES[name], linewidth=1.0)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("coherence [-]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return fig
