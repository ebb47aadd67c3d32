"""The configuration's documentation, generated from the schema (the table at the end of
config/SCHEMA.md, docs/reference/config.md)."""
from __future__ import annotations

import math

from hil.config.schema import SCHEMA
from hil.units import SI_UNIT


def schema_markdown() -> str:
    """The documentation table of every key (the end of config/SCHEMA.md, whose prose it keeps)."""
    rows = ["| key | kind (SI unit) | default | meaning |", "|---|---|---|---|"]
    for key, f in SCHEMA.items():
        if callable(f.kind):
            kind = f"{f.kind({'actuator.type': 'rotary'})} / {f.kind({'actuator.type': 'linear'})}"
            unit = f"{SI_UNIT[f.kind({'actuator.type': 'rotary'})]} / {SI_UNIT[f.kind({'actuator.type': 'linear'})]}"
        else:
            kind, unit = f.kind, SI_UNIT.get(f.kind, "")
        if f.required:
            default = "required"
        elif f.default is None:
            default = "none"
        elif isinstance(f.default, float) and math.isinf(f.default):
            default = "inf"
        else:
            default = repr(f.default)
        choices = f" One of: {', '.join(f.choices)}." if f.choices else ""
        if f.minimum is not None and isinstance(f.kind, str) and f.kind in SI_UNIT:
            top = f" .. {f.maximum:g}" if f.maximum is not None else ""
            choices += f" Range: {f.minimum:g}{top} {SI_UNIT[f.kind]}."
        rows.append(f"| `{key.replace('*', 'N')}` | {kind} ({unit}) | {default} | {f.doc}.{choices} |"
                    .replace(" () |", " |"))
    return "\n".join(rows) + "\n"
