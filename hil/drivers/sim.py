"""The embedded simulated plant as a backend (the default): the hil.sim_plant model advanced by its
exact zero-order-hold discretization, one cycle per :meth:`sync`.

It can stand in for a drive in any of the three loop arrangements: ``closes = "none"`` (the host
sends torque every velocity period, as a drive in torque mode), ``"velocity"`` (the host sends a
speed every position period and this backend runs the velocity loop, as a drive in velocity
mode) or ``"both"`` (the host sends positions, as cyclic synchronous position mode). The loops it
closes are hil.control's functions: the same law everywhere.

The terms between the law and the plant are hil.control's :func:`~hil.control.loop_terms`, as in
the compiled loop: the output delay (in torque mode the host's loop applies the controller's
output delay and this backend the plant's transport delay), the current loop's lag and the
effect table.

For dry runs the runtime (hil.runtime) sends a whole command through the compiled loop
(hil.simulate) on this backend's plant and controller, at once.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from hil.control import (
    controller_from_config,
    delay_line,
    history_push,
    history_read,
    loop_terms,
    measured_speed,
    new_velocity_state,
    position_law,
    quantize,
    velocity_law,
)
from hil.drivers.base import LOOPS, Backend, Feedback, Setpoint
from hil.plant_config import plant_from_config
from hil.sim_plant.kernel import plant_step

__all__ = ["SimulatedPlant"]


@njit(cache=True)
def drive_steps(Ad, Bd, x, s, p, w_ref, steps, res_motor, ubuf, d_int, d_frac, lag_alpha, u_act, fgain, fric, dry,
                codes, eparams, f, x_new, hbuf=None, fb_mass=0, fb_res=0.0):
    """``steps`` velocity-loop steps of a drive that closes the velocity loop itself (the simulated
    plant standing in for a drive in velocity or position mode): returns the current loop's
    state. The same law, delay line and plant step as the closed-loop kernel; ``hbuf``: the
    history of the position loop's feedback (mass ``fb_mass`` read at ``fb_res``), or None."""
    n = Ad.shape[0] // 2
    for _ in range(steps):
        w = measured_speed(p, s, x[n], quantize(x[0], res_motor))
        u = velocity_law(p, s, w_ref, w, 0.0)
        if ubuf is not None:       # None (no delay): compiled away
            u = delay_line(ubuf, u, d_int, d_frac)
        u_act += lag_alpha * (u - u_act)
        plant_step(Ad, Bd, x, u_act * fgain, fric, dry, codes, eparams, f, x_new)
        if hbuf is not None:
            history_push(hbuf, quantize(x[fb_mass], fb_res))
    return u_act


@njit(cache=True)
def coast_steps(Ad, Bd, x, steps, lag_alpha, u_act, fgain, fric, dry, codes, eparams, f, x_new, hbuf=None,
                fb_mass=0, fb_res=0.0):
    """``steps`` plant steps with no torque commanded (a disabled drive): the current decays
    through the current loop's lag, the plant coasts (the feedback history, ``hbuf``, goes on).
    Returns the current loop's state."""
    for _ in range(steps):
        u_act += lag_alpha * (0.0 - u_act)
        plant_step(Ad, Bd, x, u_act * fgain, fric, dry, codes, eparams, f, x_new)
        if hbuf is not None:
            history_push(hbuf, quantize(x[fb_mass], fb_res))
    return u_act


