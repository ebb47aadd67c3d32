"""Readers of foreign measurement records into :class:`hil.measurement.Measurement`.

One mapping convention for every format, ``--map SOURCE=CHANNEL[unit]``: the source on the
left, the project's channel and optionally the unit the source is in on the right, e.g. for the
EMPS benchmark::

    t=t, qg=x_cmd, qm=x_motor, vir=command, vir*gtau=force

A source is an expression of the file's variables (a CSV or text column by its header name, a
MATLAB variable, an Excel column), evaluated safely (a small evaluator of the expression's syntax
tree: ``+ - * / **``, parentheses, names and numbers, nothing else is run):

- ``data[:,2]``: column 2 of the matrix variable ``data``, counted from 0 as in numpy;
  ``data(:,3)`` is the same column written as in MATLAB, counted from 1; ``data[2,:]`` and
  ``data(3,:)`` pick a row of a matrix stored with one signal per row;
- ``vir*gtau``, ``qg+pulses_N/(kp*kv)``, ``current*4.29e-5``: expressions of variables and
  numbers (scalars broadcast);
- ``pos=x_table[mm]``: the unit the source is in, where the file gives none. Without a unit,
  MATLAB and Excel values are taken as SI, and CSV columns keep the unit of their header; the
  variables of an expression are read in SI (their header unit applied), then the map's unit.

Formats (:func:`read_any`, by the suffix and the first lines): the project's CSV
(hil.io.measurement); text with a plain header (names, optionally ``name[unit]`` or
``name (unit)``) separated by whitespace, tabs, semicolons (a decimal comma is read) or commas,
or with no header at all: then the whole table is the matrix variable ``data``; MATLAB ``.mat``
(scipy.io) and MATLAB 7.3 ``.mat`` (HDF5, h5py, the ``[mat73]`` extra); Excel ``.xlsx``
(openpyxl, the ``[excel]`` extra; ``sheet`` names the sheet, the first by default), whose first
row is the header.

Every map entry must be used: a source that names no variable or column, a matrix without its
column, a channel the project does not know, or a channel given twice is one error line naming
the entry. :func:`data_warnings` adds warnings (never errors) for channels with outliers beyond a
robust bound, gaps in the time base, and a sample period far above the loop's, with the sample
numbers.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np

from hil.io.measurement import (
    CHANNELS,
    Measurement,
    MeasurementError,
    _check_time,
    _kind_of,
    _shown,
    check_fields,
    check_record_file,
)
from hil.io.measurement import parse_text as parse_csv_text

__all__ = ["read_mat", "read_any", "read_table", "parse_mapping", "evaluate", "data_warnings", "EMPS_MAPPING"]

EMPS_MAPPING = {"t": "t", "qg": "x_cmd", "qm": "x_motor", "vir": "command", "vir*gtau": "force"}

_TARGET = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*(?:\[([^\]]*)\])?$")
# MATLAB's 1-based column or row: data(:,3) -> data[:,2], data(3,:) -> data[2,:]
_MATLAB_COL = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\(\s*:\s*,\s*(\d+)\s*\)")
_MATLAB_ROW = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\(\s*(\d+)\s*,\s*:\s*\)")
_HEADER_CELL = re.compile(r"^\s*(.*?)\s*(?:[\[(]([^\])]*)[\])])?\s*$")

# Bounds of a map expression (issue 30: a sum of 5000 terms, 100 000 unary signs or a power 5000
# deep overflowed the parser's stack): its length, how deeply its syntax tree nests (a sum of n
# terms nests n deep) and how many nodes it has. EMPS's longest is "vir*gtau".
MAX_EXPR_CHARS = 500
MAX_EXPR_DEPTH = 40
MAX_EXPR_NODES = 400
# a MATLAB file's variables, all together (elements): 10^8 doubles are 800 MB
MAX_MAT_ELEMENTS = 100_000_000


def _target(source: str, target: str, where: str):
    """(channel, factor to SI or None when the map gives no unit) of a mapping's right-hand side."""
    m = _TARGET.match(target.strip())
    if not m:
        raise MeasurementError(f"--map {source}={target}: expected CHANNEL or CHANNEL[unit]")
    name, unit = m.group(1), m.group(2)
    if name not in CHANNELS:
        raise MeasurementError(f"--map {source}={target}: {name!r} is not a channel of the measurement format "
                               f"(known: {', '.join(CHANNELS)})")
    if unit is None or not unit.strip():
        return name, None, ""
    _, factor = _kind_of(name, unit.strip(), where)
    return name, factor, unit.strip()


