"""Fitting the catalogue's effects and parameters to measured frequency responses.

The same effects and ``parameter:<key>`` names as the time-domain fit (hil.sim_plant.effects), set
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

from hil.control import controller_from_config
from hil.errors import MeasurementError
from hil.frf import model_responses
from hil.plant_config import candidate, plant_from_config
from hil.sim_plant.effects import Combination

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
        if not (f.size == mag.size == ph.size == coh.size == std.size) or f.size < 3:
            raise FrfDataError(f"{path}: responses.{name}: lists of different lengths or fewer than 3 lines")
        ok = np.isfinite(f) & np.isfinite(mag) & np.isfinite(ph) & (mag > 0)
        out.f[name] = f[ok]
        out.h[name] = mag[ok] * np.exp(1j * ph[ok])
        out.rel_std[name] = np.clip(np.nan_to_num(std[ok] / mag[ok], nan=1.0), 1e-4, None)
        out.coherence[name] = coh[ok]
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
    held = {p.name: start[p.name] for p in eff.params if not p.fit}     # settings of the effect, not fitted
    logs = [p.lower >= 0 and start[p.name] > 0 for p in params]

    def to_values(z):
        return dict(held, **{p.name: (math.exp(v) if lg else v) for p, lg, v in zip(params, logs, z)})

    def f(z):
        try:
            return _residuals(eff.configure(cfg, to_values(z)), data, min_coherence)[0]
        except (ValueError, np.linalg.LinAlgError):
            return np.full(n_res, 1e3)

    r0, per0 = _residuals(cfg, data, min_coherence)
    n_res = r0.size
    z0 = np.array([math.log(start[p.name]) if lg else start[p.name] for p, lg in zip(params, logs)])
    lo = np.array([math.log(max(p.lower, 1e-300)) if lg else p.lower for p, lg in zip(params, logs)])
    hi = np.array([math.log(p.upper) if lg else p.upper for p, lg in zip(params, logs)])
    z0 = np.clip(z0, lo + 1e-9, hi - 1e-9)
    sol = least_squares(f, z0, bounds=(lo, hi), x_scale="jac", max_nfev=max_nfev)
    values = to_values(sol.x)
    new_cfg = eff.configure(cfg, values)
    r1, per1 = _residuals(new_cfg, data, min_coherence)
    return FrfFit(eff.name, values, float(np.sqrt(np.mean(r0 ** 2) * 1.0)), float(np.sqrt(np.mean(r1 ** 2))),
                  {k: {"before": per0.get(k), "after": per1.get(k)} for k in per0}, new_cfg)
