"""The project's measurement file format: CSV with units in the header.

::

    # sample_period = 0.004 s
    # config = config/paper_bench.toml
    t [s],x_cmd [mm],x_motor [mm],x_table [mm],x_tip [mm],torque [N*m]
    0,0,0,0,0,0
    ...

Optional ``#`` comment lines first (``key = value`` metadata), then one header row whose names
carry their unit in brackets. Channels: ``t`` and ``x_cmd`` are required (``x_cmd`` not in an
open-loop record, which has the actuator's command instead); ``v_cmd``, ``x_motor``, ``x_table``,
``x_tip``, ``torque``, ``force``, ``command``, ``e_table``, ``e_tip`` are known; unknown channels
are kept and ignored. Everything is converted to SI on reading.

Measured inputs besides the command (hil.ident.replay feeds them into the one compiled loop):

- ``u_add``: an additive command after the controller (a pulse train, a frequency-response
  excitation), in the actuator's units: a torque [N*m] on a rotary axis, a command [V] or a
  force [N] on a linear one (a force is divided by the drive gain). Whether the recorded
  controller output (torque / force / command) includes it is the config key
  ``measurement.output_includes_u_add`` (default true: the drive's command was logged after the
  addition, as EMPS's ``vir``).
- ``f_ext_table``, ``f_ext_tip`` [N]: a measured external force on the table or on the tool tip
  (a cutting force), + in +x, acting on that mass of the chain.
- an open-loop record (``--open-loop``): no position loop; the actuator's measured command
  (``torque`` on a rotary axis, ``command`` or ``force`` on a linear one) drives the plant, and
  the positions are compared. ``x_cmd`` may then be absent or identically zero.

Reading never fails for a record that can still be replayed: gaps of the time base come back as
``Measurement.warnings`` (sample numbers counted from 1), printed by the commands.
"""
from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hil.errors import MeasurementError

__all__ = ["Measurement", "MeasurementError", "read", "write", "CHANNELS", "UNITS", "header_name"]


# unit text -> (quantity kind, factor to SI)
UNITS = {
    "s": ("time", 1.0), "ms": ("time", 1e-3),
    "m": ("length", 1.0), "mm": ("length", 1e-3), "um": ("length", 1e-6), "µm": ("length", 1e-6),
    "m/s": ("speed", 1.0), "mm/s": ("speed", 1e-3), "mm/min": ("speed", 1e-3 / 60), "m/min": ("speed", 1 / 60),
    "N*m": ("torque", 1.0), "N m": ("torque", 1.0), "Nm": ("torque", 1.0),
    "N": ("force", 1.0), "kN": ("force", 1e3), "V": ("voltage", 1.0), "mV": ("voltage", 1e-3),
    "1": ("dimensionless", 1.0), "A": ("current", 1.0), "mA": ("current", 1e-3), "mN*m": ("torque", 1e-3),
    "rad": ("angle", 1.0), "rad/s": ("angular_speed", 1.0),
}

# known channels -> expected kind
CHANNELS = {
    "t": "time", "x_cmd": "length", "v_cmd": "speed", "x_motor": "length", "x_table": "length",
    "x_tip": "length", "torque": "torque", "force": "force", "command": "voltage",
    "e_table": "length", "e_tip": "length",
    # 1 where the row's feedback repeats the last answer (a real axis's missed cycle), else 0
    "stale": "dimensionless",
    # measured inputs besides the command: an additive command after the controller (in the
    # actuator's units: torque, force or voltage) and external forces on the table and the tip
    "u_add": "actuator", "f_ext_table": "force", "f_ext_tip": "force",
}
# the kinds an "actuator" channel may have
ACTUATOR_KINDS = ("torque", "force", "voltage")
INPUT_CHANNELS = ("u_add", "f_ext_table", "f_ext_tip")
REQUIRED = ("t", "x_cmd")