def _split_items(text: str) -> list[str]:
    """Split at the commas outside brackets and parentheses (``data[:,2]=x_cmd,t=t``)."""
    out, depth, cur = [], 0, []
    for ch in text:
        if ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
        if ch == "," and depth <= 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur))
    return out


def parse_mapping(items) -> dict[str, str]:
    """``["qg=x_cmd", "vir*gtau=force"]`` or ``"qg=x_cmd,pos=x_table[mm],data[:,2]=x_motor"`` ->
    {source: target}."""
    if items is None:
        return {}
    if isinstance(items, str):
        items = [items]
    out = {}
    for item in items:
        for part in _split_items(item):
            part = part.strip()
            if not part:
                continue
            if "=" not in part:
                raise MeasurementError(f"--map {_shown(part)}: expected SOURCE=CHANNEL[unit], e.g. qg=x_cmd or "
                                       f"pos=x_table[mm]")
            a, _, b = part.rpartition("=")
            a, b = a.strip(), b.strip()
            if not _TARGET.match(b):
                raise MeasurementError(f"--map {_shown(part)}: {_shown(b)} is not CHANNEL or CHANNEL[unit]")
            if not a or "=" in a:
                raise MeasurementError(f"--map {_shown(part)}: expected one SOURCE=CHANNEL[unit]")
            if len(a) > MAX_EXPR_CHARS:
                raise MeasurementError(f"--map {_shown(part)}: a source of {len(a)} characters, expected an "
                                       f"expression of at most {MAX_EXPR_CHARS}")
            if a in out:
                raise MeasurementError(f"--map {_shown(part)}: the source {_shown(a)} is mapped twice")
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


_BINOPS = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply, ast.Div: np.divide, ast.Pow: np.power}


def evaluate(expr: str, data: dict, source: str = "<record>", factors: dict | None = None,
             entry: str | None = None) -> np.ndarray:
    """The value of a map source over the file's variables ``data`` (name -> array), safely: only
    numbers, names, ``+ - * / **``, unary signs, parentheses and a matrix's column (``name[:,k]``,
    0-based) or row (``name[k,:]``); MATLAB's ``name(:,k)`` is read 1-based. ``factors``: each
    variable's factor to SI (header units); ``entry``: the whole map entry, for the messages.
    Returns a 1-D array (a scalar as one value)."""
    try:
        return _evaluate(expr, data, source, factors or {})
    except MeasurementError as exc:
        msg = str(exc)
        label = entry or expr
        if len(label) > 200:        # one line: the start of a long entry says which one it is
            label = label[:200] + "..."
        if msg.startswith(f"--map {expr!r}: "):
            raise MeasurementError(f"--map {label}: " + msg[len(f"--map {expr!r}: "):]) from None
        if msg.startswith(f"{source}: ") and not msg.startswith(f"{source}: --map"):
            raise MeasurementError(f"{source}: --map {label}: " + msg[len(source) + 2:]) from None
        raise


