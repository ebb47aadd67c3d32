"""Readers of foreign measurement records into :class:`hil.measurement.Measurement`.

MATLAB ``.mat`` files are read with :func:`scipy.io.loadmat`. A *variable mapping* says which
channel each variable (or product of variables and numbers) becomes, e.g. for the EMPS benchmark::

    t=t, x_cmd=qg, x_motor=qm, command=vir, force=vir*gtau

Values are taken as SI (the mapping may multiply by a number to convert: ``x_motor=qm*1e-3``).
:func:`read_any` chooses the reader by the file suffix, so every command reads both formats.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .measurement import CHANNELS, Measurement, MeasurementError, _check_time
from .measurement import read as read_csv

__all__ = ["read_mat", "read_any", "parse_mapping", "EMPS_MAPPING"]

EMPS_MAPPING = {"t": "t", "x_cmd": "qg", "x_motor": "qm", "command": "vir", "force": "vir*gtau"}

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def parse_mapping(items) -> dict[str, str]:
    """``["x_cmd=qg", "force=vir*gtau"]`` or ``"x_cmd=qg,force=vir*gtau"`` -> dict."""
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
                raise MeasurementError(f"--map {part!r}: expected NAME=SOURCE, e.g. x_cmd=qg")
            a, _, b = part.partition("=")
            out[a.strip()] = b.strip()
    return out


def _evaluate(expr: str, data: dict, source: str) -> np.ndarray:
    value = np.array(1.0)
    for factor in expr.split("*"):
        factor = factor.strip()
        if _TOKEN.match(factor):
            if factor not in data:
                known = ", ".join(k for k in data if not k.startswith("__"))
                raise MeasurementError(f"{source}: no variable {factor!r} (the file has: {known})")
            v = np.asarray(data[factor], dtype=float)
        else:
            try:
                v = np.array(float(factor))
            except ValueError:
                raise MeasurementError(f"{source}: mapping {expr!r}: {factor!r} is neither a variable nor a "
                                       f"number") from None
        value = value * v.reshape(-1) if v.size > 1 else value * float(v.reshape(-1)[0])
    return np.asarray(value, float).reshape(-1)


def read_mat(path: str | Path, mapping: dict[str, str] | None = None) -> Measurement:
    """Read a MATLAB record. ``mapping``: channel -> variable or product (default: identity for
    the variables named like channels, plus the EMPS names when present)."""
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
            mapping = dict(EMPS_MAPPING) | {k: v for k, v in mapping.items()}
    channels: dict[str, np.ndarray] = {}
    for name, expr in mapping.items():
        channels[name] = _evaluate(expr, data, source)
    for req in ("t", "x_cmd"):
        if req not in channels:
            raise MeasurementError(f"{source}: the mapping gives no {req!r} channel (use --map {req}=VARIABLE)")
    n = channels["t"].size
    for name, v in channels.items():
        if v.size != n:
            raise MeasurementError(f"{source}: channel {name!r} ({mapping[name]}) has {v.size} samples, "
                                   f"'t' has {n}")
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise MeasurementError(f"{source}: channel {name!r} ({mapping[name]}), sample {bad[0] + 1}: NaN or "
                                   f"infinite value")
    _check_time(channels["t"], source, 1)
    meta = {"format": "mat", "mapping": ",".join(f"{k}={v}" for k, v in mapping.items())}
    return Measurement(channels, meta, source, {k: "" for k in channels})


def read_any(path: str | Path, mapping: dict[str, str] | None = None) -> Measurement:
    """A measurement CSV, or a MATLAB ``.mat`` record (chosen by the suffix)."""
    if str(path).lower().endswith(".mat"):
        return read_mat(path, mapping)
    return read_csv(path, mapping)
