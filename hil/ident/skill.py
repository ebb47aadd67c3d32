"""Skill against baselines that need no model.

A fall of the error says the model got better than it was; not that it is any good. Two baselines
judge it:

- ``start``: the model the diagnosis started from (the config as given);
- ``command``: "the axis is where it was told to be", the measured position predicted by the
  position command itself. Its error is the following error, ``x - x_cmd`` on each measured
  position channel. A model whose position error is no smaller than that predicts the positions no
  better than no model at all (LinA's sine sweep: a fitted 34 um against a following error of
  31 um).

Each is given as the fit in percent, NRMSE-style, ``100 (1 - e_model / e_baseline)`` (RMS over the
same samples): 100 % a perfect model, 0 % no better than the baseline, negative worse. Closed-loop
records with a position command only; an open-loop record has no such baseline.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["POSITION_CHANNELS", "command_baseline", "skill", "skill_text"]

POSITION_CHANNELS = ("x_motor", "x_table", "x_tip")


def command_baseline(replay) -> dict[str, float]:
    """Per position channel that ``replay`` (a Replay or Records) compares: the RMS of ``x - x_cmd``
    over its records' samples. Empty for an open-loop record or one without ``x_cmd``."""
    parts = getattr(replay, "parts", [replay])
    out = {}
    for c in POSITION_CHANNELS:
        ss, n = 0.0, 0
        for p in parts:
            m = p.meas
            if getattr(p, "open_loop", False) or c not in p.channels or "x_cmd" not in m or c not in m:
                n = 0
                break
            e = np.asarray(m[c], float) - np.asarray(m["x_cmd"], float)
            ss, n = ss + float(np.sum(e * e)), n + e.size
        if n:
            out[c] = math.sqrt(ss / n)
    return out


def _fit(err: dict, base: dict) -> dict:
    return {c: 100.0 * (1.0 - err[c] / base[c]) for c in base if c in err and base[c] > 0}


def skill(replay, start: dict, final: dict) -> dict:
    """The final error ``final`` (RMS per channel; ``error``) against the two baselines: ``baseline``
    {"start": start, "command": following error}, ``fit_percent`` {"start": ..., "command": ...},
    ``no_skill``: the position channels where the model is no better than the command, and
    ``has_skill``: False where that holds on every position channel that has the baseline."""
    base = command_baseline(replay)
    no_skill = [c for c in base if c in final and final[c] >= base[c]]
    return {"error": dict(final), "baseline": {"start": dict(start), "command": base},
            "fit_percent": {"start": _fit(final, start), "command": _fit(final, base)},
            "no_skill": no_skill, "has_skill": not (base and len(no_skill) == len(base))}


def skill_text(s: dict, fmt) -> list[str]:
    """The answer first where the model has no skill; then the fit against each baseline.
    ``fmt(channel, value)``: a value in the channel's unit."""
    lines = []
    base = s["baseline"]["command"]
    if not s["has_skill"]:
        lines.append("the model has no skill here: it predicts "
                     + ", ".join(f"{c} no better than the command itself (model {fmt(c, s['error'][c])}, "
                                 f"following error {fmt(c, base[c])})" for c in s["no_skill"]))
    fit = s["fit_percent"]
    if fit["command"] or fit["start"]:
        lines.append("skill (fit %: 100 perfect, 0 no better than the baseline):")
    if fit["command"]:
        lines.append("  against the command ('the axis is where it was told to be'): "
                     + ", ".join(f"{c} {v:.1f} % (following error {fmt(c, base[c])})" for c, v in fit["command"].items()))
    if fit["start"]:
        lines.append("  against the start model: " + ", ".join(f"{c} {v:.1f} %" for c, v in fit["start"].items()))
    return lines
