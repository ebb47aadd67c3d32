"""Model against measurement: replay the measured command through the model with the same loops,
set the simulated channels against the measured ones, and analyse the residual.

Definitions (every figure in SI units):

* residual r = y_measured - y_simulated, per channel;
* RMS and peak of r; NRMSE fit % = 100 (1 - ||y - y_hat|| / ||y - mean y||);
* relative 2-norm error % = 100 ||y - y_hat|| / ||y|| (the EMPS benchmark's measure);
* overshoot difference: largest overshoot past the final target of each move, measured minus
  simulated (positions only);
* motion phases from the commanded velocity v and acceleration a: standstill (|v| < 1 % of
  max|v|), reversal (within 50 ms of a change of the direction of motion), acceleration
  (a v > 0), deceleration (a v < 0), constant speed (|a| < 2 % of max|a|);
* whiteness: residual autocorrelation against the 99 % band +-2.576/sqrt(N); the
  cross-correlation with the commanded velocity against the same band;
* noise floor: the residual's white part, 1.4826 MAD(third difference) / sqrt(20).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hil.plant_config import plant_from_config

__all__ = ["Replay", "metrics", "analyse", "noise_floor", "spectrum_peaks", "periodic_in_position",
           "relative_error", "nrmse_fit", "motion_phases", "POSITION_CHANNELS"]

POSITION_CHANNELS = ("x_motor", "x_table", "x_tip")
_FORCE = ("torque", "force", "command")
_UNITS = {"x_motor": "m", "x_table": "m", "x_tip": "m", "x_motor-x_table": "m", "torque": "N*m", "force": "N",
          "command": "V", "e_table": "m", "e_tip": "m"}


def relative_error(y, yhat) -> float:
    y = np.asarray(y, float)
    n = float(np.linalg.norm(y))
    return 100.0 * float(np.linalg.norm(y - yhat)) / n if n > 0 else math.nan


def nrmse_fit(y, yhat) -> float:
    y = np.asarray(y, float)
    d = float(np.linalg.norm(y - np.mean(y)))
    return 100.0 * (1.0 - float(np.linalg.norm(y - yhat)) / d) if d > 0 else math.nan


def noise_floor(r) -> float:
    r = np.asarray(r, float)
    if r.size < 8:
        return 0.0
    d3 = np.diff(r, 3)
    return float(1.4826 * np.median(np.abs(d3 - np.median(d3))) / math.sqrt(20.0))


def spectrum_peaks(r, dt: float, n: int = 3, fmin: float = 0.5):
    """The ``n`` strongest peaks (frequency Hz, amplitude) of the residual's spectrum."""
    from scipy.signal import find_peaks
    r = np.asarray(r, float) - np.mean(r)
    if r.size < 16:
        return []
    w = np.hanning(r.size)
    spec = np.abs(np.fft.rfft(r * w)) * 2 / w.sum()
    f = np.fft.rfftfreq(r.size, dt)
    sel = f >= fmin
    idx, _ = find_peaks(np.where(sel, spec, 0.0))
    idx = idx[np.argsort(spec[idx])[::-1]][:n]
    return [(float(f[i]), float(spec[i])) for i in idx]


def periodic_in_position(x, r, t, n: int = 2):
    """Peaks of the residual as a function of position while moving (Lomb-Scargle): a list of
    (period m, amplitude, phase rad) of the ``n`` strongest periods."""
    from scipy.signal import find_peaks, lombscargle
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
    lo, hi = 3 * dx, max((xs.max() - xs.min()) / 3, 4 * dx)
    periods = np.geomspace(lo, hi, 1500)
    wn = 2 * np.pi / periods
    p = lombscargle(xs, rs - rs.mean(), wn)
    idx, _ = find_peaks(p)
    idx = idx[np.argsort(p[idx])[::-1]][:n]
    out = []
    for i in idx:
        c, s = np.cos(wn[i] * xs), np.sin(wn[i] * xs)
        coef, *_ = np.linalg.lstsq(np.column_stack([s, c]), rs, rcond=None)
        out.append((float(periods[i]), float(math.hypot(*coef)), float(math.atan2(coef[1], coef[0]))))
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


