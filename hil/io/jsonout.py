"""JSON output of the commands (``--json``): numpy values to plain ones, and NaN or infinite
numbers to null, so that what a command prints is strict JSON for any parser.

The keys each command prints are data beside the code that prints them: a module-level
``JSON_KEYS`` dict of the command's module, key -> :class:`JsonKey` (unit, meaning, when it is
present). The documentation's page reference/json.md is generated from those dicts when the site
is built (docs/gen_reference.py), and tests/test_json_reference.py runs every command with
``--json`` and checks its output against them.

Key names: a top-level key as printed (``verdict``); a key of the entries of a list
``candidates[].effect``; a key of a nested object ``final.end``. The convention of every command:
values are SI unless the key names its unit (``_um``, ``_hz``, ``_pct``, ``_us``, ``_deg``,
``_db``); the unit column says it for every numeric key.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import NamedTuple

__all__ = ["plain", "dumps", "JsonKey"]


class JsonKey(NamedTuple):
    """One documented key of a command's ``--json`` object.

    Parameters
    ----------
    unit : str
        The unit of its value ("" for text, flags, counts, lists and objects without one unit).
    text : str
        What it is, one line.
    when : str or None
        When the key is present (``"with --report"``); None: in every ordinary run of the command.
    """
    unit: str
    text: str
    when: str | None = None


def plain(x):
    """``x`` with numpy arrays and scalars, tuples and paths made plain, non-finite floats None."""
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if hasattr(x, "tolist"):        # numpy arrays and scalars (duck-typed: no numpy import at start-up)
        return plain(x.tolist())
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, (str, int, bool)) or x is None:
        return x
    if isinstance(x, Path):
        return str(x)
    return str(x)


def dumps(obj, indent: int | None = None) -> str:
    return json.dumps(plain(obj), indent=indent, allow_nan=False)
