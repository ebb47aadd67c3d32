"""Plots of runs (matplotlib, Agg): computation stays in the modules that produce the data."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hil.io.safe_write import save_figure

__all__ = ["plot_move"]


def wrap_to(fig, text: str, fontsize: float) -> str:
    """``text`` broken into lines that fit the width of ``fig`` at ``fontsize`` (a long config path
    and a move's figures, a stop's reason: one line was cut off at the figure's edges)."""
    import textwrap
    # an average glyph of DejaVu Sans is about 0.6 of the font size wide; a margin of 5 %
    chars = max(20, int(0.95 * fig.get_figwidth() * 72 / (0.6 * fontsize)))
    return "\n".join(textwrap.wrap(text, chars, break_long_words=True)) if len(text) > chars else text


def move_figure(channels: dict, title: str = "", stopped: tuple[str, str] | None = None):
    """The figure of :func:`plot_move` (matplotlib), not yet saved."""
    t = channels["t"]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 7), sharex=True, layout="constrained")
    ax1.plot(t, channels["x_cmd"] * 1e3, "k--", lw=1, label="command")
    ax1.plot(t, channels["x_table"] * 1e3, lw=1.5, label="table (linear encoder)")
    ax1.plot(t, channels["x_tip"] * 1e3, lw=1, label="tool tip")
    ax1.set_ylabel("position [mm]")
    ax1.legend(loc="best")
    ax1.grid(True, alpha=0.3)
    ax2.plot(t, (channels["x_cmd"] - channels["x_table"]) * 1e6, lw=1.5, label="table")
    ax2.plot(t, (channels["x_cmd"] - channels["x_tip"]) * 1e6, lw=1, label="tool tip")
    stale = np.asarray(channels.get("stale", ()), float)
    if stale.size == len(t) and stale.any():
        # a cycle without its answer repeats the last reading while the command moves on: its
        # following error is not the axis's; marked, and the summary leaves it out
        miss = stale != 0
        ax2.plot(t[miss], ((channels["x_cmd"] - channels["x_table"]) * 1e6)[miss], "x", color="red", ms=4,
                 label=f"no answer ({int(miss.sum())} cycles: stale reading)")
    ax2.set_ylabel("following error x_cmd - x [um]")
    ax2.set_xlabel("time [s]")
    ax2.legend(loc="best")
    ax2.grid(True, alpha=0.3)
    if title:
        ax1.set_title(wrap_to(fig, title, 11), fontsize=11)
    if stopped is not None and len(t):
        status, reason = stopped
        for ax in (ax1, ax2):
            ax.axvline(t[-1], color="red", lw=1.5)
        ax1.annotate(f"{status.upper()} at t = {t[-1]:.3f} s", (t[-1], ax1.get_ylim()[1]), color="red",
                     ha="right", va="top", fontsize=9)
        fig.suptitle(wrap_to(fig, f"run did not complete: {status}: {reason}", 9), color="red", fontsize=9)
    return fig


def plot_move(channels: dict, path: str | Path, title: str = "", target: float | None = None,
              stopped: tuple[str, str] | None = None) -> Path:
    """Like the paper's Fig. 10: position (top) and following error (bottom) at table and tool tip.

    ``stopped``: (status, reason) of a run that did not complete: a red line where the record ends
    (the stop) on both axes, and the status and reason written above the figure. Titles are wrapped
    to the figure's width."""
    fig = move_figure(channels, title, stopped)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path
