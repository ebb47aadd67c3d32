"""The closed loop on the simulated plant, compiled: position loop every Tp, velocity loop every
Tv, the plant advanced by its exact zero-order-hold discretization over each Tv.

The cycle is drivers.control's, stage by stage (the same functions the real-time loop and the
simulated backend call), and so are the terms between the law and the plant (delays, current-loop
lag, effect table: :func:`drivers.control.loop_terms`); the plant step and its forces (dry friction,
effects) are sim_plant.kernel's. :func:`simulate` returns a
:class:`SimulationResult`, a plain data object (plotting lives in hil.plots). The
frequency-response experiment (hil.frf.run) runs the same compiled loop, :func:`closed_loop_kernel`,
with its excitation, measurement noise and per-period record, which the simulation leaves out.
"""
from __future__ import annotations

import os
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from drivers.control import (
    ControllerSettings,
    P,
    S,
    actuate,
    controller_from_config,
    encoders,
    feedback_position,
    feedback_reading,
    history_push,
    loop_terms,
    motor_feedback,
    new_velocity_state,
    plant_period,
    position_tick,
    speed_feedback,
    terms_of,
    velocity_step,
)
from hil.plant_config import plant_from_config
from sim_plant.kernel import mass_token, njit_cycle, state_size
from sim_plant.plant import Plant

__all__ = ["SimulationResult", "simulate", "simulate_many", "closed_loop_batch", "batch_threads", "simulate_config", "closed_loop_kernel", "Record", "per_velocity_period",
           "external_forces", "TORQUE_SAMPLING"]

# which controller output a record holds: the current after the delay and the current loop, or the command
TORQUE_SAMPLING = ("actual", "command")


