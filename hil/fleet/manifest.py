"""The records of a fleet: a manifest (CSV or TOML) or a folder of records.

Conventions: one :class:`Entry` per record: ``record`` (path), ``axis`` (an id), ``timestamp``
(ISO 8601 text, a date or a date and time; the order of an axis's records), ``config`` (path of
the axis's config; the command's ``--config`` where the manifest gives none) and ``baseline``
(true: one of the records the axis's control limits come from; when no record of an axis is
named, its first ``n_baseline`` are).

* CSV: a header with the columns ``record, axis, timestamp`` and optionally ``config, baseline``;
* TOML: ``[[record]]`` tables with the same keys;
* a folder: ``manifest.csv`` or ``manifest.toml`` in it when there is one, else every record
  named ``AXIS/TIMESTAMP.EXT`` or ``AXIS_TIMESTAMP.EXT`` (.csv, .mat, .txt, .xlsx), the timestamp
  ISO 8601.

Relative paths are relative to the manifest's folder. Bad input is one line naming the file, the
row and the column.
"""
from __future__ import annotations

import csv
import datetime as _dt
import io
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from hil.errors import ConfigError

__all__ = ["Entry", "read_manifest", "RECORD_SUFFIXES"]

RECORD_SUFFIXES = (".csv", ".mat", ".txt", ".xlsx")
COLUMNS = ("record", "axis", "timestamp", "config", "baseline")
_AXIS_RE = re.compile(r"^[A-Za-z0-9][\w.-]{0,63}$")
_FILE_RE = re.compile(r"^(?P<axis>[A-Za-z0-9][\w.-]*?)_(?P<ts>\d{4}-\d{2}-\d{2}(?:[T ]\d{2}[:\d]*)?)$")


@dataclass(frozen=True)
class Entry:
    """One record of the fleet (see the module's conventions)."""
    record: str
    axis: str
    timestamp: str
    config: str | None = None
    baseline: bool = False

    @property
    def id(self) -> str:
        """The record's name in reports and summaries: ``AXIS@TIMESTAMP``."""
        return f"{self.axis}@{self.timestamp}"


MAX_MANIFEST_BYTES = 16 << 20         # a manifest of a million records is a few tens of MiB: a bound, not a limit


def _text(path: Path) -> str:
    """A manifest's text: UTF-8 (a byte-order mark, as Excel's "CSV UTF-8" writes, dropped) or
    UTF-16 with its byte-order mark; a regular file of at most :data:`MAX_MANIFEST_BYTES`. One line
    naming the file for anything else."""
    try:
        st = path.stat()
        if not path.is_file():
            raise ConfigError(f"{path}: is not a regular file (a pipe or a device), expected a manifest")
        if st.st_size > MAX_MANIFEST_BYTES:
            raise ConfigError(f"{path}: {st.st_size >> 20} MiB, expected a manifest of at most "
                              f"{MAX_MANIFEST_BYTES >> 20} MiB")
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
            return raw.decode("utf-16")
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}); save the manifest as UTF-8 "
                          f"(a spreadsheet's \"CSV UTF-8\")") from None


def _timestamp(text: str, where: str) -> str:
    t = str(text).strip()
    try:
        _dt.datetime.fromisoformat(t)
    except ValueError:
        raise ConfigError(f"{where}: timestamp {t!r}: expected ISO 8601, e.g. 2026-03-04 or 2026-03-04T22:00") from None
    return t


def _bool(v, where: str) -> bool:
    if isinstance(v, bool):
        return v
    s = str(v).strip().lower()
    if s in ("", "0", "false", "no"):
        return False
    if s in ("1", "true", "yes"):
        return True
    raise ConfigError(f"{where}: baseline {v!r}: expected true or false")


def _config_path(cfg: str | None, base: Path) -> str | None:
    """A manifest's ``config`` as ``--config`` resolves it: absolute as it is; relative, the file
    beside the manifest where there is one, else a shipped example by that name (``paper_bench.toml``,
    ``config/paper_bench.toml``); neither: the path beside the manifest, which loading names."""
    if cfg is None or Path(cfg).is_absolute():
        return cfg
    from hil.config import shipped_example
    beside = base / cfg
    if beside.exists():
        return str(beside)
    shipped = shipped_example(Path(cfg))
    return str(shipped) if shipped is not None else str(beside)


def _entry(row: dict, base: Path, where: str) -> Entry:
    for col in ("record", "axis", "timestamp"):
        if not str(row.get(col) or "").strip():
            raise ConfigError(f"{where}: column {col!r} is empty or missing (expected: {', '.join(COLUMNS[:3])}"
                              f"; optional: config, baseline)")
    axis = str(row["axis"]).strip()
    if not _AXIS_RE.match(axis):
        raise ConfigError(f"{where}: axis {axis!r}: expected letters, digits, '_', '-', '.' (at most 64)")
    rec = Path(str(row["record"]).strip())
    rec = rec if rec.is_absolute() else base / rec
    if rec.exists() and not rec.is_file():
        raise ConfigError(f"{where}: record {str(rec)!r}: is not a regular file (a folder, a pipe or a device), "
                          f"expected a measurement file")
    cfg = _config_path(str(row.get("config") or "").strip() or None, base)
    return Entry(str(rec), axis, _timestamp(row["timestamp"], where),
                 cfg,
                 _bool(row.get("baseline", False), where))


