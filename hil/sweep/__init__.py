"""Jerk sweeps: overshoot against commanded jerk, and the largest jerk a tolerance allows.

One *run* is one sine-square move (stroke, feed, jerk) from rest plus a dwell long enough to
capture the residual vibration; its figures are :class:`hil.analysis.MoveFigures` (overshoot of
table and tip over the whole move and dwell, floored at 0; peak following errors; residual tip
vibration; settling). Two analyses, as in the paper:

- ``mechatronic``: the whole closed loop on the simulated plant (:func:`hil.simulate.simulate`,
  recorded every ``record_every`` velocity steps, 0.5 ms by default, so that overshoot is not
  sampled at the 4 ms position clock only), or on a real axis through ``hil.runtime``;
- ``transmission`` (Section 3): the motor x1 follows the sine-square path exactly; x2 = TF2 x1 and
  x3 = TF3 x2, computed as the response of masses 2..N of the chain to the prescribed x1, v1
  (exactly TF2 and TF3 of Table 1), with a first-order-hold discretization (exact for a
  piecewise-linear input).

On top of the runs: the most conservative largest jerk for a tip tolerance (the first crossing,
refined by bisection on the simulated overshoot), the admissible intervals of a non-monotonic
curve, the local minima (vibration cancellation, explained with the dominant frequency), and a
proposal of the jerk that minimizes tip overshoot within a move-time budget.

Runs are independent: they go to a process pool (all cores) or a Dask cluster, and each finished
run is appended to ``runs.jsonl`` in the output folder, so an interrupted sweep resumes where it
stopped. The numbers do not depend on where a run was computed.

Modules, each importing only those above it:

- :mod:`~hil.sweep.jerk`: t_acc <-> j_max (Eq. 15-16) and the log-spaced jerk grid;
- :mod:`~hil.sweep.model`: a configuration's plant and controller, built once per process, and
  the configuration's fingerprint;
- :mod:`~hil.sweep.transmission`: Section 3, masses 2..N driven by the prescribed motor;
- :mod:`~hil.sweep.run`: one run (:class:`RunSpec`, its store key, its figures), on the
  simulated plant or on a runtime backend;
- :mod:`~hil.sweep.executors`: where runs go (process pool, Dask, an axis);
- :mod:`~hil.sweep.store`: ``runs.jsonl``, the finished runs;
- :mod:`~hil.sweep.curve`: the analyses of an overshoot curve (pure functions);
- :mod:`~hil.sweep.sweep`: :class:`SweepSettings` and :func:`run_sweep`, the report.
"""
from __future__ import annotations

from hil.sweep.curve import (
    admissible_intervals,
    cancellation_jerks,
    crossing,
    local_minima,
    tolerance_answer,
    verify_intervals,
)
from hil.sweep.jerk import jerk_grid, jmax_to_t_acc, t_acc_to_jmax
from hil.sweep.model import fingerprint, model_of
from hil.sweep.run import ANALYSES, RUN_FIELDS, RunSpec, backend_trajectory, dominant_frequency, run_on_backend, run_one
from hil.sweep.store import ResultStore
from hil.sweep.sweep import SweepSettings, default_dwell, lowest_mode_hz, min_dwell, run_sweep, sampling, warm_up
from hil.sweep.transmission import transmission_response

__all__ = ["RunSpec", "SweepSettings", "run_one", "run_sweep", "admissible_intervals", "crossing",
           "local_minima", "tolerance_answer", "dominant_frequency", "cancellation_jerks",
           "t_acc_to_jmax", "jmax_to_t_acc", "ResultStore", "fingerprint", "jerk_grid", "warm_up",
           "transmission_response", "default_dwell", "ANALYSES", "RUN_FIELDS", "model_of",
           "backend_trajectory", "run_on_backend", "verify_intervals", "lowest_mode_hz", "min_dwell", "sampling"]