def _evaluate(expr: str, data: dict, source: str, factors: dict) -> np.ndarray:
    if len(expr) > MAX_EXPR_CHARS:
        raise MeasurementError(f"--map {_shown(expr)}: {len(expr)} characters, expected an expression of at most "
                               f"{MAX_EXPR_CHARS}")
    text = _MATLAB_COL.sub(lambda m: f"{m.group(1)}[:,{int(m.group(2)) - 1}]", expr)
    text = _MATLAB_ROW.sub(lambda m: f"{m.group(1)}[{int(m.group(2)) - 1},:]", text)
    if re.search(r"[A-Za-z_][A-Za-z0-9_]*\(\s*0\s*,|,\s*0\s*\)", expr):
        raise MeasurementError(f"--map {expr!r}: MATLAB's (:,k) counts from 1; write data[:,0] for the first column")
    tree = _expression_tree(expr, text)

    def known():
        return ", ".join(k for k in data if not k.startswith("__"))

    def var(name):
        if name not in data or name.startswith("__"):
            # (scipy's __header__, __version__, __globals__ are file metadata, not variables)
            raise MeasurementError(f"{source}: no variable {name!r} (the file has: {known()})")
        return _numeric(data[name], name, source) * factors.get(name, 1.0)

    def index(node):
        if isinstance(node, ast.Constant) and isinstance(node.value, int) and not isinstance(node.value, bool):
            return node.value
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub) and isinstance(node.operand, ast.Constant) \
                and isinstance(node.operand.value, int):
            return -node.operand.value
        return None

    def full(node):
        return isinstance(node, ast.Slice) and node.lower is None and node.upper is None and node.step is None

    def ev(node):
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
            return np.array(float(node.value))
        if isinstance(node, ast.Name):
            v = var(node.id)
            if v.ndim >= 2 and sorted(v.shape)[-2] > 1:
                raise MeasurementError(f"--map {expr!r}: {node.id!r} is a {' x '.join(map(str, v.shape))} matrix: "
                                       f"pick a column, e.g. {node.id}[:,0] (0-based) or {node.id}(:,1) (MATLAB)")
            return v.reshape(-1) if v.size > 1 else np.array(float(v.reshape(-1)[0]))
        if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
            with np.errstate(all="ignore"):
                a, b = ev(node.left), ev(node.right)
                if a.size > 1 and b.size > 1 and a.size != b.size:
                    raise MeasurementError(f"--map {expr!r}: operands of {a.size} and {b.size} samples")
                return _BINOPS[type(node.op)](a, b)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            v = ev(node.operand)
            return -v if isinstance(node.op, ast.USub) else v
        if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name):
            v = var(node.value.id)
            sl = node.slice
            if isinstance(sl, ast.Tuple) and len(sl.elts) == 2 and v.ndim == 2:
                r, c = sl.elts
                if full(r) and index(c) is not None:
                    k, axis = index(c), 1
                elif full(c) and index(r) is not None:
                    k, axis = index(r), 0
                else:
                    k = None
                if k is not None:
                    if not -v.shape[axis] <= k < v.shape[axis]:
                        raise MeasurementError(f"--map {expr!r}: {node.value.id!r} has {v.shape[axis]} "
                                               f"{'columns' if axis else 'rows'} (0-based index {k})")
                    return (v[:, k] if axis else v[k, :]).copy()
            raise MeasurementError(f"--map {expr!r}: expected a column NAME[:,k] or a row NAME[k,:] of a matrix "
                                   f"({node.value.id!r} is {' x '.join(map(str, v.shape))})")
        what = ast.unparse(node) if hasattr(ast, "unparse") else type(node).__name__
        raise MeasurementError(f"--map {expr!r}: {_shown(what, 80)} is not allowed (use numbers, variables, + - * / **, "
                               f"parentheses and NAME[:,k])")

    return np.asarray(ev(tree), float).reshape(-1)


