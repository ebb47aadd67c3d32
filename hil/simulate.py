"""The closed loop on the simulated plant, compiled: position loop every Tp, velocity loop every
Tv, the plant advanced by its exact zero-order-hold discretization over each Tv.

The control law is hil.control's (the same functions the real-time loop calls); plant forces
(dry friction, effects) are sim_plant.kernel's. :func:`simulate` returns a
:class:`SimulationResult`, a plain data object (plotting lives in hil.plots).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from sim_plant.kernel import effect_forces, empty_effects, friction_force
from sim_plant.plant import Plant

from hil.control import (ControllerSettings, controller_from_config, measured_speed, new_velocity_state, pi_law,
                      position_law, quantize, velocity_law)
from hil.plant_config import plant_from_config

__all__ = ["SimulationResult", "simulate", "simulate_config", "closed_loop_kernel", "plant_step", "drive_steps", "coast_steps"]


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


@njit(cache=True, inline="always")
def plant_step(Ad, Bd, x, f_drive, fric, dry, codes, eparams, f, x_new):
    """Advance the plant state ``x`` in place over one step: x+ = Ad x + Bd f, where f holds the
    drive force on mass 1, the effects' forces and the dry friction on the motor (which needs the
    free motion of the step to decide between sticking and sliding).

    Written for speed (this is the simulator's inner loop): one pass over Ad, the friction decided
    from mass 1's free velocity alone, the other force columns only when effects exist."""
    nn = Ad.shape[0]
    n = nn // 2
    f0 = f_drive
    effects = codes is not None        # None (no effects): numba compiles the branch away
    if effects:
        for i in range(n):
            f[i] = 0.0
        effect_forces(codes, eparams, x[:n], x[n:], f)
        f[0] += f_drive
        f0 = f[0]
    stuck = False
    if dry:
        v_free = Bd[n, 0] * f0
        for c in range(nn):
            v_free += Ad[n, c] * x[c]
        if effects:
            for c in range(1, n):
                v_free += Bd[n, c] * f[c]
        ff, stuck = friction_force(fric, x[n], v_free, Bd[n, 0])
        f0 += ff
    for r in range(nn):
        acc = Bd[r, 0] * f0
        for c in range(nn):
            acc += Ad[r, c] * x[c]
        x_new[r] = acc
    if effects:
        for r in range(nn):
            for c in range(1, n):
                x_new[r] += Bd[r, c] * f[c]
    for r in range(nn):
        x[r] = x_new[r]
    if stuck:
        x[n] = 0.0       # exactly at rest, not a round-off away from it


@njit(cache=True)
def drive_steps(Ad, Bd, x, s, p, w_ref, steps, res_motor, lag_alpha, u_act, fgain, fric, dry, codes, eparams,
                f, x_new):
    """``steps`` velocity-loop steps of a drive that closes the velocity loop itself (the simulated
    plant standing in for a drive in velocity or position mode): returns the last output and the
    current loop's state. The same law and plant step as the closed-loop kernel."""
    n = Ad.shape[0] // 2
    u = 0.0
    for _ in range(steps):
        w = measured_speed(p, s, x[n], quantize(x[0], res_motor))
        u = velocity_law(p, s, w_ref, w, 0.0)
        u_act += lag_alpha * (u - u_act)
        plant_step(Ad, Bd, x, u_act * fgain, fric, dry, codes, eparams, f, x_new)
    return u, u_act


@njit(cache=True)
def coast_steps(Ad, Bd, x, steps, lag_alpha, u_act, fgain, fric, dry, codes, eparams, f, x_new):
    """``steps`` plant steps with no torque commanded (a disabled drive): the current decays
    through the current loop's lag, the plant coasts. Returns the current loop's state."""
    for _ in range(steps):
        u_act += lag_alpha * (0.0 - u_act)
        plant_step(Ad, Bd, x, u_act * fgain, fric, dry, codes, eparams, f, x_new)
    return u_act


@njit(cache=True)
def closed_loop_kernel(Ad, Bd, x0, p, fgain, x_cmd, n_sub, table, tip, fb_motor, fric, res_table, res_motor,
                       codes, eparams, delay, ubuf, lag_alpha, record_every,
                       X, V, U, XM, XT, XCMD):
    """Run len(x_cmd) - 1 position ticks. Records every ``record_every`` velocity steps into the
    output arrays (positions, velocities, output, measured motor and table, command).

    ``delay``: computation delay of the output in velocity periods (float: a transport delay
    of the plant adds a fraction, interpolated linearly between the held outputs)."""
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
    w_ref = 0.0
    a_cmd = 0.0
    for k in range(K):
        # --- position loop, tick k ---
        xm = quantize(x[0], res_motor)
        xt = quantize(x[table], res_table)
        xfb = xm if fb_motor else xt
        w_ref = position_law(p, x_cmd[k], x_cmd[k + 1], xfb)
        if k > 0:
            a_cmd = (x_cmd[k + 1] - 2.0 * x_cmd[k] + x_cmd[k - 1]) / (tp * tp)
        else:
            a_cmd = (x_cmd[k + 1] - x_cmd[k]) / (tp * tp)
        ff = acc_ff * a_cmd
        for j in range(n_sub):
            # --- velocity loop ---
            if speed_from_position:
                w_meas = measured_speed(p, s, x[n], quantize(x[0], res_motor))
            else:
                w_meas = x[n] * speed_scale
            u, integral, saturated = pi_law(kp, ti, tv, limit, integral, saturated, w_ref, w_meas, ff)
            # computation delay, then the current loop (ideal, or a first-order lag)
            if ubuf is not None:       # None (no delay): compiled away
                for i in range(d_int + 1, 0, -1):
                    ubuf[i] = ubuf[i - 1]
                ubuf[0] = u
                u = (1.0 - d_frac) * ubuf[d_int] + d_frac * ubuf[d_int + 1]
            u_act += lag_alpha * (u - u_act)
            countdown -= 1
            if countdown == 0:
                countdown = record_every
                for i in range(n):
                    X[rec, i] = x[i]
                    V[rec, i] = x[n + i]
                U[rec] = u_act
                XM[rec] = quantize(x[0], res_motor)
                XT[rec] = quantize(x[table], res_table)
                # between ticks the command is interpolated, as the NC's fine interpolation would
                XCMD[rec] = x_cmd[k] + (x_cmd[k + 1] - x_cmd[k]) * j / n_sub
                rec += 1
            # --- plant over one Tv ---
            plant_step(Ad, Bd, x, u_act * fgain, fric, dry, codes, eparams, f, x_new)
    return rec


def simulate(plant: Plant, ctrl: ControllerSettings, x_cmd, *, record_every: int | None = None,
             x0: float | None = None, v_cmd=None) -> SimulationResult:
    """Closed-loop response to the command ``x_cmd`` sampled on the position clock.

    ``x_cmd[k]`` is the command at tick k; the loop runs ``len(x_cmd)`` ticks (the command is
    held after the last sample, which the feed-forward of the last tick needs). The plant starts
    at rest at ``x0`` (default ``x_cmd[0]``). ``record_every``: velocity steps per recorded
    sample (default: one per position tick)."""
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
    codes, eparams = _effect_table(plant)
    # transport delays of the plant (sim_plant.kernel.TIME_DELAY rows) join the output delay
    from sim_plant.kernel import TIME_DELAY
    delay = float(ctrl.output_delay) + float(sum(q[0] for c, q in plant.effects if c == TIME_DELAY)) / ctrl.velocity_period
    lag = _lag_alpha(plant, ctrl)
    ubuf = np.zeros(int(math.floor(delay)) + 2) if delay > 0.0 else None
    closed_loop_kernel(disc.A, disc.B, state0, ctrl.as_array(), plant.force_gain, cmd, n_sub,
                       plant.table, plant.tip, ctrl.position_feedback == "motor",
                       plant.friction.as_tuple(), plant.table_resolution, plant.motor_resolution,
                       codes, eparams, delay, ubuf, lag, record_every, X, V, U, XM, XT, XC)
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


def _effect_table(plant: Plant):
    """The effects' kernel terms: (codes, params), or (None, params) when there are none, so that
    the compiled loop is specialised without the effect branch (it is the simulator's hot path)."""
    if not plant.effects:
        return None, empty_effects()[1]
    codes = np.array([c for c, _ in plant.effects], np.int64)
    from sim_plant.kernel import N_EFFECT_PARAMS
    params = np.zeros((len(plant.effects), N_EFFECT_PARAMS))
    for i, (_, q) in enumerate(plant.effects):
        params[i, :len(q)] = q
    return codes, params


def _lag_alpha(plant: Plant, ctrl: ControllerSettings) -> float:
    tc = plant.current_loop_time_constant
    return 1.0 if tc <= 0 else float(1.0 - np.exp(-ctrl.velocity_period / tc))


def simulate_config(cfg, x_cmd, **kw) -> SimulationResult:
    """:func:`simulate` for a validated configuration."""
    plant = plant_from_config(cfg)
    return simulate(plant, controller_from_config(cfg, plant), x_cmd, **kw)
