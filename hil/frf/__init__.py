"""Frequency-response measurement of an axis (commissioning in the frequency domain).

The axis runs at a slow constant speed (the working point: friction does not change sign) with
its loops closed; a periodic excitation (multisine with Schroeder phases, periodic chirp or PRBS)
is added either to the controller output (a torque disturbance) or to the speed reference of the
velocity loop (a velocity disturbance). Every velocity period the loop records the excitation,
the total output, the controller's output and input, the speed references and the encoders.

Estimates use the excitation as instrumental variable: H_yu = S_ry / S_ru, cross spectra with the
injected signal r averaged over whole periods (Welch with a boxcar window of one period, no
overlap: no leakage for a periodic excitation in steady state). In closed loop this removes the
bias of the plain H1 = S_uy / S_uu. Coherence gamma^2 of r with each channel, and the standard
deviation of |H|: from the scatter of the periods (the coherence formula
sigma ~ |H| sqrt((1 - g^2) / (2 n g^2)) generalised to noise correlated between the channels of the
ratio, as it is in closed loop); with fewer than 3 periods, the coherence formula.

Responses (names used everywhere, JSON included):

* ``TF1p``  torque -> measured motor speed (rad/s per N m; Eq. 12's TF1')
* ``TF2``   table / motor position, ``TF3`` tip / table (where the tip is measured)
* ``Lv``    open velocity loop (controller x plant), ``Tv`` closed velocity loop
* ``Lp``    open position loop, ``Tp`` closed position loop x_table / x_cmd (below the position
            loop's Nyquist frequency; derived from the measured x_table / speed reference)
* ``tip``   torque -> tip speed (where the tip is measured; used for the modal fit)

The model's responses are the exact ones of the sampled loop (zero-order hold of the chain over
a velocity period, output delay and current-loop lag included), so that on the simulated plant
measured and modelled responses agree to the measurement's uncertainty; the position loop is
multirate and modelled with the usual hold approximation.

Nothing here changes a configuration: tuning help comes back as a config diff text.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from hil.control import measured_speed, new_velocity_state, position_law, quantize, velocity_law
from sim_plant.kernel import plant_step as _plant_step

__all__ = ["Excitation", "make_excitation", "FrfSettings", "FrfRecord", "run_sim", "run_backend",
           "estimate", "model_responses", "fit_modes", "model_modes", "discrepancies", "tuning",
           "measure", "FrfResult", "RESPONSES"]

RESPONSES = ("TF1p", "TF2", "TF3", "tip", "Lv", "Tv", "Lp", "Tp")
UNITS = {"TF1p": "rad/s per N m", "TF2": "1", "TF3": "1", "tip": "m/s per N m", "Lv": "1", "Tv": "1",
         "Lp": "1", "Tp": "1"}
TITLES = {"TF1p": "TF1' torque -> motor speed", "TF2": "TF2 table / motor", "TF3": "TF3 tip / table",
          "tip": "torque -> tip speed", "Lv": "open velocity loop", "Tv": "closed velocity loop",
          "Lp": "open position loop", "Tp": "closed position loop"}


# --- excitation signals ------------------------------------------------------------------------

@dataclass
class Excitation:
    """One period of a periodic excitation sampled every ``dt`` (``n`` samples), peak ``amplitude``;
    ``lines``: the DFT bins (of one period) that carry energy in the band."""
    kind: str
    signal: np.ndarray
    dt: float
    lines: np.ndarray

    @property
    def n(self) -> int:
        return self.signal.size

    @property
    def period(self) -> float:
        return self.n * self.dt

    @property
    def freqs(self) -> np.ndarray:
        return self.lines / self.period


def make_excitation(kind: str, dt: float, period: float, band: tuple[float, float], amplitude: float,
                    seed: int = 0) -> Excitation:
    """Periodic excitation of one ``period`` (s) at sample time ``dt``: ``multisine`` (flat
    amplitude, Schroeder phases, lines from band[0] to band[1]), ``chirp`` (linear sweep over the
    band within the period) or ``prbs`` (maximum-length sequence clocked at ~2.5 band[1]; its
    period replaces ``period``). Scaled to a peak of ``amplitude``."""
    f_lo, f_hi = band
    if not 0 < f_lo < f_hi < 0.5 / dt:
        raise ValueError(f"band {f_lo:g}..{f_hi:g} Hz: needs 0 < low < high < {0.5 / dt:g} Hz")
    if kind == "prbs":
        hold = max(1, int(round(1.0 / (2.5 * f_hi * dt))))
        nbits = max(5, int(math.ceil(math.log2(period / (hold * dt) + 1))))
        import scipy.signal
        seq = scipy.signal.max_len_seq(nbits, state=np.ones(nbits, int) if seed == 0 else
                                       (np.random.default_rng(seed).integers(0, 2, nbits) | np.eye(1, nbits, 0, int)[0]))[0]
        x = np.repeat(2.0 * seq - 1.0, hold)
        n = x.size
    else:
        n = int(round(period / dt))
        x = None
    T = n * dt
    k_lo, k_hi = max(1, int(math.ceil(f_lo * T - 1e-9))), int(math.floor(f_hi * T + 1e-9))
    if k_hi < k_lo:
        raise ValueError(f"band {f_lo:g}..{f_hi:g} Hz holds no line of a {T:g} s period")
    lines = np.arange(k_lo, k_hi + 1)
    if kind == "multisine":
        K = lines.size
        phase = -np.pi * np.arange(K) * (np.arange(K) + 1) / K        # Schroeder
        t = np.arange(n) * dt
        x = np.zeros(n)
        for k, ph in zip(lines, phase):
            x += np.cos(2 * np.pi * k / T * t + ph)
    elif kind == "chirp":
        t = np.arange(n) * dt
        # linear sweep f_lo -> f_hi over the period, tapered at both ends
        f0, f1 = lines[0] / T, lines[-1] / T
        ph = 2 * np.pi * (f0 * t + 0.5 * (f1 - f0) / T * t ** 2)
        x = np.sin(ph)
        taper = np.clip(np.minimum(t, T - t) / (0.02 * T), 0, 1)
        x = x * (0.5 - 0.5 * np.cos(np.pi * taper))
    elif kind != "prbs":
        raise ValueError(f"unknown signal {kind!r} (multisine, chirp, prbs)")
    x = x - x.mean()
    x *= amplitude / np.max(np.abs(x))
    X = np.fft.rfft(x)
    # keep the lines that carry energy (a chirp's or PRBS's spectrum is not flat)
    strong = np.abs(X[lines]) > 1e-3 * np.abs(X[lines]).max()
    return Excitation(kind, x, dt, lines[strong])


# --- the loop with the excitation: compiled (simulated plant) ---------------------------------

# recorded channels, one column each, every velocity period
CH = ("r", "u", "u_ctrl", "e", "w", "w_ref_pos", "w_ref", "x_motor", "x_table", "x_tip")
C_R, C_U, C_UC, C_E, C_W, C_WP, C_WR, C_XM, C_XT, C_X3 = range(10)


@njit(cache=True)
def _frf_kernel(Ad, Bd, x0, p, fgain, x_cmd, n_sub, table, tip, fb_motor, fric, res_table, res_motor,
                codes, eparams, delay, lag_alpha, exc, mode, noise_w, noise_x, out):
    """Closed loop with the excitation ``exc`` (one value per velocity period) added to the output
    (mode 0) or to the speed reference (mode 1). Records every velocity period into ``out``
    (columns: see CH). Returns the number of saturated velocity periods."""
    nn = Ad.shape[0]
    n = nn // 2
    x = x0.copy()
    x_new = np.zeros(nn)
    f = np.zeros(n)
    s = new_velocity_state()
    d_int = int(math.floor(delay))
    d_frac = delay - d_int
    ubuf = np.zeros(d_int + 2)
    u_act = 0.0
    dry = max(fric[0], fric[1], fric[2], fric[3]) > 0.0
    K = x_cmd.shape[0] - 1
    lim = p[6]
    step = 0
    sat = 0
    w_pos = 0.0
    for k in range(K):
        xm = quantize(x[0], res_motor) + noise_x[step, 0]
        xt = quantize(x[table], res_table) + noise_x[step, 1]
        xfb = xm if fb_motor else xt
        w_pos = position_law(p, x_cmd[k], x_cmd[k + 1], xfb)
        for j in range(n_sub):
            r = exc[step]
            xm = quantize(x[0], res_motor) + noise_x[step, 0]
            w_meas = measured_speed(p, s, x[n] + noise_w[step], xm)
            w_ref = w_pos + (r if mode == 1 else 0.0)
            uc = velocity_law(p, s, w_ref, w_meas, 0.0)
            u = uc + (r if mode == 0 else 0.0)
            if u > lim:
                u = lim
                sat += 1
            elif u < -lim:
                u = -lim
                sat += 1
            out[step, 0] = r
            out[step, 1] = u
            out[step, 2] = uc
            out[step, 3] = w_ref - w_meas
            out[step, 4] = w_meas
            out[step, 5] = w_pos
            out[step, 6] = w_ref
            out[step, 7] = xm
            out[step, 8] = quantize(x[table], res_table) + noise_x[step, 1]
            out[step, 9] = x[tip] + noise_x[step, 2]
            if delay > 0.0:
                for i in range(d_int + 1, 0, -1):
                    ubuf[i] = ubuf[i - 1]
                ubuf[0] = u
                u = (1.0 - d_frac) * ubuf[d_int] + d_frac * ubuf[d_int + 1]
            u_act += lag_alpha * (u - u_act)
            _plant_step(Ad, Bd, x, u_act * fgain, fric, dry, codes, eparams, f, x_new)
            step += 1
    return sat


@dataclass
class FrfSettings:
    """What to measure: ``signal`` multisine | chirp | prbs, ``input`` torque | velocity,
    ``amplitude`` (N m of the output, or controller speed units), ``band`` (Hz), ``periods``
    averaged after ``settle`` seconds of the excitation, ``period`` (s) of one excitation period,
    ``speed`` of the working point (m/s), measurement noise (rms) on speed (controller units) and
    positions (m), seed."""
    signal: str = "multisine"
    input: str = "torque"
    amplitude: float = 3.0
    band: tuple = (1.0, 200.0)
    periods: int = 6
    period: float = 2.0
    settle: float = 4.0
    speed: float = 0.01
    lead_in: float = 0.5
    noise_speed: float = 0.0
    noise_position: float = 0.0
    seed: int = 1
    auto_settle: bool = True


@dataclass
class FrfRecord:
    """The recorded run: ``data`` (steps x len(CH)), sample time, the excitation, where the
    averaged periods start, saturated periods, the tip measured or not."""
    data: np.ndarray
    dt: float
    excitation: Excitation
    start: int
    periods: int
    saturated: int
    tip_measured: bool
    input: str
    backend: str = "sim"

    def channel(self, name: str) -> np.ndarray:
        return self.data[:, CH.index(name)]


def _command(ctrl, st: FrfSettings, n_steps_exc: int, x0: float = 0.0):
    """Position command on the position clock: rest, ramp to the working speed, constant speed."""
    tp = ctrl.position_period
    n_sub = ctrl.substeps
    K_lead = int(round(st.lead_in / tp))
    K = K_lead + int(math.ceil(n_steps_exc / n_sub)) + 1
    t = np.arange(K + 1) * tp
    t_r = max(st.lead_in, 1e-9)
    # sine-square speed ramp over the lead-in, then constant speed
    v = np.where(t < t_r, st.speed * np.sin(0.5 * np.pi * t / t_r) ** 2, st.speed)
    x = x0 + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * tp)])
    return x, K_lead


def _settle_time(plant, st: FrfSettings) -> float:
    """Seconds of excitation before averaging: at least ``st.settle``, and six time constants of
    the slowest mode of the (model) plant (a lightly damped mode rings long), at most 15 s."""
    if plant is None or not st.auto_settle:
        return st.settle
    try:
        wd, zd = plant.chain.damped_modes(include_ground=True)
        keep = wd > 1e-6 * max(wd.max(), 1.0)
        tau = max(1.0 / (z * w) for w, z in zip(wd[keep], zd[keep]) if z > 0)
    except ValueError:
        tau = 0.0
    return float(min(max(st.settle, 6.0 * tau), 15.0))


def run_sim(plant, ctrl, st: FrfSettings, progress=None, x0: float = 0.0) -> FrfRecord:
    """Run the excitation on the simulated plant through the compiled loop."""
    from hil.control import lag_alpha as _lag_alpha
    from sim_plant.kernel import TIME_DELAY, effect_table as _effect_table
    tv = ctrl.velocity_period
    exc = make_excitation(st.signal, tv, st.period, st.band, st.amplitude, st.seed)
    n_settle = int(math.ceil(_settle_time(plant, st) / exc.period))
    n_periods = n_settle + st.periods
    x_cmd, K_lead = _command(ctrl, st, n_periods * exc.n, x0)
    n_sub = ctrl.substeps
    steps = (x_cmd.size - 1) * n_sub
    lead = K_lead * n_sub
    r = np.zeros(steps)
    r[lead:lead + n_periods * exc.n] = np.tile(exc.signal, n_periods)
    rng = np.random.default_rng(st.seed)
    nw = rng.standard_normal(steps) * st.noise_speed
    nx = rng.standard_normal((steps, 3)) * st.noise_position
    disc = plant.chain.discretize(tv, inputs="all")
    x0v = np.zeros(2 * plant.n)
    x0v[:plant.n] = x0
    codes, eparams = _effect_table(plant)
    delay = float(ctrl.output_delay) + float(sum(q[0] for c, q in plant.effects if c == TIME_DELAY)) / tv
    out = np.zeros((steps, len(CH)))
    if progress:
        progress(f"exciting: {st.signal} {st.input} disturbance, {st.band[0]:g}..{st.band[1]:g} Hz, "
                 f"{n_settle} settling + {st.periods} averaged periods of {exc.period:g} s at "
                 f"{st.speed * 1e3:g} mm/s ({steps} velocity periods)")
    sat = _frf_kernel(disc.A, disc.B, x0v, ctrl.as_array(), plant.force_gain, x_cmd, n_sub, plant.table,
                      plant.tip, ctrl.position_feedback == "motor", plant.friction.as_array(),
                      plant.table_resolution, plant.motor_resolution, codes, eparams, delay,
                      _lag_alpha(plant, ctrl), r, 0 if st.input == "torque" else 1, nw, nx, out)
    return FrfRecord(out, tv, exc, lead + n_settle * exc.n, st.periods, int(sat), plant.tip != plant.table,
                     st.input, "sim")


def run_backend(backend, ctrl, st: FrfSettings, progress=None, supervisor=None, plant=None, clock=None) -> FrfRecord:
    """The same experiment cycle by cycle through the backend contract (drivers.base): the host
    closes both loops, so the backend must take torque (``closes == "none"``). Works on any such
    backend (the simulated plant, a CiA 402 drive in cyclic torque mode); slower than
    :func:`run_sim` on the simulated plant. Paced by ``clock`` (default: hil.loop's simulated
    clock for a simulated backend, the real-time clock otherwise); ``supervisor.check`` every
    position tick, a trip ends the run with a quick stop."""
    from drivers.base import BackendFault, Setpoint
    from hil.loop import RealTimeClock, SimulatedClock
    if backend.closes != "none":
        raise ValueError(f"backend {backend.name}: frf needs a backend in torque mode (closes='none'), "
                         f"this one closes {backend.closes!r}")
    tv = ctrl.velocity_period
    p = ctrl.as_array()
    exc = make_excitation(st.signal, tv, st.period, st.band, st.amplitude, st.seed)
    n_settle = int(math.ceil(_settle_time(plant, st) / exc.period))
    n_periods = n_settle + st.periods
    fb = backend.read_feedback()
    x_cmd, K_lead = _command(ctrl, st, n_periods * exc.n, fb.x_table)
    n_sub = ctrl.substeps
    steps = (x_cmd.size - 1) * n_sub
    lead = K_lead * n_sub
    r = np.zeros(steps)
    r[lead:lead + n_periods * exc.n] = np.tile(exc.signal, n_periods)
    out = np.zeros((steps, len(CH)))
    s = new_velocity_state()
    lim = ctrl.output_limit
    sat = 0
    tip_measured = True
    step = 0
    mode = 0 if st.input == "torque" else 1
    if clock is None:
        period = backend.cycle_time or tv
        clock = SimulatedClock(period) if getattr(backend, "simulated", False) else RealTimeClock(period)
    clock.start()
    try:
        for k in range(x_cmd.size - 1):
            for j in range(n_sub):
                fb = backend.read_feedback()
                if fb.fault:
                    raise BackendFault(fb.fault)
                if j == 0:
                    xfb = fb.x_motor if ctrl.position_feedback == "motor" else fb.x_table
                    w_pos = position_law(p, x_cmd[k], x_cmd[k + 1], xfb)
                    if supervisor is not None:
                        trip = supervisor.check(k * ctrl.position_period, fb, x_cmd[k])
                        if trip:
                            backend.quick_stop()
                            raise RuntimeError(f"supervisor tripped: {trip}")
                rr = r[step]
                w = measured_speed(p, s, fb.v_motor, fb.x_motor)
                w_ref = w_pos + (rr if mode == 1 else 0.0)
                uc = velocity_law(p, s, w_ref, w, 0.0)
                u = min(max(uc + (rr if mode == 0 else 0.0), -lim), lim)
                sat += abs(u) >= lim
                tip = fb.x_tip
                if math.isnan(tip):
                    tip_measured = False
                out[step] = (rr, u, uc, w_ref - w, w, w_pos, w_ref, fb.x_motor, fb.x_table, tip)
                backend.write_setpoint(Setpoint(output=u))
                backend.sync()
                clock.wait()
                step += 1
            if progress and k % 1000 == 0:
                progress(f"  {step / steps:5.1%}")
    except BaseException:
        try:
            backend.quick_stop()
        except Exception:
            pass
        raise
    return FrfRecord(out, tv, exc, lead + n_settle * exc.n, st.periods, int(sat), tip_measured, st.input,
                     getattr(backend, "name", "backend"))


# --- estimation ------------------------------------------------------------------------------

@dataclass
class Response:
    """One frequency response: complex values, coherence, standard deviation of |H|."""
    f: np.ndarray
    h: np.ndarray
    coherence: np.ndarray
    sigma: np.ndarray
    derived: bool = False

    def as_dict(self) -> dict:
        return {"frequency_hz": self.f.tolist(), "magnitude": np.abs(self.h).tolist(),
                "phase_deg": np.degrees(np.angle(self.h)).tolist(), "coherence": self.coherence.tolist(),
                "magnitude_std": self.sigma.tolist(), "derived": self.derived}


def _spectra(rec: FrfRecord):
    """Per-period DFTs at the excitation lines: dict channel -> (periods x lines) complex."""
    n = rec.excitation.n
    seg = rec.data[rec.start:rec.start + rec.periods * n]
    if seg.shape[0] < rec.periods * n:
        raise ValueError("record shorter than the averaged periods")
    seg = seg.copy()
    # positions move at the working speed: remove that trend (for a periodic response plus a
    # ramp, x[i + n] - x[i] is the ramp's rise over one period, whatever the periodic part)
    t = np.arange(seg.shape[0]) * rec.dt
    for c in ("x_motor", "x_table", "x_tip"):
        i = CH.index(c)
        if rec.periods > 1:
            slope = np.mean(seg[n:, i] - seg[:-n, i]) / (n * rec.dt)
        else:
            slope = (seg[-1, i] - seg[0, i]) / (t[-1] + rec.dt)
        seg[:, i] -= slope * t
    F = np.fft.rfft(seg.reshape(rec.periods, n, len(CH)), axis=1)[:, rec.excitation.lines, :]
    return {c: F[:, :, i] for i, c in enumerate(CH)}


def _iv(F, y: str, u: str, pre=None):
    """H = S_ry / S_ru with its coherence-based standard deviation."""
    R = F["r"]
    Y = F[y] if pre is None else pre(F[y])
    U = F[u]
    n = R.shape[0]
    Sry, Sru = np.mean(np.conj(R) * Y, 0), np.mean(np.conj(R) * U, 0)
    Srr = np.mean(np.abs(R) ** 2, 0)
    g_y = np.abs(Sry) ** 2 / (Srr * np.mean(np.abs(Y) ** 2, 0) + 1e-300)
    g_u = np.abs(Sru) ** 2 / (Srr * np.mean(np.abs(U) ** 2, 0) + 1e-300)
    g_y, g_u = np.clip(g_y, 1e-12, 1.0), np.clip(g_u, 1e-12, 1.0)
    h = Sry / Sru
    q = (1 - g_y) / g_y + (1 - g_u) / g_u
    coh = 1.0 / (1.0 + q)
    if n > 2:
        # noise of the ratio from the scatter over periods (the coherence formula generalised to
        # noise correlated between the two channels, as a closed loop makes it): per period the
        # residual of Y = H U, its variance over the periods; std of |H| = that / sqrt 2
        # (half the complex variance lies along H)
        Ym, Um = Y.mean(0), U.mean(0)
        D = (Y - Ym) - h * (U - Um)
        var = np.sum(np.abs(D) ** 2, 0) / ((n - 1) * n * np.abs(Um) ** 2)
        sigma = np.sqrt(var / 2)
    else:
        sigma = np.abs(h) * np.sqrt(q / (2 * max(n, 1)))      # Bendat & Piersol, from the coherence
    return h, coh, sigma


def estimate(rec: FrfRecord, ctrl) -> dict[str, Response]:
    """The responses a drive engineer reads, estimated from the record (instrumental variable:
    the injected excitation)."""
    F = _spectra(rec)
    f = rec.excitation.freqs
    jw = 2j * np.pi * f
    # speeds from positions: the DFT of a periodic steady state, d/dt -> j w (exact for the lines)
    scale = ctrl.speed_scale
    out: dict[str, Response] = {}
    if rec.input == "torque":
        h, c, s = _iv(F, "w", "u")
        out["TF1p"] = Response(f, h, c, s)
        h, c, s = _iv(F, "x_tip", "u", pre=lambda X: X * jw)
        if rec.tip_measured:
            out["tip"] = Response(f, h, c, s)
        # open velocity loop: controller (u_ctrl / e) x plant (w / u)
        hc, cc, sc = _iv(F, "u_ctrl", "e")
        lv = hc * out["TF1p"].h
        out["Lv"] = Response(f, lv, np.minimum(cc, out["TF1p"].coherence),
                             np.abs(lv) * np.hypot(sc / np.maximum(np.abs(hc), 1e-300),
                                                   out["TF1p"].sigma / np.maximum(np.abs(out["TF1p"].h), 1e-300)))
        tv = lv / (1 + lv)
        out["Tv"] = Response(f, tv, out["Lv"].coherence, np.abs(tv) * out["Lv"].sigma / np.maximum(np.abs(lv), 1e-300)
                             / np.maximum(np.abs(1 + lv), 1e-300), derived=True)
        # table position per speed reference: x_table/u x C / (1 + Lv)
        hx, cx, sx = _iv(F, "x_table", "u")
        P = hx * hc / (1 + lv)
        rel_lv = out["Lv"].sigma / np.maximum(np.abs(lv), 1e-300)
        sP = np.abs(P) * np.sqrt((sx / np.maximum(np.abs(hx), 1e-300)) ** 2 + (sc / np.maximum(np.abs(hc), 1e-300)) ** 2
                                 + (np.abs(lv) / np.maximum(np.abs(1 + lv), 1e-300) * rel_lv) ** 2)
        cP = cx
    else:
        h, c, s = _iv(F, "w", "w_ref")
        out["Tv"] = Response(f, h, c, s)
        lv = h / (1 - h)
        out["Lv"] = Response(f, lv, c, np.abs(lv) * s / np.maximum(np.abs(h * (1 - h)), 1e-300), derived=True)
        hw, cw, sw = _iv(F, "w", "u")
        out["TF1p"] = Response(f, hw, cw, sw)
        if rec.tip_measured:
            out["tip"] = Response(f, *_iv(F, "x_tip", "u", pre=lambda X: X * jw))
        P, cP, sP = _iv(F, "x_table", "w_ref")
        # the measured open position loop, broken at the speed reference (sampled at Tp)
        hl, cl, sl = _iv(F, "w_ref_pos", "w_ref")
        lp_meas = -hl
    h2, c2, s2 = _iv(F, "x_table", "x_motor")
    out["TF2"] = Response(f, h2, c2, s2)
    if rec.tip_measured:
        out["TF3"] = Response(f, *_iv(F, "x_tip", "x_table"))
    # position loop (below its Nyquist frequency)
    tp = ctrl.position_period
    keep = f < 0.5 / tp
    hold = _hold(f, tp)
    lp = ctrl.kv * scale * P * hold
    if rec.input == "velocity":
        out["Lp"] = Response(f[keep], lp_meas[keep], cl[keep], sl[keep])
    else:
        out["Lp"] = Response(f[keep], lp[keep], cP[keep], (np.abs(lp) * sP / np.maximum(np.abs(P), 1e-300))[keep],
                             derived=True)
    lpv = out["Lp"].h
    ff = ctrl.ffv * (np.exp(jw * tp) - 1) / tp
    tpos = (ctrl.kv + ff[keep]) * scale * P[keep] * hold[keep] / (1 + lpv)
    out["Tp"] = Response(f[keep], tpos, out["Lp"].coherence,
                         np.abs(tpos) * out["Lp"].sigma / np.maximum(np.abs(lpv), 1e-300), derived=True)
    return out


def _hold(f, tp):
    """Sample-and-hold of the position loop seen at the fundamental: delay Tp/2 and sinc."""
    x = np.pi * np.asarray(f) * tp
    return np.exp(-1j * x) * np.sinc(x / np.pi)


# --- model responses -------------------------------------------------------------------------

def model_responses(plant, ctrl, f, tip_measured: bool = True) -> dict[str, np.ndarray]:
    """Exact responses of the sampled loop at ``f`` (Hz): zero-order hold of the chain over the
    velocity period, output delay and current-loop lag; controller and speed measurement as
    hil.control's law. Position loop: hold approximation (delay Tp/2, sinc)."""
    from hil.control import lag_alpha as _lag_alpha
    from sim_plant.kernel import TIME_DELAY
    f = np.asarray(f, float)
    tv, tp = ctrl.velocity_period, ctrl.position_period
    disc = plant.chain.discretize(tv, inputs="motor")
    A, b = disc.A, disc.B[:, 0] * plant.force_gain
    n = plant.n
    z = np.exp(2j * np.pi * f * tv)
    X = np.empty((f.size, 2 * n), complex)
    I = np.eye(2 * n)
    for i, zi in enumerate(z):
        X[i] = np.linalg.solve(zi * I - A, b)
    delay = float(ctrl.output_delay) + float(sum(q[0] for c, q in plant.effects if c == TIME_DELAY)) / tv
    d_int = int(math.floor(delay))
    d_frac = delay - d_int
    D = (1 - d_frac) * z ** (-d_int) + d_frac * z ** (-(d_int + 1))
    a = _lag_alpha(plant, ctrl)
    D = D * a / (1 - (1 - a) / z)
    X = X * D[:, None]
    scale = ctrl.speed_scale
    taps = ctrl.velocity_filter if ctrl.velocity_feedback == "position_difference" else ()
    if taps:
        Fz = sum(t * z ** (-i) for i, t in enumerate(taps))
        gw = scale * Fz * (1 - 1 / z) / tv * X[:, 0]
    else:
        gw = scale * X[:, n]
    jw = 2j * np.pi * f
    out = {"TF1p": gw, "TF2": X[:, plant.table] / X[:, 0]}
    if tip_measured and plant.tip != plant.table:
        out["TF3"] = X[:, plant.tip] / X[:, plant.table]
        # tip speed from the tip position's DFT (as measured): j w x_tip
        out["tip"] = jw * X[:, plant.tip]
    C = ctrl.kp * (1 + (tv / ctrl.ti if math.isfinite(ctrl.ti) else 0.0) / (1 - 1 / z))
    lv = C * gw
    out["Lv"] = lv
    out["Tv"] = lv / (1 + lv)
    P = C * X[:, plant.table] / (1 + lv)
    hold = _hold(f, tp)
    lp = ctrl.kv * scale * P * hold
    ff = ctrl.ffv * (np.exp(jw * tp) - 1) / tp
    out["Lp"] = lp
    out["Tp"] = (ctrl.kv + ff) * scale * P * hold / (1 + lp)
    return out