def _apply_mapping(data: dict, factors: dict, units: dict, mapping: dict, source: str, fmt: str,
                   keep_unmapped: bool) -> Measurement:
    """Channels from the file's variables by the map (every entry used), plus, for tables with a
    header, the columns named like channels that no entry maps."""
    channels: dict[str, np.ndarray] = {}
    exprs: dict[str, str] = {}
    out_units: dict[str, str] = {}
    for expr, target in mapping.items():
        name, factor, unit = _target(expr, target, source)
        if name in channels:
            raise MeasurementError(f"{source}: --map gives channel {name!r} twice ({exprs[name]} and {expr})")
        plain = expr.strip() in data
        if plain and factor is not None:
            # the map's unit replaces the header's for a plain column
            v = evaluate(expr, data, source, entry=f"{expr}={target}") * factor
        else:
            v = evaluate(expr, data, source, factors, entry=f"{expr}={target}") * (1.0 if factor is None else factor)
            if plain and factor is None and units.get(expr.strip()):
                _kind_of(name, units[expr.strip()], f"{source}: --map {expr}={target}")
        channels[name] = v
        exprs[name] = expr
        out_units[name] = unit or (units.get(expr.strip(), "") if plain else "")
    replaced = []         # a file's own channel column that a map entry replaces (issue 30: never silently)
    if keep_unmapped:
        used = set()
        for expr in mapping:
            used |= {n.id for n in ast.walk(_safe_parse(expr)) if isinstance(n, ast.Name)}
        for col in data:
            if col in channels and col not in used and col in CHANNELS:
                replaced.append(f"{source}: --map {exprs[col]}={col} replaces the file's own column {col!r}, which "
                                f"is left unused")
            if col in used or col in channels or col not in CHANNELS or col.startswith("__"):
                continue
            _kind_of(col, units.get(col) or None, source)
            channels[col] = _numeric(data[col], col, source).reshape(-1) * factors.get(col, 1.0)
            exprs[col] = col
            out_units[col] = units.get(col, "")
    if "t" not in channels:
        raise MeasurementError(f"{source}: the mapping gives no 't' channel (use --map VARIABLE=t)")
    if "x_cmd" not in channels and not any(c in channels for c in ("torque", "force", "command")):
        raise MeasurementError(f"{source}: the mapping gives no 'x_cmd' channel (use --map VARIABLE=x_cmd; an "
                               f"open-loop record maps its torque, force or command)")
    n = channels["t"].size
    if n < 2:
        raise MeasurementError(f"{source}: 't' ({exprs['t']}) has {n} sample(s), a record needs at least 2")
    for name, v in list(channels.items()):
        if v.size == 1 and name != "t":
            v = channels[name] = np.full(n, float(v[0]))
        if v.size != n:
            raise MeasurementError(f"{source}: channel {name!r} ({exprs[name]}) has {v.size} samples, "
                                   f"'t' has {n}")
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise MeasurementError(f"{source}: channel {name!r} ({exprs[name]}), sample {bad[0] + 1}: NaN or "
                                   f"infinite value")
    meas = Measurement(channels, {"format": fmt, "mapping": ",".join(f"{v}={k}" for k, v in exprs.items())},
                       source, out_units)
    meas.warnings = _check_time(channels["t"], source, 1) + replaced + _unmapped_inputs(data, exprs, channels, source)
    return meas


# a file's variable whose name says it is an input of the run (an added command, an excitation, a force)
_INPUT_LIKE = re.compile(r"pulse|u_?add|excit|inject|dist|f_?ext|force|load", re.IGNORECASE)
_INPUT_CHANNELS = ("u_add", "f_ext_table", "f_ext_tip")


def _unmapped_inputs(data: dict, exprs: dict, channels: dict, source: str) -> list[str]:
    """The file's variables that no map entry reads, to :func:`unmapped_inputs`."""
    used = set()
    for expr in exprs.values():
        try:
            used |= {n.id for n in ast.walk(_safe_parse(expr)) if isinstance(n, ast.Name)}
        except MeasurementError:
            continue
    return unmapped_inputs([v for v in data if v not in used and v not in channels], channels, source)


def unmapped_inputs(names, channels, source: str) -> list[str]:
    """A warning naming those of ``names`` (a file's variables or columns that give no channel) that
    look like an input of the run, where ``channels`` hold no input channel: replayed without them,
    the model sees another run."""
    if any(c in channels for c in _INPUT_CHANNELS):
        return []
    names = [v for v in names if not v.startswith("__") and _INPUT_LIKE.search(v)]
    if not names:
        return []
    one = len(names) == 1
    return [f"{source}: {', '.join(repr(n) for n in names[:5])} look{'s' if one else ''} like an input of "
            f"the run (an added command or a force) and {'is' if one else 'are'} not mapped: the replay "
            f"runs without {'it' if one else 'them'} (map it to u_add[unit], f_ext_table or f_ext_tip)"]


def _expression_tree(expr: str, text: str):
    """The syntax tree of a map source ``expr`` (``text``: as rewritten for Python), within
    :data:`MAX_EXPR_CHARS`, :data:`MAX_EXPR_DEPTH` and :data:`MAX_EXPR_NODES`; else one
    MeasurementError naming the expression."""
    if len(text) > MAX_EXPR_CHARS + 20:
        raise MeasurementError(f"--map {_shown(expr)}: {len(expr)} characters, expected an expression of at most "
                               f"{MAX_EXPR_CHARS}")
    deep = (f"--map {_shown(expr)}: nested too deeply or too long (expected at most {MAX_EXPR_DEPTH} levels of "
            f"operators and parentheses, {MAX_EXPR_NODES} terms)")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        if "too many nested" in str(exc) or "too complex" in str(exc):
            raise MeasurementError(deep) from None
        raise MeasurementError(f"--map {_shown(expr)}: not an expression of variables and numbers (use + - * / **, "
                               f"parentheses and NAME[:,k])") from None
    except (RecursionError, MemoryError):
        raise MeasurementError(deep) from None
    nodes, todo = 0, [(tree, 1)]
    while todo:                       # no recursion: the bound is checked before anything recurses
        node, depth = todo.pop()
        nodes += 1
        if depth > MAX_EXPR_DEPTH or nodes > MAX_EXPR_NODES:
            raise MeasurementError(deep)
        todo.extend((child, depth + 1) for child in ast.iter_child_nodes(node))
    return tree


