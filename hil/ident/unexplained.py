"""Where a residual lives when no catalogue effect explains it, and the measures of an honest end
(every figure SI, RMS per channel).

* at the noise floor: every channel's RMS residual at most :data:`AT_FLOOR` times its noise floor
  (hil.ident.noise; the factor covers the floor's own uncertainty: a few standstill samples, the
  rounding error of a dithered grid between q/sqrt(12) and sqrt(q^2/12 + sigma^2));
* the share of the gap a fit closed, in the channel where it shows:
  (RMS before - RMS after) / (RMS before - floor), 0 when the channel was at the floor; a
  candidate closing less than :data:`HALF_GAP` of it is evidence, never the verdict;
* the residual's evidence per channel above the floor: its RMS against the floor, the three
  strongest spectral peaks (hil.ident.residual.spectrum_peaks), its correlation coefficients with
  the commanded position, speed, acceleration and direction sign(v), the band of the travel (one of
  :data:`TRAVEL_BINS` equal bands of the commanded position) where its RMS is largest against the
  median band, and its RMS while the command moves against its RMS at standstill.
"""
from __future__ import annotations

import numpy as np

from hil.ident.residual import REPORT_MERGE_BINS, motion_phases, spectrum_peaks

__all__ = ["AT_FLOOR", "HALF_GAP", "rms", "at_noise_floor", "gap_closed", "residual_evidence", "describe"]

AT_FLOOR = 1.5
# beyond this many times its noise floor a fitted model misses the record: its values take up what it
# lacks (hil fit says so)
MISFIT = 3.0
HALF_GAP = 0.5
TRAVEL_BINS = 10


def rms(res: dict) -> dict:
    return {c: float(np.sqrt(np.mean(np.asarray(r) ** 2))) for c, r in res.items()}


def at_noise_floor(errors: dict, floor: dict) -> bool:
    """Every channel's RMS residual within :data:`AT_FLOOR` of its noise floor."""
    return all(errors[c] <= AT_FLOOR * floor.get(c, 0.0) for c in errors)


def gap_closed(before: float, after: float, floor: float) -> float:
    """The share of the gap between the error and the noise floor a fit closed (0 .. 1, can be
    negative when the fit made it worse)."""
    gap = before - floor
    return float((before - after) / gap) if gap > 0 else 0.0


def _corr(r, q) -> float:
    return float(np.corrcoef(r, q)[0, 1]) if np.std(q) > 0 and np.std(r) > 0 else 0.0


def _along_travel(x, r, bins: int = TRAVEL_BINS) -> dict:
    """Where along the travel the residual is largest: the commanded positions split into ``bins``
    equal bands, the RMS of the residual in each (empty bands left out), and the band with the
    largest against the median band."""
    lo, hi = float(np.min(x)), float(np.max(x))
    if hi <= lo:
        return {}
    edges = np.linspace(lo, hi, bins + 1)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    band = [float(np.sqrt(np.mean(r[idx == i] ** 2))) if np.any(idx == i) else None for i in range(bins)]
    full = [b for b in band if b is not None]
    i = int(np.nanargmax([np.nan if b is None else b for b in band]))
    return {"band": [float(edges[i]), float(edges[i + 1])], "rms": band[i],
            "against_median": band[i] / max(float(np.median(full)), 1e-300)}


def residual_evidence(replay, res: dict, best=None) -> dict:
    """The evidence of where the residual ``res`` lives, per channel above the floor (worst first),
    and the share of the gap the best candidate ``best`` (a fitted Candidate, or None) closed."""
    m = replay.meas
    t, xc = m.t, m["x_cmd"]
    v = np.gradient(xc, t)
    a = np.gradient(v, t)
    still = motion_phases(t, xc)["standstill"]
    floor = replay.noise
    err = rms(res)
    chans = sorted((c for c in res if err[c] > AT_FLOOR * floor.get(c, 0.0)),
                   key=lambda c: -err[c] / max(floor.get(c, 0.0), 1e-300))
    out = {"channels": []}
    for c in chans:
        r = np.asarray(res[c], float)
        out["channels"].append({
            "channel": c, "unit": replay.unit(c), "position_unit": replay.unit("x_motor"), "rms": err[c], "noise_floor": float(floor.get(c, 0.0)),
            "above_floor": err[c] / max(floor.get(c, 0.0), 1e-300),
            "spectral_peaks": [{"frequency": f, "amplitude": amp} for f, amp in
                               spectrum_peaks(r, replay.sample_period, merge_bins=REPORT_MERGE_BINS)],
            "correlation": {"position": _corr(r, xc), "speed": _corr(r, v), "acceleration": _corr(r, a),
                            "direction": _corr(r, np.sign(v))},
            "along_travel": _along_travel(xc, r),
            "rms_moving": float(np.sqrt(np.mean(r[~still] ** 2))) if (~still).any() else 0.0,
            "rms_standstill": float(np.sqrt(np.mean(r[still] ** 2))) if still.any() else None})
    if best is not None:
        out["best_candidate"] = best.effect
        out["best_gap_closed"] = gap_closed(best.error_before, best.error_after, floor.get(best.channel, 0.0))
    return out


def describe(ev: dict) -> list[str]:
    """The evidence as text lines, one per channel, then the best candidate's share (each figure
    in its engineering unit, hil.units.fmt)."""
    from hil.units import fmt_si
    lines = []
    for d in ev.get("channels", []):
        u = d["unit"]
        q = lambda v: fmt_si(v, u, 3)  # noqa: E731
        peaks = ", ".join(f"{p['frequency']:.1f} Hz ({q(p['amplitude'])})" for p in d["spectral_peaks"])
        cor = d["correlation"]
        top = max(cor, key=lambda k: abs(cor[k]))
        still = "no standstill" if d["rms_standstill"] is None else f"{q(d['rms_standstill'])} at standstill"
        tr = d["along_travel"]
        pu, k = ("mm", 1e3) if d.get("position_unit", "m") == "m" else (d["position_unit"], 1.0)  # rad: an angle axis
        where = (f"; largest at x = {k * tr['band'][0]:.1f} .. {k * tr['band'][1]:.1f} {pu}, {tr['against_median']:.1f} x "
                 f"the median band" if tr else "")
        lines.append(f"{d['channel']}: RMS {q(d['rms'])}, {d['above_floor']:.1f} x its noise floor "
                     f"{q(d['noise_floor'])}; spectral peaks {peaks or 'none'}; correlation with position "
                     f"{cor['position']:+.2f}, speed {cor['speed']:+.2f}, acceleration {cor['acceleration']:+.2f}, "
                     f"direction {cor['direction']:+.2f} (strongest: {top}){where}; {q(d['rms_moving'])} "
                     f"moving against {still}")
    if "best_candidate" in ev:
        g = ev["best_gap_closed"]
        lines.append(f"the best candidate, {ev['best_candidate']}, closed {100 * g:.0f} % of the gap to the noise "
                     f"floor")
    return lines