def _from_csv(path: Path) -> list[Entry]:
    rows = list(csv.reader(io.StringIO(_text(path), newline="")))
    rows = [r for r in rows if r and not (len(r) == 1 and not r[0].strip()) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ConfigError(f"{path}: empty manifest (expected a header: record, axis, timestamp[, config, baseline])")
    head = [c.strip().lower() for c in rows[0]]
    unknown = [c for c in head if c not in COLUMNS]
    if unknown:
        raise ConfigError(f"{path}: line 1: unknown column {unknown[0]!r} (expected: {', '.join(COLUMNS)})")
    out = []
    for i, r in enumerate(rows[1:], start=2):
        if len(r) != len(head):
            raise ConfigError(f"{path}: line {i}: {len(r)} fields, expected {len(head)} ({', '.join(head)})")
        out.append(_entry(dict(zip(head, r)), path.parent, f"{path}: line {i}"))
    return out


def _from_toml(path: Path) -> list[Entry]:
    try:
        data = tomllib.loads(_text(path))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    recs = data.get("record")
    if not isinstance(recs, list) or not all(isinstance(r, dict) for r in recs):
        raise ConfigError(f"{path}: expected [[record]] tables (record, axis, timestamp[, config, baseline])")
    out = []
    for i, r in enumerate(recs, start=1):
        unknown = [c for c in r if c not in COLUMNS]
        if unknown:
            raise ConfigError(f"{path}: record {i}: unknown key {unknown[0]!r} (expected: {', '.join(COLUMNS)})")
        out.append(_entry(r, path.parent, f"{path}: record {i}"))
    return out


def _from_folder(folder: Path) -> list[Entry]:
    for name in ("manifest.csv", "manifest.toml"):
        if (folder / name).is_file():
            return read_manifest(folder / name)
    out = []
    for p in sorted(folder.rglob("*")):
        if not p.is_file() or p.suffix.lower() not in RECORD_SUFFIXES:
            continue
        rel = p.relative_to(folder)
        if len(rel.parts) == 2:
            axis, ts = rel.parts[0], p.stem
        else:
            m = _FILE_RE.match(p.stem)
            if not m:
                continue
            axis, ts = m.group("axis"), m.group("ts")
        try:
            # the record relative to the folder, as a manifest's are (str(p) already holds the folder)
            out.append(_entry({"record": str(rel), "axis": axis, "timestamp": ts}, folder, str(p)))
        except ConfigError:
            continue            # not a record of the fleet's naming
    if not out:
        raise ConfigError(f"{folder}: no manifest.csv or manifest.toml and no record named AXIS/TIMESTAMP.csv "
                          f"or AXIS_TIMESTAMP.csv")
    return out


def read_manifest(path: str | Path) -> list[Entry]:
    """The fleet's records from a manifest (.csv, .toml) or a folder, in (axis, time) order;
    a record listed twice is refused."""
    p = Path(path)
    if p.is_dir():
        entries = _from_folder(p)
    elif not p.exists():
        raise ConfigError(f"{p}: no such manifest or folder")
    elif p.suffix.lower() == ".csv":
        entries = _from_csv(p)
    elif p.suffix.lower() == ".toml":
        entries = _from_toml(p)
    else:
        raise ConfigError(f"{p}: expected a manifest (.csv or .toml) or a folder of records")
    if not entries:
        raise ConfigError(f"{p}: no record listed (expected a header, then one line per record: "
                          f"{', '.join(COLUMNS[:3])}[, config, baseline])")
    times = {e.timestamp: _dt.datetime.fromisoformat(e.timestamp) for e in entries}
    zoned = {t.tzinfo is not None for t in times.values()}
    if len(zoned) > 1:
        aware = next(k for k, t in times.items() if t.tzinfo is not None)
        naive = next(k for k, t in times.items() if t.tzinfo is None)
        raise ConfigError(f"{p}: timestamps with a time zone ({aware}) and without one ({naive}): their order is "
                          f"not defined; give every timestamp a zone, or none")
    seen = {}
    for e in entries:
        instant = (e.axis, times[e.timestamp])         # 2026-03-02 and 2026-03-02T00:00 are one instant
        if instant in seen:
            first = seen[instant]
            same = "" if first.timestamp == e.timestamp else f"; {e.timestamp} is the same instant"
            raise ConfigError(f"{p}: axis {e.axis} has two records at {first.timestamp} ({first.record}, "
                              f"{e.record}){same}")
        seen[instant] = e
    return sorted(entries, key=lambda e: (e.axis, times[e.timestamp], e.timestamp))
