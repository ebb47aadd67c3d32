"""Figures of ``hil model``: Bode diagrams of TF1, TF2, TF3 (the left panels of the paper's Fig. 9).

Plotting only; the transfer functions come from :mod:`sim_plant.transfer`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.io.safe_write import save_figure

__all__ = ["bode_figure"]

_TITLES = ["TF1 = x1 / f", "TF2 = x2 / x1", "TF3 = x3 / x2"]
_UNITS = ["dB re 1 m/N", "dB", "dB"]


def bode_figure(tfs, f_hz, title: str = "", modes_hz=()):
    """A figure with one column per transfer function: magnitude (dB) above, phase (deg) below.
    ``modes_hz`` are marked by dotted lines, each labelled with its number and frequency."""
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
        # each mode named where its line meets the top of the magnitude panel (mode 2 is the first
        # elastic one, as hil model numbers them)
        for i, f in enumerate(modes_hz):
            mag.annotate(f"mode {i + 2}\n{f:.4g} Hz", xy=(f, 1.0), xycoords=("data", "axes fraction"),
                         xytext=(2, -2), textcoords="offset points", ha="left", va="top", fontsize=7, color="0.3")
    if title:
        fig.suptitle(title)
    # fixed margins: tight_layout measures every tick label of the log axes and costs more than
    # the rest of 'hil model' together
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.09, top=0.90 if title else 0.94, wspace=0.28,
                        hspace=0.08)
    return fig


def closed_loop_figure(r, out_dir) -> Path:
    """The right panels of Fig. 9: closed position loop to the table, with and without the
    feed-forward, alone and followed by TF3."""
    from pathlib import Path as _P

    import matplotlib.pyplot as plt
    fig, (am, ap) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    for h, label, style in ((r.table, "table, with FFV", "-"), (r.table_no_ff, "table, no FFV", "--"),
                            (r.table_tf3, "table x TF3, with FFV", "-"),
                            (r.table_no_ff_tf3, "table x TF3, no FFV", "--")):
        am.semilogx(r.f_hz, 20 * np.log10(np.abs(h)), style, label=label)
        ap.semilogx(r.f_hz, np.degrees(np.unwrap(np.angle(h))), style, label=label)
    am.axhline(-3, color="grey", lw=0.8, ls=":")
    am.set_ylabel("magnitude [dB]")
    ap.set_ylabel("phase [deg]")
    ap.set_xlabel("frequency [Hz]")
    am.set_title("closed position loop: command to table (and to tool tip through TF3)")
    am.legend(fontsize=8)
    for a in (am, ap):
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    out = _P(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bode_closed_loop.png"
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path
