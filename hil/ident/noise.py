"""The noise floor of a record: what no model can explain, from sources that cannot hold a model
error (every figure RMS, SI units of the channel).

Per channel, in this order:

* a figure given by the user: the config's ``[noise]`` section (``noise.x_tip = "0.1 um"``) or the
  file header (``# noise.x_tip = 0.1 um``); the sensor's own noise, to which the quantization of
  the record adds (q^2 / 12 in quadrature);
* otherwise the larger of
  - the encoder quantization: a channel whose samples all lie on a grid of step q (detected from
    the values: the largest whole fraction of the smallest difference between distinct values that
    every value is a whole multiple of, from the smallest, to 1 % of q: a file's stored digits round
    the grid) carries at least q / sqrt(12), the RMS of a uniform rounding error;
  - for a force channel (torque, force, command: a current read by the drive), the measured
    channel's own standstill noise: the RMS of the channel in the settled standstills of at least
    ``MEASURED_MIN`` samples, less a straight line per segment (the holding current and its creep are the model's business), pooled
    over the quiet segments as below (:func:`channel_standstill_noise`). A drive's current hunts
    around its holding value at rest (the loop answering its encoder's steps); no deterministic
    model follows that, and the record's quantization (1 mA) says nothing about it. Per segment
    the lesser of the channel's variance and the residual's (each about its line): an axis whose
    lightly damped mode rings for seconds after a move (the paper bench's tip, 15 Hz at a damping
    ratio of 0.015) holds that ringing in its current at rest, which the model replays and the
    residual has not; the noise is no larger than either. Where it exists, this is the force
    channel's standstill figure (not the residual's AR estimate below, which holds the model's
    error at rest where the model is wrong there: the noise is no larger than the channel's own
    variation at rest);
  - the standstill noise: the residual in the settled part of each standstill of the command
    (hil.ident.residual.motion_phases; each standstill less its first ``SETTLE`` s, at most half of
    it), less a straight line per segment (a static offset or a creep is a model error, not noise),
    less what an autoregressive predictor of order ``AR_ORDER`` fitted to the segment explains
    (a ringing mode is a damped sinusoid, which an AR(2) predicts exactly; white noise is not
    predictable). The innovation variance SSR / (n - 2p) of each segment; the floor pools the
    segments whose variance is within ``QUIET`` times the quietest's (segments with leftover
    structure stand out above it);
* otherwise (no standstill, no grid, no figure) the third difference of the whole residual,
  1.4826 MAD(d3 r) / sqrt(20) (hil.ident.scores.noise_floor), marked as possibly holding structure:
  a light mode at a quarter of the sampling rate survives a third difference.

Never from the whole residual when another source exists: a residual that still holds a mode or a
ripple would raise its own floor and declare itself explained.
"""
from __future__ import annotations

import math

import numpy as np

from hil.ident.residual import motion_phases
from hil.ident.scores import noise_floor as third_difference_floor
from hil.plant_config import _NOISE_KINDS

__all__ = ["quantization_step", "standstill_noise", "channel_standstill_noise", "FORCE_CHANNELS", "record_noise", "given_noise", "run_to_run_spread",
           "same_test", "MEASURED_MIN", "SETTLE", "AR_ORDER", "QUIET", "NOISE_KINDS", "SAME_TEST"]

SETTLE = 0.1        # s skipped at the start of each standstill (at most half of it)
AR_ORDER = 4        # two resonances predicted away
QUIET = 2.5         # segments within this factor of the quietest's variance are pooled
SAME_TEST = 0.01    # repetitions of one test: their commands differ by at most this share of the command's RMS
NOISE_KINDS = _NOISE_KINDS     # the unit kind of each channel's noise figure (the config's [noise] section)


def quantization_step(y, max_divisor: int = 200) -> float:
    """The step q of the grid all samples of ``y`` lie on (0.0 when they do not, or too few levels).

    d is the smallest difference between distinct values (differences below 1e-9 of the largest
    magnitude are float noise of the unit conversion); q is the largest d / n (n = 1, 2, ...
    ``max_divisor``: a fast record rarely visits neighbouring levels) that every sample is a whole
    multiple of, from the smallest value, to 1e-2 q (a record's stored digits round the grid)."""
    y = np.asarray(y, float)
    u = np.unique(y)
    if u.size < 3:
        return 0.0
    du = np.diff(u)
    du = du[du > 1e-9 * max(float(np.max(np.abs(u))), 1e-300)]
    if du.size == 0:
        return 0.0
    d = float(np.min(du))
    off = u - u[0]
    for n in range(1, max_divisor + 1):
        q = d / n
        # refined on ever more levels (d itself is rounded): least squares of the offsets on k q
        for span in (30.0, 1e3, math.inf):
            sel = off <= span * q
            k = np.round(off[sel] / q)
            if np.any(k):
                q = float(np.dot(k, off[sel]) / np.dot(k, k))
        if np.all(np.abs(off / q - np.round(off / q)) < 1e-2):
            return q
    return 0.0


