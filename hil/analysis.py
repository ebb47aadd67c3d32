"""Figures of a point-to-point move: overshoot, following errors, settling, residual vibration.

Overshoot is the largest excursion past the final target in the direction of motion over the
whole move and the dwell after it, floored at 0 (at high jerk the table can pass the target
before the command ends, so the whole record counts, not only the time after the command).

A row whose feedback is stale (its answer did not come in; the readings repeat the last one while
the command moves on, the ``stale`` channel of a real axis's record) is left out of the following
errors, which it would inflate by the command's travel in the missed cycles; ``stale_samples``
says how many rows were left out.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["overshoot", "settling_time", "residual_amplitude", "observed_after", "MoveFigures", "move_figures"]


def overshoot(x, target: float, direction: float) -> float:
    """Largest excursion of ``x`` past ``target`` in ``direction`` (+1 or -1), floored at 0."""
    x = np.asarray(x, float)
    if direction == 0 or x.size == 0:
        return 0.0
    return float(max(0.0, np.max((x - target) * np.sign(direction))))


def settling_time(t, x, target: float, band: float, t_end_cmd: float) -> float | None:
    """Time after the end of the command until ``x`` stays within ``target +- band``; None if it
    never settles within the record, or the record has fewer than 2 samples after the command
    (no dwell: it cannot be measured, see :func:`observed_after`)."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    outside = np.abs(x - target) > band
    after = t >= t_end_cmd - 1e-12
    if np.count_nonzero(after) < 2:      # no record after the command: cannot be measured, not 0
        return None
    idx = np.flatnonzero(outside & after)
    if idx.size == 0:
        return 0.0
    last = idx[-1]
    if last >= len(t) - 1:
        return None
    return float(t[last + 1] - t_end_cmd)


def observed_after(t, t_end_cmd: float) -> float:
    """Seconds of record after the end of the command (0: fewer than 2 samples there, so that
    settling and residual vibration cannot be measured)."""
    t = np.asarray(t, float)
    after = t[t >= t_end_cmd - 1e-12]
    return float(after[-1] - t_end_cmd) if after.size >= 2 else 0.0


def residual_amplitude(t, x, target: float, t_end_cmd: float) -> float | None:
    """Half the peak-to-peak motion of ``x`` about the target after the command has ended; None
    when the record has fewer than 2 samples after it (cannot be measured: not 0)."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    sel = t >= t_end_cmd - 1e-12
    if np.count_nonzero(sel) < 2:
        return None
    d = x[sel] - target
    return float(0.5 * (d.max() - d.min()))


@dataclass
class MoveFigures:
    """What a drive engineer reads off one move (SI, except the *_um fields)."""
    overshoot_table_um: float
    overshoot_tip_um: float
    peak_following_error_table_um: float
    peak_following_error_tip_um: float
    residual_tip_um: float | None
    settling_time_table: float | None
    settling_time_tip: float | None
    peak_torque: float
    j_max: float
    a_max: float
    peak_speed: float
    t_acc: float | None
    settle_band_um: float
    observed_after_s: float = 0.0     # record after the command's end (0: settling, residual not measurable)
    stale_samples: int = 0            # rows whose feedback repeats the last answer, left out of the following errors

    def as_dict(self) -> dict:
        return asdict(self)


def move_figures(t, x_cmd, x_table, x_tip, u, move, t_start: float = 0.0, t_end: float | None = None,
                 band: float = 1e-6, stale=None, tail: float = 0.0) -> MoveFigures:
    """Figures of ``move`` (a planned SineSquareMove starting at ``t_start``) from a record.

    ``t_end``: end of the window examined (the next move's start, or the record's end).
    ``tail``: how much later than the move the command ends (an input shaper's last impulse,
    hil.shaping): settling and the residual vibration are measured from the command's end.
    ``stale``: per row, nonzero where the feedback repeats the last answer (left out of the
    following errors); None: every row is a fresh answer."""
    t = np.asarray(t, float)
    t_end = t[-1] if t_end is None else t_end
    sel = (t >= t_start - 1e-12) & (t <= t_end + 1e-12)
    tt = t[sel]
    stale_sel = np.zeros(t.size, bool) if stale is None else (np.asarray(stale, float) != 0) & sel
    fresh = sel & ~stale_sel
    if not fresh.any():                  # nothing but repeats: no following error can be read off
        fresh = sel
    target = move.end
    d = move.direction
    t_cmd_end = t_start + move.duration + tail
    spec = move.spec
    return MoveFigures(
        overshoot_table_um=overshoot(np.asarray(x_table)[sel], target, d) * 1e6,
        overshoot_tip_um=overshoot(np.asarray(x_tip)[sel], target, d) * 1e6,
        peak_following_error_table_um=float(np.max(np.abs(np.asarray(x_cmd)[fresh] - np.asarray(x_table)[fresh]))) * 1e6,
        peak_following_error_tip_um=float(np.max(np.abs(np.asarray(x_cmd)[fresh] - np.asarray(x_tip)[fresh]))) * 1e6,
        residual_tip_um=_um(residual_amplitude(tt, np.asarray(x_tip)[sel], target, t_cmd_end)),
        settling_time_table=settling_time(tt, np.asarray(x_table)[sel], target, band, t_cmd_end),
        settling_time_tip=settling_time(tt, np.asarray(x_tip)[sel], target, band, t_cmd_end),
        peak_torque=float(np.max(np.abs(np.asarray(u)[sel]))) if np.size(u) else 0.0,
        j_max=move.j_max, a_max=move.a_max, peak_speed=move.peak_speed,
        t_acc=(spec.t_acc if spec is not None and spec.t_acc is not None else
               (spec.g0 * np.pi / (2 * move.a_max) if spec is not None and spec.g0 else None)),
        settle_band_um=band * 1e6, observed_after_s=observed_after(tt, t_cmd_end),
        stale_samples=int(np.count_nonzero(stale_sel)))


def _um(v: float | None) -> float | None:
    return None if v is None else v * 1e6
