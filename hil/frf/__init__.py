"""Frequency-response measurement of an axis (commissioning in the frequency domain).

The axis runs at a slow constant speed with its loops closed while a periodic excitation is
added to the torque or to the speed reference; the responses a drive engineer reads (TF1',
TF2, TF3, the velocity and position loops) are estimated with the excitation as instrumental
variable, set against the model's exact sampled-loop responses, the modes fitted, the
discrepancies named by the parameter that explains them, and tuning help given as a config diff
(never applied).

Modules, in the order of a measurement:

* :mod:`hil.frf.excitation`   periodic excitation signals (multisine, chirp, PRBS)
* :mod:`hil.frf.run`          the experiment: working point, excitation, the run (compiled on
                              the simulated plant, or cycle by cycle on a backend through
                              hil.loop) and its record
* :mod:`hil.frf.estimation`   responses from the record, coherence and uncertainty; their names
* :mod:`hil.frf.model`        the model's responses of the sampled loop
* :mod:`hil.frf.modes`        modal fit and discrepancies against the model
* :mod:`hil.frf.loop_tuning`  margins, bandwidths, largest gains, filters, feed-forward
* :mod:`hil.frf.measurement`  all of it in one call (:func:`measure`, :class:`FrfResult`)
"""
from __future__ import annotations

from hil.frf.estimation import RESPONSES, TITLES, UNITS, Response, estimate
from hil.frf.excitation import Excitation, make_excitation
from hil.frf.loop_tuning import acc_ff_effect, bandwidth, largest_gain, margins, tuning
from hil.frf.measurement import FrfResult, measure, stderr_progress
from hil.frf.model import model_responses, position_hold
from hil.frf.modes import Mode, discrepancies, fit_mode, fit_modes, model_modes
from hil.frf.run import CH, FrfRecord, FrfSettings, run_backend, run_sim, settle_time

__all__ = ["Excitation", "make_excitation",
           "CH", "FrfSettings", "FrfRecord", "settle_time", "run_sim", "run_backend",
           "RESPONSES", "UNITS", "TITLES", "Response", "estimate",
           "model_responses", "position_hold",
           "Mode", "fit_mode", "model_modes", "fit_modes", "discrepancies",
           "margins", "bandwidth", "largest_gain", "tuning", "acc_ff_effect",
           "FrfResult", "measure", "stderr_progress"]