# --- modal fit -------------------------------------------------------------------------------

@dataclass
class Mode:
    f_hz: float
    zeta: float
    response: str
    f_std: float = 0.0
    zeta_std: float = 0.0

    def as_dict(self):
        return {"frequency_hz": self.f_hz, "damping_ratio": self.zeta, "response": self.response,
                "frequency_std_hz": self.f_std, "damping_std": self.zeta_std}


def fit_mode(f, h, f_guess: float, weight=None, rel_band: float = 0.3) -> tuple[float, float, float, float]:
    """Fit one mode around ``f_guess``: H(s) ~ (b1 s + b0) / (s^2 + 2 z w s + w^2) + e_1/s + e0 + e1 s
    (rigid body and the other modes as background), by variable projection: for (w, z) the
    residue and background are a linear least-squares fit, (w, z) by nonlinear least squares.
    Returns (f, zeta, std f, std zeta)."""
    import scipy.optimize
    f = np.asarray(f)
    sel = (f > f_guess * (1 - rel_band)) & (f < f_guess * (1 + rel_band))
    if sel.sum() < 6:
        raise ValueError(f"too few lines near {f_guess:.3g} Hz to fit a mode")
    ff, hh = f[sel], h[sel]
    w = np.ones(ff.size) if weight is None else np.asarray(weight)[sel]
    s = 2j * np.pi * ff
    norm = np.median(np.abs(hh))
    hh = hh / norm

    def basis(theta):
        wn = 2 * np.pi * theta[0]
        zeta = theta[1]
        d = s ** 2 + 2 * zeta * wn * s + wn ** 2
        return np.stack([s / d * wn, wn ** 2 / d, wn / s, np.ones_like(s), s / wn], axis=1)

    def resid(theta):
        B = basis(theta)
        Br = np.vstack([B.real, B.imag]) * np.concatenate([w, w])[:, None]
        y = np.concatenate([hh.real, hh.imag]) * np.concatenate([w, w])
        c, *_ = np.linalg.lstsq(Br, y, rcond=None)
        return Br @ c - y

    # start: the peak of |H| near the guess, damping from a coarse grid
    pk = ff[np.argmax(np.abs(hh) * (np.abs(ff - f_guess) < 0.15 * f_guess))]
    best = None
    for z0 in (0.005, 0.015, 0.04, 0.1, 0.2):
        for f0 in (pk, f_guess):
            r = scipy.optimize.least_squares(resid, [f0, z0], bounds=([ff[0], 1e-4], [ff[-1], 0.9]),
                                             x_scale=[f_guess * 0.01, 0.01])
            if best is None or r.cost < best.cost:
                best = r
    J = best.jac
    dof = max(2 * ff.size - 7, 1)
    s2 = 2 * best.cost / dof
    try:
        cov = np.linalg.inv(J.T @ J) * s2
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        sd = np.array([np.nan, np.nan])
    return float(best.x[0]), float(best.x[1]), float(sd[0]), float(sd[1])