def _safe_parse(expr: str):
    text = _MATLAB_COL.sub(lambda m: f"{m.group(1)}[:,0]", expr)
    text = _MATLAB_ROW.sub(lambda m: f"{m.group(1)}[0,:]", text)
    try:
        return _expression_tree(expr, text)
    except MeasurementError:
        return ast.parse("0", mode="eval")


def read_mat(path: str | Path, mapping: dict[str, str] | None = None) -> Measurement:
    """Read a MATLAB record (v4-v7 by scipy.io, v7.3 HDF5 by h5py). ``mapping``: source
    (expression) -> ``channel`` or ``channel[unit]`` (default: the variables named like channels,
    plus the EMPS names when present)."""
    import scipy.io
    source = str(path)
    check_record_file(source)
    try:
        size = sum(int(np.prod(shape)) for _, shape, _ in scipy.io.whosmat(source))
    except Exception:         # v7.3 (HDF5), or not a .mat: loadmat below says which
        size = 0
    if size > MAX_MAT_ELEMENTS:
        raise MeasurementError(f"{source}: its variables hold {size} values, expected at most {MAX_MAT_ELEMENTS}")
    try:
        data = scipy.io.loadmat(source)
    except FileNotFoundError:
        raise MeasurementError(f"{source}: no such file") from None
    except NotImplementedError:             # MATLAB 7.3: HDF5 inside
        data = _load_mat73(source)
    except Exception as exc:    # scipy raises several kinds for a file that is not a .mat
        raise MeasurementError(f"{source}: not a readable MATLAB file ({exc})") from None
    if not mapping:
        mapping = {k: k for k in data if k in CHANNELS}
        if "qm" in data and "qg" in data:
            mapping = dict(EMPS_MAPPING) | mapping
    return _apply_mapping(data, {}, {}, mapping, source, "mat", keep_unmapped=False)


def _load_mat73(source: str) -> dict:
    """The numeric variables of a MATLAB 7.3 file (HDF5; MATLAB stores matrices transposed)."""
    try:
        import h5py
    except ImportError:
        raise MeasurementError(f"{source}: a MATLAB 7.3 (HDF5) file needs h5py: pip install "
                               f"'compliant-axis-hil[mat73]'") from None
    out = {}
    try:
        with h5py.File(source, "r") as f:
            sets = [(k, v) for k, v in f.items() if isinstance(v, h5py.Dataset) and v.dtype.kind in "biuf"]
            size = sum(int(v.size) for _, v in sets)
            if size > MAX_MAT_ELEMENTS:
                raise MeasurementError(f"{source}: its variables hold {size} values, expected at most "
                                       f"{MAX_MAT_ELEMENTS}")
            for k, v in sets:
                a = np.asarray(v[()])
                out[k] = a.T if a.ndim == 2 else a
    except OSError as exc:
        raise MeasurementError(f"{source}: not a readable MATLAB 7.3 file ({exc})") from None
    return out


def _header_names(cells: list[str], source: str) -> tuple[list[str], dict[str, str]]:
    """Identifiers and units of a plain header's cells (``Position Actual (mm)`` -> Position_Actual, mm)."""
    names, units = [], {}
    for i, cell in enumerate(cells):
        m = _HEADER_CELL.match(cell)
        raw, unit = (m.group(1), m.group(2)) if m else (cell, None)
        name = re.sub(r"[^A-Za-z0-9_]+", "_", raw.strip()).strip("_") or f"col{i}"
        if name[0].isdigit():
            name = "c" + name
        if name in names:
            raise MeasurementError(f"{source}: header: column {name!r} appears twice")
        names.append(name)
        if unit is not None and unit.strip():
            units[name] = unit.strip()
    return names, units


