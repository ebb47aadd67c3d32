"""The closed loop on the simulated plant, compiled: position loop every Tp, velocity loop every
Tv, the plant advanced by its exact zero-order-hold discretization over each Tv.

The control law is hil.control's (the same functions the real-time loop calls), and so are the
terms between the law and the plant (delays, current-loop lag, effect table:
:func:`hil.control.loop_terms`); the plant step and its forces (dry friction, effects) are
hil.sim_plant.kernel's. :func:`simulate` returns a
:class:`SimulationResult`, a plain data object (plotting lives in hil.plots). The
frequency-response experiment (hil.frf.run) runs the same compiled loop, :func:`closed_loop_kernel`,
with its excitation, measurement noise and per-period record, which the simulation leaves out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from hil.control import (
    ControllerSettings,
    controller_from_config,
    delay_line,
    history_push,
    history_read,
    loop_terms,
    measured_speed,
    new_velocity_state,
    pi_law,
    position_law,
    quantize,
)
from hil.plant_config import plant_from_config
from hil.sim_plant.kernel import plant_step
from hil.sim_plant.plant import Plant

__all__ = ["SimulationResult", "simulate", "simulate_config", "closed_loop_kernel", "per_velocity_period",
           "external_forces", "TORQUE_SAMPLING"]

# which controller output a record holds: the current after the delay and the current loop, or the command
TORQUE_SAMPLING = ("actual", "command")


@dataclass
class SimulationResult:
    """Channels on the record clock (every position tick unless asked otherwise), SI units.

    ``x``, ``v``: positions and velocities of every mass (true); ``x_motor``, ``x_table``: what the
    encoders read (quantized where the config says so); ``x_tip``: the tool tip (true, or the
    table for a chain without a tip); ``u``: controller output (torque N m, or command V);
    ``x_cmd``, ``v_cmd``: the command at each recorded instant."""
    t: np.ndarray
    x_cmd: np.ndarray
    v_cmd: np.ndarray
    x: np.ndarray
    v: np.ndarray
    u: np.ndarray
    x_motor: np.ndarray
    x_table: np.ndarray
    x_tip: np.ndarray
    rotary: bool = True
    meta: dict = field(default_factory=dict)

    @property
    def e_table(self) -> np.ndarray:
        return self.x_cmd - self.x_table

    @property
    def e_tip(self) -> np.ndarray:
        return self.x_cmd - self.x_tip

    def channels(self) -> dict[str, np.ndarray]:
        """The measurement-format channels (SI): t, x_cmd, v_cmd, x_motor, x_table, x_tip,
        torque or force, e_table, e_tip."""
        out = {"t": self.t, "x_cmd": self.x_cmd, "v_cmd": self.v_cmd, "x_motor": self.x_motor,
               "x_table": self.x_table, "x_tip": self.x_tip}
        out["torque" if self.rotary else "command"] = self.u
        if not self.rotary and "force_gain" in self.meta:
            out["force"] = self.u * self.meta["force_gain"]
        out["e_table"] = self.e_table
        out["e_tip"] = self.e_tip
        return out


@njit(cache=True)
def closed_loop_kernel(Ad, Bd, x0, p, fgain, x_cmd, n_sub, table, tip, fb_motor, fric, res_table, res_motor,
                       codes, eparams, delay, ubuf, lag_alpha, record_every,
                       X, V, U, XM, XT, XCMD, exc=None, exc_into_speed=False, noise_w=None, noise_x=None, out=None,
                       hbuf=None, fb_delay=0.0, u_add=None, f_ext=None, open_loop=False, log_command=False):
    """Run len(x_cmd) - 1 position ticks. Records every ``record_every`` velocity steps into the
    output arrays (positions, velocities, output, measured motor and table, command).

    ``delay``: computation delay of the output in velocity periods (float: a transport delay
    of the plant adds a fraction, interpolated linearly between the held outputs).

    The frequency-response experiment (hil.frf) adds, each None where absent (numba then
    compiles it away): ``exc``, one excitation value per velocity period, added to the output
    before its limit (or to the speed reference, ``exc_into_speed``), and then no acceleration
    feed-forward; measurement noise on the motor speed (``noise_w``, one per velocity period)
    and on the motor, table and tip positions (``noise_x``, one row per velocity period); ``out``,
    one row per velocity period with the columns of hil.loop.CYCLE_CHANNELS. ``X`` (and the other
    records) may be None when ``out`` is given.

    ``hbuf``, ``fb_delay``: the history of the position loop's feedback and its delay in velocity
    periods (hil.control.LoopTerms.feedback_buffer; None: no feedback delay, compiled away). The
    feedback position is pushed after every plant step and read ``fb_delay`` periods old at each
    position tick; the recorded positions are the true ones.

    Measured inputs of a record (hil.ident.replay), each None where absent (compiled away):
    ``u_add``, one value per velocity period added to the controller's output after the law (the
    feed-forward stays) and limited with it; ``f_ext``, one row per velocity period of external
    forces on the masses (N; needs ``codes``, an empty table when the plant has no effects).
    ``open_loop``: no position or velocity loop, the output is ``u_add`` alone, not limited (the
    actuator's command measured in an open-loop run).

    ``log_command``: the recorded output ``U`` is the controller's output at the sample, before
    the delay and the current loop (a drive that logs its torque command); False: the current
    after them (a drive that logs its measured current).

    Returns the number of velocity periods in which the excitation drove the output past its limit."""
    nn = Ad.shape[0]
    n = nn // 2
    x = x0.copy()
    x_new = np.zeros(nn)
    f = np.zeros(n)
    s = new_velocity_state()
    d_int = int(math.floor(delay))
    d_frac = delay - d_int
    u_act = 0.0
    dry = max(fric[0], fric[1], fric[2], fric[3]) > 0.0
    K = x_cmd.shape[0] - 1
    tp = p[0]          # P.TP
    # the velocity loop's settings and state as locals: they stay in registers in the hot loop
    kp, ti, tv, limit, acc_ff, speed_scale = p[4], p[5], p[1], p[6], p[8], p[7]   # P.KP, TI, TV, ULIM, ACC_FF, SPEED_SCALE
    speed_from_position = p[9] > 0.0                                               # P.N_TAPS
    integral = 0.0
    saturated = False
    countdown = 1                  # velocity steps until the next recorded sample
    rec = 0
    n_sat = 0
    w_ref = 0.0
    a_cmd = 0.0
    fd_int = int(math.floor(fb_delay))
    fd_frac = fb_delay - fd_int
    if hbuf is not None:           # the axis was at rest before the start
        history_push(hbuf, quantize(x[0], res_motor) if fb_motor else quantize(x[table], res_table))
    for k in range(K):
        # --- position loop, tick k ---
        xm = quantize(x[0], res_motor)
        xt = quantize(x[table], res_table)
        if noise_x is not None:
            xm += noise_x[k * n_sub, 0]
            xt += noise_x[k * n_sub, 1]
        xfb = xm if fb_motor else xt
        if hbuf is not None:       # the feedback as it arrives, fb_delay velocity periods late
            xfb = history_read(hbuf, fd_int, fd_frac)
            if noise_x is not None:
                xfb += noise_x[k * n_sub, 0 if fb_motor else 1]
        w_ref = position_law(p, x_cmd[k], x_cmd[k + 1], xfb)
        if k > 0:
            a_cmd = (x_cmd[k + 1] - 2.0 * x_cmd[k] + x_cmd[k - 1]) / (tp * tp)
        else:
            a_cmd = (x_cmd[k + 1] - x_cmd[k]) / (tp * tp)
        ff = acc_ff * a_cmd
        if exc is not None:
            ff = 0.0
        for j in range(n_sub):
            # --- velocity loop ---
            step = k * n_sub + j
            r = 0.0
            w_ref_v = w_ref
            if exc is not None:
                r = exc[step]
                w_ref_v = w_ref + (r if exc_into_speed else 0.0)
            # the encoders as read this period (the measured speed of the noisy run is always hil.control's)
            xm = quantize(x[0], res_motor)
            if noise_x is not None:
                xm += noise_x[step, 0]
            if noise_w is not None:
                w_meas = measured_speed(p, s, x[n] + noise_w[step], xm)
            elif speed_from_position:
                w_meas = measured_speed(p, s, x[n], xm)
            else:
                w_meas = x[n] * speed_scale
            if open_loop:
                u_ctrl = 0.0
            else:
                u_ctrl, integral, saturated = pi_law(kp, ti, tv, limit, integral, saturated, w_ref_v, w_meas, ff)
            u = u_ctrl
            if exc is not None:
                # a torque excitation is added to the controller's output and limited with it
                u = u_ctrl + (0.0 if exc_into_speed else r)
                if u > limit:
                    u = limit
                    n_sat += 1
                elif u < -limit:
                    u = -limit
                    n_sat += 1
            if u_add is not None:
                # a measured command after the controller (EMPS's pulses), limited with the output
                u = u + u_add[step]
                if not open_loop:
                    if u > limit:
                        u = limit
                    elif u < -limit:
                        u = -limit
            if out is not None:
                out[step, 0] = r
                out[step, 1] = u
                out[step, 2] = u_ctrl
                out[step, 3] = w_ref_v - w_meas
                out[step, 4] = w_meas
                out[step, 5] = w_ref
                out[step, 6] = w_ref_v
                out[step, 7] = xm
                out[step, 8] = quantize(x[table], res_table) + (noise_x[step, 1] if noise_x is not None else 0.0)
                out[step, 9] = x[tip] + (noise_x[step, 2] if noise_x is not None else 0.0)
            u_cmd = u
            # computation delay, then the current loop (ideal, or a first-order lag)
            if ubuf is not None:       # None (no delay): compiled away
                u = delay_line(ubuf, u, d_int, d_frac)
            u_act += lag_alpha * (u - u_act)
            if X is not None:
                countdown -= 1
                if countdown == 0:
                    countdown = record_every
                    for i in range(n):
                        X[rec, i] = x[i]
                        V[rec, i] = x[n + i]
                    U[rec] = u_cmd if log_command else u_act
                    XM[rec] = quantize(x[0], res_motor)
                    XT[rec] = quantize(x[table], res_table)
                    # between ticks the command is interpolated, as the NC's fine interpolation would
                    XCMD[rec] = x_cmd[k] + (x_cmd[k + 1] - x_cmd[k]) * j / n_sub
                    rec += 1
            # --- plant over one Tv ---
            if f_ext is not None:
                plant_step(Ad, Bd, x, u_act * fgain, fric, dry, codes, eparams, f, x_new, f_ext[step])
            else:
                plant_step(Ad, Bd, x, u_act * fgain, fric, dry, codes, eparams, f, x_new)
            if hbuf is not None:
                history_push(hbuf, quantize(x[0], res_motor) if fb_motor else quantize(x[table], res_table))
    return n_sat


def simulate(plant: Plant, ctrl: ControllerSettings, x_cmd, *, record_every: int | None = None,
             x0: float | None = None, v_cmd=None, u_add=None, f_ext=None, open_loop: bool = False,
             torque: str = "actual") -> SimulationResult:
    """Closed-loop response to the command ``x_cmd`` sampled on the position clock.

    ``x_cmd[k]`` is the command at tick k; the loop runs ``len(x_cmd)`` ticks (the command is
    held after the last sample, which the feed-forward of the last tick needs). The plant starts
    at rest at ``x0`` (default ``x_cmd[0]``). ``record_every``: velocity steps per recorded
    sample (default: one per position tick).

    Measured inputs (:func:`per_velocity_period` puts a record's samples on the loop's clock):
    ``u_add``, one value per velocity period added after the controller (controller units: N m on
    a rotary axis, V on a linear one); ``f_ext``, one row per velocity period of forces on each
    mass (N); ``open_loop``: no loops, ``u_add`` is the whole output. Arrays shorter than the run
    hold their last value. ``torque``: which output the record holds, ``"actual"`` (the current
    after the delay and the current loop) or ``"command"`` (the controller's output at the
    sample, before them)."""
    if torque not in TORQUE_SAMPLING:
        raise ValueError(f"torque: expected one of {', '.join(TORQUE_SAMPLING)}, got {torque!r}")
    x_cmd = np.ascontiguousarray(x_cmd, dtype=float)
    if x_cmd.ndim != 1 or x_cmd.size < 2:
        raise ValueError("x_cmd: expected a 1-D array of at least 2 samples")
    n_sub = ctrl.substeps
    record_every = n_sub if record_every is None else int(record_every)
    if record_every < 1 or n_sub % record_every and record_every % n_sub:
        raise ValueError(f"record_every must divide or be a multiple of {n_sub} velocity steps per tick")
    cmd = np.append(x_cmd, x_cmd[-1])
    K = x_cmd.size
    steps = K * n_sub
    n_rec = (steps + record_every - 1) // record_every
    n = plant.n
    disc = plant.chain.discretize(ctrl.velocity_period, inputs="all")
    state0 = np.zeros(2 * n)
    state0[:n] = x_cmd[0] if x0 is None else x0
    X, V = np.zeros((n_rec, n)), np.zeros((n_rec, n))
    U, XM, XT, XC = (np.zeros(n_rec) for _ in range(4))
    terms = loop_terms(plant, ctrl)
    codes, params = terms.codes, terms.params
    inputs = {}
    if u_add is not None or open_loop:
        inputs["u_add"] = _held(np.zeros(1) if u_add is None else u_add, steps)
        inputs["open_loop"] = bool(open_loop)
    if f_ext is not None:
        fe = np.asarray(f_ext, float)
        if fe.ndim != 2 or fe.shape[1] != n:
            raise ValueError(f"f_ext: expected one row of {n} forces per velocity period")
        inputs["f_ext"] = np.ascontiguousarray(fe[np.minimum(np.arange(steps), fe.shape[0] - 1)])
        if codes is None:            # external forces take the effects' force path
            codes, params = np.zeros(0, np.int64), np.zeros((0, params.shape[1]))
    closed_loop_kernel(disc.A, disc.B, state0, ctrl.as_array(), plant.force_gain, cmd, n_sub,
                       plant.table, plant.tip, ctrl.position_feedback == "motor",
                       plant.friction.as_tuple(), plant.table_resolution, plant.motor_resolution,
                       codes, params, terms.delay, terms.delay_buffer(), terms.lag_alpha, record_every,
                       X, V, U, XM, XT, XC, hbuf=terms.feedback_buffer(), fb_delay=terms.feedback_delay,
                       log_command=torque == "command", **inputs)
    t = np.arange(n_rec) * record_every * ctrl.velocity_period
    if v_cmd is None:
        # the interpolator's velocity for the coming period, held like the command
        vk = np.diff(cmd) / ctrl.position_period
        v_rec = vk[np.minimum((np.arange(n_rec) * record_every) // n_sub, K - 1)]
    else:
        v_rec = np.asarray(v_cmd, float)[np.minimum((np.arange(n_rec) * record_every) // n_sub, K - 1)]
    return SimulationResult(t=t, x_cmd=XC, v_cmd=v_rec, x=X, v=V, u=U, x_motor=XM, x_table=XT,
                            x_tip=X[:, plant.tip].copy() if plant.tip != plant.table else XT.copy(),
                            rotary=plant.pitch is not None,
                            meta={"force_gain": plant.force_gain, "record_period": record_every * ctrl.velocity_period})


def _held(y, steps: int) -> np.ndarray:
    """``y`` on ``steps`` velocity periods, its last value held past its end."""
    y = np.asarray(y, float).reshape(-1)
    return np.ascontiguousarray(y[np.minimum(np.arange(steps), y.size - 1)])


def per_velocity_period(t_samples, y, t0: float, velocity_period: float, steps: int) -> np.ndarray:
    """A recorded input (samples ``y`` at times ``t_samples``) on the loop's clock: the value of
    velocity period j (starting at t0 + j Tv) is the last sample taken at or before its start, as
    a drive holds the command it was sent (zero-order hold; the first sample before the record)."""
    t_samples = np.asarray(t_samples, float)
    tj = t0 + np.arange(steps) * velocity_period
    # a relative tolerance: sample instants that fall on a period's start belong to it
    idx = np.searchsorted(t_samples, tj + 1e-9 * velocity_period, side="right") - 1
    return np.ascontiguousarray(np.asarray(y, float)[np.clip(idx, 0, t_samples.size - 1)])


def external_forces(plant, t_samples, channels, velocity_period: float, steps: int) -> np.ndarray | None:
    """The measured external forces of ``channels`` (``f_ext_table``, ``f_ext_tip``: samples at
    ``t_samples``, N) on the loop's clock, one column per mass of the plant (its table and tip
    masses); None where the record has neither."""
    if "f_ext_table" not in channels and "f_ext_tip" not in channels:
        return None
    t_samples = np.asarray(t_samples, float)
    fe = np.zeros((steps, plant.n))
    for c, mass in (("f_ext_table", plant.table), ("f_ext_tip", plant.tip)):
        if c in channels:
            fe[:, mass] += per_velocity_period(t_samples, channels[c], t_samples[0], velocity_period, steps)
    return fe


def simulate_config(cfg, x_cmd, **kw) -> SimulationResult:
    """:func:`simulate` for a validated configuration."""
    plant = plant_from_config(cfg)
    return simulate(plant, controller_from_config(cfg, plant), x_cmd, **kw)
