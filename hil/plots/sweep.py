"""Figure of ``hil sweep``: overshoot against the maximum commanded jerk, like the paper's Fig. 5
and Fig. 12 (log jerk axis; table on the left, tool tip on the right; the swept model, the
transmission analysis and the compared 2-dof model; the tolerance line and the answers).

Plotting only; the numbers come from :func:`hil.sweep.run_sweep`'s report.
"""
from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

__all__ = ["sweep_figure"]


def _xy(rows, field):
    rows = sorted((r for r in rows if not r.get("refine")), key=lambda r: r["j_max"])
    return [r["j_max"] for r in rows], [r[field] for r in rows]


def sweep_figure(report: dict, title: str = ""):
    fig, axes = plt.subplots(1, 2, figsize=(12, 6.0), sharex=True)
    an = "transmission" if report.get("analysis") == "transmission" else "mechatronic"
    name = report.get("name") or report.get("config", "model")
    series = [(report.get("runs"), f"{name}, {an}", "C0", "-o")]
    if report.get("runs_transmission"):
        series.append((report["runs_transmission"], f"{name}, transmission (Section 3)", "C0", ":^"))
    if report.get("compare_runs"):
        cname = report.get("compare_name") or report.get("compare_config", "compare")
        series.append((report["compare_runs"], f"{cname}, {an}", "C3", "-s"))
        if report.get("compare_runs_transmission"):
            series.append((report["compare_runs_transmission"], f"{cname}, transmission", "C3", ":v"))
    for ax, field, what in ((axes[0], "overshoot_table_um", "table (linear encoder)"),
                            (axes[1], "overshoot_tip_um", "tool tip (compliant mass)")):
        for rows, label, color, style in series:
            if rows:
                x, y = _xy(rows, field)
                ax.semilogx(x, y, style, color=color, ms=3.5, lw=1.2, label=label,
                            alpha=1.0 if style.startswith("-") else 0.7)
        ax.set_title(f"overshoot at the {what}")
        ax.set_xlabel("maximum commanded jerk j_max [m/s^3]")
        ax.set_ylabel("overshoot [um]")
        ax.grid(True, which="both", alpha=0.3)
    tol = report.get("tolerance_um")
    if tol is not None:
        tip = axes[1]
        tip.axhline(tol, color="k", lw=0.9, ls="--", label=f"tolerance {tol:g} um")
        for key, color, lab in (("max_jerk", "C0", "max jerk"), ("max_jerk_compare", "C3", "max jerk (compare)")):
            v = report.get(key)
            if v:
                tip.axvline(v, color=color, lw=0.9, ls="-.", label=f"{lab} {v:.3g} m/s^3")
        for lo, hi in report.get("admissible") or []:
            tip.axvspan(lo, hi, color="C2", alpha=0.08)
        if report.get("estimate_error_pct") is not None:
            tip.text(0.98, 0.03, f"2-dof estimate error {report['estimate_error_pct']:.1f} %",
                     transform=tip.transAxes, va="bottom", ha="right", fontsize=9)
        tip.set_yscale("symlog", linthresh=max(tol / 8, 1e-3))
    for i, m in enumerate(report.get("local_minima") or []):
        axes[1].plot([m["j_max"]], [m["overshoot_tip_um"]], "o", mfc="none", mec="C1", ms=9,
                     label="local minima (vibration-cancelling jerks)" if i == 0 else None)
    if report.get("admissible") and tol is not None:
        axes[1].axvspan(0, 0, color="C2", alpha=0.08, label=f"jerks within {tol:g} um")    # the band's legend entry
    p = report.get("proposal") or {}
    if tol is not None and report.get("max_jerk"):
        # the answer to the question asked: the largest jerk within the tolerance, on the tolerance line
        axes[1].plot([report["max_jerk"]], [tol], "*", color="C0", ms=12,
                     label=f"answer: {report['max_jerk']:.4g} m/s^3 within {tol:g} um")
    if p.get("j_max"):
        beyond = tol is not None and p["overshoot_tip_um"] > tol
        what = f"proposed for the move time {p['j_max']:.3g} m/s^3" if beyond else f"proposed {p['j_max']:.3g} m/s^3"
        axes[1].plot([p["j_max"]], [p["overshoot_tip_um"]], "*", color="C1", ms=12 if not beyond else 9,
                     mfc="none" if beyond else "C1",
                     label=what + (f" (<= {p['budget_s']:.3g} s)" if p.get("budget_s") else "")
                     + (", beyond the tolerance" if beyond else ""))
    axes[0].set_yscale("symlog", linthresh=1.0)
    seen: dict = {}
    for ax in axes:
        ax.set_ylim(bottom=0)
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    # one legend for both panels, below them, where it covers no line (inside, it hid the answer's jerk)
    fig.legend(list(seen.values()), list(seen), loc="lower center", ncol=3, fontsize=7, frameon=False)
    mv = report.get("move", {})
    fig.suptitle(title or (f"overshoot vs. jerk: stroke {mv.get('stroke_m', 0) * 1e3:g} mm, feed "
                           f"{mv.get('feed_m_per_s', 0) * 60:g} m/min, dwell {mv.get('dwell_s', 0):g} s"))
    fig.tight_layout(rect=(0, 0.05 + 0.028 * math.ceil(len(seen) / 3), 1, 1))
    return fig
