"""Figures of model against measurement (PNG): overlay, residual, spectrum, residual scatter."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.io.safe_write import save_figure


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def comparison_figures(analysis: dict, out: Path, tag: str = "", after: dict | None = None) -> list[Path]:
    """Write overlay, residual, spectrum and scatter PNGs; ``after``: a second analysis (the fitted
    model) drawn beside the first. Returns the paths."""
    plt = _plt()
    out.mkdir(parents=True, exist_ok=True)
    A = analysis["_arrays"]
    B = after["_arrays"] if after else None
    t = A["t"]
    chans = list(A["measured"])
    paths = []
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 2.6 * len(chans)), sharex=True, squeeze=False)
    for ax, c in zip(axes[:, 0], chans):
        ax.plot(t, A["measured"][c], "k", lw=1, label="measured")
        ax.plot(t, A["simulated"][c], "C0", lw=0.8, label="model")
        if B:
            ax.plot(t, B["simulated"][c], "C3--", lw=0.8, label="fitted model")
        ax.set_ylabel(c)
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    paths.append(out / f"overlay{tag}.png")
    save_figure(fig, paths[-1], dpi=90)
    plt.close(fig)
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 2.4 * len(chans)), sharex=True, squeeze=False)
    for ax, c in zip(axes[:, 0], chans):
        ax.plot(t, A["residual"][c], "C0", lw=0.7, label="residual, model")
        if B:
            ax.plot(t, B["residual"][c], "C3", lw=0.7, label="residual, fitted")
        ax.set_ylabel(f"{c} residual")
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    paths.append(out / f"residual{tag}.png")
    save_figure(fig, paths[-1], dpi=90)
    plt.close(fig)
    dt = analysis["sample_period"]
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 2.4 * len(chans)), squeeze=False)
    for ax, c in zip(axes[:, 0], chans):
        for arr, col, lab in ((A, "C0", "model"), (B, "C3", "fitted")):
            if arr is None:
                continue
            r = arr["residual"][c] - np.mean(arr["residual"][c])
            w = np.hanning(r.size)
            ax.semilogy(np.fft.rfftfreq(r.size, dt), np.abs(np.fft.rfft(r * w)) * 2 / w.sum() + 1e-30, col, lw=0.7,
                        label=lab)
        ax.set_ylabel(f"|{c} residual|")
        ax.legend(fontsize=7)
    axes[-1, 0].set_xlabel("frequency [Hz]")
    fig.tight_layout()
    paths.append(out / f"spectrum{tag}.png")
    save_figure(fig, paths[-1], dpi=90)
    plt.close(fig)
    fig, axes = plt.subplots(len(chans), 3, figsize=(11, 2.6 * len(chans)), squeeze=False)
    for i, c in enumerate(chans):
        for j, (k, lab) in enumerate((("v", "velocity [m/s]"), ("a", "acceleration [m/s^2]"), ("x_cmd", "position [m]"))):
            axes[i, j].plot(A[k], A["residual"][c], ".", ms=1, alpha=0.4)
            axes[i, j].set_xlabel(lab)
            axes[i, j].set_ylabel(f"{c} residual" if j == 0 else "")
    fig.tight_layout()
    paths.append(out / f"scatter{tag}.png")
    save_figure(fig, paths[-1], dpi=90)
    plt.close(fig)
    return paths


def error_fall_figure(rows: list[dict], out: Path, keys=("position", "velocity", "force")) -> Path:
    """Bar chart of the relative errors per added effect (rows: {"step", key: %})."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4.2))
    x = np.arange(len(rows))
    for i, k in enumerate(keys):
        ax.bar(x + (i - 1) * 0.27, [r[k] for r in rows], 0.27, label=f"{k} error %")
    ax.set_xticks(x, [r.get("short", r["step"]) for r in rows], rotation=30, ha="right", fontsize=7)
    ax.set_ylabel("relative 2-norm error %")
    ax.grid(axis="y", which="both", alpha=0.3)
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, out, dpi=90)
    plt.close(fig)
    return out