# the unit the writer uses per kind
WRITE_UNIT = {"time": "s", "length": "mm", "speed": "mm/s", "torque": "N*m", "force": "N", "voltage": "V",
              "dimensionless": "1", "angle": "rad", "angular_speed": "rad/s", "current": "A"}

_HEADER = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(?:\[([^\]]*)\])?\s*$")

# Bounds of what a record file may hold (issue 30): the file (a 1 kHz record of an hour's run is
# some 400 MB), one field of a row or of the header (a number, a "name [unit]").
MAX_RECORD_BYTES = 1 << 30
MAX_FIELD_CHARS = 256


@dataclass
class Measurement:
    """Channels in SI by name, the metadata of the comment lines, and where it came from."""
    channels: dict[str, np.ndarray]
    meta: dict[str, str] = field(default_factory=dict)
    source: str = "<measurement>"
    units: dict[str, str] = field(default_factory=dict)   # as written in the file
    warnings: list[str] = field(default_factory=list)     # what the reader noticed (gaps), for the commands to print

    def __getitem__(self, name: str) -> np.ndarray:
        return self.channels[name]

    def __contains__(self, name: str) -> bool:
        return name in self.channels

    @property
    def t(self) -> np.ndarray:
        return self.channels["t"]

    @property
    def sample_period(self) -> float:
        return float(np.median(np.diff(self.t)))

    def __len__(self) -> int:
        return len(self.t)


def header_name(name: str, kind: str | None = None) -> str:
    kind = kind or CHANNELS.get(name, "dimensionless")
    if kind == "actuator":
        kind = "torque"
    return f"{name} [{WRITE_UNIT[kind]}]"


def _kind_of(name: str, unit: str | None, where: str) -> tuple[str, float]:
    if unit is None or unit.strip() == "":
        if name in CHANNELS and CHANNELS[name] != "dimensionless":
            raise MeasurementError(f"{where}: column {name!r} has no unit in brackets (e.g. "
                                   f"'{header_name(name)}')")
        return "dimensionless", 1.0
    u = unit.strip()
    if u not in UNITS:
        raise MeasurementError(f"{where}: column {name!r}: unknown unit [{u}] (known: {', '.join(UNITS)})")
    kind, factor = UNITS[u]
    want = CHANNELS.get(name)
    if want == "actuator":
        if kind not in ACTUATOR_KINDS:
            raise MeasurementError(f"{where}: column {name!r}: unit [{u}] is a {kind}, expected the actuator's unit "
                                   f"(a torque [N*m], a force [N] or a command [V])")
        return kind, factor
    if want is not None and kind != want:
        raise MeasurementError(f"{where}: column {name!r}: unit [{u}] is a {kind}, expected a {want} "
                               f"(e.g. [{WRITE_UNIT[want]}])")
    return kind, factor


def read(path: str | Path, mapping: dict[str, str] | None = None) -> Measurement:
    """Read a measurement file (SI on return). ``mapping`` renames columns (``{"pos": "x_table"}``)
    and may give a unit for columns that have none (``{"pos": "x_table [mm]"}``)."""
    path = str(path)
    text, notes = read_record_text(path)
    meas = parse_text(text, path, mapping)
    meas.warnings[:0] = notes
    return meas