def model_modes(plant):
    """The model's elastic modes: (frequency Hz, damping ratio) from the damped eigenvalues
    (motor viscous friction included), and the undamped mass-normalized shapes."""
    ch = plant.chain
    w, phi = ch.modes()
    wd, zd = ch.damped_modes(include_ground=True)
    keep = wd > 1e-6 * max(wd.max(), 1.0)
    wd, zd = wd[keep][-(ch.n - 1):], zd[keep][-(ch.n - 1):]
    return [(float(a / 2 / np.pi), float(b)) for a, b in zip(wd, zd)], w[1:], phi[:, 1:]


def _response_for_mode(plant, phi_col, available) -> str:
    """The measured response where a mode shows most: the sensor with the largest mode-shape entry."""
    cand = [("TF1p", abs(phi_col[0]))]
    if "tip" in available:
        cand.append(("tip", abs(phi_col[plant.tip])))
    return max(cand, key=lambda c: c[1])[0]


def fit_modes(responses: dict, plant, model_h: dict | None = None) -> list[dict]:
    """Fit each of the model's modes inside the measured band, in the response where it shows
    most; the same fit on the model's exact response gives the comparison values."""
    mm, _, phi = model_modes(plant)
    out = []
    for i, (fm, zm) in enumerate(mm):
        name = _response_for_mode(plant, phi[:, i], responses)
        r = responses.get(name)
        if r is None or not (r.f[0] * 1.3 < fm < r.f[-1] / 1.3):
            continue
        wgt = np.sqrt(r.coherence) / np.maximum(r.sigma / np.maximum(np.abs(r.h), 1e-300), 1e-3)
        wgt = wgt / wgt.max()
        try:
            f_, z_, sf, sz = fit_mode(r.f, r.h, fm, wgt)
        except ValueError:
            continue
        row = {"mode": i + 2, "response": name, "measured": Mode(f_, z_, name, sf, sz).as_dict(),
               "model_eigen": {"frequency_hz": fm, "damping_ratio": zm}}
        if model_h is not None and name in model_h:
            fm2, zm2, _, _ = fit_mode(r.f, model_h[name], fm)
            row["model"] = {"frequency_hz": fm2, "damping_ratio": zm2}
        else:
            row["model"] = dict(row["model_eigen"])
        out.append(row)
    return out