def _overshoots(t, x_cmd, x):
    out = []
    moves = _moves(t, x_cmd)
    for i, (s, e) in enumerate(moves):
        nxt = moves[i + 1][0] if i + 1 < len(moves) else len(t)
        target, d = x_cmd[e], np.sign(x_cmd[e] - x_cmd[s])
        if d == 0:
            continue
        out.append(max(0.0, float(np.max((x[s:nxt] - target) * d))))
    return np.array(out)


def _xcorr(a, b, maxlag):
    a = (a - a.mean()) / (a.std() or 1.0)
    b = (b - b.mean()) / (b.std() or 1.0)
    n = a.size
    full = np.correlate(a, b, mode="full") / n
    mid = n - 1
    lags = np.arange(-maxlag, maxlag + 1)
    return lags, full[mid - maxlag:mid + maxlag + 1]


class Replay:
    """A measurement replayed through a config's model: the simulated channels on the measured
    sample times, and their residuals."""

    def __init__(self, meas, cfg, channels=None, align: bool = False):
        self.meas = meas
        self.cfg = cfg
        self.plant = plant_from_config(cfg)
        self.align = align
        self.shifts: dict[str, int] = {}
        t = meas.t
        self.sample_period = meas.sample_period
        tp = cfg["control.position_period"]
        n = int(math.floor((t[-1] - t[0]) / tp + 1e-9)) + 1
        self.t_sim = t[0] + np.arange(n) * tp
        self.x_cmd_sim = np.interp(self.t_sim, t, meas["x_cmd"])
        self.one_to_one = n == t.size and np.allclose(self.t_sim, t, atol=1e-6 * tp)
        avail = [c for c in POSITION_CHANNELS if c in meas]
        if "force" in meas and not cfg.rotary:
            avail.append("force")
        elif "command" in meas and not cfg.rotary:
            avail.append("command")
        elif "torque" in meas and cfg.rotary:
            avail.append("torque")
        if channels:
            bad = [c for c in channels if c not in avail]
            if bad:
                from hil.errors import UserError
                raise UserError(f"{meas.source}: channel {bad[0]!r} is not in the record or not simulated "
                                f"(available: {', '.join(avail)})")
            avail = list(channels)
        if not avail:
            from hil.errors import UserError
            raise UserError(f"{meas.source}: no measured channel to compare (need one of x_motor, x_table, x_tip, "
                            f"torque, force)")
        self.channels = avail
        self.force_channel = next((c for c in avail if c in _FORCE and c != "command"), None)
        self.force_to_load = (2 * math.pi / cfg["plant.pitch"]) if (cfg.rotary and self.force_channel) else 1.0
        fb = "x_motor" if cfg.get("control.position_feedback") == "motor" else "x_table"
        first_pos = [c for c in (fb,) + POSITION_CHANNELS if c in meas]
        self.x0 = float(meas[first_pos[0]][0]) if first_pos else float(meas["x_cmd"][0])
        res0 = self.residuals(cfg, first=True)
        rms = {c: float(np.sqrt(np.mean(res0[c] ** 2))) for c in self.channels}
        self.noise = {c: noise_floor(res0[c]) for c in self.channels}
        from hil.ident.diagnose import _Objective
        self.objective = _Objective(self, {c: 1.0 / max(rms[c], self.noise[c], 1e-15) for c in self.channels})
        self.objective.n = sum(res0[c].size for c in self.channels)
        self.base_residuals = res0

    def with_config(self, cfg) -> "Replay":
        return Replay(self.meas, cfg, self.channels, self.align)

    def simulate(self, cfg=None):
        from hil.simulate import simulate
        from hil.control import controller_from_config
        cfg = cfg or self.cfg
        plant = self.plant if cfg is self.cfg else plant_from_config(cfg)
        return simulate(plant, controller_from_config(cfg, plant), self.x_cmd_sim, x0=self.x0)

    def simulated(self, cfg=None) -> dict[str, np.ndarray]:
        """Simulated channels on the measurement's sample times."""
        ch = self.simulate(cfg).channels()
        out = {}
        for c in self.channels + ["x_motor", "x_table", "x_tip"]:
            if c in ch:
                y = ch[c]
                out[c] = y[:self.meas.t.size].copy() if self.one_to_one else np.interp(self.meas.t, self.t_sim, y)
        return out

    def residuals(self, cfg=None, first: bool = False) -> dict[str, np.ndarray]:
        sim = self.simulated(cfg)
        out = {}
        for c in self.channels:
            y = self.meas[c]
            if first and self.align:
                self.shifts[c] = _best_shift(y, sim[c])
            s = self.shifts.get(c, 0)
            out[c] = _shifted(y, s) - sim[c] if s else y - sim[c]
        return out

    def unit(self, chan) -> str:
        return _UNITS.get(chan, "")

    def primary_channel(self, res) -> str:
        return self.force_channel or max(self.channels, key=lambda c: float(np.mean(res[c] ** 2) * self.objective.weights[c] ** 2))


