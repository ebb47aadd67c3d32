"""The embedded simulated plant as a backend (the default): the sim_plant model advanced by its
exact zero-order-hold discretization, one cycle per :meth:`sync`.

It can stand in for a drive in any of the three loop arrangements: ``closes = "none"`` (the host
sends torque every velocity period, as a drive in torque mode), ``"velocity"`` (the host sends a
speed every position period and this backend runs the velocity loop, as a drive in velocity
mode) or ``"both"`` (the host sends positions, as cyclic synchronous position mode). The loops it
closes are drivers.control's functions: the same law everywhere.

The terms between the law and the plant are drivers.control's :func:`~drivers.control.loop_terms`, as in
the compiled loop: the output delay (in torque mode the host's loop applies the controller's
output delay and this backend the plant's transport delay), the current loop's lag and the
effect table.

For dry runs the runtime (hil.runtime) sends a whole command through the compiled loop
(hil.simulate) on this backend's plant and controller, at once.
"""
from __future__ import annotations

import copy
from contextlib import contextmanager

import numpy as np
from numba import njit

from drivers.base import LOOPS, Backend, Fault, Feedback, Setpoint
from drivers.control import (
    T,
    controller_from_config,
    encoders,
    feedback_position,
    feedback_reading,
    history_push,
    history_read,
    loop_terms,
    motor_feedback,
    new_velocity_state,
    plant_cycle,
    plant_period,
    position_law,
    quantize,
    speed_feedback,
    terms_of,
    velocity_law,
)
from sim_plant.kernel import njit_cycle

_NAN = float("nan")

__all__ = ["SimulatedPlant"]


@njit_cycle
def drive_cycle(Ad, Bd, fric, codes, eparams, terms, p, s, speed_filter, x, f, x_new, ubuf, hbuf, w_ref,
                u_act, enc=None):
    """One position period of a drive that closes the velocity loop itself (the simulated plant
    standing in for a drive in velocity or position mode; real-time): the velocity law on the
    speed reference ``w_ref``, then the command and the plant (drivers.control's stages), every
    velocity period. Returns the current loop's output ``u_act``."""
    t = terms_of(terms)
    for _ in range(int(t.substeps)):
        xm, v_motor = motor_feedback(p, t, x, enc)
        w = speed_feedback(p, s, speed_filter, v_motor, xm)
        u = velocity_law(p, s, w_ref, w, 0.0)
        u_act = plant_cycle(Ad, Bd, fric, codes, eparams, t, x, f, x_new, ubuf, hbuf, u, u_act, enc)
    return u_act


@njit_cycle
def coast_cycle(Ad, Bd, fric, codes, eparams, terms, x, f, x_new, hbuf, u_act, steps, enc=None):
    """``steps`` plant periods with no torque commanded (a disabled drive; real-time): the current
    decays through the current loop's lag, the plant coasts (the feedback history goes on).
    Returns the current loop's output."""
    t = terms_of(terms)
    for _ in range(steps):
        u_act = u_act + t.lag_alpha * (0.0 - u_act)
        plant_period(Ad, Bd, fric, codes, eparams, t, x, f, x_new, hbuf, u_act, None, enc=enc)
    return u_act


@njit_cycle
def torque_cycle(Ad, Bd, fric, codes, eparams, terms, x, f, x_new, ubuf, hbuf, u, u_act, enc=None):
    """One velocity period under the output ``u`` (a drive in torque mode; real-time):
    drivers.control's :func:`~drivers.control.plant_cycle`. Returns the current loop's output."""
    return plant_cycle(Ad, Bd, fric, codes, eparams, terms_of(terms), x, f, x_new, ubuf, hbuf, u, u_act, enc)


@njit(cache=True)
def drive_feedback(terms, enc, x, hbuf):
    """The position a drive's position loop closes on (real-time): drivers.control's
    :func:`~drivers.control.feedback_position`."""
    return feedback_position(terms_of(terms), x, hbuf, enc)


@njit(cache=True)
def encoder_feedback(terms, enc, p, x):
    """The encoders as they read and the motor's speed as the drive derives it (real-time; a plant
    with an encoder's interpolation error): drivers.control's :func:`~drivers.control.encoders` and
    :func:`~drivers.control.motor_feedback`."""
    t = terms_of(terms)
    xm, xt = encoders(t, x, enc)
    return xm, xt, motor_feedback(p, t, x, enc)[1]


@njit(cache=True)
def pushed_feedback(terms, enc, x):
    """The feedback encoder's reading that goes into the feedback delay's history (real-time):
    drivers.control's :func:`~drivers.control.feedback_reading`."""
    return feedback_reading(terms_of(terms), x, enc)