# --- discrepancies ---------------------------------------------------------------------------

def _energy_shares(plant, phi_col):
    """Per damper / spring: its share of the mode's modal damping and stiffness, with the
    parameter's dotted name and the value in config units."""
    ch = plant.chain
    damp, stiff = [], []
    for j, (k, c) in enumerate(zip(ch.k, ch.c)):
        d2 = (phi_col[j] - phi_col[j + 1]) ** 2
        damp.append((f"plant.c{j + 1}", c, d2, 1.0))
        stiff.append((f"plant.k{j + 1}", k, d2))
    if ch.c_ground[0] > 0 or True:
        conv = plant.speed_scale ** 2 if plant.pitch else 1.0      # N s/m per (N m s/rad)
        damp.append(("friction.viscous", ch.c_ground[0], phi_col[0] ** 2, conv))
    return damp, stiff


def discrepancies(modes: list[dict], plant, f_tol: float = 0.02, z_tol: float = 0.2) -> list[dict]:
    """One sentence per mode whose measured frequency or damping differs from the model's by more
    than ``f_tol`` / ``z_tol`` (relative), naming the parameter that dominates it (modal energy of
    each damper or spring) and the value that would close the gap."""
    _, w, phi = model_modes(plant)
    names = {2: "compliant-mass", 3: "drive"} if plant.n == 3 else {}
    out = []
    for row in modes:
        i = row["mode"] - 2
        me, mo = row["measured"], row["model"]
        fr = me["frequency_hz"] / mo["frequency_hz"]
        zr = me["damping_ratio"] / mo["damping_ratio"]
        damp, stiff = _energy_shares(plant, phi[:, i])
        parts = []
        diff = {}
        if abs(zr - 1) > z_tol:
            tot = sum(c * d2 for _, c, d2, _ in damp)
            name, c, d2, conv = max(damp, key=lambda t: t[1] * t[2] if t[1] > 0 else t[2] * 1e-12)
            share = c * d2 / tot if tot > 0 else 1.0
            # modal damping 2 zeta w; change the dominant damper by the missing amount
            need = 2 * w[i] * (me["damping_ratio"] - mo["damping_ratio"])
            new_c = max(c + need / d2, 0.0)
            factor = new_c / c if c > 0 else math.inf
            word = "too low" if factor > 1 else "too high"
            label = {"plant.c1": "transmission damping c1", "plant.c2": "compliant-mass damping c2",
                     "friction.viscous": "motor viscous friction"}.get(name, name)
            parts.append(f"the {label} ({name}, {share:.0%} of the mode's damping) is about "
                         f"{factor if factor >= 1 else 1 / factor:.1f}x {word}: try {name} = {new_c / conv:.4g}")
            diff[name] = (c / conv, new_c / conv)
        if abs(fr - 1) > f_tol:
            tot = sum(k * d2 for _, k, d2 in stiff)
            name, k, d2 = max(stiff, key=lambda t: t[1] * t[2])
            share = k * d2 / tot
            new_k = k * (1 + (fr ** 2 - 1) / share)
            parts.append(f"the stiffness {name} ({share:.0%} of the mode's strain energy) is about "
                         f"{new_k / k:.2f}x the config's: try {name} = {new_k:.4g}")
            diff[name] = (k, new_k)
        if not parts:
            continue
        label = names.get(row["mode"], f"mode {row['mode']}")
        s = (f"{label} mode: measured {me['frequency_hz']:.2f} Hz, damping {me['damping_ratio']:.3f}; "
             f"model {mo['frequency_hz']:.2f} Hz, {mo['damping_ratio']:.3f}: " + "; ".join(parts))
        out.append({"mode": row["mode"], "sentence": s, "changes": {k: list(v) for k, v in diff.items()},
                    "frequency_ratio": fr, "damping_ratio_ratio": zr})
    return out


