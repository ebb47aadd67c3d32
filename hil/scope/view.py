"""The live scope's view logic in plain Python: triggers, the capture around a trigger, cursors
and the export of the view (issue 27).

The page (:mod:`hil.scope.server`) calls these on the columns it copied out of the ring (a dict of
numpy arrays, ``t`` in s and every channel in its display unit, e.g. mm or um); nothing here knows
about Bokeh, so every rule is unit-tested on closed-form signals.

Conventions:

* A channel trigger compares a channel with a ``level`` in the channel's display unit. ``rising``:
  the first sample ``i`` with ``y[i-1] < level <= y[i]`` (an edge: the sample before must be below);
  ``falling``: ``y[i-1] > level >= y[i]``; ``above`` / ``below``: the first sample at or above
  (at or below) the level, a level trigger, which fires on the first sample already when the
  signal is there. NaN never triggers. The trigger's time is the crossing interpolated between the
  two samples (an edge) or the sample's time (a level).
* The start of a move: the first sample where ``x_cmd`` changes after at least one sample at rest
  (``x_cmd[i] != x_cmd[i-1] == x_cmd[i-2]``); its time is ``t[i-1]``, the last sample at rest.
* A capture shows ``[t_trigger - pre, t_trigger + post]``.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["SLOPES", "SOURCES", "Trigger", "find_level", "move_starts", "capture", "stride_for", "cursor_values",
           "view_csv"]

SLOPES = ("rising", "falling", "above", "below")
# what a trigger listens to: a channel, a trip (a supervisor trip, a drive fault, an abort), the start of a move
SOURCES = ("channel", "trip", "move")


def find_level(t: np.ndarray, y: np.ndarray, level: float, slope: str, t_from: float = -math.inf) -> float | None:
    """The time of the first trigger of ``y`` on ``level`` at or after ``t_from`` (see the module
    docstring), or None. ``t``, ``y``: samples in time order; the sample just before ``t_from`` takes
    part as the 'before' of an edge."""
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    if slope not in SLOPES:
        raise ValueError(f"slope {slope!r}: expected one of {', '.join(SLOPES)}")
    start = int(np.searchsorted(t, t_from, side="left"))
    with np.errstate(invalid="ignore"):
        if slope in ("above", "below"):
            hit = (y[start:] >= level) if slope == "above" else (y[start:] <= level)
            idx = np.flatnonzero(hit)
            return float(t[start + idx[0]]) if idx.size else None
        lo = max(start, 1)
        before, after = y[lo - 1:-1], y[lo:]
        hit = (before < level) & (after >= level) if slope == "rising" else (before > level) & (after <= level)
    idx = np.flatnonzero(hit)
    if not idx.size:
        return None
    i = lo + int(idx[0])
    y0, y1 = y[i - 1], y[i]
    frac = (level - y0) / (y1 - y0) if y1 != y0 else 1.0
    return float(t[i - 1] + frac * (t[i] - t[i - 1]))


def move_starts(t: np.ndarray, x_cmd: np.ndarray) -> np.ndarray:
    """The times at which a move starts: the last sample at rest before ``x_cmd`` changes."""
    x = np.asarray(x_cmd, float)
    if x.size < 3:
        return np.zeros(0)
    i = np.flatnonzero((x[2:] != x[1:-1]) & (x[1:-1] == x[:-2])) + 1
    return np.asarray(t, float)[i]


class Trigger:
    """A trigger's settings: ``source`` (:data:`SOURCES`), and for a channel its ``channel``,
    ``slope`` (:data:`SLOPES`) and ``level`` (display unit); ``pre`` and ``post`` (s)."""

    def __init__(self, source: str = "channel", channel: str = "e_table", slope: str = "rising", level: float = 0.0,
                 pre: float = 0.5, post: float = 0.5):
        self.source, self.channel, self.slope, self.level = source, channel, slope, float(level)
        self.pre, self.post = float(pre), float(post)

    def find(self, cols: dict, trips: list[float], t_from: float) -> float | None:
        """The first trigger at or after ``t_from`` in ``cols`` (the page's columns), or among
        ``trips`` (the times of the trips seen); None: not yet."""
        if self.source == "trip":
            return next((tt for tt in sorted(trips) if tt >= t_from), None)
        t = cols["t"]
        if self.source == "move":
            starts = move_starts(t, cols["x_cmd"])
            starts = starts[starts >= t_from]
            return float(starts[0]) if starts.size else None
        return find_level(t, cols[self.channel], self.level, self.slope, t_from)

    def describe(self, unit: str = "") -> str:
        if self.source == "trip":
            what = "a trip"
        elif self.source == "move":
            what = "the start of a move"
        else:
            what = f"{self.channel} {self.slope} {'through' if self.slope in ('rising', 'falling') else ''} " \
                   f"{self.level:g} {unit}".replace("  ", " ").strip()
        return f"{what}, {self.pre * 1e3:g} ms before, {self.post * 1e3:g} ms after"


def stride_for(n_rows: int, max_points: int) -> int:
    """Every how many rows one is shown so that ``n_rows`` give at most ``max_points`` points."""
    return max(1, math.ceil(n_rows / max(1, max_points)))


def capture(rows: np.ndarray, t_trigger: float, pre: float, post: float, max_points: int) -> np.ndarray:
    """The ring's rows (``rows[:, 0]`` the time, in order) in ``[t_trigger - pre, t_trigger + post]``,
    every ``stride``-th kept so that at most ``max_points`` remain (the row nearest the trigger is
    one of them, so the trigger sample is on screen)."""
    t = rows[:, 0]
    lo = int(np.searchsorted(t, t_trigger - pre, side="left"))
    hi = int(np.searchsorted(t, t_trigger + post, side="right"))
    sel = rows[lo:hi]
    stride = stride_for(sel.shape[0], max_points)
    if stride == 1 or sel.shape[0] == 0:
        return sel
    k = int(np.argmin(np.abs(sel[:, 0] - t_trigger)))
    return sel[k % stride::stride]


def cursor_values(cols: dict, names, ta: float, tb: float) -> list[tuple[str, float, float, float]]:
    """Each channel of ``names`` at the cursors' times (linear interpolation between the samples
    on screen): ``[(name, value at A, value at B, B - A), ...]``; NaN outside the samples."""
    t = np.asarray(cols["t"], float)
    out = []
    for n in names:
        y = np.asarray(cols[n], float)
        if t.size == 0:
            a = b = math.nan
        else:
            a, b = (float(np.interp(x, t, y, left=math.nan, right=math.nan)) for x in (ta, tb))
        out.append((n, a, b, b - a))
    return out


def view_csv(cols: dict, units: dict, t0: float, t1: float, names=None) -> str:
    """The rows of ``cols`` with ``t0 <= t <= t1`` as CSV text: a header naming each column with its
    unit (``t [s]``, ``x_table [mm]``), then one line per row, full precision (``repr``)."""
    names = list(names if names is not None else [n for n in cols if n != "t"])
    t = np.asarray(cols["t"], float)
    keep = (t >= t0) & (t <= t1)
    header = ["t [s]"] + [f"{n} [{units[n]}]" if units.get(n) else n for n in names]
    lines = [",".join(header)]
    data = [t[keep]] + [np.asarray(cols[n], float)[keep] for n in names]
    for row in zip(*data):
        lines.append(",".join(repr(float(v)) for v in row))
    return "\n".join(lines) + "\n"
