"""Model against measurement, as ``hil compare`` reports it: metrics per channel and the analysis
of the residual r = y_measured - y_simulated (every figure in SI units).

* RMS and peak of r; NRMSE fit % and relative 2-norm error % (hil.ident.scores);
* overshoot difference: the largest difference of the overshoots past the final target of each
  move, measured against simulated; the RMS following error x_cmd - y, measured and simulated
  (positions only);
* RMS error per motion phase (hil.ident.residual.motion_phases), the noise floor, the spectrum's
  peaks;
* whiteness: the residual's autocorrelation at lags 1 .. min(200, N/4) against the 99 % band
  +-2.576/sqrt(N), white when at most 1 % of the lags fall outside; the cross-correlation with
  the commanded velocity against the same band, its largest magnitude and lag (s);
* the correlation coefficient of r with v, a, x_cmd and sign(v).

The spectrum's peaks are merged (hil.ident.residual.REPORT_MERGE_BINS) and interpolated; the
correlation functions themselves (for MATLAB ``resid``'s figure) are in ``_arrays``.
"""
from __future__ import annotations

import math

import numpy as np

from hil.ident.replay import POSITION_CHANNELS, UNITS, Replay
from hil.ident.residual import REPORT_MERGE_BINS, motion_phases, overshoots, spectrum_peaks, xcorr
from hil.ident.scores import noise_floor, nrmse_fit, relative_error

__all__ = ["metrics", "analyse"]


def metrics(t, x_cmd, y, yhat, chan: str, unit: str | None = None) -> dict:
    r = y - yhat
    out = {"rms": float(np.sqrt(np.mean(r * r))), "peak": float(np.max(np.abs(r))), "fit": nrmse_fit(y, yhat),
           "relative_error": relative_error(y, yhat), "unit": UNITS.get(chan, "") if unit is None else unit}
    if chan in POSITION_CHANNELS:
        om, os_ = overshoots(t, x_cmd, y), overshoots(t, x_cmd, yhat)
        out["overshoot_difference"] = float(np.max(np.abs(om - os_))) if om.size else 0.0
        e, ehat = x_cmd - y, x_cmd - yhat
        out["following_error_rms_measured"] = float(np.sqrt(np.mean(e * e)))
        out["following_error_rms_simulated"] = float(np.sqrt(np.mean(ehat * ehat)))
    return out


def analyse(replay: Replay, cfg=None) -> dict:
    """Everything ``hil compare`` reports: metrics per channel, error per motion phase, spectrum
    peaks, whiteness, correlation with the command, and residual against v, a, x."""
    m = replay.meas
    sim = replay.simulated(cfg)
    res = replay.residuals(cfg)
    t, xc = m.t, m["x_cmd"]
    v = np.gradient(xc, t)
    a = np.gradient(v, t)
    phases = motion_phases(t, xc)
    out = {"channels": {}, "phases": list(phases), "sample_period": replay.sample_period,
           "shifts": dict(replay.shifts), "inputs": replay.input_notes()}
    n = t.size
    band = 2.576 / math.sqrt(n)
    maxlag = min(200, n // 4)
    acf, ccf = {}, {}          # the correlation functions (lag s, value) for the resid figure
    for c in replay.channels:
        y = m[c]
        r = res[c]
        d = metrics(t, xc, y, y - r, c, replay.unit(c))
        d["noise_floor"] = noise_floor(r)
        # the record's own floor (quantization, standstill noise: hil.ident.noise), which the
        # diagnosis judges against too; the answer of a comparison is whether the model reaches it
        d["record_floor"] = float(replay.noise.get(c, 0.0))
        d["phase_rms"] = {p: (float(np.sqrt(np.mean(r[mask] ** 2))) if mask.any() else None)
                          for p, mask in phases.items()}
        d["spectrum_peaks"] = [{"frequency": f, "amplitude": amp} for f, amp in
                               spectrum_peaks(r, replay.sample_period, merge_bins=REPORT_MERGE_BINS)]
        lags, ac = xcorr(r, r, maxlag)
        acf[c] = (lags * replay.sample_period, ac)
        outside = np.abs(ac[lags > 0]) > band
        d["whiteness"] = {"band_99": band, "fraction_outside": float(outside.mean()) if outside.size else 0.0,
                          "white": bool(outside.mean() <= 0.01) if outside.size else True}
        lags, cc = xcorr(r, v, maxlag)
        ccf[c] = (lags * replay.sample_period, cc)
        d["cross_correlation_command"] = {"max": float(np.max(np.abs(cc))), "lag_s": float(lags[np.argmax(np.abs(cc))]
                                                                                            * replay.sample_period),
                                          "band_99": band}
        d["correlation"] = {k: float(np.corrcoef(r, q)[0, 1]) if np.std(q) > 0 and np.std(r) > 0 else 0.0
                            for k, q in (("velocity", v), ("acceleration", a), ("position", xc),
                                         ("sign_velocity", np.sign(v)))}
        out["channels"][c] = d
    out["_arrays"] = {"t": t, "x_cmd": xc, "v": v, "a": a, "measured": {c: m[c] for c in replay.channels},
                      "simulated": sim, "residual": res, "phases": phases,
                      "autocorrelation": acf, "cross_correlation": ccf, "band_99": band}
    return out