# --- tuning help -----------------------------------------------------------------------------

def margins(f, L) -> dict:
    """Gain margin (dB), phase margin (deg), crossover and phase-crossover frequencies (Hz) of an
    open loop L sampled at f (linear interpolation between lines; None where not in the data)."""
    f, L = np.asarray(f), np.asarray(L)
    mag = np.abs(L)
    ph = np.unwrap(np.angle(L))
    out = {"crossover_hz": None, "phase_margin_deg": None, "phase_crossover_hz": None, "gain_margin_db": None}
    # every crossing of |L| = 1: the crossover is the last one down, the phase margin the least
    idx = np.nonzero((mag[:-1] >= 1) != (mag[1:] >= 1))[0]
    pms = []
    for i in idx:
        t = (np.log(mag[i])) / (np.log(mag[i]) - np.log(mag[i + 1]))
        phc = ph[i] + t * (ph[i + 1] - ph[i])
        # the angular distance of L from -180 deg where |L| = 1
        pms.append(float(180 - abs((np.degrees(phc) + 180) % 360 - 180)))
        if mag[i] >= 1:
            out["crossover_hz"] = float(f[i] + t * (f[i + 1] - f[i]))
    if pms:
        out["phase_margin_deg"] = min(pms)
    cross = np.nonzero(np.diff(np.floor((ph + np.pi) / (2 * np.pi))) != 0)[0]
    if cross.size:
        # the margin for a gain increase: where the phase falls through -180 deg as the
        # frequency rises (a rise through it, e.g. an integrating plant under a PI at low
        # frequency, bounds a gain decrease instead); |L| >= 1 there gives a negative margin
        gms = []
        for i in cross:
            m = 0.5 * (mag[i] + mag[i + 1])
            if ph[i + 1] < ph[i]:
                gms.append((-20 * np.log10(m), f[i]))
        if gms:
            gm, fg = min(gms)
            out["gain_margin_db"], out["phase_crossover_hz"] = float(gm), float(fg)
    return out


