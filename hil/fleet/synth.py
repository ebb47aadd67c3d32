"""A fleet with a known answer (``hil synth --fleet SPEC.toml``): axes x dates of records of one
base config, with effects that drift along the dates, for tests and the tutorial.

The spec (TOML; quantities with their units)::

    axes = ["X1", "X2", "X3"]
    start = "2026-03-02"          # the first date (ISO 8601)
    count = 6                     # dates
    every = "7 days"              # between dates (a time)
    duration = "2 s"              # each record's length
    scatter = 0.01                # night-to-night scatter, relative (1 %)
    [effects]                     # every axis, every date, before the scatter
    backlash = { gap = "4 um" }
    [[drift]]
    axis = "X2"
    parameter = "backlash.gap"    # effect.param (an effect of [effects], or a new one)
    from = "2026-03-16"           # the first date it differs
    step = "6 um"                 # added from that date on
    rate = "0.5 um"               # added per day after that date (optional)

Every record runs the same test move (the move sequence of seed 0, as a nightly check repeats
one program) with its own sensor noise; each effect value is scattered by a Gaussian factor
(1 + scatter N(0, 1)) per record, drawn from a seed of the axis and the date, so the fleet is the
same on every run. Written: ``AXIS_DATE.csv`` per record, ``manifest.csv`` (record, axis,
timestamp) and ``truth.json`` (every record's true values; per axis the drifting
parameters and the date each starts).
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import tomllib
from pathlib import Path

from hil.errors import ConfigError

__all__ = ["read_spec", "synthesize_fleet", "EXAMPLE"]

# ``--fleet example``: three axes of the paper bench, six weekly dates; X2's backlash grows from
# the fourth date (a worn nut), Y1's friction rises from the fifth (failing lubrication)
EXAMPLE = """\
axes = ["X1", "X2", "Y1"]
start = "2026-03-02"
count = 6
every = "7 days"
duration = "1.5 s"
scatter = 0.01
[effects]
backlash = { gap = "4 um" }
coulomb_friction = { level = "1.5 N*m" }
[[drift]]
axis = "X2"
parameter = "backlash.gap"
from = "2026-03-23"
step = "5 um"
rate = "0.1 um"
[[drift]]
axis = "Y1"
parameter = "coulomb_friction.level"
from = "2026-03-30"
step = "0.6 N*m"
"""

SPEC_KEYS = ("axes", "start", "count", "every", "duration", "sample_period", "scatter", "effects", "drift")
DRIFT_KEYS = ("axis", "parameter", "from", "step", "rate")


def _q(v, kind: str, where: str) -> float:
    from hil.units import DIMENSIONS, UnitError, parse_option
    try:
        return float(parse_option(str(v), kind if kind in DIMENSIONS else "dimensionless", where))
    except UnitError as exc:
        raise ConfigError(str(exc)) from None


def _param_kind(cfg, effect: str, param: str, where: str) -> str:
    from hil.plant_config import candidate
    try:
        eff = candidate(effect, cfg)
    except KeyError as exc:
        raise ConfigError(f"{where}: {str(exc).strip(chr(39) + chr(34))}") from None
    for p in eff.params:
        if p.name == param:
            return p.kind_for(cfg.rotary)
    raise ConfigError(f"{where}: {effect} has no parameter {param!r} (its parameters: "
                      f"{', '.join(p.name for p in eff.params)})")


def read_spec(path, cfg) -> dict:
    """The spec (a file, or ``"example"``: :data:`EXAMPLE`), checked and in SI: axes, dates (ISO text), duration, sample_period, scatter,
    effects {effect: {param: value}}, drift [{axis, effect, param, from, step, rate (per day)}]."""
    p = Path(path)
    try:
        raw = tomllib.loads(EXAMPLE if str(path) == "example" else p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"--fleet {p}: cannot be read ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"--fleet {p}: not valid TOML ({exc})") from None
    for k in raw:
        if k not in SPEC_KEYS:
            raise ConfigError(f"{p}: unknown key {k!r} (expected: {', '.join(SPEC_KEYS)})")
    axes = raw.get("axes")
    if not isinstance(axes, list) or not axes or not all(isinstance(a, str) and a.strip() for a in axes):
        raise ConfigError(f"{p}: axes: expected a list of axis names, e.g. [\"X1\", \"X2\"]")
    try:
        start = _dt.date.fromisoformat(str(raw.get("start", "2026-01-05")))
    except ValueError:
        raise ConfigError(f"{p}: start {raw.get('start')!r}: expected a date, e.g. 2026-03-02") from None
    count = raw.get("count", 5)
    if not isinstance(count, int) or not 1 <= count <= 1000:
        raise ConfigError(f"{p}: count {count!r}: expected a whole number of dates, 1 to 1000")
    every = _q(raw.get("every", "7 days"), "time", f"{p}: every")
    if not every >= 86400 - 1e-6:
        raise ConfigError(f"{p}: every {raw.get('every')!r}: expected at least 1 day")
    days = round(every / 86400)
    dates = [(start + _dt.timedelta(days=i * days)).isoformat() for i in range(count)]
    scatter = raw.get("scatter", 0.01)
    if not isinstance(scatter, (int, float)) or not 0 <= scatter < 0.5:
        raise ConfigError(f"{p}: scatter {scatter!r}: expected a relative scatter, 0 to 0.5 (0.01: 1 %)")
    effects = {}
    for eff, vals in (raw.get("effects") or {}).items():
        if not isinstance(vals, dict):
            raise ConfigError(f"{p}: effects.{eff}: expected a table of parameters, e.g. {{ gap = \"4 um\" }}")
        effects[eff] = {k: _q(v, _param_kind(cfg, eff, k, f"{p}: effects.{eff}"), f"{p}: effects.{eff}.{k}")
                        for k, v in vals.items()}
    drift = []
    for i, d in enumerate(raw.get("drift") or [], start=1):
        where = f"{p}: drift {i}"
        if not isinstance(d, dict) or any(k not in DRIFT_KEYS for k in d):
            raise ConfigError(f"{where}: expected the keys {', '.join(DRIFT_KEYS)}")
        if d.get("axis") not in axes:
            raise ConfigError(f"{where}: axis {d.get('axis')!r} is not one of axes")
        eff, _, par = str(d.get("parameter", "")).partition(".")
        kind = _param_kind(cfg, eff, par, where)
        try:
            since = _dt.date.fromisoformat(str(d.get("from"))).isoformat()
        except ValueError:
            raise ConfigError(f"{where}: from {d.get('from')!r}: expected a date, e.g. 2026-03-16") from None
        drift.append({"axis": d["axis"], "effect": eff, "param": par, "from": since,
                      "step": _q(d.get("step", "0"), kind, f"{where} step") if "step" in d else 0.0,
                      "rate": _q(d["rate"], kind, f"{where} rate") if "rate" in d else 0.0})
    duration = _q(raw.get("duration", "2 s"), "time", f"{p}: duration")
    sample_period = _q(raw.get("sample_period", "4 ms"), "time", f"{p}: sample_period")
    return {"axes": list(axes), "dates": dates, "duration": duration, "sample_period": sample_period,
            "scatter": float(scatter), "effects": effects, "drift": drift}


def _values(spec, axis: str, date: str) -> dict:
    """The true effect values of one record, before the scatter."""
    vals = {e: dict(v) for e, v in spec["effects"].items()}
    for d in spec["drift"]:
        if d["axis"] != axis or date < d["from"]:
            continue
        cur = vals.setdefault(d["effect"], {})
        base = cur.get(d["param"], 0.0)
        days = (_dt.date.fromisoformat(date) - _dt.date.fromisoformat(d["from"])).days
        cur[d["param"]] = base + d["step"] + d["rate"] * days
    return vals


def _seed(axis: str, date: str) -> int:
    return int.from_bytes(hashlib.sha256(f"{axis}|{date}".encode()).digest()[:4], "little")


def synthesize_fleet(cfg, spec: dict, out_dir, config_path: str, inputs=()) -> dict:
    """Write the fleet (see the module's conventions) to ``out_dir``; returns the truth."""
    import numpy as np

    from hil.ident.synth import move_sequence, synthesize
    from hil.io.measurement import write
    from hil.io.safe_write import write_atomic
    from hil.plant_config import candidate, configure
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    x_cmd = move_sequence(spec["duration"], cfg["control.position_period"], 0)
    rows = ["record,axis,timestamp"]         # the config: hil fleet run --config (each record's header names it)
    truth = {"records": {}, "drift": spec["drift"], "scatter": spec["scatter"]}
    for axis in spec["axes"]:
        for date in spec["dates"]:
            seed = _seed(axis, date)
            rng = np.random.default_rng(seed)
            vals = {e: {k: v * (1.0 + spec["scatter"] * rng.standard_normal()) for k, v in ps.items()}
                    for e, ps in _values(spec, axis, date).items()}
            rich = cfg
            for e, ps in vals.items():
                eff = candidate(e, rich)
                rich = configure(eff, rich, {p.name: ps.get(p.name, p.guess) for p in eff.params})
            ch, _ = synthesize(rich, None, duration=spec["duration"], sample_period=spec["sample_period"],
                               seed=seed % 100000, x_cmd=x_cmd)
            name = f"{axis}_{date}.csv"
            write(out / name, ch, {"sample_period": f"{spec['sample_period']:g} s", "config": config_path,
                                   "axis": axis, "timestamp": date,
                                   "hidden_effects": json.dumps(vals, sort_keys=True)}, inputs=inputs)
            rows.append(f"{name},{axis},{date}")
            truth["records"][f"{axis}@{date}"] = vals
    write_atomic(out / "manifest.csv", "\n".join(rows) + "\n", inputs=inputs)
    write_atomic(out / "truth.json", json.dumps(truth, indent=1, sort_keys=True) + "\n", inputs=inputs)
    return truth
