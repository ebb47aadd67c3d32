"""JSON output of the commands (``--json``): numpy values to plain ones, and NaN or infinite
numbers to null, so that what a command prints is strict JSON for any parser."""
from __future__ import annotations

import json
import math
from pathlib import Path

__all__ = ["plain", "dumps"]


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
