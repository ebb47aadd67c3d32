"""Error measures and model-choice scores of a replay's residuals (every figure in SI units).

Definitions, per channel, with y the measured and y_hat the simulated signal:

* residual r = y - y_hat;
* NRMSE fit % = 100 (1 - ||y - y_hat|| / ||y - mean y||);
* relative 2-norm error % = 100 ||y - y_hat|| / ||y|| (the EMPS benchmark's measure);
* noise floor: the residual's white part, 1.4826 MAD(third difference) / sqrt(20). The third
  difference removes a smooth model error; of white noise of variance s^2 it has variance 20 s^2,
  and 1.4826 MAD is a robust standard deviation;
* effective samples N_eff = N / (1 + 2 sum rho_k), the autocorrelation rho_k summed over the lags
  up to the first that is not positive: replay residuals are correlated in time (a missing effect
  leaves a smooth error), a white residual keeps N;
* BIC: the Gaussian log-likelihood with one unknown variance per channel gives
  BIC = N ln(SSR / N) + k ln N per channel. The score of a candidate effect is BIC(before) -
  BIC(after) counted on N_eff (higher is better, :func:`bic_score`); it is significant when it
  exceeds :data:`MIN_SCORE` (6: "strong" evidence, Kass and Raftery) and the channel's error
  before the fit stands above :data:`SIGNIFICANT_ABOVE_NOISE` times its noise floor.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["MIN_SCORE", "SIGNIFICANT_ABOVE_NOISE", "relative_error", "nrmse_fit", "fmt_fit", "noise_floor",
           "effective_samples", "bic_score"]

MIN_SCORE = 6.0          # a BIC difference above 6: "strong" evidence (Kass and Raftery)
SIGNIFICANT_ABOVE_NOISE = 1.2


def relative_error(y, yhat) -> float:
    y = np.asarray(y, float)
    n = float(np.linalg.norm(y))
    return 100.0 * float(np.linalg.norm(y - yhat)) / n if n > 0 else math.nan


def nrmse_fit(y, yhat) -> float:
    """NRMSE fit %; NaN (undefined, JSON null) for a reference without spread: a constant channel,
    whose ``y - mean y`` is rounding alone (1e-19 m of a constant 0.1 mm printed
    -4140097623904975872.00 %)."""
    y = np.asarray(y, float)
    d = float(np.linalg.norm(y - np.mean(y)))
    floor = 1e-12 * float(np.max(np.abs(y), initial=0.0)) * math.sqrt(max(y.size, 1))
    return 100.0 * (1.0 - float(np.linalg.norm(y - yhat)) / d) if d > floor else math.nan


def fmt_fit(v) -> str:
    """An NRMSE fit as printed: ``"97.12 %"``, or why there is none."""
    return "undefined (constant measured channel)" if v is None or not math.isfinite(v) else f"{v:.2f} %"


def noise_floor(r) -> float:
    r = np.asarray(r, float)
    if r.size < 8:
        return 0.0
    d3 = np.diff(r, 3)
    return float(1.4826 * np.median(np.abs(d3 - np.median(d3))) / math.sqrt(20.0))


def effective_samples(r) -> float:
    """Effective number of independent samples of a residual: N / (1 + 2 sum rho_k), the sum of
    its autocorrelation over the lags up to the first that is not positive (Bartlett/Bayley-Hammersley).
    A white residual keeps N; a smooth one (a model error) keeps about one sample per correlation time."""
    r = np.asarray(r, float) - np.mean(r)
    n = r.size
    if n < 8 or not np.any(r):
        return float(n)
    m = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(r, m)
    ac = np.fft.irfft(f * np.conj(f), m)[:n // 2]
    ac = ac / ac[0]
    neg = np.flatnonzero(ac[1:] <= 0.0)
    k = int(neg[0]) + 1 if neg.size else ac.size
    tau = 1.0 + 2.0 * float(np.sum(ac[1:k]))
    return float(min(n, max(1.0, n / max(tau, 1.0))))


def bic_score(res0: dict, res1: dict, chans, n_params: int, floor: dict | None = None) -> float:
    """BIC(before) - BIC(after) with one unknown variance per channel, counted on the effective
    number of independent samples of the residual after the fit (see :func:`effective_samples`):
    sum_c N_eff,c ln(SSR0_c / SSR1_c) - k ln(sum_c N_eff,c). Replay residuals are correlated in
    time; counting every sample as independent would rate any small gain as significant. A
    residual variance below the channel's noise floor (``floor``, RMS) counts as the floor: fitting
    the sensor noise is no evidence."""
    tot, n_eff = 0.0, 0.0
    floor = floor or {}
    for c in chans:
        ne = effective_samples(res1[c])
        f2 = float(floor.get(c, 0.0)) ** 2
        s0 = max(float(np.mean(res0[c] ** 2)), f2, 1e-300)
        s1 = max(float(np.mean(res1[c] ** 2)), f2, 1e-300)
        tot += ne * math.log(s0 / s1)
        n_eff += ne
    return tot - n_params * math.log(max(n_eff, 2.0))
