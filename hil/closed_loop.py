"""Frequency response of the closed position loop (the right panels of the paper's Fig. 9).

The two-rate cascade is linear between position ticks (friction off, no saturation), so it is
lifted exactly to the position period: the velocity loop's Tp/Tv steps, each a PI step and a ZOH
plant step, compose into one map s[k+1] = Phi s[k] + Gamma w_ref[k] of the state s = (plant, PI
integral). Closing the position loop gives a discrete system from the command samples to the
table (and tip) samples, exact at the ticks: H(z) = C (zI - A)^-1 Gamma R (Kv + FFV (z - 1)/Tp).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hil.control import controller_from_config
from hil.errors import UnstableLoopError
from hil.plant_config import plant_from_config
from sim_plant.transfer import chain_tfs

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


def loop_stability(cfg) -> tuple[bool, float] | None:
    """(stable, spectral radius) of the configured cascade on the model, lifted exactly to the
    position period; None where the lifted model does not cover the configuration (a speed
    estimated from position, or a computation delay)."""
    if cfg.get("control.velocity_feedback", "motor_speed") != "motor_speed" or cfg.get("control.output_delay", 0):
        return None
    r = closed_loop_response(cfg, [1.0])
    return r.stable, r.spectral_radius


def check_loop_stability(cfg) -> None:
    """Refuse a loop configuration whose closed loop the model shows unstable."""
    res = loop_stability(cfg)
    if res is None or res[0]:
        return
    tv, tp = cfg["control.velocity_period"], cfg["control.position_period"]
    raise UnstableLoopError(
        f"loop configuration refused: the model's closed loop is unstable (spectral radius {res[1]:.3g} > 1 "
        f"per position period) with control.velocity_period {tv * 1e3:g} ms, control.position_period "
        f"{tp * 1e3:g} ms, control.kp {cfg['control.kp']:g}, control.ti {cfg['control.ti']:g} s, control.kv "
        f"{cfg['control.kv']:g} 1/s; a shorter velocity period or lower gains would fit ('hil model "
        f"--closed-loop' shows the loop)")
