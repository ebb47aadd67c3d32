"""Figures of model against measurement (PNG): overlay (each channel measured and simulated, its
residual beneath on the same time axis, the fit % in the legend), residual, spectrum, residual
scatter, and MATLAB ``resid``'s figure (the residual's autocorrelation and its cross-correlation with the
input, with the 99 % confidence band +-2.576/sqrt(N)).

Every axis names its quantity and its unit; lengths, speeds, times and torques are drawn in the
unit an engineer reads (um, mm, mm/s, ms, N m: hil.plots.engineering), never in SI e-notation.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.io.safe_write import save_figure
from hil.plots.engineering import display_unit

# the input MATLAB's resid correlates the residual with: here the commanded velocity (the
# derivative of x_cmd, the record's input), as hil.ident.residual_analysis's cross-correlation
INPUT_NAME = "commanded velocity"


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _channel_units(analysis: dict, key: str, chans, extra: dict | None = None) -> dict:
    """Per channel (display unit, SI per display unit) of the arrays ``_arrays[key]`` (and of
    ``extra``'s, drawn on the same axis)."""
    A = analysis["_arrays"]
    out = {}
    for c in chans:
        unit = analysis["channels"][c]["unit"]
        vals = [np.max(np.abs(A[key][c]))] + ([np.max(np.abs(extra[key][c]))] if extra else [])
        out[c] = display_unit(unit, *vals)
    return out


def fit_label(name: str, fit: float) -> str:
    """A legend entry with the model's fit, as MATLAB's ``compare`` writes it: ``model: 97.31 %``
    (NRMSE fit, 100 (1 - ||y - y_hat|| / ||y - mean y||))."""
    return f"{name}: {fit:.2f} %"


def overlay_figure(analysis: dict, after: dict | None = None, names=("model", "fitted model")):
    """Per channel, measured and simulated on top, their residual (measured - simulated) beneath,
    every panel on one shared time axis (zooming one zooms all); the fit % of each model in the
    legend. Returns the matplotlib figure."""
    plt = _plt()
    A = analysis["_arrays"]
    B = after["_arrays"] if after else None
    t = A["t"]
    chans = list(A["measured"])
    sig_u = _channel_units(analysis, "measured", chans)
    res_u = _channel_units(analysis, "residual", chans, B)
    fig = plt.figure(figsize=(10, 3.7 * len(chans)), layout="constrained")
    grid = fig.add_gridspec(2 * len(chans), 1, height_ratios=[2.4, 1.0] * len(chans))
    first = None
    for i, c in enumerate(chans):
        ax = fig.add_subplot(grid[2 * i], sharex=first)
        first = first or ax
        axr = fig.add_subplot(grid[2 * i + 1], sharex=first)
        name, k = sig_u[c]
        ax.plot(t, A["measured"][c] / k, "k", lw=1, label="measured")
        ax.plot(t, A["simulated"][c] / k, "C0", lw=0.8, label=fit_label(names[0], analysis["channels"][c]["fit"]))
        rname, rk = res_u[c]
        axr.plot(t, A["residual"][c] / rk, "C0", lw=0.7)
        if B:
            ax.plot(t, B["simulated"][c] / k, "C3--", lw=0.8, label=fit_label(names[1], after["channels"][c]["fit"]))
            axr.plot(t, B["residual"][c] / rk, "C3", lw=0.7)
        axr.axhline(0.0, color="0.5", lw=0.5)
        ax.set_ylabel(f"{c} [{name}]")
        axr.set_ylabel(f"residual [{rname}]")
        ax.legend(loc="upper right", fontsize=7, title="fit (NRMSE)", title_fontsize=7)
        ax.tick_params(labelbottom=False)
        if i < len(chans) - 1:
            axr.tick_params(labelbottom=False)
    axr.set_xlabel("time [s]")
    return fig


def comparison_figures(analysis: dict, out: Path, tag: str = "", after: dict | None = None) -> list[Path]:
    """Write overlay, residual, spectrum, scatter and correlation (resid's figure) PNGs; ``after``: a second analysis
    (the fitted model) drawn beside the first. Returns the paths."""
    plt = _plt()
    out.mkdir(parents=True, exist_ok=True)
    A = analysis["_arrays"]
    B = after["_arrays"] if after else None
    t = A["t"]
    chans = list(A["measured"])
    paths = []
    res_u = _channel_units(analysis, "residual", chans, B)
    fig = overlay_figure(analysis, after)
    paths.append(out / f"overlay{tag}.png")
    save_figure(fig, paths[-1], dpi=90)
    plt.close(fig)
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 2.4 * len(chans)), sharex=True, squeeze=False)
    for ax, c in zip(axes[:, 0], chans):
        name, k = res_u[c]
        ax.plot(t, A["residual"][c] / k, "C0", lw=0.7, label="residual, model")
        if B:
            ax.plot(t, B["residual"][c] / k, "C3", lw=0.7, label="residual, fitted")
        ax.set_ylabel(f"{c} residual [{name}]")
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    paths.append(out / f"residual{tag}.png")
    save_figure(fig, paths[-1], dpi=90)
    plt.close(fig)
    dt = analysis["sample_period"]
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 2.4 * len(chans)), squeeze=False)
    for ax, c in zip(axes[:, 0], chans):
        name, k = res_u[c]
        for arr, col, lab in ((A, "C0", "model"), (B, "C3", "fitted")):
            if arr is None:
                continue
            r = arr["residual"][c] - np.mean(arr["residual"][c])
            w = np.hanning(r.size)
            ax.semilogy(np.fft.rfftfreq(r.size, dt), np.abs(np.fft.rfft(r * w)) * 2 / w.sum() / k + 1e-30, col,
                        lw=0.7, label=lab)
        ax.set_ylabel(f"|{c} residual| [{name}]")
        ax.legend(fontsize=7)
    axes[-1, 0].set_xlabel("frequency [Hz]")
    fig.tight_layout()
    paths.append(out / f"spectrum{tag}.png")
    save_figure(fig, paths[-1], dpi=90)
    plt.close(fig)
    v_name, v_k = display_unit("m/s", np.max(np.abs(A["v"])))
    x_name, x_k = display_unit("m", np.max(np.abs(A["x_cmd"])))
    fig, axes = plt.subplots(len(chans), 3, figsize=(11, 2.6 * len(chans)), squeeze=False)
    for i, c in enumerate(chans):
        name, k = res_u[c]
        for j, (key, lab, scale) in enumerate((("v", f"commanded velocity [{v_name}]", v_k),
                                               ("a", "commanded acceleration [m/s^2]", 1.0),
                                               ("x_cmd", f"commanded position [{x_name}]", x_k))):
            axes[i, j].plot(A[key] / scale, A["residual"][c] / k, ".", ms=1, alpha=0.4)
            axes[i, j].set_xlabel(lab)
            axes[i, j].set_ylabel(f"{c} residual [{name}]" if j == 0 else f"[{name}]")
    fig.tight_layout()
    paths.append(out / f"scatter{tag}.png")
    save_figure(fig, paths[-1], dpi=90)
    plt.close(fig)
    paths.append(resid_figure(analysis, out / f"correlation{tag}.png", after=after))
    return paths


