"""Figures of ``hil model``: Bode diagrams of TF1, TF2, TF3 (the left panels of the paper's Fig. 9).

Plotting only; the transfer functions come from :mod:`sim_plant.transfer`.
"""
from __future__ import annotations

import numpy as np

__all__ = ["bode_figure"]

_TITLES = ["TF1 = x1 / f", "TF2 = x2 / x1", "TF3 = x3 / x2"]
_UNITS = ["dB re 1 m/N", "dB", "dB"]


def bode_figure(tfs, f_hz, title: str = "", modes_hz=()):
    """A figure with one column per transfer function: magnitude (dB) above, phase (deg) below.
    ``modes_hz`` are marked by dotted lines."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f_hz = np.asarray(f_hz, float)
    n = len(tfs)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 6.0), sharex=True, squeeze=False)
    for j, tf in enumerate(tfs):
        h = tf.freqresp(f_hz)
        mag, ax_p = axes[0, j], axes[1, j]
        mag.semilogx(f_hz, 20 * np.log10(np.abs(h)))
        ax_p.semilogx(f_hz, np.degrees(np.unwrap(np.angle(h))))
        name = _TITLES[j] if j < len(_TITLES) else f"TF{j + 1} = x{j + 1} / x{j}"
        mag.set_title(name)
        mag.set_ylabel(f"magnitude ({_UNITS[j] if j < len(_UNITS) else 'dB'})")
        ax_p.set_ylabel("phase (deg)")
        ax_p.set_xlabel("frequency (Hz)")
        for ax in (mag, ax_p):
            ax.grid(True, which="both", alpha=0.3)
            for f in modes_hz:
                ax.axvline(f, color="0.5", linestyle=":", linewidth=0.8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
