"""Fitting the catalogue's effects and parameters to measured frequency responses.

The same effects and ``parameter:<key>`` names as the time-domain fit (sim_plant.effects), set
against the responses ``hil frf`` measured (its ``frf.json``): the model's exact responses
(hil.frf.model_responses) are compared with the measured ones on a log scale,
log H_model - log H_measured (real part: the gain error in nepers, imaginary part: the phase
error in radians), each line weighted by its measured relative uncertainty, over the lines whose
coherence is high. The optimizer works on the logarithm of positive parameters.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from drivers.control import controller_from_config
from hil.errors import MeasurementError
from hil.frf import model_responses
from hil.plant_config import candidate, configure, plant_from_config
from sim_plant.effects import Combination

__all__ = ["FrfData", "load_frf", "fit_frf", "FrfFit", "is_frf_file", "PLANT_RESPONSES"]

# the responses of the plant itself (the loops' responses follow from them and the controller)
PLANT_RESPONSES = ("TF1p", "TF2", "TF3", "tip")


class FrfDataError(MeasurementError):
    """A frequency-response file that cannot be used; the message names the file and the key."""


@dataclass
class FrfData:
    f: dict[str, np.ndarray]
    h: dict[str, np.ndarray]          # complex
    rel_std: dict[str, np.ndarray]    # std of |H| / |H|
    coherence: dict[str, np.ndarray]
    source: str = "<frf>"


def is_frf_file(path) -> bool:
    """True for a ``hil frf`` result (JSON with ``responses``)."""
    p = Path(path)
    if p.suffix.lower() != ".json" or not p.is_file():
        return False
    try:
        return "responses" in json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False


# the magnitudes a response in SI units can have (m/(N m) of a stiff drive ~1e-9, a dimensionless
# TF2 ~1): beyond these it is not a measurement (issue 30: 1e300 fitted c2 = 8.4e6)
MAG_RANGE = (1e-30, 1e30)
# the largest median factor between a response and the start model's at the same lines: more is
# another axis or other units, not something a fit of one effect can explain
MAX_MODEL_FACTOR = 1e6
# the largest |phase| of an unwrapped response: a 10 ms delay at 1 kHz is 3600 deg, 1e5 deg is
# 278 turns; more is not a measurement (the red-team re-run: 1e300 deg fitted c2 = 65 for 11.8)
PHASE_LIMIT_DEG = 1e5


def _check_lines(where: str, f, mag, ph, coh, std) -> None:
    """One clear line for a response's lists that are not a measurement: the frequencies positive,
    finite and ascending (negative ones fitted c2 = 10.45), magnitudes positive and finite within
    :data:`MAG_RANGE`, phases finite within :data:`PHASE_LIMIT_DEG`, coherence 0..1, standard deviations finite and >= 0."""
    checks = (("frequency_hz", f, ~(np.isfinite(f) & (f > 0)), "positive finite frequencies in Hz"),
              ("magnitude", mag, ~(np.isfinite(mag) & (mag >= MAG_RANGE[0]) & (mag <= MAG_RANGE[1])),
               f"positive finite magnitudes within {MAG_RANGE[0]:g} .. {MAG_RANGE[1]:g}"),
              ("phase_deg", ph, ~(np.isfinite(ph) & (np.abs(ph) <= PHASE_LIMIT_DEG)),
               f"finite phases within +-{PHASE_LIMIT_DEG:g} deg"),
              ("coherence", coh, ~(np.isfinite(coh) & (coh >= 0) & (coh <= 1)), "a coherence 0 .. 1"),
              ("magnitude_std", std, ~(np.isfinite(std) & (std >= 0)), "finite standard deviations >= 0"))
    for key, v, bad, what in checks:
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise FrfDataError(f"{where}.{key}: expected {what}, got {v[i]:g} at line {i}")
    if np.any(np.diff(f) <= 0):
        i = int(np.flatnonzero(np.diff(f) <= 0)[0]) + 1
        raise FrfDataError(f"{where}.frequency_hz: expected ascending frequencies, got {f[i]:g} after {f[i - 1]:g} "
                           f"at line {i}")


def load_frf(path) -> FrfData:
    path = str(path)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FrfDataError(f"{path}: no such file") from None
    except ValueError as exc:
        raise FrfDataError(f"{path}: not JSON ({exc})") from None
    resp = data.get("responses")
    if not isinstance(resp, dict) or not resp:
        raise FrfDataError(f"{path}: no 'responses' object (expected the frf.json written by 'hil frf')")
    out = FrfData({}, {}, {}, {}, path)
    for name, r in resp.items():
        if name not in PLANT_RESPONSES or r.get("derived"):
            continue
        try:
            f = np.asarray(r["frequency_hz"], float)
            mag = np.asarray(r["magnitude"], float)
            ph = np.radians(np.asarray(r["phase_deg"], float))
            coh = np.asarray(r.get("coherence", np.ones_like(f)), float)
            std = np.asarray(r.get("magnitude_std", 0.05 * mag), float)
        except (KeyError, TypeError, ValueError) as exc:
            raise FrfDataError(f"{path}: responses.{name}: expected frequency_hz, magnitude, phase_deg lists "
                               f"({exc})") from None
        if not (f.size == mag.size == ph.size == coh.size == std.size) or f.size < 3 or f.ndim != 1:
            raise FrfDataError(f"{path}: responses.{name}: lists of different lengths or fewer than 3 lines")
        _check_lines(f"{path}: responses.{name}", f, mag, ph, coh, std)
        out.f[name] = f
        out.h[name] = mag * np.exp(1j * ph)
        out.rel_std[name] = np.clip(std / mag, 1e-4, None)
        out.coherence[name] = coh
    if not out.f:
        raise FrfDataError(f"{path}: none of the plant responses {', '.join(PLANT_RESPONSES)} is in the file")
    return out


@dataclass
class FrfFit:
    effect: str
    params: dict[str, float]
    error_before: float               # rms of the weighted log error
    error_after: float
    per_response: dict = field(default_factory=dict)
    config: object = None


def _residuals(cfg, data: FrfData, min_coherence: float):
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    out, per = [], {}
    for name, f in data.f.items():
        model = model_responses(plant, ctrl, f, tip_measured=name in ("TF3", "tip")).get(name)
        if model is None:
            continue
        sel = data.coherence[name] >= min_coherence
        if not np.any(sel):
            continue
        e = np.log(model[sel]) - np.log(data.h[name][sel])
        e = e.imag * 1j + e.real           # gain error (nepers) + i phase error (rad)
        e.imag = (e.imag + np.pi) % (2 * np.pi) - np.pi
        w = 1.0 / data.rel_std[name][sel]
        per[name] = float(np.sqrt(np.mean(np.abs(e) ** 2)))
        out.append(np.concatenate([e.real * w, e.imag * w]) / math.sqrt(sel.sum()))
    if not out:
        raise FrfDataError(f"{data.source}: no response line above coherence {min_coherence:g} that the model has")
    return np.concatenate(out), per


def _check_scale(cfg, data: FrfData) -> None:
    """Refuse a response whose magnitudes lie :data:`MAX_MODEL_FACTOR` or more from the start
    model's (median over its lines): another axis, or other units, not a fit's business."""
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    for name, f in data.f.items():
        model = model_responses(plant, ctrl, f, tip_measured=name in ("TF3", "tip")).get(name)
        if model is None:
            continue
        ratio = float(np.exp(np.median(np.log(np.abs(data.h[name])) - np.log(np.abs(model) + 1e-300))))
        if not 1.0 / MAX_MODEL_FACTOR < ratio < MAX_MODEL_FACTOR:
            raise FrfDataError(f"{data.source}: responses.{name}.magnitude: {ratio:.3g} times the model's (median over "
                               f"the lines), more than {MAX_MODEL_FACTOR:g} apart: not a response of this axis in SI "
                               f"units (is it the frf.json of this config?)")


def fit_frf(cfg, data: FrfData, names: list[str], min_coherence: float = 0.8, max_nfev: int = 200) -> FrfFit:
    """Fit the effects or ``parameter:<key>`` ``names`` (together) to the measured responses."""
    effs = [candidate(n, cfg) for n in names]
    eff = effs[0] if len(effs) == 1 else Combination(effs)
    plant = plant_from_config(cfg)
    start = {p.name: p.guess for p in eff.params}
    try:
        start.update(eff.guess(plant, {}))
    except Exception:       # an effect whose guess needs a time record: keep the catalogue's guess
        pass
    params = list(eff.fitted_params)
    # settings of the effect, not fitted (one a start does not give keeps the config's value)
    held = {p.name: start[p.name] for p in eff.params if not p.fit and p.name in start}
    logs = [p.lower >= 0 and start[p.name] > 0 for p in params]

    def to_values(z):
        return dict(held, **{p.name: (math.exp(v) if lg else v) for p, lg, v in zip(params, logs, z)})

    def f(z):
        try:
            return _residuals(configure(eff, cfg, to_values(z)), data, min_coherence)[0]
        except (ValueError, np.linalg.LinAlgError):
            return np.full(n_res, 1e3)

    r0, per0 = _residuals(cfg, data, min_coherence)
    _check_scale(cfg, data)
    n_res = r0.size
    z0 = np.array([math.log(start[p.name]) if lg else start[p.name] for p, lg in zip(params, logs)])
    lo = np.array([math.log(max(p.lower, 1e-300)) if lg else p.lower for p, lg in zip(params, logs)])
    hi = np.array([math.log(p.upper) if lg else p.upper for p, lg in zip(params, logs)])
    z0 = np.clip(z0, lo + 1e-9, hi - 1e-9)
    sol = least_squares(f, z0, bounds=(lo, hi), x_scale="jac", max_nfev=max_nfev)
    values = to_values(sol.x)
    new_cfg = configure(eff, cfg, values)
    r1, per1 = _residuals(new_cfg, data, min_coherence)
    return FrfFit(eff.name, values, float(np.sqrt(np.mean(r0 ** 2) * 1.0)), float(np.sqrt(np.mean(r1 ** 2))),
                  {k: {"before": per0.get(k), "after": per1.get(k)} for k in per0}, new_cfg)
