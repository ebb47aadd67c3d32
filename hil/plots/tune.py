"""The figure of ``hil tune``: the tip's settling before and after, and the shapers' robustness."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hil.io.safe_write import save_figure  # noqa: E402
from hil.shaping import ALL_KINDS, Shaper, residual_vibration  # noqa: E402

__all__ = ["plot_tune"]


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
