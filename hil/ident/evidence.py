"""The evidence of a fitted candidate: what in the residual before the fit points at the effect,
then the fall of the error the fit brought, as one line of text.

Per effect (r the residual before the fit, v the commanded velocity, "moving" |v| > 2 % of
max|v|):

* friction and force effects: the regression of the force residual while moving,
  r = Fc sign(v) + c v + f0 (per direction, level and slope, for asymmetric friction); a ball
  screw's load-dependent friction, r on sign(v) and |F_link| sign(v) (the link's force from the
  measured motion), and what it looks like (Coulomb friction and a mass change while accelerating);
* position-periodic effects: the fitted period (x_motor - x_table for a lead error);
* an added mode: its frequency, against the model's modes (the chain's undamped natural
  frequencies sqrt(eig(M^-1 K)) / 2 pi);
* backlash, mass change and ``parameter:<key>``: the fitted value;
* flexible_transmission: the residual's ringing after the record's edges, and the link fitted;
* the delays (actuator_delay, alias time_delay; feedback_delay): the fitted delay in the loop's
  periods, and where it sits;
* channel_skew, tip_skew: the skew in samples, said to be a logging artefact, not physics;
* force_offset, position_offset: the offset, said to be a sensor's, not a load (the force
  residual's mean at rest and moving: a sensor offset is the same in both);
* stiffness_along_travel: k1 and the transmission mode's frequency (sim_plant.modal) at both ends
  of the stretch, and whether the record can see the variation at all: a constant k1 (the best of
  the two end values and their middle) scored against the fit (BIC, hil.ident.scores); when it
  does as well, the variation cannot be seen over the stroke the record covers;
* a combination: each member's evidence, then the fall of the joint fit.

Each effect says its own (its hook :meth:`sim_plant.effects.base.Effect.evidence`, with a
context of the replay, hil.ident.context); a combination is assembled here.

It ends with "RMS <channel> error <before> -> <after> (<fall> % less)", each error in its
engineering unit (hil.units.fmt).
"""
from __future__ import annotations

import numpy as np

from hil.ident.context import EffectContext
from hil.ident.replay import Replay
from hil.plant_config import candidate, plant_from_config
from hil.units import fmt_si

__all__ = ["evidence", "model_modes"]


def evidence(eff_name: str, vals: dict, replay: Replay, res0: dict, chan: str, before: float, after: float,
             base_modes) -> str:
    unit = replay.unit(chan)
    # each figure in its engineering unit (203 um -> 337 nm), hil.units
    fall = (f"RMS {chan} error {fmt_si(before, unit, 3)} -> {fmt_si(after, unit, 3)} "
            f"({100 * (1 - after / before) if before else 0:.0f} % less)")
    if "+" in eff_name:
        # a combination: each member's evidence, then the fall of the joint fit
        heads = []
        for m, v in zip(eff_name.split("+"), candidate(eff_name).split(vals)):
            h = evidence(m, v, replay, res0, chan, before, after, base_modes)
            heads.append(h[:-len(fall)].rstrip("; ") if h.endswith(fall) and h != fall else "")
        return "; ".join([h for h in heads if h] + [fall])
    # the effect's own hook says what in the residual points at it (sim_plant.effects.base)
    eff = candidate(eff_name, replay.cfg)
    ctx = EffectContext(replay, res0, replay.cfg, chan=chan, base_modes=base_modes)
    return eff.evidence(ctx, vals) + fall


def model_modes(cfg):
    try:
        pl = plant_from_config(cfg)
        w = np.sqrt(np.maximum(np.linalg.eigvals(np.linalg.solve(pl.chain.M, pl.chain.K)).real, 0))
        return sorted(float(x / (2 * np.pi)) for x in w if x > 1e-6)
    except Exception:  # noqa: BLE001 - evidence text only
        return []
