"""Readers of foreign measurement records into :class:`hil.measurement.Measurement`.

One mapping convention for every format, ``--map SOURCE=CHANNEL[unit]``: the source (a CSV
column, or a MATLAB variable or a product of variables and numbers) on the left, the project's
channel and optionally the unit the source is in on the right, e.g. for the EMPS benchmark::

    t=t, qg=x_cmd, qm=x_motor, vir=command, vir*gtau=force

``pos=x_table[mm]`` reads the column or variable ``pos`` as x_table in millimetres. Without a
unit, MATLAB values are taken as SI and CSV columns keep the unit of their header.
:func:`read_any` chooses the reader by the file suffix, so every command reads both formats.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from hil.io.measurement import CHANNELS, Measurement, MeasurementError, _check_time
from hil.io.measurement import read as read_csv

__all__ = ["read_mat", "read_any", "parse_mapping", "EMPS_MAPPING"]

EMPS_MAPPING = {"t": "t", "qg": "x_cmd", "qm": "x_motor", "vir": "command", "vir*gtau": "force"}

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_TARGET = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*(?:\[([^\]]*)\])?$")


def _target(source: str, target: str, where: str):
    """(channel, factor to SI) of a mapping's right-hand side."""
    from hil.io.measurement import _kind_of
    m = _TARGET.match(target.strip())
    if not m:
        raise MeasurementError(f"--map {source}={target}: expected CHANNEL or CHANNEL[unit]")
    name, unit = m.group(1), m.group(2)
    if unit is None or not unit.strip():
        return name, 1.0
    _, factor = _kind_of(name, unit.strip(), where)
    return name, factor


def parse_mapping(items) -> dict[str, str]:
    """``["qg=x_cmd", "vir*gtau=force"]`` or ``"qg=x_cmd,pos=x_table[mm]"`` -> {source: target}."""
    if items is None:
        return {}
    if isinstance(items, str):
        items = [items]
    out = {}
    for item in items:
        for part in item.split(","):
            part = part.strip()
            if not part:
                continue
            if "=" not in part:
                raise MeasurementError(f"--map {part!r}: expected SOURCE=CHANNEL[unit], e.g. qg=x_cmd or pos=x_table[mm]")
            a, _, b = part.partition("=")
            a, b = a.strip(), b.strip()
            if not _TARGET.match(b):
                raise MeasurementError(f"--map {part!r}: {b!r} is not CHANNEL or CHANNEL[unit]")
            out[a] = b
    return out


def _numeric(raw, name: str, source: str) -> np.ndarray:
    """A MATLAB variable as real numbers, or one line saying why it is not one (a string, a cell
    or struct, complex values with an imaginary part, nothing at all)."""
    a = np.asarray(raw)
    if a.dtype.kind in "USO" or a.dtype.names is not None:
        what = {"U": "text", "S": "text", "O": "a cell array or struct"}.get(a.dtype.kind, "a struct")
        raise MeasurementError(f"{source}: variable {name!r} is {what}, expected numbers")
    if a.dtype.kind == "c":
        if np.any(a.imag != 0):
            raise MeasurementError(f"{source}: variable {name!r} is complex (imaginary parts not 0), expected "
                                   f"real numbers")
        a = a.real
    if a.dtype.kind not in "biuf":
        raise MeasurementError(f"{source}: variable {name!r} has type {a.dtype}, expected numbers")
    if a.size == 0:
        raise MeasurementError(f"{source}: variable {name!r} is empty")
    return a.astype(float)


def _evaluate(expr: str, data: dict, source: str) -> np.ndarray:
    value = np.array(1.0)
    for factor in expr.split("*"):
        factor = factor.strip()
        if _TOKEN.match(factor):
            if factor not in data or factor.startswith("__"):
                # (scipy's __header__, __version__, __globals__ are file metadata, not variables)
                known = ", ".join(k for k in data if not k.startswith("__"))
                raise MeasurementError(f"{source}: no variable {factor!r} (the file has: {known})")
            v = _numeric(data[factor], factor, source)
        else:
            try:
                v = np.array(float(factor))
            except ValueError:
                raise MeasurementError(f"{source}: mapping {expr!r}: {factor!r} is neither a variable nor a "
                                       f"number") from None
        value = value * v.reshape(-1) if v.size > 1 else value * float(v.reshape(-1)[0])
    return np.asarray(value, float).reshape(-1)


def read_mat(path: str | Path, mapping: dict[str, str] | None = None) -> Measurement:
    """Read a MATLAB record. ``mapping``: source (variable or product) -> ``channel`` or
    ``channel[unit]`` (default: the variables named like channels, plus the EMPS names when
    present)."""
    import scipy.io
    source = str(path)
    try:
        data = scipy.io.loadmat(source)
    except FileNotFoundError:
        raise MeasurementError(f"{source}: no such file") from None
    except Exception as exc:    # scipy raises several kinds for a file that is not a .mat
        raise MeasurementError(f"{source}: not a readable MATLAB file ({exc})") from None
    if not mapping:
        mapping = {k: k for k in data if k in CHANNELS}
        if "qm" in data and "qg" in data:
            mapping = dict(EMPS_MAPPING) | mapping
    channels: dict[str, np.ndarray] = {}
    exprs: dict[str, str] = {}
    for expr, target in mapping.items():
        name, factor = _target(expr, target, source)
        if name in channels:
            raise MeasurementError(f"{source}: --map gives channel {name!r} twice ({exprs[name]} and {expr})")
        channels[name] = _evaluate(expr, data, source) * factor
        exprs[name] = expr
    mapping = exprs
    for req in ("t", "x_cmd"):
        if req not in channels:
            raise MeasurementError(f"{source}: the mapping gives no {req!r} channel (use --map VARIABLE={req})")
    n = channels["t"].size
    if n < 2:
        raise MeasurementError(f"{source}: 't' ({mapping['t']}) has {n} sample(s), a record needs at least 2")
    for name, v in channels.items():
        if v.size != n:
            raise MeasurementError(f"{source}: channel {name!r} ({mapping[name]}) has {v.size} samples, "
                                   f"'t' has {n}")
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise MeasurementError(f"{source}: channel {name!r} ({mapping[name]}), sample {bad[0] + 1}: NaN or "
                                   f"infinite value")
    _check_time(channels["t"], source, 1)
    meta = {"format": "mat", "mapping": ",".join(f"{v}={k}" for k, v in mapping.items())}
    return Measurement(channels, meta, source, {k: "" for k in channels})


def read_any(path: str | Path, mapping: dict[str, str] | None = None) -> Measurement:
    """A measurement CSV, or a MATLAB ``.mat`` record (chosen by the suffix)."""
    if str(path).lower().endswith(".mat"):
        return read_mat(path, mapping)
    return read_csv(path, mapping)
