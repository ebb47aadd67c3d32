"""The experiment: a working point with a periodic excitation, run and recorded every velocity period.

The axis runs at a slow constant speed (the working point: friction does not change sign) with
its loops closed; after a lead-in (a sine-square speed ramp) the excitation is added, period
after period, either to the controller output (``input = "torque"``: a torque disturbance) or to
the speed reference of the velocity loop (``"velocity"``). The first periods let the response
settle (:func:`settle_time`), the last ``periods`` are averaged by :mod:`hil.frf.estimation`.

Every velocity period the run records the channels :data:`CH` (hil.loop's cycle record): the
excitation ``r``, the total output ``u`` and the controller's ``u_ctrl``, its input ``e``, the
measured speed ``w``, the speed references ``w_ref_pos`` (position loop) and ``w_ref`` (velocity
loop), the encoders ``x_motor``, ``x_table``, ``x_tip``.

Two ways to run it, with the same numbers on the simulated plant:

* :func:`run_sim`: hil.simulate's compiled closed loop with the excitation and optional
  measurement noise;
* :func:`run_backend`: cycle by cycle through the backend contract (drivers.base), on
  hil.loop's :class:`~hil.loop.ControlLoop` with an :class:`~hil.loop.Injection`; the host closes
  both loops, so the backend takes torque (a CiA 402 drive in cyclic torque mode, the
  simulated plant).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from drivers.control import loop_terms
from hil.errors import RunStopped
from hil.frf.excitation import Excitation, make_excitation
from hil.loop import CYCLE_CHANNELS, ControlLoop, Injection
from hil.simulate import closed_loop_kernel

__all__ = ["CH", "FrfSettings", "FrfRecord", "settle_time", "run_sim", "run_backend"]

# recorded channels, one column each, every velocity period (the compiled run writes the same)
CH = CYCLE_CHANNELS


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


def settle_time(plant, st: FrfSettings) -> float:
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


def _experiment(plant, ctrl, st: FrfSettings, x0: float):
    """The schedule of a run: the excitation, the position command (position clock, one sample
    more than the ticks run), the excitation of every velocity period (zero in the lead-in),
    where the averaged periods start, the settling periods."""
    exc = make_excitation(st.signal, ctrl.velocity_period, st.period, st.band, st.amplitude, st.seed)
    n_settle = int(math.ceil(settle_time(plant, st) / exc.period))
    n_periods = n_settle + st.periods
    x_cmd, K_lead = _command(ctrl, st, n_periods * exc.n, x0)
    n_sub = ctrl.substeps
    lead = K_lead * n_sub
    r = np.zeros((x_cmd.size - 1) * n_sub)
    r[lead:lead + n_periods * exc.n] = np.tile(exc.signal, n_periods)
    return exc, x_cmd, r, lead + n_settle * exc.n, n_settle


def run_sim(plant, ctrl, st: FrfSettings, progress=None, x0: float = 0.0) -> FrfRecord:
    """Run the excitation on the simulated plant through the compiled loop."""
    tv = ctrl.velocity_period
    exc, x_cmd, r, start, n_settle = _experiment(plant, ctrl, st, x0)
    steps = r.size
    rng = np.random.default_rng(st.seed)
    nw = rng.standard_normal(steps) * st.noise_speed
    nx = rng.standard_normal((steps, 3)) * st.noise_position
    disc = plant.chain.discretize(tv, inputs="all")
    x0v = np.zeros(2 * plant.n)
    x0v[:plant.n] = x0
    terms = loop_terms(plant, ctrl)
    out = np.zeros((steps, len(CH)))
    if progress:
        progress(f"exciting: {st.signal} {st.input} disturbance, {st.band[0]:g}..{st.band[1]:g} Hz, "
                 f"{n_settle} settling + {st.periods} averaged periods of {exc.period:g} s at "
                 f"{st.speed * 1e3:g} mm/s ({steps} velocity periods)")
    sat = closed_loop_kernel(disc.A, disc.B, plant.friction.as_tuple(), terms.codes, terms.params, terms.array,
                             ctrl.as_array(), x0v, x_cmd, terms.delay_buffer(), terms.feedback_buffer(),
                             exc=r, exc_into_speed=st.input == "velocity", noise_w=nw, noise_x=nx, out=out,
                             speed_filter=ctrl.speed_filter(), enc=terms.enc)
    return FrfRecord(out, tv, exc, start, st.periods, int(sat), plant.tip != plant.table, st.input, "sim")


def run_backend(backend, ctrl, st: FrfSettings, progress=None, supervisor=None, plant=None, clock=None,
                scope=None) -> FrfRecord:
    """The same experiment cycle by cycle through the backend contract (drivers.base), on
    :class:`hil.loop.ControlLoop` with the excitation as its :class:`~hil.loop.Injection`: the
    host closes both loops, so the backend must take torque (``closes == "none"``). Works on any
    such backend (the simulated plant, a CiA 402 drive in cyclic torque mode); slower than
    :func:`run_sim` on the simulated plant. Paced by ``clock`` (default: hil.loop's simulated
    clock for a simulated backend, the real-time clock otherwise); ``supervisor.check`` every
    position tick. ``plant``: the model, for the settling time. ``scope``: the live scope's ring.

    Raises
    ------
    RunStopped
        The drive faulted or was lost, or the supervisor tripped (the loop has commanded the
        controlled stop); its ``status``, ``reason`` and ``exit_code`` say how.
    """
    if backend.closes != "none":
        raise ValueError(f"backend {backend.name}: frf needs a backend in torque mode (closes='none'), "
                         f"this one closes {backend.closes!r}")
    exc, x_cmd, r, start, _ = _experiment(plant, ctrl, st, backend.read_feedback().x_table)
    injection = Injection(r, st.input)
    # as the compiled run (run_sim): no acceleration feed-forward on the working point's ramp
    loop = ControlLoop(backend, replace(ctrl, acc_ff=0.0), clock=clock, supervisor=supervisor,
                       injection=injection, scope=scope, progress=(lambda done: progress(f"  {done:5.1%}")) if progress else None)
    result = loop.run(x_cmd[:-1], x_after=x_cmd[-1])
    if result.status != "complete":      # stopped (the loop commanded the controlled stop): how, in the exit code
        raise RunStopped(f"frf did not complete: {result.status}: {result.reason}", result.status, result.reason,
                         result.stop)
    data = injection.data
    saturated = int(np.count_nonzero(np.abs(data[:, CH.index("u")]) >= ctrl.output_limit))
    tip_measured = not np.isnan(data[:, CH.index("x_tip")]).any()
    return FrfRecord(data, ctrl.velocity_period, exc, start, st.periods, saturated, tip_measured, st.input,
                     getattr(backend, "name", "backend"))
