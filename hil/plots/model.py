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


def _figure(**kw):
    """A matplotlib figure drawn by Agg, outside pyplot: no global figure manager to close, no
    backend switched for the rest of the process."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(**kw)
    FigureCanvasAgg(fig)
    return fig


def _frequency_ticks(axes, f_hz) -> None:
    """Ticks of the panels' shared log frequency axis that cost little to draw: decades labelled
    as plain numbers (0.1, 1, 10, 100; the default 10^n labels go through mathtext, whose first
    parse cost 0.13 s), and only ticks inside the view (LogLocator gives a decade beyond each end;
    matplotlib makes each such tick, five artists, before it leaves it undrawn). The grid between
    the decades, at 2 and 5 of each, is one line collection per panel, not minor ticks (each tick is
    five artists: 0.04 s of savefig for the six panels). ``hil model``'s six Bode panels: 390 ticks
    -> 84, savefig 0.55 -> 0.2 s."""
    from matplotlib import rcParams
    from matplotlib.ticker import LogLocator, NullLocator, StrMethodFormatter

    class InView(LogLocator):
        def tick_values(self, vmin, vmax):
            locs = super().tick_values(vmin, vmax)
            lo, hi = sorted((vmin, vmax))
            return locs[(locs >= lo * (1 - 1e-9)) & (locs <= hi * (1 + 1e-9))]

    axis = axes[0].xaxis            # shared by every panel, with its locators and formatters: set once
    axis.set_major_locator(InView(10.0))
    axis.set_major_formatter(StrMethodFormatter("{x:g}"))
    axis.set_minor_locator(NullLocator())
    lo, hi = float(np.min(f_hz)), float(np.max(f_hz))
    between = [m * 10.0 ** e for e in range(int(np.floor(np.log10(lo))), int(np.ceil(np.log10(hi))) + 1)
               for m in (2.0, 5.0) if lo <= m * 10.0 ** e <= hi]
    for ax in axes:
        ax.vlines(between, 0, 1, transform=ax.get_xaxis_transform(), colors=rcParams["grid.color"],
                  linewidths=rcParams["grid.linewidth"], alpha=0.3, zorder=0.5)


def bode_figure(tfs, f_hz, title: str = "", modes_hz=()):
    """A figure with one column per transfer function: magnitude (dB) above, phase (deg) below.
    ``modes_hz`` are marked by dotted lines, each labelled with its number and frequency."""
    f_hz = np.asarray(f_hz, float)
    n = len(tfs)
    fig = _figure(figsize=(4.2 * n, 6.0))
    axes = fig.subplots(2, n, sharex=True, squeeze=False)
    for j, tf in enumerate(tfs):
        h = tf.freqresp(f_hz)
        mag, ax_p = axes[0, j], axes[1, j]
        mag.semilogx(f_hz, 20 * np.log10(np.abs(h)))
        ax_p.semilogx(f_hz, np.degrees(np.unwrap(np.angle(h))))
        name = _TITLES[j] if j < len(_TITLES) else f"TF{j + 1} = x{j + 1} / x{j}"
        mag.set_title(name, y=1.0)      # placed, not measured: the automatic place costs 0.1 s
        mag.set_ylabel(f"magnitude ({_UNITS[j] if j < len(_UNITS) else 'dB'})")
        ax_p.set_ylabel("phase (deg)")
        ax_p.set_xlabel("frequency (Hz)")
        for ax in (mag, ax_p):
            ax.grid(True, alpha=0.3)
            for f in modes_hz:
                ax.axvline(f, color="0.5", linestyle=":", linewidth=0.8)
        # each mode named where its line meets the top of the magnitude panel (mode 2 is the first
        # elastic one, as hil model numbers them)
        for i, f in enumerate(modes_hz):
            mag.annotate(f"mode {i + 2}\n{f:.4g} Hz", xy=(f, 1.0), xycoords=("data", "axes fraction"),
                         xytext=(2, -2), textcoords="offset points", ha="left", va="top", fontsize=7, color="0.3")
    _frequency_ticks(axes.ravel(), f_hz)
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

    fig = _figure(figsize=(8, 7))
    am, ap = fig.subplots(2, 1, sharex=True)
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
    return path