def read_record_text(path: str | Path) -> tuple[str, list[str]]:
    """The text of a measurement file (without a BOM: spreadsheet exports), and the reader's
    notes about it: a record whose run did not end cleanly comes without a last line cut in its
    write (:func:`_cut_record`)."""
    path = str(path)
    check_record_file(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MeasurementError(f"{path}: no such file") from None
    except UnicodeDecodeError:
        raise MeasurementError(f"{path}: not a UTF-8 text file") from None
    except IsADirectoryError:
        raise MeasurementError(f"{path}: is a folder, expected a measurement file") from None
    except OSError as exc:
        raise MeasurementError(f"{path}: cannot read ({exc.strerror})") from None
    text, notes = _cut_record(text, path)
    return text.removeprefix("\ufeff"), notes


def check_record_file(path: str | Path) -> None:
    """Refuse, in one line, a record ``path`` that is no regular file (a folder, a FIFO, a
    device: reading one would never end) or larger than :data:`MAX_RECORD_BYTES`."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise MeasurementError(f"{path}: no such file") from None
    except OSError as exc:
        raise MeasurementError(f"{path}: cannot read ({exc.strerror})") from None
    if p.is_dir():
        raise MeasurementError(f"{path}: is a folder, expected a measurement file")
    if not p.is_file():
        raise MeasurementError(f"{path}: is not a regular file (a pipe or a device), expected a measurement file")
    if st.st_size > MAX_RECORD_BYTES:
        raise MeasurementError(f"{path}: {st.st_size / 2**20:.0f} MiB, expected a record of at most "
                               f"{MAX_RECORD_BYTES >> 20} MiB (split it, or keep every n-th row)")


def check_fields(line: str, lineno: int, source: str, sep: str | None = ",", names=None,
                 what: str = "a number") -> None:
    """Refuse, in one line naming the file, line and column, a ``line`` with a field longer than
    :data:`MAX_FIELD_CHARS` (``sep``: the separator, None: whitespace; ``names``: the columns)."""
    if len(line) <= MAX_FIELD_CHARS:
        return
    for c, cell in enumerate(line.split(sep)):
        if len(cell) > MAX_FIELD_CHARS:
            col = repr(names[c]) if names is not None and c < len(names) else str(c + 1)
            raise MeasurementError(f"{source}, line {lineno}, column {col}: a field of {len(cell)} characters "
                                   f"({_shown(cell)}), expected {what} of at most {MAX_FIELD_CHARS} characters")


def _shown(text: str, n: int = 40) -> str:
    """A text as written, cut for a one-line message."""
    return repr(text) if len(text) <= n else repr(text[:n]) + "..."


def _cut_record(text: str, path: str) -> tuple[str, list[str]]:
    """A record whose run did not end cleanly (its status beside it still says ``running``, the
    recording process gone: killed, crashed): the text without its last line where that was cut
    in its ``write()`` (no line break at its end), and a warning saying so."""
    from hil.io.record_status import status_of
    st = status_of(path)
    if st is None or st.get("ended_cleanly") is not False:
        return text, []
    notes = []
    if text and not text.endswith(("\n", "\r")):
        lineno = text.count("\n") + 1
        text = text[:text.rfind("\n") + 1]
        notes.append(f"{path}, line {lineno}: cut short when its run ended, dropped")
    notes.append(f"{path}: the run did not end cleanly (its status {Path(path).with_suffix('.json').name} still says "
                 f"running, {st.get('rows', '?')} rows at its last update; the recording process is gone): the "
                 f"record ends where the run was cut")
    return text, notes


def parse_text(text: str, source: str = "<text>", mapping: dict[str, str] | None = None, raw: bool = False):
    """The measurement of a CSV text; ``raw``: (names, units as written, values as written, meta),
    for a map to evaluate expressions of the columns (hil.io.importers)."""
    lines = text.splitlines()
    meta: dict[str, str] = {}
    i = 0
    while i < len(lines) and (lines[i].startswith("#") or not lines[i].strip()):
        body = lines[i][1:].strip() if lines[i].startswith("#") else ""
        if "=" in body:
            k, _, v = body.partition("=")
            meta[k.strip()] = v.strip()
        i += 1
    if i >= len(lines):
        raise MeasurementError(f"{source}: no header line (expected e.g. 't [s],x_cmd [mm],x_table [mm]')")
    header_line = i + 1
    check_fields(lines[i], header_line, source, what="a header cell 'name [unit]'")
    try:
        header = next(csv.reader([lines[i]]))
    except csv.Error as exc:
        raise MeasurementError(f"{source}, line {header_line}: not a header of 'name [unit]' cells ({exc})") from None
    names, factors, units = [], [], {}
    seen = set()          # the names so far, for the duplicate check (a list search was quadratic: 100 000 columns took 53 s)
    mapping = mapping or {}
    for col, cell in enumerate(header):
        m = _HEADER.match(cell)
        if not m:
            raise MeasurementError(f"{source}, line {header_line}: column {col + 1} header {_shown(cell)} is not "
                                   f"'name [unit]'")
        name, unit = m.group(1), m.group(2)
        if raw:
            if name in seen:
                raise MeasurementError(f"{source}, line {header_line}: column {name!r} appears twice")
            seen.add(name)
            names.append(name)
            factors.append(1.0)
            if unit is not None and unit.strip():
                units[name] = unit.strip()
            continue
        if name in mapping:
            target = mapping[name]
            mm = _HEADER.match(target)
            if not mm:
                raise MeasurementError(f"--map {name}={target}: expected 'channel' or 'channel [unit]'")
            name = mm.group(1)
            unit = mm.group(2) if mm.group(2) is not None else unit
        where = f"{source}, line {header_line}"
        kind, factor = _kind_of(name, unit, where)
        if name in seen:
            raise MeasurementError(f"{where}: column {name!r} appears twice")
        seen.add(name)
        names.append(name)
        factors.append(factor)
        units[name] = unit or ""
    for req in () if raw else REQUIRED:
        if req == "x_cmd" and any(c in names for c in ("torque", "force", "command")):
            continue          # an open-loop record: its actuator's command drives (check_usable asks for --open-loop)
        if req not in names:
            shown = ", ".join(names)
            shown = shown if len(shown) <= 200 else shown[:197] + "..."
            raise MeasurementError(f"{source}, line {header_line}: missing required column {req!r} "
                                   f"(header has: {shown}); a record with other column names is read with "
                                   f"--map SOURCE=CHANNEL[unit], e.g. --map 'Time=t[s],Cmd=x_cmd[mm]' "
                                   f"(docs/how-to/column-names.md)")
    rows = []
    data_lines = lines[i + 1:]
    for j, line in enumerate(data_lines):
        lineno = i + 2 + j
        if not line.strip() or line.startswith("#"):
            continue
        check_fields(line, lineno, source, names=names)
        cells = line.split(",")
        if len(cells) != len(names):
            if j == len(data_lines) - 1:
                break        # a last line cut short (a run killed mid-write): drop it
            raise MeasurementError(f"{source}, line {lineno}: {len(cells)} values, expected {len(names)}")
        try:
            row = [float(c) for c in cells]
            if "_" in line:          # float() reads "1_000" as 1000: a cell means what it shows
                raise ValueError
        except ValueError:
            bad = next(c for c in cells if not _is_float(c))
            col = cells.index(bad)
            raise MeasurementError(f"{source}, line {lineno}, column {names[col]!r}: {_shown(bad.strip())} is not "
                                   f"a number") from None
        for c, v in enumerate(row):
            if math.isnan(v) or math.isinf(v):
                raise MeasurementError(f"{source}, line {lineno}, column {names[c]!r}: {cells[c].strip()} "
                                       f"(NaN or infinite values are not allowed; remove or fill the gap)")
        rows.append(row)
    if len(rows) < 2:
        raise MeasurementError(f"{source}: fewer than 2 data rows")
    arr = np.array(rows) * np.array(factors)
    if raw:
        return names, units, arr, meta
    channels = {n: arr[:, c].copy() for c, n in enumerate(names)}
    warnings = _check_time(channels["t"], source, i + 2)
    return Measurement(channels, meta, source, units, warnings)


def _is_float(s: str) -> bool:
    try:
        if "_" in s:
            return False
        float(s)
        return True
    except ValueError:
        return False


def _check_time(t: np.ndarray, source: str, first_line: int) -> list[str]:
    """Refuse a time base that does not increase; a gap (a step over 1.5 sample periods) is a
    warning with its line (sample) numbers: the replay interpolates over it."""
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise MeasurementError(f"{source}, line {first_line + k}, column 't': time {t[k]:g} s is not after "
                               f"the previous {t[k - 1]:g} s (time must increase strictly)")
    med = float(np.median(dt))
    where = "line" if first_line > 1 else "sample"
    gaps = np.flatnonzero(dt > 1.5 * med)
    out = []
    if gaps.size:
        k = int(gaps[0]) + 1
        more = f" ({gaps.size} gaps in all, the widest {dt.max():g} s)" if gaps.size > 1 else ""
        out.append(f"{source}, {where} {first_line + k}, column 't': a gap of {dt[k - 1]:g} s after {t[k - 1]:g} s "
                   f"(the sample period is {med:g} s){more}; the replay interpolates over it")
    # irregular steps short of a gap (a logger that samples every 12-20 ms): the spectra and the noise
    # floor assume one period, so more than IRREGULAR_SHARE of the steps off by IRREGULAR_STEP is said
    off = np.flatnonzero((np.abs(dt - med) > IRREGULAR_STEP * med) & (dt <= 1.5 * med))
    if off.size > IRREGULAR_SHARE * dt.size:
        first = ", ".join(str(first_line + int(k) + 1) for k in off[:5])
        out.append(f"{source}, column 't': irregular sampling: {off.size} of {dt.size} steps differ from the median "
                   f"{med:g} s by more than {IRREGULAR_STEP:.0%} (from {dt.min():g} s to {dt.max():g} s; first at "
                   f"{where}s {first}); the replay interpolates between the samples, the spectra assume {med:g} s")
    return out


IRREGULAR_STEP = 0.10      # a step this far from the median period is irregular
IRREGULAR_SHARE = 0.01     # ... and said when more than this share of the steps are


def format_rows(columns: list[np.ndarray], factors: list[float]) -> str:
    """CSV rows of the given SI columns, each divided by its factor (to the written unit)."""
    buf = io.StringIO()
    data = np.column_stack([c / f for c, f in zip(columns, factors)])
    np.savetxt(buf, data, delimiter=",", fmt="%.10g")
    return buf.getvalue()


def write(path: str | Path, channels: dict[str, np.ndarray], meta: dict[str, object] | None = None,
          inputs=(), kinds: dict[str, str] | None = None) -> Path:
    """Write channels (SI) in the measurement format, at once (hil.io.safe_write.write_atomic:
    never through a symbolic link, never over one of ``inputs``). ``kinds``: the quantity of a
    channel whose kind is not fixed (``u_add``: torque, force or voltage; torque by default)."""
    from hil.io.safe_write import write_atomic
    path = Path(path)
    if path.suffix.lower() == ".mat":
        return write_mat(path, channels, meta, inputs)
    names = list(channels)
    kinds = [(kinds or {}).get(n) or CHANNELS.get(n, "dimensionless") for n in names]
    kinds = ["torque" if k == "actuator" else k for k in kinds]
    fh = io.StringIO()
    for k, v in (meta or {}).items():
        fh.write(f"# {k} = {v}\n")
    fh.write(",".join(header_name(n, k) for n, k in zip(names, kinds)) + "\n")
    fh.write(format_rows([np.asarray(channels[n], float) for n in names],
                         [UNITS[WRITE_UNIT[k]][1] for k in kinds]))
    write_atomic(path, fh.getvalue(), inputs=inputs)
    return path


def write_mat(path: str | Path, channels: dict[str, np.ndarray], meta: dict[str, object] | None = None,
              inputs=()) -> Path:
    """Write channels (SI) as a MATLAB v5 file (scipy.io.savemat): one column vector per channel,
    named like the channel, so that ``hil compare FILE.mat`` reads it without ``--map``; ``meta``
    as text variables. At once, never through a link (hil.io.safe_write.write_atomic)."""
    import scipy.io

    from hil.io.safe_write import write_atomic
    fh = io.BytesIO()
    data = {n: np.asarray(v, float).reshape(-1, 1) for n, v in channels.items()}
    data.update({k: str(v) for k, v in (meta or {}).items() if k.isidentifier() and k not in data})
    scipy.io.savemat(fh, data, do_compression=True)
    write_atomic(Path(path), fh.getvalue(), inputs=inputs)
    return Path(path)


# a record shorter than this says nothing about the loop (and the statistics divide by N - 1)
MIN_ROWS = 10
# any value beyond this (SI) is a corrupt cell, not a reading (1e300 in a spreadsheet)
MAX_VALUE = 1e6
POSITIONS = ("x_cmd", "x_motor", "x_table", "x_tip")


def check_usable(meas: Measurement, travel: tuple[float, float], position_period: float,
                 velocity_period: float, open_loop: bool = False) -> None:
    """Refuse, in one line, a record that cannot be compared or diagnosed as it is: too few rows,
    a cell beyond any reading, positions that do not fit the axis travel (a unit that does not
    fit: mm written as m), a sample period no loop of the axis has (a ``t [ms]`` header on
    seconds), or a command that does not move.

    Parameters
    ----------
    meas : Measurement
        The record (SI).
    travel : (float, float)
        The axis's travel limits (m); positions may reach one travel beyond them (a record of
        another origin), not more.
    position_period, velocity_period : float
        The configuration's loop periods (s).
    """
    from hil.errors import MeasurementError
    src = meas.source
    n = meas.t.size
    if n < MIN_ROWS:
        raise MeasurementError(f"{src}: {n} rows, at least {MIN_ROWS} needed to compare a record")
    for name, v in meas.channels.items():
        big = np.flatnonzero(np.abs(v) > MAX_VALUE)
        if big.size:
            raise MeasurementError(f"{src}: channel {name!r}, row {big[0] + 1}: {v[big[0]]:g} is beyond any reading "
                                   f"(|value| > {MAX_VALUE:g} in SI units)")
    lo, hi = travel
    span = hi - lo
    for name in POSITIONS:
        if name in meas.channels:
            v = meas.channels[name]
            if v.min() < lo - span or v.max() > hi + span:
                far = v.max() if v.max() > hi + span else v.min()
                raise MeasurementError(f"{src}: channel {name!r} reaches {far:g} m, far beyond the axis travel "
                                       f"[{lo:g}, {hi:g}] m: is its unit right (mm written as m)?")
    dt = float(np.median(np.diff(meas.t)))
    if not velocity_period / 2 <= dt <= 1.0:
        raise MeasurementError(f"{src}: sample period {dt:g} s, expected between {velocity_period / 2:g} s and 1 s "
                               f"(the loops run every {position_period:g} / {velocity_period:g} s): is the unit of "
                               f"'t' right (a [ms] header on seconds)?")
    if meas.t[-1] - meas.t[0] < MIN_ROWS * position_period:
        raise MeasurementError(f"{src}: the record lasts {meas.t[-1] - meas.t[0]:g} s, less than {MIN_ROWS} position "
                               f"periods")
    drive = next((c for c in ("torque", "command", "force") if c in meas.channels), None)
    if open_loop:
        if drive is None:
            raise MeasurementError(f"{src}: --open-loop: the record has no torque, force or command channel to drive "
                                   f"the plant")
        return
    if "x_cmd" not in meas.channels or np.ptp(meas.channels["x_cmd"]) == 0.0:
        what = "has no command x_cmd" if "x_cmd" not in meas.channels else "never moves its command x_cmd"
        hint = (f"; if it is an open-loop run driven by its {drive} channel, say so with --open-loop"
                if drive is not None and np.ptp(meas.channels[drive]) > 0 else "")
        if "x_cmd" in meas.channels and not hint:
            raise MeasurementError(f"{src}: the command x_cmd never moves: nothing to compare or diagnose")
        raise MeasurementError(f"{src}: the record {what}{hint}")