def _shifted(y, s):
    return np.concatenate([y[s:], np.full(s, y[-1])]) if s > 0 else np.concatenate([np.full(-s, y[0]), y[:s]])


def _best_shift(y, yhat, maxlag: int = 200) -> int:
    """Samples by which ``y`` lags ``yhat`` (cross-correlation of their derivatives)."""
    a, b = np.diff(y), np.diff(yhat)
    maxlag = min(maxlag, a.size // 4)
    lags, c = _xcorr(a, b, maxlag)
    return int(lags[np.argmax(c)])


def metrics(t, x_cmd, y, yhat, chan: str) -> dict:
    r = y - yhat
    out = {"rms": float(np.sqrt(np.mean(r * r))), "peak": float(np.max(np.abs(r))), "fit": nrmse_fit(y, yhat),
           "relative_error": relative_error(y, yhat), "unit": _UNITS.get(chan, "")}
    if chan in POSITION_CHANNELS:
        om, os_ = _overshoots(t, x_cmd, y), _overshoots(t, x_cmd, yhat)
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
           "shifts": dict(replay.shifts)}
    n = t.size
    band = 2.576 / math.sqrt(n)
    maxlag = min(200, n // 4)
    for c in replay.channels:
        y = m[c]
        r = res[c]
        d = metrics(t, xc, y, y - r, c)
        d["noise_floor"] = noise_floor(r)
        d["phase_rms"] = {p: (float(np.sqrt(np.mean(r[mask] ** 2))) if mask.any() else None)
                          for p, mask in phases.items()}
        d["spectrum_peaks"] = [{"frequency": f, "amplitude": amp} for f, amp in spectrum_peaks(r, replay.sample_period)]
        lags, ac = _xcorr(r, r, maxlag)
        outside = np.abs(ac[lags > 0]) > band
        d["whiteness"] = {"band_99": band, "fraction_outside": float(outside.mean()) if outside.size else 0.0,
                          "white": bool(outside.mean() <= 0.01) if outside.size else True}
        lags, cc = _xcorr(r, v, maxlag)
        d["cross_correlation_command"] = {"max": float(np.max(np.abs(cc))), "lag_s": float(lags[np.argmax(np.abs(cc))]
                                                                                            * replay.sample_period),
                                          "band_99": band}
        d["correlation"] = {k: float(np.corrcoef(r, q)[0, 1]) if np.std(q) > 0 and np.std(r) > 0 else 0.0
                            for k, q in (("velocity", v), ("acceleration", a), ("position", xc),
                                         ("sign_velocity", np.sign(v)))}
        out["channels"][c] = d
    out["_arrays"] = {"t": t, "x_cmd": xc, "v": v, "a": a, "measured": {c: m[c] for c in replay.channels},
                      "simulated": sim, "residual": res, "phases": phases}
    return out