def _is_number(s: str) -> bool:
    try:
        float(s.replace(",", "."))
        return True
    except ValueError:
        return False


def _table_variables(names, units, arr, source):
    """{name: column} and {name: factor to SI} of a table whose header may carry units."""
    from hil.io.measurement import UNITS
    data = {n: arr[:, i] for i, n in enumerate(names)}
    factors = {}
    for n, u in units.items():
        if u not in UNITS:
            continue           # a unit this format does not know (A, rpm): SI through the map's expression
        factors[n] = UNITS[u][1]
    if "data" not in data:
        data["data"] = arr
    return data, factors


def read_text(path: str | Path, mapping: dict[str, str] | None = None) -> Measurement:
    """A text log: whitespace-, tab-, semicolon- or comma-separated numbers, with a plain header
    line of names (``name[unit]`` or ``name (unit)`` optional) or none (then the matrix ``data``)."""
    source = str(path)
    check_record_file(source)
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace").removeprefix("\ufeff")
    except FileNotFoundError:
        raise MeasurementError(f"{source}: no such file") from None
    except IsADirectoryError:
        raise MeasurementError(f"{source}: is a folder, expected a measurement file") from None
    except OSError as exc:
        raise MeasurementError(f"{source}: cannot read ({exc.strerror})") from None
    numbered = [(i + 1, ln) for i, ln in enumerate(text.splitlines())
                if ln.strip() and not ln.lstrip().startswith(("#", "%"))]
    if not numbered:
        raise MeasurementError(f"{source}: no data")
    lines = [ln for _, ln in numbered]
    first = lines[0]
    delim = ";" if ";" in first else "\t" if "\t" in first else "," if "," in first else None
    for lineno, ln in numbered:
        check_fields(ln, lineno, source, delim, what="a number or a name")
    split = (lambda s: s.split(delim)) if delim else (lambda s: s.split())
    cells = [c.strip() for c in split(first)]
    has_header = not all(_is_number(c) for c in cells if c)
    body = lines[1:] if has_header else lines
    if len(body) < 2:
        raise MeasurementError(f"{source}: fewer than 2 data rows")
    if delim == ";":        # a decimal comma (European spreadsheets)
        body = [ln.replace(",", ".") for ln in body]
    try:
        arr = np.loadtxt(body, delimiter=delim, ndmin=2, dtype=float)
    except ValueError as exc:
        raise MeasurementError(f"{source}: {exc}") from None
    if arr.shape[0] < 2:
        raise MeasurementError(f"{source}: fewer than 2 data rows")
    if has_header:
        names, units = _header_names(cells, source)
        if len(names) != arr.shape[1]:
            raise MeasurementError(f"{source}: the header has {len(names)} names, the rows {arr.shape[1]} values")
    else:
        names, units = [], {}
    data, factors = _table_variables(names, units, arr, source)
    if not mapping:
        if not has_header:
            raise MeasurementError(f"{source}: no header: map the columns of 'data', e.g. --map "
                                   f"data[:,0]=t,data[:,1]=x_cmd[mm] (0-based columns)")
        mapping = {n: n for n in names if n in CHANNELS}
    return _apply_mapping(data, factors, units, mapping, source, "text", keep_unmapped=has_header)


