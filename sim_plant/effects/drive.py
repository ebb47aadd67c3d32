"""Effects of the drive between the controller's output and the motor's torque: the current loop's
finite bandwidth, the torque constant's tolerance.

* ``current_loop_lag``: the current (torque) follows the controller's output through a first-order
  lag of time constant tau (the current loop closed at a bandwidth of 1 / (2 pi tau)); it replaces
  the config's ``actuator.current_loop_time_constant``. Closed form: at a frequency f the torque
  lags the command by atan(2 pi f tau) with the amplitude 1 / sqrt(1 + (2 pi f tau)^2); well below
  its bandwidth it acts as a delay of tau (and so it resembles ``actuator_delay``). Its error is not
  convex in tau: a grid of time constants from a quarter velocity period to :attr:`CurrentLoopLag.MAX`.
* ``torque_constant``: the motor's torque constant differs from the data sheet (a tolerance of a
  few %, a magnet's temperature): the torque delivered is ``factor`` times what the drive logs
  (current times the nominal constant), on a linear motor its force constant. M x'' + C x' + K x
  = factor F is (M / factor) x'' + (C / factor) x' + (K / factor) x = F: the factor mimics every
  mass (and damping and stiffness) divided by it, and where inertia dominates a uniform change of
  the masses; its evidence says so, one parameter where the masses are several.
"""
from __future__ import annotations

import dataclasses
import math

from sim_plant.effects.base import Effect, Param, register

__all__ = ["CurrentLoopLag", "TorqueConstant"]


@register
class CurrentLoopLag(Effect):
    name = "current_loop_lag"
    description = ("the current loop's finite bandwidth: the torque (force) follows the controller's output "
                   "through a first-order lag (replaces the config's current-loop time constant)")
    params = (Param("time_constant", "time", 0.0, 0.01, 2e-4,
                    "time constant of the current loop's first-order lag (bandwidth 1/(2 pi tau))"),)
    MAX = 5e-3           # the grid's upper end, s: a current loop closed at 30 Hz or faster
    synth_strength = {"time_constant": 5e-4}
    lags_the_torque = True

    def apply(self, plant, values):
        tau = values["time_constant"]
        if tau < 0:
            raise ValueError(f"{self.name}: the time constant must not be negative (got {tau:g} s)")
        return dataclasses.replace(plant, current_loop_time_constant=tau)

    def guess(self, plant, scale):
        return {"time_constant": 2e-4}

    def grid(self, plant, ctrl, scale):
        tv = ctrl.velocity_period
        out, tau = [], 0.25 * tv
        while tau < self.MAX:
            out.append({"time_constant": tau})
            tau *= 1.6
        return out + [{"time_constant": self.MAX}]

    def evidence(self, ctx, values):
        tau = values.get("time_constant", 0.0)
        if tau <= 0:
            return "no lag of the current loop: an ideal one; "
        fb = 1.0 / (2 * math.pi * tau)
        f_ref = 10.0
        lag = math.degrees(math.atan(2 * math.pi * f_ref * tau))
        return (f"the {ctx.force_channel or 'force'} reaches the motor through the current loop's first-order lag of "
                f"{tau * 1e3:.3g} ms (bandwidth {fb:.4g} Hz; {lag:.2g} deg of phase at {f_ref:g} Hz, "
                f"atan(2 pi f tau)): well below its bandwidth it acts as a delay of {tau * 1e3:.3g} ms, like "
                f"actuator_delay; ")


@register
class TorqueConstant(Effect):
    name = "torque_constant"
    description = ("the motor's torque (force) constant differs from the nominal: the torque delivered is a "
                   "factor times the one logged; it mimics a uniform change of every mass")
    params = (Param("factor", "dimensionless", 0.5, 2.0, 1.0,
                    "torque delivered per torque logged (1: the nominal torque constant)"),)
    synth_strength = {"factor": 0.93}

    def apply(self, plant, values):
        k = values["factor"]
        if k <= 0:
            raise ValueError(f"{self.name}: the factor must be positive (got {k:g})")
        return dataclasses.replace(plant, force_gain=plant.force_gain * k)

    def guess(self, plant, scale):
        return {"factor": 1.0}

    def evidence(self, ctx, values):
        k = values.get("factor", 1.0)
        masses = ctx.plant.chain.m
        return (f"the motor delivers {k:.4g} times the torque logged ({100 * (k - 1):+.2g} % on the nominal torque "
                f"constant); the same motion as every mass divided by {k:.4g} (with the dampings and stiffnesses "
                f"exact, M x'' + C x' + K x = {k:.4g} F): one parameter, not a change of each of the "
                f"{len(masses)} masses; ")