class SimulatedPlant(Backend):
    """The embedded plant as a backend (the module docstring). Real-time: :meth:`read_feedback`,
    :meth:`write_setpoint`, :meth:`sync`, :meth:`advance`, :meth:`quick_stop`; the rest is not."""
    name = "sim"
    simulated = True
    takes_plant = "required"      # hil.backends.open_backend hands it the configuration's plant

    def __init__(self, cfg, plant, closes: str = "none"):
        """``cfg``: the configuration (the controller's keys); ``plant``: the
        :class:`sim_plant.plant.Plant` to simulate (``hil.plant_config.plant_from_config(cfg)``)."""
        if closes not in LOOPS:
            raise ValueError(f"closes must be one of {LOOPS}, got {closes!r}")
        self.cfg = cfg
        self.plant = plant
        self.ctrl = controller_from_config(cfg, self.plant)
        self.closes = closes
        self.cycle_time = self.ctrl.velocity_period if closes == "none" else self.ctrl.position_period
        self._p = self.ctrl.as_array()
        self._speed_filter = self.ctrl.speed_filter()
        disc = self.plant.chain.discretize(self.ctrl.velocity_period, inputs="all")
        # in torque mode the host's loop delays its output itself (hil.loop); the plant's transport delay is ours
        self.terms = loop_terms(self.plant, self.ctrl, with_output_delay=closes != "none")
        # the plant as drivers.control's stages take it: matrices, friction, effect table, loop terms
        self._model = (disc.A, disc.B, self.plant.friction.as_tuple(), self.terms.codes, self.terms.params,
                       self.terms.array)
        self._ubuf = self.terms.output_buffer()
        self._hbuf = self.terms.feedback_history()     # the position loop's feedback history (a feedback delay)
        # an encoder's interpolation error (sim_plant.effects.encoder): the readings go through the stages
        self._enc = self.terms.enc
        self._reads_wrong = self._enc is not None
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
        self._fb = Feedback(0.0, 0.0, 0.0)     # this backend's one Feedback, updated in place (drivers.base)
        self._push_feedback()

    # -- contract -------------------------------------------------------------------------------
    def open(self) -> None:
        self.time = 0.0

    def home_at(self, position: float) -> None:
        """Put the plant at rest at ``position`` (the simulated axis starts where it is told; not
        real-time)."""
        n = self.plant.n
        self.x[:] = 0.0
        self.x[:n] = position
        self._s = new_velocity_state()
        self._prev_position = position
        self._ubuf = self.terms.output_buffer()
        self._hbuf = self.terms.feedback_history()
        self._push_feedback()

    def start_at(self, position: float) -> None:
        """The contract's start of a run: :meth:`home_at` (not real-time)."""
        self.home_at(position)

    def dry_run_model(self):
        """In torque mode, the plant and the controller: the runtime computes the whole run at
        once through the compiled loop, the same cycle (not real-time)."""
        return (self.plant, self.ctrl) if self.closes == "none" else None

    @property
    def settings(self) -> np.ndarray:
        """The controller's settings array (drivers.control.P) of the loops this backend closes."""
        return self._p

    def _push_feedback(self) -> None:
        if self.terms.array[T.FEEDBACK_LATE] != 0.0:
            if self._reads_wrong:
                history_push(self._hbuf, pushed_feedback(self.terms.array, self._enc, self.x))
            else:
                history_push(self._hbuf, quantize(self.x[int(self.terms.array[T.FEEDBACK_MASS])],
                                                  self.terms.array[T.FEEDBACK_RES]))

    def _late_feedback(self) -> float:
        """The position the position loop receives (the feedback delay's history), NaN without one."""
        t = self.terms.array
        if t[T.FEEDBACK_LATE] == 0.0:
            return _NAN
        return float(history_read(self._hbuf, int(t[T.FEEDBACK_INT]), t[T.FEEDBACK_FRAC]))

    @property
    def enabled(self) -> bool:
        return self._enabled

    @enabled.setter
    def enabled(self, on: bool) -> None:
        if on and not self._enabled:       # switched on: nothing commanded is in transit yet
            self._ubuf = self.terms.output_buffer()
        self._enabled = bool(on)

    def enable(self) -> None:
        self.enabled = True

    def read_feedback(self) -> Feedback:
        """This cycle's encoders, speed and current (real-time: the backend's Feedback, in place)."""
        n, pl, fb = self.plant.n, self.plant, self._fb
        if self._reads_wrong:          # an encoder's interpolation error: the stages' readings
            xm, xt, vm = encoder_feedback(self.terms.array, self._enc, self._p, self.x)
            fb.x_motor, fb.x_table, fb.v_motor = float(xm), float(xt), float(vm)
        else:
            fb.x_motor = float(quantize(self.x[0], pl.motor_resolution))
            fb.x_table = float(quantize(self.x[pl.table], pl.table_resolution))
            fb.v_motor = float(self.x[n])
        fb.output = float(self._u_act)
        fb.x_tip = float(self.x[pl.tip]) if pl.tip != pl.table else _NAN
        fb.x_feedback = self._late_feedback()
        # a caller may have marked the last one (a test's stand-in for a faulty drive): a plant is well
        fb.fault, fb.reason, fb.stale = Fault.NONE, "", False
        return fb

    def write_setpoint(self, setpoint: Setpoint) -> None:
        """This cycle's setpoint, used by :meth:`sync` (real-time)."""
        self._set = setpoint

    def sync(self) -> None:
        """Advance one cycle (real-time)."""
        if not self.enabled:          # no torque: the plant coasts (friction and effects still act)
            steps = 1 if self.closes == "none" else self.ctrl.substeps
            self._u_act = coast_cycle(*self._model, self.x, self._f, self._xn, self._hbuf, self._u_act, steps, self._enc)
            self.time += steps * self.ctrl.velocity_period
            return
        if self.closes == "none":
            self.advance(self._set.output)
            return
        if self.closes == "both":
            prev = self._prev_position if self._prev_position is not None else self._set.position
            xfb = drive_feedback(self.terms.array, self._enc, self.x, self._hbuf)
            # the drive's interpolation: the setpoint is where to be at the next tick
            w_ref = position_law(self._p, prev, self._set.position, xfb)
            self._prev_position = self._set.position
        else:
            w_ref = self._set.speed
        self._u_act = drive_cycle(*self._model, self._p, self._s, self._speed_filter, self.x, self._f, self._xn,
                                  self._ubuf, self._hbuf, w_ref, self._u_act, self._enc)
        self.time += self.ctrl.position_period

    def advance(self, u: float) -> None:
        """One velocity period under the output ``u`` (torque or command): the plant's transport
        delay, the current loop and the plant (real-time)."""
        self._u_act = torque_cycle(*self._model, self.x, self._f, self._xn, self._ubuf, self._hbuf, u, self._u_act,
                                   self._enc)
        self.time += self.ctrl.velocity_period

    _step = advance          # the name the drive simulators call (drivers.canopen, serial)

    def disable(self) -> None:
        self.enabled = False

    def close(self) -> None:
        self.enabled = False

    # the state a cycle changes (restored): the plant's, its loops', its buffers', its clock
    _CYCLE_STATE = ("x", "_xn", "_f", "_s", "_ubuf", "_hbuf", "_u_act", "time", "_prev_position", "_set", "_enabled")

    @contextmanager
    def restored(self):
        """Within it, cycles may run (a warm-up); after it, the state is as it was: the same array
        objects with the contents they had, and the other values (not real-time)."""
        kept = {k: (v, copy.deepcopy(v)) for k, v in vars(self).items() if k in self._CYCLE_STATE}
        try:
            yield self
        finally:
            for k, (obj, contents) in kept.items():
                if isinstance(obj, np.ndarray):
                    obj[...] = contents
                setattr(self, k, obj if isinstance(obj, np.ndarray) else contents)

    def warm_up(self) -> None:
        """Load every compiled function a cycle of this backend calls (enabled, disabled and
        stepped by a drive simulator, and the feedback it reads), the state :meth:`restored` (not
        real-time). A drive simulator calls it before it serves: a function first called in its
        cycle is compiled or loaded there, seconds on a fresh install, and the drive neither
        answers nor greets a client meanwhile."""
        with self.restored():
            self.read_feedback()
            self.enabled = False
            self.sync()                           # coasting
            self.enabled = True
            self.write_setpoint(Setpoint(position=float(self.x[0]), speed=0.0, output=0.0))
            self.sync()
            self.advance(0.0)                     # a drive's own loop (its quick stop) steps the output
            self.read_feedback()

    # -- for a drive simulator that runs this plant as its shaft (drivers.canopen.drive_sim,
    #    drivers.serial.drive_sim): its own stop ramp, a change of mode, a fresh enable -------
    @property
    def law_params(self) -> np.ndarray:
        """The controller's parameters as drivers.control's laws take them (read only)."""
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
