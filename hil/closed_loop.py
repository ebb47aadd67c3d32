"""Frequency response of the closed position loop (the right panels of the paper's Fig. 9).

The two-rate cascade is linear between position ticks (friction off, no saturation), so it is
lifted exactly to the position period: the velocity loop's Tp/Tv steps, each a PI step and a ZOH
plant step, compose into one map s[k+1] = Phi s[k] + Gamma w_ref[k] of the state s = (plant, PI
integral). Closing the position loop gives a discrete system from the command samples to the
table (and tip) samples, exact at the ticks: H(z) = C (zI - A)^-1 Gamma R (Kv + FFV (z - 1)/Tp).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from drivers.control import controller_from_config
from hil.errors import UnstableLoopError
from hil.plant_config import plant_from_config
from sim_plant.transfer import chain_tfs

logger = logging.getLogger(__name__)

__all__ = ["ClosedLoopResponse", "closed_loop_response", "closed_loop_report", "bandwidth"]


@dataclass
class ClosedLoopResponse:
    f_hz: np.ndarray
    table: np.ndarray            # x_table / x_cmd with the configured feed-forward
    table_no_ff: np.ndarray      # the same without feed-forward
    tip: np.ndarray              # exact, command to tip
    table_tf3: np.ndarray        # table response followed by TF3 (the paper's way)
    table_no_ff_tf3: np.ndarray
    stable: bool
    spectral_radius: float


def _lifted(plant, ctrl):
    """Phi, Gamma (speed reference), Gamma_ff (torque feed-forward) of one position period."""
    n = plant.n
    disc = plant.chain.discretize(ctrl.velocity_period)
    Ad, b = disc.A, disc.B[:, 0] * plant.force_gain
    Tv, Kp, Ti, R = ctrl.velocity_period, ctrl.kp, ctrl.ti, ctrl.speed_scale
    inv_ti = 0.0 if math.isinf(Ti) else 1.0 / Ti
    ns = 2 * n + 1
    # one velocity step: e = w_ref - R v1;  I+ = I + Tv e;  tau = Kp (e + I+ / Ti) + tau_ff;  x+ = Ad x + b tau
    cv = np.zeros(ns)
    cv[n] = R
    E_s, E_w = -cv, 1.0
    I_s = np.zeros(ns)
    I_s[-1] = 1.0
    Ip_s, Ip_w = I_s + Tv * E_s, Tv * E_w
    tau_s, tau_w = Kp * (E_s + inv_ti * Ip_s), Kp * (E_w + inv_ti * Ip_w)
    F = np.zeros((ns, ns))
    F[:2 * n, :2 * n] = Ad
    F[:2 * n, :] += np.outer(b, tau_s)
    F[-1, :] = Ip_s
    G = np.zeros(ns)
    G[:2 * n] = b * tau_w
    G[-1] = Ip_w
    Gff = np.zeros(ns)
    Gff[:2 * n] = b
    Phi, Gam, Gamff = np.eye(ns), np.zeros(ns), np.zeros(ns)
    for _ in range(ctrl.substeps):
        Phi, Gam, Gamff = F @ Phi, F @ Gam + G, F @ Gamff + Gff
    return Phi, Gam, Gamff


def closed_loop_response(cfg, f_hz=None, ffv: float | None = None) -> ClosedLoopResponse:
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    Tp, Kv, R = ctrl.position_period, ctrl.kv, ctrl.speed_scale
    if f_hz is None:
        f_hz = np.logspace(-1, math.log10(0.5 / Tp), 600)
    f_hz = np.asarray(f_hz, float)
    Phi, Gam, Gamff = _lifted(plant, ctrl)
    n = plant.n
    ns = 2 * n + 1
    c_fb = np.zeros(ns)
    c_fb[plant.table if ctrl.position_feedback == "table" else 0] = 1.0
    A = Phi - np.outer(Gam * R * Kv, c_fb)
    rho = float(np.max(np.abs(np.linalg.eigvals(A))))
    if _extra_terms(cfg):
        # the response above leaves them out; stability is judged on the whole loop (lifted_loop)
        rho = loop_stability(cfg)[1]
    c_table = np.zeros(ns)
    c_table[plant.table] = 1.0
    c_tip = np.zeros(ns)
    c_tip[plant.tip] = 1.0
    z = np.exp(1j * 2 * np.pi * f_hz * Tp)

    def resp(c, ffv_):
        out = np.empty(z.size, complex)
        for i, zi in enumerate(z):
            inp = Gam * R * (Kv + ffv_ * (zi - 1) / Tp) + Gamff * ctrl.acc_ff * (zi - 2 + 1 / zi) / Tp ** 2
            out[i] = c @ np.linalg.solve(zi * np.eye(ns) - A, inp)
        return out

    ffv = ctrl.ffv if ffv is None else ffv
    table = resp(c_table, ffv)
    table0 = resp(c_table, 0.0)
    tip = resp(c_tip, ffv)
    tfs = chain_tfs(plant.chain)
    tf3 = tfs[2].freqresp(f_hz) if len(tfs) > 2 and plant.tip != plant.table else np.ones_like(table)
    return ClosedLoopResponse(f_hz, table, table0, tip, table * tf3, table0 * tf3, rho < 1.0, rho)


def bandwidth(f_hz, h) -> float | None:
    """The first frequency at which |h| falls below -3 dB of its low-frequency value."""
    mag = np.abs(h) / abs(h[0])
    below = np.flatnonzero(mag < 1 / math.sqrt(2))
    if below.size == 0:
        return None
    i = below[0]
    if i == 0:
        return float(f_hz[0])
    # interpolate in log frequency
    m0, m1 = mag[i - 1], mag[i]
    t = (m0 - 1 / math.sqrt(2)) / (m0 - m1)
    return float(10 ** (np.log10(f_hz[i - 1]) + t * (np.log10(f_hz[i]) - np.log10(f_hz[i - 1]))))


def closed_loop_report(r: ClosedLoopResponse) -> dict:
    """Bandwidths and peak gains of the closed position loop of a :func:`closed_loop_response`
    (the figure is hil.plots.model's)."""
    return {"stable": r.stable, "spectral_radius": r.spectral_radius,
           "bandwidth_hz": {"table_ff": bandwidth(r.f_hz, r.table), "table_no_ff": bandwidth(r.f_hz, r.table_no_ff),
                            "tip_ff": bandwidth(r.f_hz, r.tip), "table_ff_tf3": bandwidth(r.f_hz, r.table_tf3),
                            "table_no_ff_tf3": bandwidth(r.f_hz, r.table_no_ff_tf3)},
           "peak_gain_db": {k: float(20 * np.log10(np.max(np.abs(v)))) for k, v in
                            (("table_ff", r.table), ("tip_ff", r.tip), ("table_ff_tf3", r.table_tf3))}}


def lifted_loop(plant, ctrl):
    """The whole sampled loop as a linear map over one position period, every term the
    configuration describes included: s[k+1] = Phi s[k] + Gam w_ref[k] + Gff ff[k], with the
    speed reference w_ref and the torque feed-forward ff held over the period.

    The state, at the start of a velocity step (the compiled kernel's order, hil.simulate):
    the plant's positions and velocities (2n), the PI integral, for a speed estimated from
    position (``velocity_feedback = "position_difference"``) the motor positions of the last
    ``len(taps) - 1`` steps and the last filtered position, the outputs held in the delay line
    (``loop_terms(...).delay`` velocity periods: the computation delay and the plant's transport
    delay, interpolated linearly when fractional), the current loop's lagged output, and two
    states per filter section (``control.filters``: the torque path's, then the speed path's).
    One velocity step::

        w = R v1                         or  (sum_i taps_i q_(j-i) - qf_(j-1)) R / Tv
        w = S(w)                         (the speed path's sections, if any)
        e = w_ref - w;  I+ = I + Tv e;   u = Q(Kp (e + I+ / Ti) + ff)   (Q: the torque path's)
        u_d = (1 - f) u_(j-d) + f u_(j-d-1)          (the delay line)
        u_a+ = u_a + alpha (u_d - u_a)                (the current loop)
        x+ = Ad x + b u_a+

    Linear between ticks: friction, saturation, quantization and the plant's nonlinear effects
    are left out (the small-signal loop).

    Returns
    -------
    Phi, Gam, Gff : ndarray
        The maps over one position period.
    index : dict
        Where the terms sit in the state: ``"plant"``, ``"integral"``, ``"history"``,
        ``"qf"``, ``"delay"``, ``"lag"`` (slices or indices).
    """
    from drivers.control import loop_terms
    n = plant.n
    disc = plant.chain.discretize(ctrl.velocity_period)
    Ad, b = disc.A, disc.B[:, 0] * plant.force_gain
    Tv, Kp, Ti, R = ctrl.velocity_period, ctrl.kp, ctrl.ti, ctrl.speed_scale
    inv_ti = 0.0 if math.isinf(Ti) else 1.0 / Ti
    taps = np.asarray(ctrl.velocity_filter if ctrl.velocity_feedback == "position_difference" else (), float)
    terms = loop_terms(plant, ctrl)
    d_int, d_frac = terms.delay_parts
    nd = d_int + 1 if terms.delay > 0.0 else 0
    nh = max(taps.size - 1, 0)
    i_I = 2 * n
    h0 = i_I + 1
    i_qf = h0 + nh
    b0 = i_qf + (1 if taps.size else 0)
    i_lag = b0 + nd
    i_tq = i_lag + 1                       # the filter sections' states, two each (torque, then speed)
    i_sp = i_tq + 2 * len(ctrl.torque_filters)
    ns = i_sp + 2 * len(ctrl.speed_filters)
    F = np.zeros((ns, ns))
    G = np.zeros(ns)
    Gf = np.zeros(ns)
    # each velocity step as affine rows in (state, w_ref, ff): value = row_s @ s + row_w w_ref + row_f ff
    w_s = np.zeros(ns)
    if taps.size:
        qf_s = np.zeros(ns)
        qf_s[0] = taps[0]
        qf_s[h0:h0 + nh] = taps[1:]
        w_s = (qf_s - np.eye(ns)[i_qf]) * R / Tv
    else:
        w_s[n] = R
    w_s, _, _ = _sections(F, G, Gf, ctrl.speed_filters, i_sp, (w_s, 0.0, 0.0))
    e_s, e_w = -w_s, 1.0
    Ip_s, Ip_w = np.eye(ns)[i_I] + Tv * e_s, Tv * e_w
    u_s, u_w, u_f = _sections(F, G, Gf, ctrl.torque_filters, i_tq,
                              (Kp * (e_s + inv_ti * Ip_s), Kp * (e_w + inv_ti * Ip_w), 1.0))
    F[i_I], G[i_I] = Ip_s, Ip_w
    if taps.size:
        F[i_qf] = qf_s
        if nh:
            F[h0, 0] = 1.0
            for i in range(1, nh):
                F[h0 + i, h0 + i - 1] = 1.0
    # the delay line: b'_0 = u, b'_i = b_(i-1); u_d = (1 - f) b'_d + f b'_(d+1)
    if nd:
        F[b0], G[b0], Gf[b0] = u_s, u_w, u_f
        for i in range(1, nd):
            F[b0 + i, b0 + i - 1] = 1.0

        def bprime(i):
            if i == 0:
                return u_s, u_w, u_f
            return np.eye(ns)[b0 + i - 1], 0.0, 0.0
        a_s, a_w, a_f = bprime(d_int)
        c_s, c_w, c_f = (np.eye(ns)[b0 + d_int], 0.0, 0.0)
        ud_s, ud_w, ud_f = ((1 - d_frac) * a_s + d_frac * c_s, (1 - d_frac) * a_w + d_frac * c_w,
                            (1 - d_frac) * a_f + d_frac * c_f)
    else:
        ud_s, ud_w, ud_f = u_s, u_w, u_f
    al = terms.lag_alpha
    ua_s = (1 - al) * np.eye(ns)[i_lag] + al * ud_s
    ua_w, ua_f = al * ud_w, al * ud_f
    F[i_lag], G[i_lag], Gf[i_lag] = ua_s, ua_w, ua_f
    F[:2 * n, :] = np.outer(b, ua_s)
    F[:2 * n, :2 * n] += Ad
    G[:2 * n], Gf[:2 * n] = b * ua_w, b * ua_f
    Phi, Gam, Gff = np.eye(ns), np.zeros(ns), np.zeros(ns)
    for _ in range(ctrl.substeps):
        Phi, Gam, Gff = F @ Phi, F @ Gam + G, F @ Gff + Gf
    index = {"plant": slice(0, 2 * n), "integral": i_I, "history": slice(h0, h0 + nh),
             "qf": i_qf if taps.size else None, "delay": slice(b0, b0 + nd), "lag": i_lag,
             "filters": slice(i_tq, ns)}
    return Phi, Gam, Gff, index


def _sections(F, G, Gf, secs, z0: int, x):
    """Filter sections (drivers.filters, transposed direct form II) on the affine row ``x`` =
    (row_s, row_w, row_f): their states' rows into ``F``, ``G``, ``Gf`` from index ``z0``, two
    per section; returns the output's row."""
    ns = F.shape[0]
    for i, (b0, b1, b2, a1, a2) in enumerate(secs):
        z1, z2 = z0 + 2 * i, z0 + 2 * i + 1
        y = (b0 * x[0] + np.eye(ns)[z1], b0 * x[1], b0 * x[2])
        F[z1], G[z1], Gf[z1] = b1 * x[0] - a1 * y[0] + np.eye(ns)[z2], b1 * x[1] - a1 * y[1], b1 * x[2] - a1 * y[2]
        F[z2], G[z2], Gf[z2] = b2 * x[0] - a2 * y[0], b2 * x[1] - a2 * y[1], b2 * x[2] - a2 * y[2]
        x = y
    return x


def _extra_terms(cfg) -> list[str]:
    """The loop terms the frequency response of :func:`closed_loop_response` leaves out."""
    out = []
    if cfg.get("control.output_delay", 0):
        out.append("control.output_delay")
    if cfg.get("control.velocity_feedback", "motor_speed") != "motor_speed":
        out.append("control.velocity_feedback")
    if cfg.get("control.filters"):
        out.append("control.filters")
    if cfg.get("actuator.current_loop_time_constant", 0.0):
        out.append("actuator.current_loop_time_constant")
    from sim_plant.kernel import time_delay
    if time_delay(plant_from_config(cfg)) > 0:
        out.append("the plant's transport delay")
    return out


def closed_loop_matrix(plant, ctrl) -> np.ndarray:
    """The closed position loop over one position period (command held at zero): the state
    matrix whose eigenvalues decide stability (:func:`lifted_loop`'s state). Without integral
    action (``ti`` inf: a P velocity loop) the integral still sums the error, but nothing reads it:
    its eigenvalue is 1 exactly and says nothing about the loop, so its state is left out (its
    column is zero but for itself: the other eigenvalues are those of the loop without it)."""
    Phi, Gam, _, index = lifted_loop(plant, ctrl)
    c_fb = np.zeros(Phi.shape[0])
    c_fb[plant.table if ctrl.position_feedback == "table" else 0] = 1.0
    A = Phi - np.outer(Gam * ctrl.speed_scale * ctrl.kv, c_fb)
    if math.isinf(ctrl.ti):
        i = index["integral"]
        A = np.delete(np.delete(A, i, axis=0), i, axis=1)
    return A


# state sizes the eigenvalue check is asked to handle (the schema bounds the delay below this)
MAX_LIFTED_STATES = 2000


def loop_stability(cfg) -> tuple[bool, float] | None:
    """(stable, spectral radius) of the configured cascade on the model, lifted exactly to the
    position period with every linear term the configuration describes (:func:`lifted_loop`:
    the computation and transport delays, the speed estimated from filtered positions, the
    current loop's lag)."""
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    from drivers.control import loop_terms
    size = 2 * plant.n + 3 + len(ctrl.velocity_filter) + int(loop_terms(plant, ctrl).delay)
    if size > MAX_LIFTED_STATES:
        raise UnstableLoopError(f"loop configuration refused: its delay ({size} states) is too long to judge the "
                                f"loop's stability (at most {MAX_LIFTED_STATES}); shorten control.output_delay or "
                                f"the plant's transport delay")
    with np.errstate(over="ignore", invalid="ignore"):
        A = closed_loop_matrix(plant, ctrl)
    if not np.all(np.isfinite(A)):
        # the loop grows beyond the floating-point range within one position period
        return False, math.inf
    rho = float(np.max(np.abs(np.linalg.eigvals(A))))
    return rho < 1.0, rho


def check_loop_stability(cfg) -> None:
    """Refuse a loop configuration whose closed loop the model shows unstable."""
    res = loop_stability(cfg)
    logger.debug("loop stability of %s: %s", cfg.source, res)
    if res is None or res[0]:
        return
    tv, tp = cfg["control.velocity_period"], cfg["control.position_period"]
    terms = []
    if cfg.get("control.output_delay", 0):
        terms.append(f"control.output_delay {cfg['control.output_delay']}")
    if cfg.get("control.velocity_feedback", "motor_speed") != "motor_speed":
        terms.append(f"control.velocity_feedback {cfg['control.velocity_feedback']}")
    if cfg.get("actuator.current_loop_time_constant", 0.0):
        terms.append(f"actuator.current_loop_time_constant {cfg['actuator.current_loop_time_constant'] * 1e3:g} ms")
    for f in cfg.get("control.filters") or ():
        terms.append(f"control.filters {f['kind']}" + (f" at {f['frequency']:g} Hz" if "frequency" in f else "")
                     + f" on the {f['at']} path")
    raise UnstableLoopError(
        f"loop configuration refused: the model's closed loop is unstable (spectral radius {res[1]:.3g} > 1 "
        f"per position period) with {''.join(t + ', ' for t in terms)}control.velocity_period {tv * 1e3:g} ms, control.position_period "
        f"{tp * 1e3:g} ms, control.kp {cfg['control.kp']:g}, control.ti {cfg['control.ti']:g} s, control.kv "
        f"{cfg['control.kv']:g} 1/s; a shorter velocity period or lower gains would fit ('hil model "
        f"--closed-loop' shows the loop)")
