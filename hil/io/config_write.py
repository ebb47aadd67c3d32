"""Writing a changed configuration as an edit of the user's file, not a rewrite.

``hil fit`` and ``hil diagnose --out`` change a few keys of a configuration (the fitted
parameters, the effects' sections). The file the user wrote keeps everything else: comments,
layout, the units each value was written in (``"10 mm"`` stays ``"10 mm"``), the keys left at
their defaults left out. Only the changed keys are touched (tomlkit, a style-preserving TOML
editor):

* a key the file has keeps its unit: the new SI value is converted into the unit it was written
  in (pint), a bare number stays a bare number (SI);
* a key the file does not have (a new ``[effects.<name>]`` section, a default that changed) is
  added with its value in an engineering unit (``hil.units.display_unit``);
* a value with a standard error is rounded to it (two significant digits of the error,
  ``hil.units.round_to_uncertainty``) and the error is written in a comment beside it; a value
  without one keeps 10 significant digits;
* a key whose new value is None is removed.

The comment beside a changed value says what changed it (``note``) and keeps the comment the line
had before.
"""
from __future__ import annotations

import math
import re
from typing import Any

import tomlkit
from tomlkit.items import Table

from hil.config import Config, field_for, load
from hil.errors import ConfigError
from hil.units import SI_UNIT, display_unit, parse, round_to_uncertainty

__all__ = ["changed_keys", "edit_config_text", "write_config"]

_NUMBER_UNIT = re.compile(r"^\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*(?P<unit>.*?)\s*$")


def changed_keys(old: Config, new: Config) -> list[str]:
    """The keys whose value differs between two configs (added, changed or removed), in the
    order of ``new`` (removed ones last)."""
    keys = [k for k, v in new.values.items() if v != old.values.get(k)]
    keys += [k for k, v in old.values.items() if v is not None and k not in new.values]
    return keys


def _kind(key: str, values: dict) -> str:
    f = field_for(key)
    return f.kind_for(values) if f is not None else "dimensionless"


def _written_unit(item) -> str | None:
    """The unit a string value was written with ("11.80 N*s/m" -> "N*s/m"); None when the item is
    not a number with a unit."""
    if not isinstance(item, str):
        return None
    m = _NUMBER_UNIT.match(str(item))
    return m.group("unit") if m and m.group("unit") else None


def _number_text(x: float, decimals: int | None) -> str:
    if decimals is None:            # no uncertainty: the value to 10 digits (no float noise)
        return f"{x:.10g}"
    return f"{x:.{max(decimals, 0)}f}" if decimals >= 0 else f"{round(x, decimals):.0f}"


def _new_item(key: str, value: Any, values: dict, old_item, sigma: float | None):
    """(tomlkit value, the standard error as text in the value's unit or None)."""
    if isinstance(value, (bool, int, str, list)) or value is None:
        return tomlkit.item(value), None
    value = float(value)
    kind = _kind(key, values)
    unit = _written_unit(old_item)
    if unit is not None:
        try:
            factor = 1.0 / parse(f"1 {unit}", kind, key)         # SI -> the unit it was written in
        except Exception:                                       # the old spelling no longer reads
            unit = None
    if unit is None:
        if isinstance(old_item, (int, float)) and not isinstance(old_item, bool) or kind == "dimensionless":
            unit, factor = "", 1.0                              # a bare number stays bare (SI)
        else:
            shown, factor = display_unit(value, kind)
            unit = _pint_spelling(kind, shown)
    if math.isinf(value):
        return tomlkit.item("inf" if value > 0 else "-inf"), None
    x = value * factor
    s = abs(sigma) * factor if sigma is not None and math.isfinite(sigma) and sigma > 0 else None
    r, dec = round_to_uncertainty(x, s) if s is not None else (x, None)
    text = _number_text(r, dec)
    s_text = (_number_text(s, dec) + (f" {unit}" if unit else "")) if s is not None else None
    if not unit:
        return tomlkit.item(float(text) if ("." in text or "e" in text) else int(text)), s_text
    return tomlkit.item(f"{text} {unit}"), s_text


