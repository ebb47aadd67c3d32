"""The analyses of an overshoot curve: pure functions of (jerk, overshoot) points.

Conventions: ``j`` ascending jerks (m/s^3), ``y`` the overshoot at each (any unit, the same as
``tol``); ``f(j)``, when given, computes the overshoot at any jerk (a run on the simulated
plant) and refines what lies between grid points. Tested on hand-made curves.

- :func:`crossing`: bisection in log jerk between an admissible jerk a (f <= tol) and an
  inadmissible b: m = sqrt(a b), until b / a - 1 <= ``rel``; the admissible end is returned.
- :func:`admissible_intervals`: the [low, high] stretches of the curve within ``tol`` (the
  curve need not be monotonic: vibration cancellation makes it dip).
- :func:`tolerance_answer`: the most conservative largest jerk (the first crossing, refined),
  or a note saying which way to extend the range.
- :func:`verify_answer`: the answer checked, not interpolated: around every local maximum of the
  grid curve below it a golden-section search for the peak between its neighbours
  (:func:`peak_search`), and then runs at log-spaced jerks no more than ``verify_rel`` apart from
  the lowest jerk up to the answer itself; any run over the tolerance moves the answer down to
  the crossing below it (bisected to ``rel``). A bump between grid points (the 40-point grid's
  5.17 m/s^3 with 8.8-9.2 um at 4.2-4.4 m/s^3) no longer hides.
- :func:`local_minima` and :func:`cancellation_jerks`: the dips, and where they are expected.
  The acceleration of a sine-square ramp of length T_r is a half-sine pulse, whose spectrum is
  zero at (k + 1/2) / T_r, k >= 1; a ramp with f_dom T_r = k + 1/2 therefore leaves (almost) no
  vibration at the dominant frequency f_dom, at the jerk j = pi^2 V_f / (2 T_r^2).
"""
from __future__ import annotations

import math
from typing import Callable

__all__ = ["crossing", "admissible_intervals", "tolerance_answer", "local_minima", "cancellation_jerks",
           "peak_search", "verify_answer"]


def crossing(ok_j: float, over_j: float, f: Callable[[float], float], tol: float,
             rel: float = 0.002, max_iter: int = 30) -> float:
    """Bisection (in log jerk) between an admissible jerk ``ok_j`` (f <= tol) and an inadmissible one
    ``over_j``; returns the admissible end of the final bracket (relative width ``rel``)."""
    a, b = ok_j, over_j
    for _ in range(max_iter):
        if abs(b / a - 1.0) <= rel:
            break
        m = math.sqrt(a * b)
        if f(m) <= tol:
            a = m
        else:
            b = m
    return a


def admissible_intervals(j, y, tol: float, f: Callable[[float], float] | None = None,
                         rel: float = 0.002) -> list[list[float]]:
    """The [low, high] jerk intervals where ``y`` (overshoot at the jerks ``j``, ascending) stays
    within ``tol``; interval ends between grid points are refined with ``f`` when given."""
    j = [float(v) for v in j]
    ok = [float(v) <= tol for v in y]
    out = []
    i, n = 0, len(j)
    while i < n:
        if not ok[i]:
            i += 1
            continue
        k = i
        while k + 1 < n and ok[k + 1]:
            k += 1
        lo = j[i] if (i == 0 or f is None) else crossing(j[i], j[i - 1], f, tol, rel)
        hi = j[k] if (k == n - 1 or f is None) else crossing(j[k], j[k + 1], f, tol, rel)
        out.append([lo, hi])
        i = k + 1
    return out


def tolerance_answer(j, y, tol: float, f: Callable[[float], float] | None = None,
                     rel: float = 0.002, unit: str = "m/s^3", y_scale: float = 1.0, y_unit: str = "") -> dict:
    """``max_jerk`` (the most conservative: where the overshoot first exceeds ``tol``, refined),
    ``admissible`` intervals, and a ``note`` when there is no answer in the range."""
    j = [float(v) for v in j]
    y = [float(v) for v in y]
    intervals = admissible_intervals(j, y, tol, f, rel)
    res = {"max_jerk": None, "admissible": intervals, "note": None}
    def q(v):
        return f"{v * y_scale:.3g}{(' ' + y_unit) if y_unit else ''}"

    if not j:
        res["note"] = "no runs"
    elif y[0] > tol:
        res["note"] = (f"the lowest jerk of the range, {j[0]:.4g} {unit}, already overshoots "
                       f"{q(y[0])} > {q(tol)}: the most conservative jerk lies below it; extend the "
                       f"range down (e.g. --jmax {j[0] / 10:.3g}..{j[0]:.4g})")
        if intervals:
            res["note"] += " (higher up, admissible intervals exist: see 'admissible')"
    elif all(v <= tol for v in y):
        res["note"] = (f"no jerk of the range exceeds the tolerance (largest overshoot {q(max(y))} <= "
                       f"{q(tol)}): the limit lies above {j[-1]:.4g} {unit}; extend the range up "
                       f"(e.g. --jmax {j[-1]:.4g}..{j[-1] * 10:.3g})")
    else:
        res["max_jerk"] = intervals[0][1]
    return res


