"""The simulated drive's quick stop and fault reaction (quick stop option code 2, 0x605A; fault
reaction 0x605E = 2): the speed reference ramps from the present speed to zero at the quick-stop
deceleration 0x6085 (position units per s^2; 0 or 0xFFFFFFFF: 80 % of what the torque limit
gives the axis), then the drive holds the position where the motor came to rest (its speed
crossed zero), never a stale target, until the motor and the table are at rest, and only then
switches the power stage off.

The drive's own velocity loop runs it, on the plant's public API (drivers.sim.SimulatedPlant:
``law_params``, ``step_output``). :meth:`QuickStopRamp.step` is real-time (one drive cycle).
"""
from __future__ import annotations

import math

import numpy as np

from drivers.control import P, new_velocity_state, velocity_law

__all__ = ["QuickStopRamp", "QS_REST_SPEED", "QS_MIN_HOLD", "QS_EASE"]

QS_REST_SPEED = 1e-4      # m/s: motor and table below this, the quick stop has ended
QS_MIN_HOLD = 0.02        # s: and the position held at least this long
QS_EASE = 0.01            # s: the quick-stop deceleration falls to zero over about this time


class QuickStopRamp:
    """The ramp and hold of one quick stop (``state`` None: none running)."""

    def __init__(self):
        self.state: dict | None = None                 # the ramp, its direction, the hold, the time held
        self.loop_state = new_velocity_state()         # the drive's velocity loop while it stops

    def start(self, plant) -> None:
        """A quick stop begins at the plant's present speed."""
        self.loop_state = new_velocity_state()
        v = float(plant.x[plant.plant.n])
        self.state = {"ramp": v, "dir": 1.0 if v >= 0 else -1.0, "hold": None, "held": 0.0}

    @staticmethod
    def deceleration(plant, tmax: float, conf) -> float:
        """The quick-stop deceleration (m/s^2): 0x6085 (position units per s^2), or where it is 0
        or 0xFFFFFFFF, 80 % of what the torque limit gives the whole axis."""
        raw = conf["qs_dec"] if conf is not None else 0xFFFFFFFF
        if raw and raw != 0xFFFFFFFF:
            return raw / conf["cpm"]
        pl = plant.plant
        return 0.8 * tmax * pl.force_gain / pl.total_mass

    def step(self, plant, tmax: float, conf, period: float, log, syncs: int) -> bool:
        """One drive cycle (``period``) of the stop: the speed reference ramps to zero at the
        quick-stop deceleration, the drive's velocity loop follows it; when the ramp is at zero and
        the motor's speed has crossed zero (it stands), the position where it stands is held (the
        position loop on the motor). True when the motor and the table are at rest and the
        position has been held ``QS_MIN_HOLD``: the stop has ended (logged into ``log`` at cycle
        ``syncs``)."""
        pl = plant
        n, tv = pl.plant.n, pl.ctrl.velocity_period
        q = self.state
        dv = self.deceleration(plant, tmax, conf) * tv
        scale, kv = pl.ctrl.speed_scale, pl.law_params[P.KV]
        steps = max(1, int(round(period / tv)))
        for _ in range(steps):
            if q.get("done"):
                pl.step_output(0.0)                     # the power stage is off: the axis coasts
                continue
            if q["hold"] is None:
                w_ref = self._ramp(q, pl.x[n], dv, tv, pl)
            else:
                w_ref = kv * (q["hold"] - pl.x[0])
                if self._held_to_rest(q, pl, tv):
                    q["done"] = True
                    log.append((syncs, f"quick stop ended: held at {q['hold']:.6f} m"))
                    pl.step_output(0.0)
                    continue
            u = velocity_law(pl.law_params, self.loop_state, w_ref * scale, pl.x[n] * scale, 0.0)
            pl.step_output(max(-tmax, min(tmax, u)))
        return bool(q.get("done"))

    def _ramp(self, q: dict, v: float, dv: float, tv: float, pl) -> float:
        """The speed reference one velocity period on; the hold begins where the motor stands."""
        r = q["ramp"]
        # the deceleration eases off near zero speed (jerk-limited over QS_EASE): the end of the
        # ramp does not set the compliant axis swinging back
        step = min(dv, math.sqrt(2.0 * dv / QS_EASE * tv * abs(r)), abs(r))
        q["ramp"] = r = 0.0 if abs(r) - step < 1e-9 else r - math.copysign(step, r)
        if r == 0.0 and v * q["dir"] <= 0.0:
            q["hold"] = float(pl.x[0])           # where the motor came to rest
            self.loop_state = new_velocity_state()   # the braking torque is not carried on
        return r

    @staticmethod
    def _held_to_rest(q: dict, pl, tv: float) -> bool:
        """The hold has lasted ``QS_MIN_HOLD`` and the axis is at rest: the motor and the table
        still, and the axis's momentum (the compliant masses still swing) crossing zero, so that
        nothing carries the axis on once the power stage is off and it coasts."""
        n = pl.plant.n
        q["held"] += tv
        v = pl.x[n]
        p = float(np.dot(pl.plant.chain.m, pl.x[n:]))
        if q["held"] >= QS_MIN_HOLD and abs(v) < QS_REST_SPEED and abs(pl.x[n + pl.plant.table]) < \
                QS_REST_SPEED and (p * q.get("p", p) <= 0.0 or abs(p) < 1e-6 * pl.plant.total_mass):
            return True
        q["p"] = p
        return False
