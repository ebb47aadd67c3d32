"""The figure of ``hil tune``: the tip's settling before and after, and the shapers' robustness."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hil.io.safe_write import save_figure  # noqa: E402
from hil.shaping import ALL_KINDS, Shaper, residual_vibration  # noqa: E402

__all__ = ["plot_tune", "plot_loops"]


def plot_tune(path: Path, tol: float, given: dict | None, tuned: dict | None, mode: dict | None,
              mode_error: float, settle: dict) -> Path:
    """``path`` (PNG): left, the tip's distance from its target against the time since the start of
    the move, for the move as given and the tuned one (records' channels ``t``, ``x_tip`` and the
    target under ``target``), the tolerance band and when each is within it for good (``settle``:
    label -> s or None); right, the residual vibration of the ZV, ZVD, EI and SI shapers for the mode
    against the frequency error, the band the choice was made to tolerate shaded."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5), layout="constrained")
    for label, rec, style in (("as given", given, dict(color="0.5", lw=1)), ("tuned", tuned, dict(color="C0", lw=1.5))):
        if rec is None:
            continue
        err = (np.asarray(rec["x_tip"]) - rec["target"]) * 1e6
        ax1.plot(rec["t"] * 1e3, err, label=f"tip, {label}", **style)
        s = settle.get(label)
        if s is not None:
            ax1.axvline(s * 1e3, ls=":", **style)
            ax1.annotate(f"{s * 1e3:.0f} ms", (s * 1e3, tol * 1e6), textcoords="offset points", xytext=(3, 6),
                         color=style["color"], fontsize=8)
    ax1.axhspan(-tol * 1e6, tol * 1e6, color="C2", alpha=0.15, label=f"tolerance +-{tol * 1e6:g} um")
    ax1.set_ylim(-8 * tol * 1e6, 8 * tol * 1e6)
    ax1.set_xlabel("time since the start of the move [ms]")
    ax1.set_ylabel("tip - target [um]")
    ax1.set_title("the tool tip's arrival (dotted: within the tolerance for good)")
    ax1.legend(loc="upper right", fontsize=8)
    ax1.grid(True, alpha=0.3)
    if mode is not None:
        f0, z = mode["measured"]["frequency_hz"], mode["measured"]["damping_ratio"]
        ratio = np.linspace(0.6, 1.4, 401)
        for kind in ALL_KINDS:
            sh = Shaper.design(kind, f0, z)
            ax2.plot(ratio * 100 - 100, residual_vibration(sh, ratio * f0, z) * 100, label=f"{kind.upper()} "
                     f"({sh.duration * 1e3:.0f} ms longer)")
        ax2.axvspan(-mode_error * 100, mode_error * 100, color="C2", alpha=0.15,
                    label=f"the error tolerated: +-{mode_error:.0%}")
        ax2.set_title(f"shapers at the tip's mode as measured: {f0:.4g} Hz, damping {z:.3g}")
        ax2.legend(loc="upper center", fontsize=8)
    else:
        ax2.text(0.5, 0.5, "no mode measured in the tip's response: no shaper", ha="center", transform=ax2.transAxes)
    ax2.set_xlabel("the mode's frequency error [%]")
    ax2.set_ylabel("residual vibration [% of the unshaped]")
    ax2.grid(True, alpha=0.3)
    try:
        return save_figure(fig, path)
    finally:
        plt.close(fig)


LOOPS = (("Lv", "open velocity loop"), ("Lp", "open position loop"))


def plot_loops(path: Path, before, after) -> Path | None:
    """``path`` (PNG): the open velocity and position loops as measured (hil.frf.FrfResult) with
    the gains as given and as tuned, magnitude and phase, the 0 dB and -180 deg lines (where the
    margins are read); None where neither measurement holds a loop."""
    names = [(n, t) for n, t in LOOPS if any(r is not None and n in r.responses for r in (before, after))]
    if not names:
        return None
    fig, axes = plt.subplots(2, len(names), figsize=(6 * len(names), 6), squeeze=False, layout="constrained")
    for j, (name, title) in enumerate(names):
        mag, ph = axes[0, j], axes[1, j]
        for label, res, style in (("as given", before, dict(color="0.5", lw=1)),
                                  ("tuned", after, dict(color="C0", lw=1.5))):
            r = res.responses.get(name) if res is not None else None
            if r is None:
                continue
            mag.semilogx(r.f, 20 * np.log10(np.abs(r.h)), label=label, **style)
            phase = np.degrees(np.unwrap(np.angle(r.h)))
            phase -= 360 * np.round(phase[0] / 360)       # the branch that starts near 0 deg
            ph.semilogx(r.f, phase, **style)
        mag.axhline(0.0, color="C3", lw=0.8, ls="--", label="0 dB (crossover: phase margin)")
        ph.axhline(-180.0, color="C3", lw=0.8, ls="--", label="-180 deg (gain margin)")
        mag.set_title(f"{title}, as measured")
        mag.set_ylabel("magnitude [dB]")
        ph.set_ylabel("phase [deg]")
        ph.set_xlabel("frequency [Hz]")
        for ax in (mag, ph):
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(loc="lower left", fontsize=8)
    try:
        return save_figure(fig, path)
    finally:
        plt.close(fig)