def _pint_spelling(kind: str, shown: str) -> str:
    """The config spelling of a displayed unit (``"N m"`` -> ``"N*m"``), which hil.units reads back."""
    from hil.units import DISPLAY_UNITS
    for s, pint_unit, _ in DISPLAY_UNITS.get(kind, []):
        if s == shown:
            return pint_unit
    return SI_UNIT[kind]


def _table(doc, section: str, create: bool):
    """The table of a dotted section name (``effects.coulomb_friction``), created when asked."""
    node = doc
    parts = section.split(".") if section else []
    for i, part in enumerate(parts):
        if part not in node:
            if not create:
                return None
            # a parent that only holds sub-tables is written as [effects.x], not an empty [effects]
            node[part] = tomlkit.table(is_super_table=i < len(parts) - 1)
        node = node[part]
    return node


def edit_config_text(text: str, new: Config, keys: list[str], *, stderr: dict[str, float] | None = None,
                     note: str | dict[str, str] | None = None) -> str:
    """``text`` (a config file) with ``keys`` set to their values in ``new``, everything else as
    written.

    Parameters
    ----------
    text : str
        The TOML text of the original file.
    new : Config
        The changed configuration (SI values).
    keys : list of str
        Dotted keys to write (see :func:`changed_keys`); a key that ``new`` has as None is removed.
    stderr : dict, optional
        Standard error (SI) per key: the value is rounded to it and the error written in the comment.
    note : str or dict, optional
        What changed the values, written in the comment beside each (e.g. ``"hil fit on c2.csv"``);
        a dict: the note of each key (``hil tune``: each change with its reason).
    """
    try:
        doc = tomlkit.parse(text)
    except Exception as exc:  # tomlkit raises its own ParseError kinds
        raise ConfigError(f"cannot edit the config: not valid TOML ({exc})") from None
    stderr = stderr or {}
    for key in keys:
        section, _, name = key.rpartition(".")
        value = new.values.get(key)
        if value is None:
            tbl = _table(doc, section, create=False)
            if tbl is not None and name in tbl:
                del tbl[name]
            continue
        tbl = _table(doc, section, create=True)
        old_item = tbl.get(name)
        old_comment = getattr(getattr(old_item, "trivia", None), "comment", "") or ""
        old_comment = old_comment.lstrip("#").strip()
        item, s_text = _new_item(key, value, new.values, old_item, stderr.get(key))
        parts = []
        this = note.get(key) if isinstance(note, dict) else note
        if this:
            parts.append(this)
        if s_text:
            parts.append(f"+- {s_text} (standard error)")
        if old_item is not None and not isinstance(old_item, Table):
            parts.append(f"was {_as_written(old_item)}")
        if old_comment:
            parts.append(old_comment)
        if parts and hasattr(item, "comment"):
            item.comment("; ".join(parts))
        tbl[name] = item
    return tomlkit.dumps(doc)


def _as_written(item) -> str:
    v = item.unwrap() if hasattr(item, "unwrap") else item
    return f'"{v}"' if isinstance(v, str) else str(v)


def write_config(path, source: str, new: Config, *, stderr: dict[str, float] | None = None,
                 note: str | dict[str, str] | None = None,
                 inputs: tuple = ()) -> list[str]:
    """Write ``new`` to ``path`` as an edit of the config file ``source``: the keys where ``new``
    differs from the file (the --set values included) are written,
    the rest of the file kept. Returns the keys written."""
    from pathlib import Path

    from hil.io.safe_write import write_atomic
    base = load(source)
    text = Path(base.source).read_text(encoding="utf-8")
    keys = changed_keys(base, new)
    write_atomic(path, edit_config_text(text, new, keys, stderr=stderr, note=note), inputs=inputs)
    return keys