def read_xlsx(path: str | Path, mapping: dict[str, str] | None = None, sheet: str | None = None) -> Measurement:
    """An Excel sheet (openpyxl): the first row a header of names (units as in text logs), the
    numbers below; ``sheet`` by name (default: the first)."""
    source = str(path)
    try:
        import openpyxl
    except ImportError:
        raise MeasurementError(f"{source}: reading Excel files needs openpyxl: pip install "
                               f"'compliant-axis-hil[excel]'") from None
    try:
        wb = openpyxl.load_workbook(source, read_only=True, data_only=True)
    except FileNotFoundError:
        raise MeasurementError(f"{source}: no such file") from None
    except Exception as exc:
        raise MeasurementError(f"{source}: not a readable Excel file ({exc})") from None
    try:
        if sheet is None:
            ws = wb.worksheets[0]
        elif sheet in wb.sheetnames:
            ws = wb[sheet]
        else:
            raise MeasurementError(f"{source}: no sheet {sheet!r} (the file has: {', '.join(wb.sheetnames)})")
        rows = [r for r in ws.iter_rows(values_only=True) if any(v is not None for v in r)]
    finally:
        wb.close()
    if len(rows) < 3:
        raise MeasurementError(f"{source}: fewer than 2 data rows below the header")
    head = [str(c) if c is not None else "" for c in rows[0]]
    width = max(i + 1 for i, c in enumerate(head) if c)
    names, units = _header_names(head[:width], source)
    vals = []
    for i, r in enumerate(rows[1:]):
        row = []
        if len(vals) * width > MAX_MAT_ELEMENTS:
            raise MeasurementError(f"{source}, sheet {ws.title}: more than {MAX_MAT_ELEMENTS} values")
        for j in range(width):
            v = r[j] if j < len(r) else None
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                row.append(float(v))
            elif v is None:
                row.append(np.nan)
            else:
                raise MeasurementError(f"{source}, sheet {ws.title}, row {i + 2}, column {names[j]!r}: {v!r} is not "
                                       f"a number")
        vals.append(row)
    arr = np.array(vals, float)
    data, factors = _table_variables(names, units, arr, source)
    if not mapping:
        mapping = {n: n for n in names if n in CHANNELS}
    return _apply_mapping(data, factors, units, mapping, source, "xlsx", keep_unmapped=True)


def _project_csv(path: Path) -> bool:
    """Whether a .csv/.txt file is in the project's format: it starts with ``#`` metadata, or its
    first line is a comma-separated header of ``name`` or ``name [unit]`` cells."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                s = line.strip().removeprefix("\ufeff")
                if not s:
                    continue
                if s.startswith("#"):
                    return True
                cells = s.split(",")
                from hil.io.measurement import _HEADER
                return ("," in s and ";" not in s and not all(_is_number(c) for c in cells)
                        and all(_HEADER.match(c) for c in cells))
    except OSError:
        return True          # the CSV reader says what is wrong
    return True


def read_table(path, mapping=None) -> Measurement:
    """The project's CSV with a map: any expression of its columns (the header's units applied)."""
    from hil.io.measurement import read_record_text
    source = str(path)
    text, notes = read_record_text(path)
    names, units, arr, meta = parse_csv_text(text, source, None, raw=True)
    from hil.io.measurement import UNITS
    data = {n: arr[:, i] for i, n in enumerate(names)}
    factors = {n: UNITS[u][1] for n, u in units.items() if u in UNITS}
    out = _apply_mapping(data, factors, units, mapping, source, "csv", keep_unmapped=True)
    out.meta = meta | out.meta
    out.warnings[:0] = notes
    return out


def read_any(path: str | Path, mapping: dict[str, str] | None = None, sheet: str | None = None) -> Measurement:
    """A measurement record of any supported layout, chosen by the suffix and the first line:
    the project's CSV, a MATLAB ``.mat`` (v7.3 too), an Excel ``.xlsx``, or a text log."""
    from hil.io.measurement import read as read_csv
    p = str(path)
    low = p.lower()
    if sheet is not None and not low.endswith((".xlsx", ".xlsm")):
        raise MeasurementError(f"--sheet {sheet}: {p} is not an Excel file")
    if low.endswith(".mat"):
        return read_mat(path, mapping)
    if low.endswith((".xlsx", ".xlsm")):
        check_record_file(p)
        return read_xlsx(path, mapping, sheet)
    if Path(p).is_file() and not _project_csv(Path(p)):
        return read_text(path, mapping)
    if mapping:
        return read_table(path, mapping)
    return read_csv(path, mapping)


# --- data sanity: warnings, never errors -----------------------------------------------------

OUTLIER_MADS = 20.0       # an outlier: this many robust deviations from the local median, and beyond the bulk
SLOW_FACTOR = 5.0         # a sample period this many position periods long cannot resolve the loop


def _samples(idx, limit: int = 5) -> str:
    s = ", ".join(str(int(i) + 1) for i in idx[:limit])
    return s + (f" and {idx.size - limit} more" if idx.size > limit else "")


