"""The whole measurement: excite, estimate, set against the model, fit the modes, suggest.

:func:`measure` runs the experiment (:mod:`hil.frf.run`: compiled on the simulated plant, or cycle
by cycle on a backend), estimates the responses (:mod:`hil.frf.estimation`), computes the model's
(:mod:`hil.frf.model`), fits the modes and names the discrepancies (:mod:`hil.frf.modes`) and
adds the tuning help (:mod:`hil.frf.loop_tuning`). :class:`FrfResult` holds it all; its
:meth:`~FrfResult.as_dict` is the ``--json`` report of ``hil frf``.
"""
from __future__ import annotations

import logging
import sys
from dataclasses import dataclass, field

import numpy as np

from hil.frf.estimation import TITLES, UNITS, estimate
from hil.frf.loop_tuning import tuning
from hil.frf.model import model_responses
from hil.frf.modes import discrepancies, fit_modes
from hil.frf.run import FrfRecord, FrfSettings, run_backend, run_sim

logger = logging.getLogger(__name__)

__all__ = ["FrfResult", "measure", "stderr_progress"]


@dataclass
class FrfResult:
    """A measurement: the estimated responses (name -> Response), the model's at the same lines,
    the fitted modes, the discrepancies, the tuning help, the record, warnings."""
    responses: dict
    model: dict
    modes: list
    discrepancies: list
    tuning: dict
    record: FrfRecord
    warnings: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {
            "responses": {k: dict(v.as_dict(), title=TITLES[k], unit=UNITS[k],
                                  model_magnitude=np.abs(self.model[k]).tolist() if k in self.model else None,
                                  model_phase_deg=np.degrees(np.angle(self.model[k])).tolist()
                                  if k in self.model else None)
                          for k, v in self.responses.items()},
            "modes": self.modes, "discrepancies": [d["sentence"] for d in self.discrepancies],
            "suggested_changes": {k: v for d in self.discrepancies for k, v in d["changes"].items()},
            "tuning": {k: v for k, v in self.tuning.items()}, "warnings": self.warnings,
            "excitation": {"signal": self.record.excitation.kind, "input": self.record.input,
                           "period_s": self.record.excitation.period, "periods": self.record.periods,
                           "lines": int(self.record.excitation.lines.size),
                           "saturated_periods": self.record.saturated, "backend": self.record.backend},
        }


def measure(plant_true, plant_model, ctrl, st: FrfSettings, backend=None, progress=None, pm_min: float = 45.0,
            gm_min_db: float = 6.0, supervisor=None, scope=None) -> FrfResult:
    """Excite, estimate, set against the model, fit the modes, suggest. ``plant_true`` is what the
    simulated run uses (None with a backend); ``plant_model`` the config's model; ``scope``: the
    live scope's ring the backend's cycle writes into."""
    logger.info("frf: %s excitation of %s on %s", st.signal, st.input, getattr(backend, "name", "the simulated plant"))
    if backend is None:
        rec = run_sim(plant_true, ctrl, st, progress)
    else:
        rec = run_backend(backend, ctrl, st, progress, supervisor=supervisor, plant=plant_model, scope=scope)
    if progress:
        progress("estimating the responses")
    resp = estimate(rec, ctrl)
    model_all = model_responses(plant_model, ctrl, rec.excitation.freqs, rec.tip_measured)
    model = {k: (v[: resp[k].f.size] if k in resp else v) for k, v in model_all.items()}
    if progress:
        progress("fitting the modes")
    modes = fit_modes(resp, plant_model, model)
    disc = discrepancies(modes, plant_model)
    f_hi = rec.excitation.freqs[-1]
    fw = np.geomspace(f_hi * 1.001, 0.45 / ctrl.velocity_period, 400)
    wide = model_responses(plant_model, ctrl, fw, False)
    wide["f"] = fw
    tun = tuning(resp, ctrl, modes, pm_min, gm_min_db, plant=plant_model, model_wide=wide)
    warnings = []
    if rec.saturated:
        warnings.append(f"the output saturated in {rec.saturated} velocity periods: lower --amplitude")
    w = rec.channel("w")[rec.start:]
    if st.speed != 0 and np.any(np.sign(w) == -np.sign(st.speed)):
        warnings.append("the motor speed reverses during the excitation: friction changes sign and the "
                        "responses are not those of the working point; raise --speed or lower --amplitude")
    low = np.mean(resp["TF1p"].coherence < 0.8)
    if low > 0.2:
        warnings.append(f"coherence below 0.8 on {low:.0%} of the lines of TF1': raise --amplitude or --periods")
    return FrfResult(resp, model, modes, disc, tun, rec, warnings)


def stderr_progress(msg: str) -> None:
    """The command's progress lines, on stderr (stdout carries the report)."""
    print(f"hil frf: {msg}", file=sys.stderr, flush=True)
