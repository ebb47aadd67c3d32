"""The residual as a signal: where in frequency, in position and in the motion it lives.

Definitions (SI units; t in s, positions in m):

* spectrum: the Hann-windowed amplitude spectrum 2 |FFT(r w)| / sum w of the mean-free residual;
  its peaks above ``fmin``, strongest first (for the reports: neighbouring maxima of one peak
  merged, its frequency interpolated between bins);
* periodic in position: the Lomb-Scargle periodogram of the residual against the position where
  the axis moves (|v| > 5 % of max|v|), after subtracting a running mean over 25 samples (the slow
  part, a function of velocity and time); periods from three position steps to a third of the
  stroke; amplitude and phase of each peak by least squares on sin and cos of 2 pi x / period;
  beyond 2500 moving samples, every s-th of them (and the shortest period three of those steps);
  the periodogram is scipy.signal.lombscargle's (equal weights, no floating mean, "power"),
  computed with one sine and cosine per sample and frequency (:func:`position_periodogram`);
* motion phases from the commanded velocity v and acceleration a: standstill (|v| < 1 % of
  max|v|), reversal (within 50 ms of a change of the direction of motion), acceleration
  (a v > 0), deceleration (a v < 0), constant speed (|a| < 2 % of max|a|);
* moves: motion between standstills; overshoot: the largest excursion past a move's final target
  in its direction, up to the start of the next move, floored at 0;
* cross-correlation of a and b at lag l: sum_n a'[n + l] b'[n] / N of the standardised signals.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.signal import find_peaks

__all__ = ["REPORT_MERGE_BINS", "spectrum_peaks", "periodic_in_position", "position_periodogram", "motion_phases",
           "overshoots", "xcorr"]

MAX_SAMPLES = 2500      # moving samples the position periodogram uses at most (every s-th beyond)
REPORT_MERGE_BINS = 3   # spectral maxima this many bins or closer to a stronger one are one peak


def spectrum_peaks(r, dt: float, n: int = 3, fmin: float = 0.5, merge_bins: float = 0.0):
    """The ``n`` strongest peaks (frequency Hz, amplitude) of the residual's spectrum.

    Parameters
    ----------
    r : array
        The residual, sampled every ``dt`` s.
    dt : float
        Sample period, s.
    n : int
        How many peaks at most, strongest first.
    fmin : float
        Lowest frequency considered, Hz.
    merge_bins : float
        0 (the default, as the diagnosis's starting values use it): every local maximum of the
        spectrum is a peak, at its bin's frequency. Above 0 (the reports): a local maximum within
        ``merge_bins`` bin widths of a stronger one, or joined to it by a valley that never falls
        below half of its own amplitude, is the same peak (the Hann window's main lobe is 4 bins
        wide, and noise on a peak makes local maxima of its neighbouring bins), listed once, at
        the frequency and amplitude of the parabola through the log amplitudes of its bin and the
        two beside it (interpolated between bins: within 0.02 bin and +4 % in amplitude for the
        Hann window's lobe, against 0.5 bin and -15 % at the bin itself).
    """
    r = np.asarray(r, float) - np.mean(r)
    if r.size < 16:
        return []
    w = np.hanning(r.size)
    spec = np.abs(np.fft.rfft(r * w)) * 2 / w.sum()
    f = np.fft.rfftfreq(r.size, dt)
    sel = f >= fmin
    idx, _ = find_peaks(np.where(sel, spec, 0.0))
    idx = idx[np.argsort(spec[idx])[::-1]]
    if merge_bins <= 0:
        return [(float(f[i]), float(spec[i])) for i in idx[:n]]
    kept = []
    for i in idx:
        if all(not _same_peak(spec, int(i), k, merge_bins) for k in kept):
            kept.append(int(i))
        if len(kept) == n:
            break
    return [_interpolated_peak(f, spec, i) for i in kept]


def _same_peak(spec, i: int, k: int, merge_bins: float) -> bool:
    """Whether the maximum at bin ``i`` belongs to the stronger one at bin ``k``: within
    ``merge_bins`` bins of it, or joined to it by a valley that stays above half of its amplitude
    (a ripple on one peak's flank, not a peak of its own)."""
    if abs(i - k) <= merge_bins:
        return True
    lo, hi = sorted((i, k))
    return bool(np.min(spec[lo:hi + 1]) >= 0.5 * spec[i])


def _interpolated_peak(f, spec, i: int) -> tuple[float, float]:
    """(frequency, amplitude) of the vertex of the parabola through the log amplitudes at bins
    i - 1, i, i + 1 (the bin itself at either end of the spectrum)."""
    if i <= 0 or i >= spec.size - 1 or min(spec[i - 1], spec[i], spec[i + 1]) <= 0:
        return float(f[i]), float(spec[i])
    a, b, c = np.log(spec[i - 1:i + 2])
    den = a - 2 * b + c
    delta = 0.5 * (a - c) / den if den < 0 else 0.0
    delta = float(np.clip(delta, -0.5, 0.5))
    return float(f[i] + delta * (f[1] - f[0])), float(np.exp(b - 0.25 * (a - c) * delta))


def periodic_in_position(x, r, t, n: int = 2):
    """Peaks of the residual as a function of position while moving (Lomb-Scargle): a list of
    (period m, amplitude, phase rad) of the ``n`` strongest periods."""
    x, r, t = (np.asarray(a, float) for a in (x, r, t))
    v = np.gradient(x, t)
    moving = np.abs(v) > 0.05 * max(np.max(np.abs(v)), 1e-12)
    if moving.sum() < 32:
        return []
    xs, rs = x[moving], r[moving]
    # remove the slow part (a function of velocity and time): a running mean over ~25 samples
    k = 25
    rs = rs - np.convolve(rs, np.ones(k) / k, mode="same")
    dx = np.max(np.abs(np.diff(x))) or 1e-9
    if xs.size > MAX_SAMPLES:
        # a long record (EMPS: 25 000 samples): every s-th moving sample, the shortest period
        # three of those steps (99th percentile; the periodogram's cost is samples x periods)
        s = -(-xs.size // MAX_SAMPLES)
        xs, rs = xs[::s], rs[::s]
        dx = max(dx, float(np.percentile(np.abs(np.diff(xs)), 99)))
    lo, hi = 3 * dx, max((xs.max() - xs.min()) / 3, 4 * dx)
    periods = np.geomspace(lo, hi, 1500)
    wn = 2 * np.pi / periods
    p = position_periodogram(xs, rs - rs.mean(), wn)
    idx, _ = find_peaks(p)
    idx = idx[np.argsort(p[idx])[::-1]][:n]
    out = []
    for i in idx:
        c, s = np.cos(wn[i] * xs), np.sin(wn[i] * xs)
        coef, *_ = np.linalg.lstsq(np.column_stack([s, c]), rs, rcond=None)
        out.append((float(periods[i]), float(math.hypot(*coef)), float(math.atan2(coef[1], coef[0]))))
    return out


@njit(cache=True)
def position_periodogram(x, y, w):
    """The Lomb-Scargle periodogram of ``y`` sampled at ``x`` at the angular frequencies ``w``:
    ``scipy.signal.lombscargle(x, y, w)`` (equal weights, no floating mean, normalize "power"), the
    same values to rounding (tests/test_speed_identity.py). scipy evaluates the sines and cosines
    twice, at the phase 0 and again at each frequency's tau (tan 2 tau = 2 CS / (CC - SS), the phase
    that makes the sine and cosine orthogonal over the samples); here once, the sums at tau being
    those at 0 rotated by tau: YC' = YC cos tau + YS sin tau, YS' = YS cos tau - YC sin tau,
    CC' = CC cos^2 tau + 2 CS cos tau sin tau + SS sin^2 tau, SS' = 1 - CC'. The power is
    N / 2 (YC'^2 / CC' + YS'^2 / SS') (Zechmeister and Kuerster 2009; sums weighted 1 / N). A
    quarter of scipy's time on the chain's periodograms (2500 samples x 1500 periods)."""
    n = x.size
    wt = 1.0 / n
    eps = np.finfo(np.float64).epsneg
    out = np.empty(w.size)
    for j in range(w.size):
        cc = 0.0
        cs = 0.0
        yc = 0.0
        ys = 0.0
        for i in range(n):
            c = math.cos(w[j] * x[i])
            s = math.sin(w[j] * x[i])
            cc += c * c
            cs += c * s
            yc += y[i] * c
            ys += y[i] * s
        cc *= wt
        cs *= wt
        yc *= wt
        ys *= wt
        ss = 1.0 - cc
        tau = 0.5 * math.atan2(2.0 * cs, cc - ss)
        ct, st = math.cos(tau), math.sin(tau)
        yc_t = yc * ct + ys * st
        ys_t = ys * ct - yc * st
        cc_t = cc * ct * ct + 2.0 * cs * ct * st + ss * st * st
        ss_t = 1.0 - cc_t
        cc_t = max(cc_t, eps)
        ss_t = max(ss_t, eps)
        out[j] = 2.0 * (yc_t * yc_t / cc_t + ys_t * ys_t / ss_t) * (n / 4.0)
    return out


def motion_phases(t, x_cmd) -> dict[str, np.ndarray]:
    """Boolean masks of the motion phases of the command (see the module's definitions)."""
    t, x = np.asarray(t, float), np.asarray(x_cmd, float)
    v = np.gradient(x, t)
    a = np.gradient(v, t)
    vmax = max(np.max(np.abs(v)), 1e-12)
    amax = max(np.max(np.abs(a)), 1e-12)
    still = np.abs(v) < 0.01 * vmax
    moving_dir = np.where(still, 0, np.sign(v))
    rev = np.zeros(t.size, bool)
    nz = np.flatnonzero(moving_dir != 0)
    dt = float(np.median(np.diff(t)))
    w = max(1, int(round(0.05 / dt)))
    for i0, i1 in zip(nz[:-1], nz[1:]):
        if moving_dir[i0] != moving_dir[i1] and (t[i1] - t[i0]) < 0.2:
            rev[max(0, i0 - w):i1 + w] = True
    const = ~still & ~rev & (np.abs(a) < 0.02 * amax)
    acc = ~still & ~rev & ~const & (a * v > 0)
    dec = ~still & ~rev & ~const & (a * v < 0)
    return {"acceleration": acc, "constant speed": const, "deceleration": dec, "standstill": still & ~rev,
            "reversal": rev}


def _moves(t, x_cmd):
    """(start, end) sample indices of the moves (motion between standstills)."""
    v = np.gradient(np.asarray(x_cmd, float), t)
    moving = np.abs(v) > 0.01 * max(np.max(np.abs(v)), 1e-12)
    edges = np.flatnonzero(np.diff(moving.astype(int)))
    starts = list(edges[::2] + 1) if not moving[0] else [0] + list(edges[1::2] + 1)
    ends = list(edges[1::2] + 1) if not moving[0] else list(edges[::2] + 1)
    return [(s, e) for s, e in zip(starts, ends) if e > s]


def overshoots(t, x_cmd, x):
    out = []
    moves = _moves(t, x_cmd)
    for i, (s, e) in enumerate(moves):
        nxt = moves[i + 1][0] if i + 1 < len(moves) else len(t)
        target, d = x_cmd[e], np.sign(x_cmd[e] - x_cmd[s])
        if d == 0:
            continue
        out.append(max(0.0, float(np.max((x[s:nxt] - target) * d))))
    return np.array(out)


def xcorr(a, b, maxlag):
    """Cross-correlation of the standardised ``a`` and ``b`` at lags -maxlag .. maxlag (the
    module's definition), in time linear in the record's length: a dot product per lag where the
    window is short, else by FFT (scipy.signal.correlate, the full correlation in O(N log N)).

    The quadratic ``np.correlate(mode="full")`` it replaces took 20 s at 10^5 samples; both ways
    agree with it to rounding (tests/test_compare_speed.py)."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    a = (a - a.mean()) / (a.std() or 1.0)
    b = (b - b.mean()) / (b.std() or 1.0)
    n = a.size
    maxlag = int(min(maxlag, n - 1))
    lags = np.arange(-maxlag, maxlag + 1)
    if (2 * maxlag + 1) <= 4 * max(math.log2(max(n, 2)), 1.0) * 8:
        c = np.empty(lags.size)
        for i, lag in enumerate(lags):
            c[i] = a[lag:] @ b[:n - lag] if lag >= 0 else a[:n + lag] @ b[-lag:]
        return lags, c / n
    from scipy.signal import correlate
    full = correlate(a, b, mode="full", method="fft") / n
    mid = n - 1
    return lags, full[mid - maxlag:mid + maxlag + 1]