def local_minima(j, y, floor: float = 0.0) -> list[int]:
    """Indices of the interior local minima of ``y`` (a dip: lower than the point before, not higher
    than the one after); flat stretches at ``floor`` (no overshoot at all) are not dips."""
    out = []
    for i in range(1, len(y) - 1):
        if y[i] < y[i - 1] and y[i] <= y[i + 1] and not (y[i] <= floor and y[i + 1] <= floor):
            out.append(i)
    return out


def cancellation_jerks(f_dom: float, feed: float, j_lo: float, j_hi: float) -> list[dict]:
    """Jerks whose ramp T_r lasts (k + 1/2) periods of ``f_dom`` (k >= 1): the half-sine
    acceleration pulse of a sine-square ramp has no spectral content at 1.5/T_r, 2.5/T_r, ...,
    so a ramp of that length leaves (almost) no vibration at f_dom."""
    out = []
    for k in range(1, 200):
        tr = (k + 0.5) / f_dom
        j = math.pi ** 2 * feed / (2.0 * tr * tr)
        if j < j_lo:
            break
        if j <= j_hi:
            out.append({"k": k, "cycles": k + 0.5, "ramp_time": tr, "j_max": j})
    return out


def peak_search(lo: float, hi: float, f: Callable[[float], float], iters: int = 12) -> tuple[float, float]:
    """The largest value of ``f`` on [lo, hi] by golden-section search in log jerk (a local
    maximum between two grid points): ``(jerk, value)`` of the best run seen."""
    g = (math.sqrt(5) - 1) / 2
    a, b = math.log(lo), math.log(hi)
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(math.exp(c)), f(math.exp(d))
    best = max((fc, c), (fd, d))
    for _ in range(iters):
        if fc >= fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = f(math.exp(c))
            best = max(best, (fc, c))
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = f(math.exp(d))
            best = max(best, (fd, d))
    return math.exp(best[1]), best[0]


def verify_answer(j, y, tol: float, answer: float, f: Callable[[float], float], f_many=None,
                  rel: float = 0.002, verify_rel: float = 0.01, max_runs: int = 400) -> dict:
    """Check a largest admissible jerk ``answer`` (the first crossing of the grid curve ``j``,
    ``y``, refined) by runs, and move it down where a run below it exceeds ``tol``.

    Parameters
    ----------
    j, y : sequence of float
        The grid: ascending jerks and their overshoots.
    tol : float
        The tolerance (the unit of ``y``).
    answer : float
        The grid's answer, ``j[0] <= answer``.
    f, f_many : callable
        The overshoot at one jerk, and at a list of jerks (default: ``f`` on each).
    rel : float
        Relative width to which a crossing found is bisected.
    verify_rel : float
        Largest relative spacing of the dense runs from ``j[0]`` to the answer (widened, and said
        so, where that would take more than ``max_runs`` runs).

    Returns
    -------
    dict
        ``max_jerk`` (the checked answer), ``peaks`` (the local maxima searched: jerk and
        overshoot found), ``runs`` (dense runs), ``spacing_rel`` (their largest relative
        spacing), ``largest_below`` (the largest overshoot of the runs at or below the answer),
        ``moved`` (whether the check lowered the answer).
    """
    f_many = f_many or (lambda js: [f(v) for v in js])
    j = [float(v) for v in j]
    y = [float(v) for v in y]
    J = float(answer)
    peaks = []
    # 1. the grid's local maxima below the answer: the peak between their neighbours
    for i in range(1, len(j) - 1):
        if j[i + 1] > J:
            break
        if y[i] >= y[i - 1] and y[i] >= y[i + 1]:
            jp, yp = peak_search(j[i - 1], j[i + 1], f)
            peaks.append({"j_max": jp, "overshoot": yp})
            if yp > tol:
                J = min(J, crossing(j[i - 1], jp, f, tol, rel))
                break
    # 2. dense runs from the lowest jerk up to the answer itself
    lo = j[0]
    n = 2 if J <= lo else int(math.ceil(math.log(J / lo) / math.log1p(verify_rel))) + 1
    n = max(2, min(n, max_runs))
    spacing = (J / lo) ** (1.0 / (n - 1)) - 1.0 if J > lo else 0.0
    pts = [lo * (J / lo) ** (k / (n - 1)) for k in range(n)] if J > lo else [lo]
    pts[-1] = J
    ys = [float(v) for v in f_many(pts)]
    largest = ys[0]
    for k, (pj, py) in enumerate(zip(pts, ys)):
        if py > tol:
            if k == 0:          # the lowest jerk itself is over: no admissible jerk
                return {"max_jerk": None, "peaks": peaks, "runs": len(pts), "spacing_rel": spacing,
                        "largest_below": py, "moved": True}
            J = crossing(pts[k - 1], pj, f, tol, rel)
            break
        largest = max(largest, py)
    return {"max_jerk": J, "peaks": peaks, "runs": len(pts), "spacing_rel": spacing, "largest_below": largest,
            "moved": J < float(answer)}