def _channel_kind(meas: Measurement, name: str) -> str:
    """The kind of quantity of a channel (its values SI): from the unit its file wrote, else from
    its name; an actuator channel written without a known unit is a torque."""
    from hil.io.measurement import UNITS
    written = (getattr(meas, "units", None) or {}).get(name)
    kind = UNITS[written][0] if written in UNITS else CHANNELS.get(name, "dimensionless")
    return "torque" if kind == "actuator" else kind


EDGE_TIME = 0.05     # s either side of a move's start or end that its torque step may take (5 samples at least)


def _drives(meas: Measurement, name: str) -> bool:
    """Whether channel ``name`` is what drives the axis (a torque, a force, a command)."""
    return _channel_kind(meas, name) in ("torque", "force") or name in ("torque", "force", "command", "u_add")


def _accelerating(meas: Measurement):
    """A mask of the samples at the edges of a move: where the command leaves standstill or comes to
    it, widened by :data:`EDGE_TIME`. A drive's torque steps there with the command (its
    acceleration and the dry friction set in at once), which explains it: the start and the end of
    every move of a clean record were warned about as outliers. None without a command."""
    x = meas.channels.get("x_cmd")
    if x is None or x.size < 3:
        return None
    step = np.abs(np.diff(x))
    top = float(np.max(step)) if step.size else 0.0
    edges = np.zeros(x.size, bool)
    if top > 0:
        moving = step > 1e-6 * top
        change = np.flatnonzero(moving[1:] != moving[:-1]) + 1      # standstill <-> motion
        edges[np.clip(change, 0, x.size - 1)] = True
        edges[np.clip(change + 1, 0, x.size - 1)] = True
    from scipy.ndimage import binary_dilation
    t = meas.channels.get("t")
    dt = float(np.median(np.diff(t))) if t is not None and t.size > 1 else 0.0
    n = max(5, int(round(EDGE_TIME / dt))) if dt > 0 else 5
    return binary_dilation(edges, iterations=n) if edges.any() else edges


def data_warnings(meas: Measurement, position_period: float | None = None) -> list[str]:
    """Warnings about a record that can still be replayed: outliers of a channel (beyond
    ``OUTLIER_MADS`` median absolute deviations of the sample-to-sample difference around a
    running median of 9, and beyond the channel's 0.5..99.5 % percentile range by that range
    again), gaps of the time base, a sample period more than ``SLOW_FACTOR`` position periods.
    A torque or force at the start or the end of a move is no outlier (:func:`_accelerating`). Sample
    numbers count from 1."""
    out = list(getattr(meas, "warnings", []) or [])
    from scipy.ndimage import median_filter
    for name, v in meas.channels.items():
        if name == "t" or v.size < 20:
            continue
        med = median_filter(v, size=9, mode="nearest")
        dev = np.abs(v - med)
        scale = float(np.median(np.abs(np.diff(v)))) * 1.4826
        floor = 1e-9 * max(float(np.max(np.abs(v))), 1e-300)
        bound = OUTLIER_MADS * max(scale, float(np.median(dev)) * 1.4826, floor)
        # and beyond the bulk of the channel by its own span (0.5 to 99.5 percentiles): a short
        # torque peak of a fast move or a quantum of a still encoder is no outlier, a glitch is
        lo, hi = np.percentile(v, [0.5, 99.5])
        span = max(float(hi - lo), floor)
        bad = np.flatnonzero((dev > bound) & ((v > hi + span) | (v < lo - span)))
        if bad.size and _drives(meas, name):
            bad = bad[~commanded[bad]] if (commanded := _accelerating(meas)) is not None else bad
        if bad.size and bad.size < 0.01 * v.size + 1:
            from hil.units import fmt as fmt_quantity
            kind = _channel_kind(meas, name)
            out.append(f"{meas.source}: channel {name!r}: {bad.size} outlier(s) beyond {fmt_quantity(bound, kind, 3)} from "
                       f"the running median, sample(s) {_samples(bad)} (e.g. {fmt_quantity(v[bad[0]], kind, 6)})")
    if position_period:
        dt = meas.sample_period
        if dt > SLOW_FACTOR * position_period:
            out.append(f"{meas.source}: sample period {dt:g} s is {dt / position_period:.0f} times the position "
                       f"loop's {position_period:g} s: the record cannot resolve the loop's dynamics")
    return out