def resid_figure(analysis: dict, path: Path, after: dict | None = None) -> Path:
    """MATLAB ``resid``'s figure, per channel: left the residual's autocorrelation at lags > 0,
    right its cross-correlation with the input (the commanded velocity) at lags of both signs,
    each with the 99 % confidence band +-2.576/sqrt(N) of a white residual independent of the
    input (shaded); the model in blue, the fitted model (``after``) in red. A model that
    explains the record leaves both inside the band."""
    plt = _plt()
    A = analysis["_arrays"]
    B = after["_arrays"] if after else None
    chans = list(A["measured"])
    band = A["band_99"]
    fig, axes = plt.subplots(len(chans), 2, figsize=(11, 2.5 * len(chans)), squeeze=False)
    for i, c in enumerate(chans):
        for j, (key, what) in enumerate((("autocorrelation", f"autocorrelation of {c} residual"),
                                         ("cross_correlation", f"{INPUT_NAME} x {c} residual"))):
            ax = axes[i, j]
            for arr, col, lab in ((A, "C0", "model"), (B, "C3", "fitted model")):
                if arr is None:
                    continue
                lag, val = arr[key][c]
                keep = lag > 0 if key == "autocorrelation" else slice(None)
                ax.plot(lag[keep] * 1e3, val[keep], col, lw=0.8, marker=".", ms=2, label=lab)
            lag = A[key][c][0]
            lo = 0.0 if key == "autocorrelation" else lag.min() * 1e3
            ax.axhspan(-band, band, color="0.85", zorder=0, label="99 % confidence band")
            ax.axhline(0, color="0.5", lw=0.5)
            ax.set_xlim(lo, lag.max() * 1e3)
            ax.set_title(what, fontsize=8)
            ax.set_ylabel("correlation [-]")
            if i == 0:
                ax.legend(fontsize=6, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("lag [ms]")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=90)
    plt.close(fig)
    return path


def error_fall_figure(rows: list[dict], out: Path, keys=("position", "velocity", "force")) -> Path:
    """Bar chart of the relative errors per added effect (rows: {"step", key: %})."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4.2))
    x = np.arange(len(rows))
    for i, k in enumerate(keys):
        ax.bar(x + (i - 1) * 0.27, [r[k] for r in rows], 0.27, label=f"{k} error")
    ax.set_xticks(x, [r.get("short", r["step"]) for r in rows], rotation=30, ha="right", fontsize=7)
    ax.set_ylabel("relative 2-norm error [%]")
    ax.set_xlabel("model (effects added one by one)")
    ax.grid(axis="y", which="both", alpha=0.3)
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, out, dpi=90)
    plt.close(fig)
    return out
