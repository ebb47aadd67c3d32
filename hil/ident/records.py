"""Several records of one axis fitted together, and a model validated on records the fit did not
use (System Identification practice: estimation and validation data; every figure SI).

:class:`Records` stands where a :class:`~hil.ident.replay.Replay` does (the fits, the diagnosis,
the chain): each record is replayed by its own Replay (its own command, start position, noise
floor and channel weights), and

* the channels are those every record has;
* a channel's residual is the records' residuals one after the other;
* the objective sums the records' weighted residuals: each record's samples weighted by its own
  1 / max(RMS of its residual under the start config, its noise floor), so that
  sum_i sum_c w_ic^2 ||r_ic||^2 is minimised and each record counts by its samples;
* a channel's noise floor is the records' floors pooled by their samples,
  sqrt(sum_i n_i f_ic^2 / sum_i n_i), each record's from its own data (hil.ident.noise);
* the analyses that read the record (starting values, evidence) see the records joined in one
  :class:`~hil.io.measurement.Measurement`, each record's time going on :data:`GAP` s after the
  previous one's end, so that a velocity differentiated across a join is that of one side (a join
  is no motion).

:func:`record_errors` gives a config's errors on one record (RMS and relative 2-norm error % per
channel, against the record's own noise floor); :func:`estimation_validation` the errors of the
start and the fitted model on the estimation records and on the validation records, side by
side.
"""
from __future__ import annotations

import math

import numpy as np

from hil.errors import UserError
from hil.ident.noise import run_to_run_spread
from hil.ident.objective import Objective
from hil.ident.replay import Replay
from hil.ident.scores import relative_error
from hil.io.measurement import Measurement

__all__ = ["Records", "GAP", "record_errors", "estimation_validation", "common_channels", "errors_text"]

GAP = 1000.0      # s between two joined records (a velocity differentiated across it is ~0)


def common_channels(replays) -> list[str]:
    """The channels every replay compares, in the first one's order."""
    chans = [c for c in replays[0].channels if all(c in r.channels for r in replays[1:])]
    if not chans:
        raise UserError("the records have no measured channel in common (" +
                        "; ".join(f"{r.meas.source}: {', '.join(r.channels)}" for r in replays) + ")")
    return chans


class _JoinedObjective(Objective):
    """The records' weighted residuals: per channel one weight per record, on its samples."""

    def __init__(self, replay, weights, sample_weights, n):
        super().__init__(replay, weights, n)
        self.sample_weights = sample_weights

    def vector(self, res: dict) -> np.ndarray:
        return np.concatenate([res[c] * self.sample_weights[c] for c in self.weights])


class Records:
    """Records of one axis replayed through one config, fitted as one (see the module's
    definitions). ``parts``: the Replay of each record, all on the same config and channels."""

    def __init__(self, parts: list[Replay]):
        if not parts:
            raise ValueError("Records: no record")
        self.parts = list(parts)
        first = self.parts[0]
        self.cfg, self.plant, self.align = first.cfg, first.plant, first.align
        self.units = first.units
        self.channels = list(first.channels)
        for p in self.parts[1:]:
            if list(p.channels) != self.channels:
                raise ValueError("Records: the replays compare different channels (use common_channels)")
            if abs(p.sample_period / first.sample_period - 1.0) > 0.01:
                raise UserError(f"{p.meas.source}: sampled every {p.sample_period:g} s, {first.meas.source} every "
                                f"{first.sample_period:g} s: records fitted together need one sample period")
        self.force_channel, self.force_to_load = first.force_channel, first.force_to_load
        self.sample_period = first.sample_period
        self.shifts = dict(first.shifts)
        self.meas = _joined([p.meas for p in self.parts], self.channels)
        sizes = [p.meas.t.size for p in self.parts]
        self.noise_sources = {}
        for c in self.channels:
            f2 = sum(n * p.noise[c] ** 2 for n, p in zip(sizes, self.parts)) / sum(sizes)
            src = "; ".join(f"{p.meas.source}: {p.noise_sources[c]['source']}" for p in self.parts)
            self.noise_sources[c] = {"rms": math.sqrt(f2), "source": src,
                                     "quantization": max(p.noise_sources[c].get("quantization", 0.0) for p in self.parts)}
            still = [(n, p.noise_sources[c]["standstill"]) for n, p in zip(sizes, self.parts)
                     if p.noise_sources[c].get("standstill")]
            if still:       # the records' standstill noise, pooled by their samples as the floor
                self.noise_sources[c]["standstill"] = math.sqrt(sum(n * v * v for n, v in still) /
                                                                sum(n for n, _ in still))
        self._add_run_to_run_spread()
        self.noise = {c: self.noise_sources[c]["rms"] for c in self.channels}
        self.base_residuals = self._join([p.base_residuals for p in self.parts])
        rms = {c: float(np.sqrt(np.mean(self.base_residuals[c] ** 2))) for c in self.channels}
        weights = {c: 1.0 / max(rms[c], self.noise[c], 1e-15) for c in self.channels}
        sample_weights = {c: np.concatenate([np.full(n, p.objective.weights[c]) for n, p in zip(sizes, self.parts)])
                          for c in self.channels}
        self.objective = _JoinedObjective(self, weights, sample_weights, sum(sizes) * len(self.channels))

    def _add_run_to_run_spread(self) -> None:
        """Repetitions of one test (hil.ident.noise.run_to_run_spread) raise each channel's floor by
        their scatter, in quadrature: a model cannot be closer to a record than the records of the
        same command are to each other."""
        first = self.parts[0]
        command = first.drive_channel if first.open_loop else "x_cmd"
        spread = run_to_run_spread([p._source_meas for p in self.parts], self.channels, command)
        self.spread = {c: s["rms"] for c, s in spread.items()}
        for c, s in spread.items():
            ns = self.noise_sources[c]
            ns["spread"], ns["sensor"] = s["rms"], ns["rms"]
            ns["rms"] = math.hypot(ns["rms"], s["rms"])
            ns["source"] += f"; run-to-run spread of {s['repetitions']} repetitions of {s['tests']} test(s)"

    def _join(self, dicts) -> dict:
        return {c: np.concatenate([d[c] for d in dicts]) for c in self.channels}

    def with_config(self, cfg) -> "Records":
        return Records([p.with_config(cfg) for p in self.parts])

    def residuals(self, cfg=None) -> dict:
        return self._join([p.residuals(cfg) for p in self.parts])

    def residuals_many(self, cfgs: list) -> list:
        """Per config the joined residuals, or the first part's error (Replay.residuals_many)."""
        per_part = [p.residuals_many(cfgs) for p in self.parts]
        out = []
        for got in zip(*per_part):
            err = next((r for r in got if isinstance(r, Exception)), None)
            out.append(err if err is not None else self._join(got))
        return out

    def simulated(self, cfg=None) -> dict:
        sims = [p.simulated(cfg) for p in self.parts]
        keys = [k for k in sims[0] if all(k in s for s in sims)]
        return {k: np.concatenate([s[k] for s in sims]) for k in keys}

    unit = Replay.unit
    primary_channel = Replay.primary_channel