def _segments(t, x_cmd, settle: float = SETTLE):
    """(start, end) of the settled part of each standstill of the command."""
    still = motion_phases(t, x_cmd)["standstill"]
    dt = float(np.median(np.diff(t)))
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
    out = []
    for s, e in zip(edges[::2], edges[1::2]):
        s2 = s + min(int(round(settle / dt)), (e - s) // 2)
        out.append((int(s2), int(e)))
    return out


FORCE_CHANNELS = ("torque", "force", "command")     # the channels whose measured standstill noise is a floor
MEASURED_MIN = 50   # samples of a settled rest for the measured channel's noise (shorter: the loop still settles)


def _pooled(est):
    """The variances (variance, dof) of the quiet segments pooled: (RMS, dof); (None, 0) for none."""
    if not est:
        return None, 0
    vmin = min(v for v, _ in est)
    quiet = [(v, d) for v, d in est if v <= QUIET * vmin]
    dof = sum(d for _, d in quiet)
    return math.sqrt(sum(v * d for v, d in quiet) / dof), int(dof)


def channel_standstill_noise(t, x_cmd, y, residual=None):
    """The measured channel ``y``'s noise in the settled standstills of the command: per segment the
    variance about a straight line (SSR / (n - 2)), the quiet segments pooled (within ``QUIET``
    times the quietest's variance): (RMS, degrees of freedom), or (None, 0) without a standstill
    of at least :data:`MEASURED_MIN` samples (a short rest holds the loop's settling, which a
    straight line does not take out: it would read as noise).

    With the model's ``residual`` of the channel, per segment the lesser of the two variances: the
    channel at rest holds its noise and the axis's own motion there (a lightly damped mode ringing
    after a move, which the model replays), the residual its noise and the model's error there;
    the noise is no larger than either."""
    y = np.asarray(y, float)
    r = None if residual is None else np.asarray(residual, float)
    est = []
    for s, e in _segments(t, x_cmd):
        n = e - s
        if n < MEASURED_MIN:
            continue
        k = np.arange(n, dtype=float)
        var = []
        for sig in (y,) if r is None else (y, r):
            seg = sig[s:e] - np.polyval(np.polyfit(k, sig[s:e], 1), k)
            var.append(float(np.sum(seg * seg)) / (n - 2))
        est.append((min(var), n - 2))
    return _pooled(est)


def standstill_noise(t, x_cmd, r, p: int = AR_ORDER):
    """The noise of residual ``r`` in the settled standstills: (RMS, samples used), or (None, 0)
    when no standstill is long enough (see the module's definition)."""
    r = np.asarray(r, float)
    est = []
    for s, e in _segments(t, x_cmd):
        n = e - s
        if n < 3 * p + 4:
            continue
        seg = r[s:e]
        k = np.arange(n, dtype=float)
        seg = seg - np.polyval(np.polyfit(k, seg, 1), k)
        X = np.column_stack([seg[p - j - 1:n - j - 1] for j in range(p)])
        y = seg[p:]
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        ssr = float(np.sum((y - X @ coef) ** 2))
        dof = y.size - p
        est.append((ssr / dof, dof))
    return _pooled(est)


def given_noise(cfg, meas, chan: str):
    """The sensor noise of ``chan`` given in the config (``noise.<chan>``) or in the record's header
    (``noise.<chan>`` or ``noise_<chan>``, with a unit), SI; None when neither gives one."""
    from hil.units import parse
    v = cfg.get(f"noise.{chan}") if cfg is not None else None
    if v is not None:
        return float(v)
    meta = getattr(meas, "meta", {}) or {}
    for key in (f"noise.{chan}", f"noise_{chan}"):
        if key in meta:
            return float(parse(meta[key], NOISE_KINDS.get(chan, "dimensionless"), f"{meas.source}: {key}"))
    return None


def record_noise(meas, cfg, residuals: dict) -> dict:
    """Per channel of ``residuals``: {"rms": floor, "source": text, "quantization": q, and where it
    was measured "standstill": the standstill noise (the larger of the residual's and, on a force
    channel, the measured channel's)} (SI)."""
    t, xc = meas.t, meas["x_cmd"]
    out = {}
    for c, r in residuals.items():
        q = quantization_step(meas[c]) if c in meas else 0.0
        fq = q / math.sqrt(12.0)
        g = given_noise(cfg, meas, c)
        if g is not None:
            out[c] = {"rms": math.hypot(g, fq), "source": "given" + (" + quantization" if q else ""),
                      "quantization": q}
            continue
        s, n = standstill_noise(t, xc, r)
        src = f"standstill ({n} samples)"
        if c in FORCE_CHANNELS and c in meas:
            # the measured channel at rest, or the residual where that is quieter (the axis rings
            # after a move as the model does): an upper bound of the noise from the record itself,
            # which the residual's AR estimate, holding the model's error at rest, can exceed
            sm, nm = channel_standstill_noise(t, xc, meas[c], r)
            if sm is not None:
                s, src = sm, f"standstill noise of the measured channel ({nm} samples)"
        if (s is not None and s > 0) or q > 0:
            src = "quantization" if (s is None or fq >= s) else src
            out[c] = {"rms": max(fq, s or 0.0), "source": src, "quantization": q}
            if s:
                out[c]["standstill"] = s
            continue
        out[c] = {"rms": third_difference_floor(r), "source": "residual third difference (may hold structure)",
                  "quantization": 0.0}
    return out


def same_test(a, b, command: str) -> bool:
    """Two records are repetitions of one test: the same sample times (within 1 % of a period over
    the common length, lengths within 1 %), the same ``command`` channel (the position command, or
    the drive channel of an open-loop run) and every measured input the same (``u_add``, an
    external force: :data:`hil.io.measurement.INPUT_CHANNELS`, in both records or in neither), each
    within :data:`SAME_TEST` of its RMS. Records of one command whose added pulses differ are two
    tests: the pulses' own response is not scatter."""
    from hil.io.measurement import INPUT_CHANNELS
    n = min(len(a.t), len(b.t))
    if n < 3 or abs(len(a.t) - len(b.t)) > 0.01 * n or command not in a or command not in b:
        return False
    ta, tb = a.t[:n] - a.t[0], b.t[:n] - b.t[0]
    if float(np.max(np.abs(ta - tb))) > 0.01 * a.sample_period:
        return False
    return all(_same_channel(a, b, c, n) for c in (command, *INPUT_CHANNELS) if c == command or c in a or c in b)


def _same_channel(a, b, channel: str, n: int) -> bool:
    """``channel`` in both records and equal within :data:`SAME_TEST` of its RMS (an input that is
    zero in both is the same)."""
    if channel not in a or channel not in b:
        return False
    ca, cb = np.asarray(a[channel][:n], float), np.asarray(b[channel][:n], float)
    scale = float(np.sqrt(np.mean(ca * ca)))
    diff = float(np.sqrt(np.mean((ca - cb) ** 2)))
    return bool(diff <= SAME_TEST * scale) if scale > 0 else diff == 0.0


def run_to_run_spread(measurements, channels, command: str) -> dict:
    """Per channel, the scatter of repetitions of one test about their mean (SI, RMS): records are
    grouped by :func:`same_test`; each group of two or more gives the sample standard deviation
    across its records at every sample (over their common length), and the groups' variances are
    pooled. This is what no model of the axis can explain: the same command gave these different
    answers. Returns {channel: {"rms", "repetitions", "tests"}}; empty when no test was repeated."""
    groups: list[list] = []
    for m in measurements:
        g = next((g for g in groups if same_test(g[0], m, command)), None)
        if g is None:
            groups.append([m])
        else:
            g.append(m)
    groups = [g for g in groups if len(g) > 1]
    out = {}
    for c in channels:
        ss, dof = 0.0, 0
        for g in groups:
            if not all(c in m for m in g):
                continue
            n = min(len(m.t) for m in g)
            y = np.stack([np.asarray(m[c][:n], float) for m in g])
            ss += float(np.sum((y - y.mean(axis=0)) ** 2))
            dof += n * (len(g) - 1)
        if dof:
            out[c] = {"rms": math.sqrt(ss / dof), "repetitions": sum(len(g) for g in groups), "tests": len(groups)}
    return out