def bandwidth(f, T) -> float | None:
    """-3 dB bandwidth of a closed loop (first frequency where |T| < 1/sqrt 2)."""
    idx = np.nonzero(np.abs(T) < 1 / math.sqrt(2))[0]
    return float(f[idx[0]]) if idx.size else None


def largest_gain(f, L, pm_min: float, gm_min_db: float, f_trust: float = math.inf) -> tuple[float, dict]:
    """Largest factor a on the loop gain (a L) keeping the phase margin >= pm_min and the gain
    margin >= gm_min_db, with the crossover below ``f_trust`` (the measured band's top: above it
    only the model speaks). Returns (a, margins at a)."""
    best = (None, None)
    for a in np.logspace(-1.5, 1.5, 241):
        m = margins(f, a * L)
        ok = (m["phase_margin_deg"] is None or m["phase_margin_deg"] >= pm_min) and \
             (m["gain_margin_db"] is None or m["gain_margin_db"] >= gm_min_db) and m["crossover_hz"] is not None \
             and m["crossover_hz"] <= f_trust
        if ok:
            best = (float(a), m)
    return best


def _extended(r, model_wide, name, f_max):
    """A measured response continued above its band by the model's (the margins need the whole
    loop; the measurement only covers the band)."""
    if r is None:
        return None
    if not model_wide or name not in model_wide:
        return r
    fw, hw = model_wide["f"], model_wide[name]
    sel = (fw > r.f[-1]) & (fw < f_max)
    return Response(np.concatenate([r.f, fw[sel]]), np.concatenate([r.h, hw[sel]]),
                    np.concatenate([r.coherence, np.ones(sel.sum())]), np.concatenate([r.sigma, np.zeros(sel.sum())]),
                    derived=r.derived)