class SimulatedPlant(Backend):
    name = "sim"
    simulated = True

    def __init__(self, cfg, closes: str = "none"):
        if closes not in LOOPS:
            raise ValueError(f"closes must be one of {LOOPS}, got {closes!r}")
        self.cfg = cfg
        self.plant = plant_from_config(cfg)
        self.ctrl = controller_from_config(cfg, self.plant)
        self.closes = closes
        self.cycle_time = self.ctrl.velocity_period if closes == "none" else self.ctrl.position_period
        self._p = self.ctrl.as_array()
        disc = self.plant.chain.discretize(self.ctrl.velocity_period, inputs="all")
        self._Ad, self._Bd = disc.A, disc.B
        # in torque mode the host's loop delays its output itself (hil.loop); the plant's transport delay is ours
        self.terms = loop_terms(self.plant, self.ctrl, with_output_delay=closes != "none")
        self._ubuf = self.terms.delay_buffer()
        # the position loop's feedback history (a feedback delay of the plant), or None
        motor_fb = self.ctrl.position_feedback == "motor"
        self._fb_mass = 0 if motor_fb else self.plant.table
        self._fb_res = self.plant.motor_resolution if motor_fb else self.plant.table_resolution
        self._hbuf = self.terms.feedback_buffer()
        self._fparts = self.terms.feedback_parts
        self._fric = self.plant.friction.as_tuple()
        self._dry = self.plant.friction.active
        n = self.plant.n
        self.x = np.zeros(2 * n)
        self._xn = np.zeros(2 * n)
        self._f = np.zeros(n)
        self._s = new_velocity_state()
        self._set = Setpoint()
        self._prev_position = None
        self._enabled = False
        self.time = 0.0
        self._u_act = 0.0
        self._push_feedback()

    # -- contract -------------------------------------------------------------------------------
    def open(self) -> None:
        self.time = 0.0

    def home_at(self, position: float) -> None:
        """Put the plant at rest at ``position`` (the simulated axis starts where it is told)."""
        n = self.plant.n
        self.x[:] = 0.0
        self.x[:n] = position
        self._s = new_velocity_state()
        self._prev_position = position
        self._ubuf = self.terms.delay_buffer()
        self._hbuf = self.terms.feedback_buffer()
        self._push_feedback()

    def _push_feedback(self) -> None:
        if self._hbuf is not None:
            history_push(self._hbuf, quantize(self.x[self._fb_mass], self._fb_res))

    def _late_feedback(self) -> float:
        """The position the position loop receives (the feedback delay's history), NaN without one."""
        return float(history_read(self._hbuf, *self._fparts)) if self._hbuf is not None else float("nan")

    @property
    def enabled(self) -> bool:
        return self._enabled

    @enabled.setter
    def enabled(self, on: bool) -> None:
        if on and not self._enabled:       # switched on: nothing commanded is in transit yet
            self._ubuf = self.terms.delay_buffer()
        self._enabled = bool(on)

    def enable(self) -> None:
        self.enabled = True

    def read_feedback(self) -> Feedback:
        n, pl = self.plant.n, self.plant
        return Feedback(x_motor=float(quantize(self.x[0], pl.motor_resolution)),
                        x_table=float(quantize(self.x[pl.table], pl.table_resolution)),
                        v_motor=float(self.x[n]), output=float(self._u_act),
                        x_tip=float(self.x[pl.tip]) if pl.tip != pl.table else float("nan"),
                        x_feedback=self._late_feedback())

    def write_setpoint(self, setpoint: Setpoint) -> None:
        self._set = setpoint

    def sync(self) -> None:
        """Advance one cycle."""
        pl, terms = self.plant, self.terms
        if not self.enabled:          # no torque: the plant coasts (friction and effects still act)
            steps = 1 if self.closes == "none" else self.ctrl.substeps
            self._u_act = coast_steps(self._Ad, self._Bd, self.x, steps, terms.lag_alpha, self._u_act, pl.force_gain,
                                      self._fric, self._dry, terms.codes, terms.params, self._f, self._xn,
                                      self._hbuf, self._fb_mass, self._fb_res)
            self.time += steps * self.ctrl.velocity_period
            return
        if self.closes == "none":
            self._step(self._set.output)
        else:
            if self.closes == "both":
                prev = self._prev_position if self._prev_position is not None else self._set.position
                xfb = quantize(self.x[0], pl.motor_resolution) if self.ctrl.position_feedback == "motor" \
                    else quantize(self.x[pl.table], pl.table_resolution)
                if self._hbuf is not None:         # the feedback arrives late
                    xfb = self._late_feedback()
                # the drive's interpolation: the setpoint is where to be at the next tick
                w_ref = position_law(self._p, prev, self._set.position, xfb)
                self._prev_position = self._set.position
            else:
                w_ref = self._set.speed
            d_int, d_frac = terms.delay_parts
            self._u_act = drive_steps(self._Ad, self._Bd, self.x, self._s, self._p, w_ref, self.ctrl.substeps,
                                      pl.motor_resolution, self._ubuf, d_int, d_frac, terms.lag_alpha, self._u_act,
                                      pl.force_gain, self._fric, self._dry, terms.codes, terms.params, self._f,
                                      self._xn, self._hbuf, self._fb_mass, self._fb_res)
            self.time += self.ctrl.position_period

    def _step(self, u: float) -> None:
        terms = self.terms
        if self._ubuf is not None:     # the plant's transport delay
            u = delay_line(self._ubuf, u, *terms.delay_parts)
        self._u_act += terms.lag_alpha * (u - self._u_act)      # current loop: ideal, or a first-order lag
        plant_step(self._Ad, self._Bd, self.x, self._u_act * self.plant.force_gain, self._fric, self._dry,
                   terms.codes, terms.params, self._f, self._xn)
        self._push_feedback()
        self.time += self.ctrl.velocity_period

    def disable(self) -> None:
        self.enabled = False

    def close(self) -> None:
        self.enabled = False

    # -- for a drive simulator that runs this plant as its shaft (hil.drivers.canopen.drive_sim,
    #    hil.drivers.serial.drive_sim): its own stop ramp, a change of mode, a fresh enable -------
    @property
    def law_params(self) -> np.ndarray:
        """The controller's parameters as hil.control's laws take them (read only)."""
        return self._p

    @property
    def output_actual(self) -> float:
        """The torque (or output) the current loop delivers now."""
        return self._u_act

    def step_output(self, u: float) -> None:
        """One velocity period with the output ``u`` commanded (the drive's own loop computed it;
        real-time)."""
        self._step(u)

    def restart_interpolation(self) -> None:
        """The next position setpoint starts the interpolation afresh (a fresh enable)."""
        self._prev_position = None

    def restart_velocity_loop(self) -> None:
        """The velocity loop's integral and speed filter start from zero."""
        self._s = new_velocity_state()

    def clear_output(self) -> None:
        """No current flows and no setpoint is pending (after a warm-up run)."""
        self._u_act = 0.0
        self._set = Setpoint()

    def take_over(self, other: "SimulatedPlant") -> None:
        """Continue ``other``'s motion (a drive that changed its mode of operation): its state, its
        current, its position as the last setpoint."""
        self.x[:] = other.x
        self._u_act = other._u_act
        self._prev_position = other.x[0]
