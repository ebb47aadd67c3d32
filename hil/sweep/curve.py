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
- :func:`verify_intervals`: the same check for every admissible interval: an excursion inside
  one splits it in two (issue 30: the first crossing at 14.03 m/s^3 hid the admissible
  15.8-23.6 m/s^3 behind it).
- :func:`local_minima` and :func:`cancellation_jerks`: the dips, and where they are expected.
  The acceleration of a sine-square ramp of length T_r is a half-sine pulse, whose spectrum is
  zero at (k + 1/2) / T_r, k >= 1; a ramp with f_dom T_r = k + 1/2 therefore leaves (almost) no
  vibration at the dominant frequency f_dom, at the jerk j = pi^2 V_f / (2 T_r^2).
"""
from __future__ import annotations

import math
from typing import Callable

__all__ = ["crossing", "admissible_intervals", "tolerance_answer", "local_minima", "cancellation_jerks",
           "peak_search", "verify_answer", "verify_intervals"]


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


def _dense(lo: float, hi: float, verify_rel: float, max_runs: int) -> tuple[list[float], float]:
    """Log-spaced jerks from ``lo`` to ``hi`` (both included) no more than ``verify_rel`` apart,
    at most ``max_runs`` of them (the spacing widens beyond): ``(jerks, spacing)``."""
    if not hi > lo:
        return [lo], 0.0
    n = int(math.ceil(math.log(hi / lo) / math.log1p(verify_rel))) + 1
    n = max(2, min(n, max_runs))
    pts = [lo * (hi / lo) ** (k / (n - 1)) for k in range(n)]
    pts[0], pts[-1] = lo, hi
    return pts, (hi / lo) ** (1.0 / (n - 1)) - 1.0


def verify_intervals(j, y, tol: float, intervals, f: Callable[[float], float], f_many=None,
                     rel: float = 0.002, verify_rel: float = 0.01, max_runs: int = 400) -> dict:
    """Check admissible intervals (those of :func:`admissible_intervals`) by runs, and split or
    shrink them where a run inside exceeds ``tol``.

    In every interval: a golden-section search for the peak around each grid local maximum in it
    (:func:`peak_search`), then runs at log-spaced jerks no more than ``verify_rel`` apart from
    its low end to its high end (at most ``max_runs`` per interval); each change between a run
    within ``tol`` and one over it is bisected to ``rel`` (:func:`crossing`), so an interval
    with an excursion inside becomes two, with the excursion's edges as ends.

    Returns
    -------
    dict
        ``intervals`` (the verified ones, ascending), ``peaks`` (the local maxima searched: jerk
        and value found), ``runs`` (dense runs), ``spacing_rel`` (their largest relative
        spacing), ``largest_within`` (the largest value of the runs inside the verified
        intervals, per interval), ``moved`` (whether any interval changed).
    """
    f_many = f_many or (lambda js: [f(v) for v in js])
    j = [float(v) for v in j]
    y = [float(v) for v in y]
    out, peaks, largest = [], [], []
    runs, spacing = 0, 0.0
    for lo, hi in intervals:
        lo, hi = float(lo), float(hi)
        extra = []
        for i in range(1, len(j) - 1):        # grid local maxima inside the interval
            if lo <= j[i] <= hi and y[i] >= y[i - 1] and y[i] >= y[i + 1]:
                jp, yp = peak_search(j[i - 1], j[i + 1], f)
                peaks.append({"j_max": jp, "overshoot": yp})
                if lo < jp < hi:
                    extra.append((jp, yp))
        pts, sp = _dense(lo, hi, verify_rel, max_runs)
        runs += len(pts)
        spacing = max(spacing, sp)
        pairs = sorted(list(zip(pts, (float(v) for v in f_many(pts)))) + extra)
        start = pairs[0][0] if pairs[0][1] <= tol else None
        top = pairs[0][1] if start is not None else -math.inf
        for (pa, ya), (pb, yb) in zip(pairs, pairs[1:]):
            if ya <= tol < yb:                # leaves the tolerance between pa and pb
                out.append([start, crossing(pa, pb, f, tol, rel)])
                largest.append(top)
                start = None
            elif yb <= tol < ya:              # comes back
                start, top = crossing(pb, pa, f, tol, rel), -math.inf
            if yb <= tol:
                top = max(top, yb)
        if start is not None:
            out.append([start, pairs[-1][0]])
            largest.append(top)
    moved = [[float(a), float(b)] for a, b in intervals] != out
    return {"intervals": out, "peaks": peaks, "runs": runs, "spacing_rel": spacing, "largest_within": largest,
            "moved": moved}


def verify_answer(j, y, tol: float, answer: float, f: Callable[[float], float], f_many=None,
                  rel: float = 0.002, verify_rel: float = 0.01, max_runs: int = 400) -> dict:
    """Check a largest admissible jerk ``answer`` (the first crossing of the grid curve ``j``,
    ``y``, refined) by runs, and move it down where a run below it exceeds ``tol``: the first
    interval [j[0], answer] checked by :func:`verify_intervals`.

    Returns
    -------
    dict
        ``max_jerk`` (the checked answer: the end of the first verified interval when it still
        starts at j[0], else None), ``intervals`` (the verified pieces of [j[0], answer]),
        ``peaks``, ``runs``, ``spacing_rel`` (as :func:`verify_intervals`), ``largest_below``
        (the largest value of the runs at or below the checked answer), ``moved`` (whether the
        check lowered the answer).
    """
    j0 = float(j[0])
    v = verify_intervals(j, y, tol, [[j0, float(answer)]], f, f_many, rel, verify_rel, max_runs)
    first = v["intervals"][0] if v["intervals"] and v["intervals"][0][0] == j0 else None
    J = first[1] if first else None
    return {"max_jerk": J, "intervals": v["intervals"], "peaks": v["peaks"], "runs": v["runs"],
            "spacing_rel": v["spacing_rel"],
            "largest_below": v["largest_within"][0] if first else float(f(j0)),
            "moved": J is None or J < float(answer)}