def tuning(responses: dict, ctrl, modes: list[dict], pm_min: float = 45.0, gm_min_db: float = 6.0,
           plant=None, model_wide: dict | None = None) -> dict:
    """Margins, bandwidths, largest gains keeping the margins, filter suggestions for structural
    modes in the velocity loop, the acceleration feed-forward's effect; the config diff as text.
    ``model_wide``: the model's responses above the measured band ({"f": ..., "Lv": ..., "Lp": ...}),
    joined to the measured loops for the margins."""
    out = {}
    diff = []
    lv = _extended(responses.get("Lv"), model_wide, "Lv", 0.5 / ctrl.velocity_period)
    lp = _extended(responses.get("Lp"), model_wide, "Lp", 0.5 / ctrl.position_period)
    if lv is not None:
        out["velocity_loop"] = dict(margins(lv.f, lv.h), bandwidth_hz=bandwidth(lv.f, lv.h / (1 + lv.h)))
        f_trust = responses["Lv"].f[-1]
        a, m = largest_gain(lv.f, lv.h, pm_min, gm_min_db, f_trust)
        if a is not None:
            out["velocity_loop"]["kp_max"] = ctrl.kp * a
            out["velocity_loop"]["at_kp_max"] = m
            diff.append(f'control.kp = "{ctrl.kp * a:.4g} N*m*s/rad"   # was {ctrl.kp:.4g}: largest Kp keeping '
                        f'PM >= {pm_min:g} deg, GM >= {gm_min_db:g} dB with the crossover ({m["crossover_hz"]:.1f} Hz) '
                        f'inside the measured band')
    if lp is not None:
        out["position_loop"] = dict(margins(lp.f, lp.h))
        # the feedback's bandwidth (the feed-forward makes x/x_cmd flat far beyond it)
        out["position_loop"]["bandwidth_hz"] = bandwidth(lp.f, lp.h / (1 + lp.h))
        a, m = largest_gain(lp.f, lp.h, pm_min, gm_min_db, responses["Lp"].f[-1])
        if a is not None:
            out["position_loop"]["kv_max"] = ctrl.kv * a
            out["position_loop"]["at_kv_max"] = m
            diff.append(f'control.kv = "{ctrl.kv * a:.4g} 1/s"   # was {ctrl.kv:.4g}: largest Kv keeping '
                        f'PM >= {pm_min:g} deg, GM >= {gm_min_db:g} dB (with the present Kp)')
    # structural modes in the velocity loop: peak of |Lv| near each fitted mode
    filters = []
    if lv is not None:
        fc = out["velocity_loop"].get("crossover_hz") or 0.0
        for row in modes:
            fm, zm = row["measured"]["frequency_hz"], row["measured"]["damping_ratio"]
            near = np.abs(lv.f - fm) < max(3 * zm * fm, 2 * (lv.f[1] - lv.f[0]))
            if not near.any():
                continue
            ipk = np.argmax(np.abs(lv.h) * near)
            peak_db = float(20 * np.log10(np.abs(lv.h[ipk])))
            ph_pk = float(np.degrees(np.angle(lv.h[ipk])))
            # phase distance from -180 deg at the peak: a collocated mode (phase near 0) is
            # phase-stabilised, a mode near -180 deg must be gain-stabilised
            dist = 180 - abs(ph_pk)
            if fm > fc and peak_db > -gm_min_db and dist > 90:
                filters.append({"mode_hz": fm, "loop_gain_db": peak_db, "phase_deg": ph_pk,
                                "note": "phase-stabilised (loop phase far from -180 deg at the mode): no filter "
                                        "needed at the present gains; a notch would cost phase margin"})
                diff.append(f"# velocity loop: |Lv| = {peak_db:+.1f} dB at the {fm:.1f} Hz mode, phase {ph_pk:.0f} deg: "
                            f"phase-stabilised, no filter needed now (a notch at {fm:.1f} Hz if delays grow)")
            elif fm > fc and peak_db > -gm_min_db:
                depth = peak_db + gm_min_db + 6
                width = max(2 * zm * fm * 2, 0.1 * fm)
                filters.append({"mode_hz": fm, "loop_gain_db": peak_db, "notch_hz": fm, "notch_width_hz": width,
                                "notch_depth_db": depth, "lowpass_hz": fm / 3 if fm / 3 > 2 * fc else None})
                diff.append(f"# velocity loop: |Lv| = {peak_db:+.1f} dB at the {fm:.1f} Hz mode (above crossover "
                            f"{fc:.1f} Hz): a notch at {fm:.1f} Hz, width {width:.1f} Hz, depth {depth:.0f} dB"
                            + (f", or a low-pass at {fm / 3:.0f} Hz" if fm / 3 > 2 * fc else "")
                            + " (no filter key in the config schema yet)")
            elif fm < fc and peak_db < 20:
                filters.append({"mode_hz": fm, "loop_gain_db": peak_db, "note": "below the crossover: the loop "
                                "acts on it; a notch would cost phase margin"})
    out["filters"] = filters
    if plant is not None:
        out["acceleration_feed_forward"] = acc_ff_effect(plant, ctrl)
        e = out["acceleration_feed_forward"]
        if e["error_per_acc_with_ff"] < e["error_per_acc_now"] * 0.5:
            diff.append(f"control.acc_ff = 1.0   # was {e['acc_ff_now']:g}: following error per acceleration "
                        f"{e['error_per_acc_now'] * 1e6:.3g} -> {e['error_per_acc_with_ff'] * 1e6:.3g} um/(m/s^2)")
    out["config_diff"] = "\n".join(diff)
    return out


