"""Identification: where the model fails against a measurement, which effect it is missing, and
the fitted parameters (``hil compare``, ``hil diagnose``, ``hil fit``, ``hil synth``, ``hil emps``).

Modules, each importing only those above it:

- ``scores``: error measures (NRMSE fit, relative error), the third-difference noise estimate,
  effective samples, BIC;
- ``residual``: the residual as a signal (spectrum peaks, periodic in position, motion phases);
- ``noise``: the noise floor of a record (a given figure, the encoder grid, settled standstills);
- ``objective``: the weighted residual vector the fits minimise;
- ``replay``: :class:`Replay`, a record replayed through a config's model;
- ``records``: several records of one axis fitted as one, estimation and validation errors;
- ``compare``: the metrics and residual analysis that ``hil compare`` reports;
- ``evidence``, ``starts``: the evidence text and the starting values of a candidate's fit;
- ``fit``: fitting and scoring one candidate (:func:`evaluate`), greedy and joint fits;
- ``parallel``: many candidates in worker processes;
- ``inverse``: the inverse dynamic model by least squares (:func:`idim_ls`);
- ``joint``: pairs of friction and force effects screened together by the inverse model;
- ``unexplained``: at the noise floor, the share of the gap a fit closed, where a residual lives;
- ``diagnosis``: every candidate fitted, ranked, the verdict (:func:`diagnose`);
- ``tolerance``: whether the config's masses, stiffnesses and dampings, drifted within their
  tolerance, explain the record (:func:`within_tolerance`: no finding);
- ``tracking``: an axis's tracked effects fitted on the night's plant (:func:`fit_tracked`, hil fleet);
- ``result``: the chain's results as typed objects (:class:`ChainStep`, its JSON);
- ``chain``: diagnose, add the verdict, refit all, diagnose again (:func:`diagnose_chain`);
- ``emps``: the EMPS benchmark end to end;
- ``frf_fit``: the same effects fitted to measured frequency responses;
- ``synth``: records of a richer plant with a hidden effect.
"""
from hil.ident.chain import diagnose_chain
from hil.ident.diagnosis import Combo, candidate_names, diagnose, pair_score
from hil.ident.emps import EmpsResult, run_emps
from hil.ident.fit import Candidate, evaluate, fit_effects, joint_refit
from hil.ident.frf_fit import FrfData, FrfFit, fit_frf, is_frf_file, load_frf
from hil.ident.inverse import idim_ls
from hil.ident.noise import record_noise
from hil.ident.replay import POSITION_CHANNELS, Replay
from hil.ident.residual import motion_phases, periodic_in_position, spectrum_peaks
from hil.ident.residual_analysis import analyse, metrics
from hil.ident.result import ChainStep
from hil.ident.scores import MIN_SCORE, bic_score, effective_samples, noise_floor, nrmse_fit, relative_error
from hil.ident.synth import HIDDEN_DEFAULTS, synthesize
from hil.ident.tolerance import within_tolerance
from hil.ident.tracking import fit_tracked

__all__ = ["Replay", "POSITION_CHANNELS", "analyse", "metrics", "relative_error", "nrmse_fit", "noise_floor",
           "effective_samples", "bic_score", "MIN_SCORE", "spectrum_peaks", "periodic_in_position",
           "motion_phases", "Candidate", "evaluate", "fit_effects", "joint_refit", "diagnose", "diagnose_chain", "candidate_names",
           "Combo", "pair_score", "idim_ls", "run_emps", "EmpsResult", "fit_frf", "load_frf", "is_frf_file",
           "FrfData", "FrfFit", "synthesize", "HIDDEN_DEFAULTS", "record_noise", "within_tolerance",
           "fit_tracked", "ChainStep"]