@dataclass
class SimulationResult:
    """Channels on the record clock (every position tick unless asked otherwise), SI units.

    ``x``, ``v``: positions and velocities of every mass (true); ``x_motor``, ``x_table``: what the
    encoders read (quantized where the config says so; with an encoder's interpolation error where the
    plant has one, sim_plant.effects.encoder); ``x_tip``: the tool tip (true, or the
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


class Record(NamedTuple):
    """The compiled loop's record, one row every ``record_every`` velocity steps: positions ``x``
    and velocities ``v`` of every mass, the current loop's output ``u``, the encoders as read
    (``x_motor``, ``x_table``) and the command ``x_cmd``."""
    x: np.ndarray
    v: np.ndarray
    u: np.ndarray
    x_motor: np.ndarray
    x_table: np.ndarray
    x_cmd: np.ndarray


@njit(cache=True, nogil=True)
def closed_loop_kernel(Ad, Bd, fric, codes, eparams, terms, p, x0, x_cmd, ubuf, hbuf, rec=None, record_every=1,
                       exc=None, exc_into_speed=False, noise_w=None, noise_x=None, out=None, u_add=None, f_ext=None,
                       open_loop=False, speed_filter=None, log_command=False, masses=None, enc=None):
    """Run len(x_cmd) - 1 position ticks of the cycle of drivers.control, stage by stage, from the
    plant state ``x0`` (not changed). The plant: ``Ad``, ``Bd``, ``fric``, ``codes``, ``eparams``
    (drivers.control's stages); ``terms``: the loop terms (drivers.control.LoopTerms.array); ``p``:
    the settings (:class:`P`); ``ubuf``, ``hbuf``: the output delay's buffer and the feedback's
    history (LoopTerms.delay_buffer, feedback_buffer; None where there is no delay: compiled
    away). ``rec``: a :class:`Record` written every
    ``record_every`` velocity steps, or None.

    The frequency-response experiment (hil.frf) adds, each None where absent (numba then
    compiles it away): ``exc``, one excitation value per velocity period, added to the output
    before its limit (or to the speed reference, ``exc_into_speed``), and then no acceleration
    feed-forward; measurement noise on the motor speed (``noise_w``, one per velocity period)
    and on the motor, table and tip positions (``noise_x``, one row per velocity period); ``out``,
    one row per velocity period with the columns of hil.loop.CYCLE_CHANNELS. The recorded
    positions are the true ones (the feedback delay is the position loop's alone).

    Measured inputs of a record (hil.ident.replay), each None where absent (compiled away):
    ``u_add``, one value per velocity period added to the controller's output after the law (the
    feed-forward stays) and limited with it; ``f_ext``, one row per velocity period of external
    forces on the masses (N; needs ``codes``, an empty table when the plant has no effects).
    ``open_loop``: no position or velocity loop, the output is ``u_add`` alone, not limited (the
    actuator's command measured in an open-loop run). ``speed_filter``: the speed filter's taps
    where the velocity loop reads filtered positions (ControllerSettings.speed_filter; the taps'
    values are in ``p``), None: the motor's speed, the filter compiled away. ``log_command``: the
    recorded output is the controller's output at the sample, before the delay and the current
    loop (a drive that logs its torque command); False: the current after them (a drive that logs
    its measured current). ``masses``: None, or a tuple of one entry per mass
    (sim_plant.kernel.mass_token): the loop compiled for the chain's size, the same numbers.
    ``enc``: the encoders' interpolation errors (LoopTerms.enc), None where they read true
    (compiled away).

    Returns the number of velocity periods in which the excitation drove the output past its
    limit. Not real-time (it allocates its work arrays); its inner loop is the cycle,
    :func:`_cycles`."""
    n = state_size(Ad, masses) // 2
    return _cycles(Ad, Bd, fric, codes, eparams, terms, p, x0.copy(), np.zeros(2 * n), np.zeros(n),
                   new_velocity_state(), x_cmd, ubuf, hbuf, rec, record_every, exc, exc_into_speed, noise_w, noise_x,
                   out, u_add, f_ext, open_loop, speed_filter, log_command, masses, enc)


# without reference counting (sim_plant.kernel.njit_cycle): a plant with effects 140-200 -> 25-45 ns
# per velocity step, the same numbers
@njit_cycle
def _cycles(Ad, Bd, fric, codes, eparams, terms, p, x, x_new, f, s, x_cmd, ubuf, hbuf, rec, record_every, exc,
            exc_into_speed, noise_w, noise_x, out, u_add, f_ext, open_loop, speed_filter, log_command, masses, enc):
    """The cycles of :func:`closed_loop_kernel` (its arguments) on the work arrays ``x`` (the plant's
    state, advanced in place), ``x_new``, ``f`` and the velocity loop's state ``s`` (real-time:
    allocates nothing)."""
    t = terms_of(terms)
    n = state_size(Ad, masses) // 2
    n_sub = int(t.substeps)
    u_act = 0.0
    countdown = 1                  # velocity steps until the next recorded sample
    row = 0
    n_sat = 0
    if hbuf is not None and t.feedback_late != 0.0:  # the axis was at rest before the start
        history_push(hbuf, feedback_reading(t, x, enc))
    for k in range(x_cmd.shape[0] - 1):
        # --- read feedback, profile, position law: tick k ---
        xfb = feedback_position(t, x, hbuf, enc)
        if noise_x is not None:
            xfb += noise_x[k * n_sub, 0 if t.feedback_motor != 0.0 else 1]
        w_ref = position_tick(p, s, x_cmd, k, xfb)
        ff = 0.0 if exc is not None else p[P.ACC_FF] * s[S.A_CMD]
        for j in range(n_sub):
            step = k * n_sub + j
            # --- read feedback, velocity law (and the experiment's inputs) ---
            u, sat = _velocity_period(p, s, t, speed_filter, x, n, step, w_ref, ff, exc, exc_into_speed, noise_w,
                                      noise_x, out, u_add, open_loop, enc)
            n_sat += sat
            # --- write command: the delay, the current loop ---
            u_act = actuate(t, ubuf, u, u_act)
            # --- record ---
            if rec is not None:
                countdown -= 1
                if countdown == 0:
                    countdown = record_every
                    # between ticks the command is interpolated, as the NC's fine interpolation would
                    _record_row(rec, row, t, x, n, u if log_command else u_act,
                                x_cmd[k] + (x_cmd[k + 1] - x_cmd[k]) * j / n_sub, enc)
                    row += 1
            # --- the plant over one Tv ---
            if f_ext is not None:
                plant_period(Ad, Bd, fric, codes, eparams, t, x, f, x_new, hbuf, u_act, f_ext[step], masses, enc)
            else:
                plant_period(Ad, Bd, fric, codes, eparams, t, x, f, x_new, hbuf, u_act, None, masses, enc)
    return n_sat


@njit(cache=True, inline="always")
def _velocity_period(p, s, t, speed_filter, x, n, step, w_ref, ff, exc, exc_into_speed, noise_w, noise_x, out,
                     u_add, open_loop, enc):
    """Read feedback and velocity law of velocity period ``step`` of :func:`closed_loop_kernel` (``n``
    masses), with the experiment's excitation, noise and measured command (each None where absent)
    and its ``out`` row; the encoders read through their interpolation errors ``enc`` (None:
    compiled away). Returns the output and 1 where the excitation drove it past its limit
    (real-time)."""
    r = 0.0
    w_ref_v = w_ref
    if exc is not None:
        r = exc[step]
        w_ref_v = w_ref + (r if exc_into_speed else 0.0)
    # the encoders as read this period (the measured speed of the noisy run is always drivers.control's)
    xm, v_motor = motor_feedback(p, t, x, enc)
    if noise_x is not None:
        xm += noise_x[step, 0]
    if noise_w is not None:
        v_motor = v_motor + noise_w[step]
    w_meas = speed_feedback(p, s, speed_filter, v_motor, xm)
    u_ctrl = 0.0 if open_loop else velocity_step(p, s, w_ref_v, w_meas, ff)
    u = u_ctrl
    sat = 0
    limit = p[P.ULIM]
    if exc is not None:
        # a torque excitation is added to the controller's output and limited with it
        u = u_ctrl + (0.0 if exc_into_speed else r)
        if u > limit or u < -limit:
            u = limit if u > limit else -limit
            sat = 1
    if u_add is not None:
        # a measured command after the controller (EMPS's pulses), limited with the output
        u = u + u_add[step]
        if not open_loop and (u > limit or u < -limit):
            u = limit if u > limit else -limit
    if out is not None:
        xt_out = encoders(t, x, enc)[1] + (noise_x[step, 1] if noise_x is not None else 0.0)
        tip_out = x[int(t.tip)] + (noise_x[step, 2] if noise_x is not None else 0.0)
        out[step, 0], out[step, 1], out[step, 2], out[step, 3], out[step, 4] = r, u, u_ctrl, w_ref_v - w_meas, w_meas
        out[step, 5], out[step, 6], out[step, 7], out[step, 8], out[step, 9] = w_ref, w_ref_v, xm, xt_out, tip_out
    return u, sat


@njit(cache=True, inline="always")
def _record_row(rec, row, t, x, n, u_act, x_cmd, enc):
    """Record (real-time): row ``row`` of ``rec``, the plant's state (``n`` masses) as it is before
    its step (the encoders as they read, :func:`drivers.control.encoders`)."""
    for i in range(n):
        rec.x[row, i] = x[i]
        rec.v[row, i] = x[n + i]
    rec.u[row] = u_act
    rec.x_motor[row], rec.x_table[row] = encoders(t, x, enc)
    rec.x_cmd[row] = x_cmd


def simulate(plant: Plant, ctrl: ControllerSettings, x_cmd, *, record_every: int | None = None,
             x0: float | None = None, v_cmd=None, u_add=None, f_ext=None, open_loop: bool = False,
             torque: str = "actual") -> SimulationResult:
    """Closed-loop response to the command ``x_cmd`` sampled on the position clock (not
    real-time: the whole run at once, through :func:`closed_loop_kernel`).

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
    run = _prepared(plant, ctrl, x_cmd, record_every, x0, u_add, f_ext, open_loop, torque)
    closed_loop_kernel(run.Ad, run.Bd, run.fric, run.codes, run.params, run.terms, run.p, run.state0, run.cmd,
                       run.ubuf, run.hbuf, run.rec, run.record_every, speed_filter=run.speed_filter,
                       log_command=run.log_command, masses=mass_token(run.state0.size // 2), enc=run.enc,
                       **run.inputs)
    return _result(run, ctrl, plant, v_cmd)


class _Run(NamedTuple):
    """The arguments of one :func:`closed_loop_kernel` run of :func:`simulate` (not real-time)."""
    Ad: np.ndarray
    Bd: np.ndarray
    fric: tuple
    codes: np.ndarray | None
    params: np.ndarray
    terms: np.ndarray
    p: np.ndarray
    state0: np.ndarray
    cmd: np.ndarray
    ubuf: np.ndarray | None
    hbuf: np.ndarray | None
    rec: Record
    record_every: int
    speed_filter: np.ndarray | None
    log_command: bool
    inputs: dict
    K: int
    n_rec: int
    enc: np.ndarray | None = None


def _prepared(plant, ctrl, x_cmd, record_every, x0, u_add, f_ext, open_loop, torque) -> _Run:
    """The kernel's arguments of :func:`simulate`, checked (the module's conventions)."""
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
    return _Run(disc.A, disc.B, plant.friction.as_tuple(), codes, params, terms.array, ctrl.as_array(), state0, cmd,
                terms.delay_buffer(), terms.feedback_buffer(), Record(X, V, U, XM, XT, XC), record_every,
                ctrl.speed_filter(), torque == "command", inputs, K, n_rec, terms.enc)


def _result(run: _Run, ctrl: ControllerSettings, plant: Plant, v_cmd=None) -> SimulationResult:
    """The :class:`SimulationResult` of a kernel run of :func:`simulate`."""
    record_every, n_rec, K, n_sub = run.record_every, run.n_rec, run.K, ctrl.substeps
    X, V, U, XM, XT, XC = run.rec
    t = np.arange(n_rec) * record_every * ctrl.velocity_period
    if v_cmd is None:
        # the interpolator's velocity for the coming period, held like the command
        vk = np.diff(run.cmd) / ctrl.position_period
        v_rec = vk[np.minimum((np.arange(n_rec) * record_every) // n_sub, K - 1)]
    else:
        v_rec = np.asarray(v_cmd, float)[np.minimum((np.arange(n_rec) * record_every) // n_sub, K - 1)]
    return SimulationResult(t=t, x_cmd=XC, v_cmd=v_rec, x=X, v=V, u=U, x_motor=XM, x_table=XT,
                            x_tip=X[:, plant.tip].copy() if plant.tip != plant.table else XT.copy(),
                            rotary=plant.pitch is not None,
                            meta={"force_gain": plant.force_gain, "record_period": record_every * ctrl.velocity_period})


def simulate_many(plants: list, ctrls: list, x_cmd, *, x0: float | None = None, u_add=None, f_ext=None,
                  open_loop: bool = False, torque: str = "actual") -> list[SimulationResult]:
    """:func:`simulate` of one command on several plants and controllers (the parameter sets of a
    finite-difference Jacobian, a grid of starts), every run the same as :func:`simulate`'s, bit
    for bit. Where the runs share their structure (:func:`_same_structure`) they run in compiled
    calls of :func:`closed_loop_batch`, one per thread (:func:`batch_threads`); else one after the
    other."""
    runs = [_prepared(pl, c, x_cmd, None, x0, u_add, f_ext, open_loop, torque) for pl, c in zip(plants, ctrls)]
    if len(runs) > 1 and _same_structure(runs):
        r0 = runs[0]
        X, V, U, XM, XT, XC = (np.stack([getattr(r.rec, f) for r in runs]) for f in Record._fields)
        args = (np.stack([r.Ad for r in runs]), np.stack([r.Bd for r in runs]), np.array([r.fric for r in runs], float),
                r0.codes, np.stack([r.params for r in runs]), np.stack([r.terms for r in runs]),
                np.stack([r.p for r in runs]), np.stack([r.state0 for r in runs]), r0.cmd,
                None if r0.ubuf is None else np.stack([r.ubuf for r in runs]),
                None if r0.hbuf is None else np.stack([r.hbuf for r in runs]),
                X, V, U, XM, XT, XC, r0.speed_filter, r0.log_command, r0.inputs.get("u_add"), r0.inputs.get("f_ext"),
                r0.inputs.get("open_loop", False), mass_token(r0.state0.size // 2))
        _run_batch(args, len(runs))
        runs = [r._replace(rec=Record(X[b], V[b], U[b], XM[b], XT[b], XC[b])) for b, r in enumerate(runs)]
    else:
        for r in runs:
            closed_loop_kernel(r.Ad, r.Bd, r.fric, r.codes, r.params, r.terms, r.p, r.state0, r.cmd, r.ubuf, r.hbuf,
                               r.rec, r.record_every, speed_filter=r.speed_filter, log_command=r.log_command,
                               masses=mass_token(r.state0.size // 2), enc=r.enc, **r.inputs)
    return [_result(r, c, pl) for r, c, pl in zip(runs, ctrls, plants)]


def _same_structure(runs: list[_Run]) -> bool:
    """Whether the runs differ only in numbers that :func:`closed_loop_batch` takes per run: the
    same state size, effect codes, buffers' sizes, speed filter and record, and no encoder's
    interpolation error (its rows are not batched: such runs go one after the other)."""
    r0 = runs[0]
    if any(r.enc is not None for r in runs):
        return False

    def shape(a):
        return None if a is None else a.shape
    for r in runs[1:]:
        if (r.Ad.shape != r0.Ad.shape or r.Bd.shape != r0.Bd.shape or r.params.shape != r0.params.shape
                or shape(r.ubuf) != shape(r0.ubuf) or shape(r.hbuf) != shape(r0.hbuf) or r.n_rec != r0.n_rec
                or r.record_every != r0.record_every or len(r.fric) != 5):
            return False
        if (r.codes is None) != (r0.codes is None) or (r.codes is not None and not np.array_equal(r.codes, r0.codes)):
            return False
        if (r.speed_filter is None) != (r0.speed_filter is None) or (
                r.speed_filter is not None and not np.array_equal(r.speed_filter, r0.speed_filter)):
            return False
    return len(r0.fric) == 5


@njit(cache=True, nogil=True)
def closed_loop_batch(Ad, Bd, fric, codes, eparams, terms, p, x0, x_cmd, ubuf, hbuf, X, V, U, XM, XT, XC,
                      speed_filter, log_command, u_add, f_ext, open_loop, masses=None, first=0, stop=-1):
    """:func:`closed_loop_kernel` for a batch of runs b of one command, each recorded once per
    position tick into row b of ``X``, ``V``, ``U``, ``XM``, ``XT``, ``XC`` (:class:`Record`):
    per run its matrices ``Ad[b]``, ``Bd[b]``, friction ``fric[b]`` (the five levels), effect
    numbers ``eparams[b]`` (the codes are shared), terms, settings, initial state and buffers (None:
    no delay, compiled away); the measured inputs and the chain's size ``masses`` are shared. Runs
    ``first`` to ``stop`` (-1: the last) only; each is the kernel's, unchanged. Without the GIL, so that threads run disjoint
    ranges of one batch at once (numba's own parallel loops are not safe in a process that forks
    its workers afterwards, as hil diagnose --jobs and hil fleet do)."""
    n_sub = int(terms[0, 0])        # T.SUBSTEPS (the record: one row per position tick)
    for b in range(first, Ad.shape[0] if stop < 0 else stop):
        fr = (fric[b, 0], fric[b, 1], fric[b, 2], fric[b, 3], fric[b, 4])
        rec = Record(X[b], V[b], U[b], XM[b], XT[b], XC[b])
        if ubuf is None:
            if hbuf is None:
                closed_loop_kernel(Ad[b], Bd[b], fr, codes, eparams[b], terms[b], p[b], x0[b], x_cmd, None, None,
                                   rec, n_sub, None, False, None, None, None, u_add, f_ext, open_loop,
                                   speed_filter, log_command, masses)
            else:
                closed_loop_kernel(Ad[b], Bd[b], fr, codes, eparams[b], terms[b], p[b], x0[b], x_cmd, None,
                                   hbuf[b], rec, n_sub, None, False, None, None, None, u_add, f_ext, open_loop,
                                   speed_filter, log_command, masses)
        elif hbuf is None:
            closed_loop_kernel(Ad[b], Bd[b], fr, codes, eparams[b], terms[b], p[b], x0[b], x_cmd, ubuf[b], None,
                               rec, n_sub, None, False, None, None, None, u_add, f_ext, open_loop,
                               speed_filter, log_command, masses)
        else:
            closed_loop_kernel(Ad[b], Bd[b], fr, codes, eparams[b], terms[b], p[b], x0[b], x_cmd, ubuf[b],
                               hbuf[b], rec, n_sub, None, False, None, None, None, u_add, f_ext, open_loop,
                               speed_filter, log_command, masses)


# per thread: whether its batches run on it alone (batches_on_this_thread)
_THIS_THREAD = threading.local()


@contextmanager
def batches_on_this_thread():
    """Within the block, the calling thread runs its batches alone (:func:`batch_threads` is 1 there):
    a thread of a pool that already shares the cores (hil.ident.parallel: candidates fitted at once)."""
    before = getattr(_THIS_THREAD, "alone", False)
    _THIS_THREAD.alone = True
    try:
        yield
    finally:
        _THIS_THREAD.alone = before


def usable_cpus() -> frozenset | None:
    """The CPUs this process may run on (its affinity), None where the platform cannot say."""
    try:
        return frozenset(os.sched_getaffinity(0))
    except AttributeError:          # pragma: no cover - platforms without affinity
        return None


class _OthersLoad:
    """The cores the other processes kept busy lately: the busy time of the CPUs this process may
    run on (``/proc/stat``) less this process's CPU time (all its threads), over a span of at least
    ``SPAN`` s since the last reading (the first from the module's import; anew in a forked child,
    whose CPU time starts again, and after ``STALE`` s without a reading); None where
    ``/proc/stat`` cannot be read or no span has passed yet. The load average says the same a
    minute late: a process that had just used two cores, or a diagnosis started after one, saw it
    as another's load and ran on one thread (a second ``hil diagnose`` after the benchmark's
    chains: 8.9 s against 4.5 s)."""

    SPAN = 0.5          # s, the shortest span read (the clock's ticks are 10 ms)
    RENEW = 2.0         # s, after which a span starts again from the last reading
    STALE = 10.0        # s, a span this long is dropped (a process that waited for its workers)

    def __init__(self):
        self._lock = threading.Lock()
        try:
            self._hz = float(os.sysconf("SC_CLK_TCK"))
        except (AttributeError, ValueError, OSError):      # pragma: no cover - not POSIX
            self._hz = 0.0
        self._cpus = usable_cpus()
        self._start()

    @staticmethod
    def _busy(hz: float, cpus=None) -> float | None:
        """Seconds of busy time (user, nice, system, irq, softirq, steal) since boot of the CPUs
        ``cpus`` (their ``cpuN`` lines; None: every CPU)."""
        if not hz:
            return None
        total, seen = 0.0, False
        try:
            with open("/proc/stat") as f:
                for line in f:
                    if not line.startswith("cpu") or not line[3:4].isdigit():
                        continue
                    name, *fields = line.split()
                    if cpus is not None and int(name[3:]) not in cpus:
                        continue
                    v = [int(x) for x in fields[:8]]
                    if len(v) < 8:
                        return None
                    total += v[0] + v[1] + v[2] + v[5] + v[6] + v[7]
                    seen = True
        except (OSError, ValueError):
            return None
        return total / hz if seen else None

    def _start(self) -> None:
        self.pid, self.t, self.cpu = os.getpid(), time.monotonic(), time.process_time()
        self.busy = self._busy(self._hz, self._cpus)
        self.value = None

    def __call__(self) -> float | None:
        with self._lock:
            if os.getpid() != self.pid:
                self._start()
            if self.busy is None:
                return None
            now = time.monotonic()
            if now - self.t > self.STALE:      # no reading for long: what it says is not recent
                self._start()
                return None
            if now - self.t >= self.SPAN:
                cpu, busy = time.process_time(), self._busy(self._hz, self._cpus)
                if busy is None:
                    return None
                self.value = max(0.0, (busy - self.busy) - (cpu - self.cpu)) / (now - self.t)
                if now - self.t >= self.RENEW:
                    self.t, self.cpu, self.busy = now, cpu, busy
            return self.value


_others_load = _OthersLoad()


def batch_threads() -> int:
    """Threads that share a batch (:func:`simulate_many`): 1 within :func:`batches_on_this_thread`;
    ``HIL_THREADS`` when set, else the cores that are idle: the CPUs this process may use less the
    others' load, rounded (:class:`_OthersLoad`; where it cannot say, the 1-minute load average
    less this process), at least 1. On a busy machine, or in a worker of a pool that fills the
    cores (hil fleet, hil diagnose --jobs), threads would only wait for each other: a batch is as
    slow as its last range (bench_fleet at load 8: 34 s for the 6 s chain with 2 threads, 27 s
    with 1)."""
    if getattr(_THIS_THREAD, "alone", False):
        return 1
    env = os.environ.get("HIL_THREADS", "").strip()
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            raise ValueError(f"HIL_THREADS: expected a whole number of threads, got {env!r}") from None
    allowed = usable_cpus()
    cpus = len(allowed) if allowed else (os.cpu_count() or 1)
    others = _others_load()
    try:
        busy = int(others + 0.5) if others is not None else int(os.getloadavg()[0] + 0.5) - 1
    except OSError:                 # pragma: no cover - platforms without a load average
        busy = 0
    return max(1, min(cpus, cpus - busy))


def _run_batch(args: tuple, count: int) -> None:
    """:func:`closed_loop_batch` over ``count`` runs, split into contiguous ranges, one per thread
    (a pool made per call: a forked worker inherits no idle threads)."""
    threads = min(batch_threads(), count)
    if threads <= 1:
        closed_loop_batch(*args)
        return
    from concurrent.futures import ThreadPoolExecutor
    edges = [round(i * count / threads) for i in range(threads + 1)]
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for f in [pool.submit(closed_loop_batch, *args, edges[i], edges[i + 1]) for i in range(threads)]:
            f.result()


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
