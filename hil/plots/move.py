"""Plots of runs (matplotlib, Agg): computation stays in the modules that produce the data."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from hil.io.safe_write import save_figure

__all__ = ["plot_move"]


def plot_move(channels: dict, path: str | Path, title: str = "", target: float | None = None,
              stopped: tuple[str, str] | None = None) -> Path:
    """Like the paper's Fig. 10: position (top) and following error (bottom) at table and tool tip.

    ``stopped``: (status, reason) of a run that did not complete: a red line where the record ends
    (the stop) on both axes, and the status and reason written above the figure."""
    t = channels["t"]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    ax1.plot(t, channels["x_cmd"] * 1e3, "k--", lw=1, label="command")
    ax1.plot(t, channels["x_table"] * 1e3, lw=1.5, label="table (linear encoder)")
    ax1.plot(t, channels["x_tip"] * 1e3, lw=1, label="tool tip")
    ax1.set_ylabel("position [mm]")
    ax1.legend(loc="best")
    ax1.grid(True, alpha=0.3)
    ax2.plot(t, (channels["x_cmd"] - channels["x_table"]) * 1e6, lw=1.5, label="table")
    ax2.plot(t, (channels["x_cmd"] - channels["x_tip"]) * 1e6, lw=1, label="tool tip")
    ax2.set_ylabel("following error x_cmd - x [um]")
    ax2.set_xlabel("time [s]")
    ax2.legend(loc="best")
    ax2.grid(True, alpha=0.3)
    if title:
        ax1.set_title(title)
    if stopped is not None and len(t):
        status, reason = stopped
        for ax in (ax1, ax2):
            ax.axvline(t[-1], color="red", lw=1.5)
        ax1.annotate(f"{status.upper()} at t = {t[-1]:.3f} s", (t[-1], ax1.get_ylim()[1]), color="red",
                     ha="right", va="top", fontsize=9)
        fig.suptitle(f"run did not complete: {status}: {reason}", color="red", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path