def acc_ff_effect(plant, ctrl, f_low: float = 0.5) -> dict:
    """Low-frequency following error per commanded acceleration (m per m/s^2) of the table, with the
    present acceleration feed-forward and with a full one (acc_ff = 1: the total inertia)."""
    from dataclasses import replace
    tp = ctrl.position_period
    f = np.array([f_low])
    res = {}
    frac_now = ctrl.acc_ff * plant.force_gain / plant.total_mass
    for label, aff in (("now", ctrl.acc_ff), ("with_ff", plant.total_mass / plant.force_gain)):
        c = replace(ctrl, acc_ff=aff)
        m = model_responses(plant, replace(c, acc_ff=0.0), f, tip_measured=False)
        Lv = m["Lv"]
        # x_table / x_cmd with the feed-forward: P (speed ref -> table) and the torque path
        Gw = m["TF1p"]
        C = Lv / Gw
        hold = _hold(f, tp)
        scale = c.speed_scale
        disc_P = m["Lp"] / (c.kv * scale * hold)          # x_table per speed reference
        gx2 = disc_P * (1 + Lv) / C                       # x_table per torque
        s = 2j * np.pi * f
        ff = c.ffv * (np.exp(s * tp) - 1) / tp
        x_over_cmd = (scale * (c.kv + ff) * hold * disc_P + aff * s ** 2 * hold * gx2 / (1 + Lv)) / (1 + m["Lp"])
        e = np.abs(1 - x_over_cmd) / np.abs(s) ** 2
        res[f"error_per_acc_{label}"] = float(e[0])
    res["acc_ff_now"] = frac_now
    return res


# --- the whole measurement -------------------------------------------------------------------

@dataclass
class FrfResult:
    responses: dict
    model: dict
    modes: list
    discrepancies: list
    tuning: dict
    record: FrfRecord
    warnings: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {
            "responses": {k: dict(v.as_dict(), title=TITLES[k], unit=UNITS[k],
                                  model_magnitude=np.abs(self.model[k]).tolist() if k in self.model else None,
                                  model_phase_deg=np.degrees(np.angle(self.model[k])).tolist()
                                  if k in self.model else None)
                          for k, v in self.responses.items()},
            "modes": self.modes, "discrepancies": [d["sentence"] for d in self.discrepancies],
            "suggested_changes": {k: v for d in self.discrepancies for k, v in d["changes"].items()},
            "tuning": {k: v for k, v in self.tuning.items()}, "warnings": self.warnings,
            "excitation": {"signal": self.record.excitation.kind, "input": self.record.input,
                           "period_s": self.record.excitation.period, "periods": self.record.periods,
                           "lines": int(self.record.excitation.lines.size),
                           "saturated_periods": self.record.saturated, "backend": self.record.backend},
        }


def measure(plant_true, plant_model, ctrl, st: FrfSettings, backend=None, progress=None, pm_min: float = 45.0,
            gm_min_db: float = 6.0, supervisor=None) -> FrfResult:
    """Excite, estimate, set against the model, fit the modes, suggest. ``plant_true`` is what the
    simulated run uses (None with a backend); ``plant_model`` the config's model."""
    if backend is None:
        rec = run_sim(plant_true, ctrl, st, progress)
    else:
        rec = run_backend(backend, ctrl, st, progress, supervisor=supervisor, plant=plant_model)
    if progress:
        progress("estimating the responses")
    resp = estimate(rec, ctrl)
    model_all = model_responses(plant_model, ctrl, rec.excitation.freqs, rec.tip_measured)
    model = {k: (v[: resp[k].f.size] if k in resp else v) for k, v in model_all.items()}
    if progress:
        progress("fitting the modes")
    modes = fit_modes(resp, plant_model, model)
    disc = discrepancies(modes, plant_model)
    f_hi = rec.excitation.freqs[-1]
    fw = np.geomspace(f_hi * 1.001, 0.45 / ctrl.velocity_period, 400)
    wide = model_responses(plant_model, ctrl, fw, False)
    wide["f"] = fw
    tun = tuning(resp, ctrl, modes, pm_min, gm_min_db, plant=plant_model, model_wide=wide)
    warnings = []
    if rec.saturated:
        warnings.append(f"the output saturated in {rec.saturated} velocity periods: lower --amplitude")
    w = rec.channel("w")[rec.start:]
    if st.speed != 0 and np.any(np.sign(w) == -np.sign(st.speed)):
        warnings.append("the motor speed reverses during the excitation: friction changes sign and the "
                        "responses are not those of the working point; raise --speed or lower --amplitude")
    low = np.mean(resp["TF1p"].coherence < 0.8)
    if low > 0.2:
        warnings.append(f"coherence below 0.8 on {low:.0%} of the lines of TF1': raise --amplitude or --periods")
    return FrfResult(resp, model, modes, disc, tun, rec, warnings)


def stderr_progress(msg: str) -> None:
    print(f"hil frf: {msg}", file=sys.stderr, flush=True)