def _joined(measurements, channels) -> Measurement:
    """The records one after the other: each one's time going on GAP s after the previous end."""
    keys = ["t", "x_cmd"] + [c for c in channels if c not in ("t", "x_cmd")]
    keys += [k for k in ("u_add",) if all(k in m for m in measurements)]
    out = {k: [] for k in keys}
    t_end = None
    for m in measurements:
        t = m.t - m.t[0] + (0.0 if t_end is None else t_end + GAP)
        t_end = float(t[-1])
        out["t"].append(t)
        for k in keys[1:]:
            out[k].append(m[k])
    return Measurement({k: np.concatenate(v) for k, v in out.items()}, {},
                       " + ".join(m.source for m in measurements))


def record_errors(replay: Replay, cfg) -> dict:
    """A config's errors on one record: {"record", "samples", "error" (RMS per channel), "relative_error"
    (% per channel, 100 ||y - y_sim|| / ||y||), "noise_floor", "above_floor" (RMS / floor)}."""
    res = replay.residuals(cfg)
    err = {c: float(np.sqrt(np.mean(res[c] ** 2))) for c in replay.channels}
    rel = {c: relative_error(replay.meas[c], replay.meas[c] - res[c]) for c in replay.channels}
    return {"record": replay.meas.source, "samples": int(replay.meas.t.size), "error": err, "relative_error": rel,
            "noise_floor": dict(replay.noise),
            "above_floor": {c: err[c] / max(replay.noise[c], 1e-300) for c in err}}


def estimation_validation(estimation: list[Replay], validation: list[Replay], fitted) -> dict:
    """The errors of each replay's own (start) config and of ``fitted`` on the estimation records
    and on the validation records: {"estimation": [...], "validation": [...]}, each entry
    {"record", "samples", "before": record_errors(start), "after": record_errors(fitted)}."""
    def rows(replays):
        out = []
        for rp in replays:
            b, a = record_errors(rp, rp.cfg), record_errors(rp, fitted)
            out.append({"record": b["record"], "samples": b["samples"], "before": b, "after": a})
        return out
    return {"estimation": rows(estimation), "validation": rows(validation)}


def errors_text(table: dict, unit) -> list[str]:
    """The estimation and validation errors side by side, one line per record: per channel the RMS
    before -> after (its ratio to the record's noise floor) and the relative error % after."""
    from hil.units import fmt_si
    lines = ["errors per record (RMS start -> fitted, x floor = ratio to the record's noise floor, rel % fitted):"]
    for kind in ("estimation", "validation"):
        for r in table.get(kind, []):
            b, a = r["before"], r["after"]
            parts = [f"{c} {fmt_si(b['error'][c], unit(c))} -> {fmt_si(a['error'][c], unit(c))} "
                     f"({a['above_floor'][c]:.1f} x floor, {a['relative_error'][c]:.3g} %)" for c in a["error"]]
            lines.append(f"  {kind:10s} {r['record']}: " + ", ".join(parts))
    return lines
