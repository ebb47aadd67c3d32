"""Bounded parsing (issue 30, the red-team pass): every input a user or a file can give is read
within bounds, and a bad one is one line naming the option, key, file, line or expression, never
a traceback or a hang.

First the cases the red team found, each of which hung or raised a traceback before (a unit
expression of a power of a power, a 1 ns loop period, a 5 MB ``meta.name``, a TOML array nested
5000 deep, a CSV field over 128 KiB, a map expression of 5000 terms, 100 000 signs or a power
5000 deep); then property-based fuzzers (hypothesis, derandomized, a SIGALRM guard against
hangs as in test_fuzz.py) over config values of every schema key, quantity texts, record files
and map expressions. The default set runs in a few seconds; ``-m slow`` runs many more examples.
"""
from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import CONFIG
from hang_guard import no_hang

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from hil import config  # noqa: E402
from hil.errors import ConfigError, HilError, MeasurementError, UnitError  # noqa: E402
from hil.io.importers import evaluate, parse_mapping, read_any  # noqa: E402
from hil.units import DIMENSIONS, parse  # noqa: E402

BENCH = CONFIG / "paper_bench.toml"
BENCH_TEXT = BENCH.read_text(encoding="utf-8")
MOVE = ["--feed", "7000mm/min", "--tacc", "200ms", "--check"]


def one_line_error(capsys, argv, seconds=10) -> str:
    """Run ``hil ARGV``: exit 2 with one line on stderr, no traceback, within ``seconds``."""
    from hil.cli import main
    with no_hang(seconds):
        rc = main(argv)
    cap = capsys.readouterr()
    assert rc == 2, (rc, cap.err[-500:])
    assert cap.err.count("\n") == 1 and "Traceback" not in cap.err, cap.err[-500:]
    assert len(cap.err) < 400, cap.err[:500]          # the line names the input, it does not repeat it
    return cap.err


def _config_with(tmp_path: Path, line_re: str, new: str, name: str = "c.toml") -> Path:
    """paper_bench.toml with the line starting with ``line_re`` replaced by ``new``."""
    import re
    text, n = re.subn(rf"(?m)^{line_re}.*$", lambda _: new, BENCH_TEXT, count=1)
    assert n == 1
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


# --- unit expressions ----------------------------------------------------------------------------------
@pytest.mark.parametrize("text", ["10**10**10 mm", "10^10^10 mm", "(10**10)**10 mm", "2**(3**40) mm",
                                  "10**10000000 mm", "1" * 500 + " mm"], ids=lambda t: t[:16])
def test_a_quantity_that_would_cost_pint_a_hang_is_one_line(capsys, text):
    """``--stroke "10**10**10 mm"`` hung (pint computes the integer); now refused at once, naming
    the option."""
    err = one_line_error(capsys, ["move", "--config", str(BENCH), "--stroke", text, *MOVE], seconds=5)
    assert "--stroke" in err and "length" in err
    assert "power of a power" in err or "exponent" in err or "characters" in err


def test_a_quantity_with_a_power_of_powers_in_a_config_names_the_key(capsys, tmp_path):
    p = _config_with(tmp_path, "c2 =", 'c2 = "10**10**10 N*s/m"')
    err = one_line_error(capsys, ["move", "--config", str(p), "--stroke", "10mm", *MOVE], seconds=5)
    assert "plant.c2" in err and "power of a power" in err


def test_ordinary_quantities_with_powers_still_read():
    assert parse("8.5e-4 kg*m^2", "inertia") == pytest.approx(8.5e-4)
    assert parse("4 m/s**2", "acceleration") == 4.0
    assert parse("2 s**-1", "frequency") == 2.0
    assert parse("10^-6 m", "length") == pytest.approx(1e-6)
    assert parse("1 m**(1/2)*m**(1/2)", "length") == 1.0
    with pytest.raises(UnitError, match="exponent 31 beyond 30"):
        parse("10**31 m", "length", "--x")


# --- config periods and times ----------------------------------------------------------------------------
@pytest.mark.parametrize("key,value", [("velocity_period", "1 ns"), ("velocity_period", "5 us"),
                                       ("position_period", "1 ns")])
def test_loop_periods_have_a_physical_lower_bound(capsys, tmp_path, key, value):
    """``control.velocity_period = "1 ns"`` hung (4 million simulated steps a position tick)."""
    p = _config_with(tmp_path, f"{key} =", f'{key} = "{value}"')
    err = one_line_error(capsys, ["move", "--config", str(p), "--stroke", "10mm", *MOVE], seconds=10)
    assert f"control.{key}" in err and "at least 1e-05 s" in err


def test_loop_period_bounds_are_schema_data():
    for key in ("control.position_period", "control.velocity_period"):
        f = config.SCHEMA[key]
        assert (f.minimum, f.maximum) == config.LOOP_PERIOD_RANGE == (10e-6, 1.0)
    # the paper's 62.5 us and the shipped configs stay inside
    for name in config.example_names():
        if "velocity_period" not in (CONFIG / name).read_text():       # not an axis (the components' table)
            continue
        cfg = config.load(CONFIG / name)
        assert 10e-6 <= cfg["control.velocity_period"] <= cfg["control.position_period"] <= 1.0
    ok = config.load(BENCH, {"control.velocity_period": "10 us", "control.position_period": "4 ms"})
    assert ok["control.velocity_period"] == pytest.approx(1e-5)


@pytest.mark.parametrize("key,value,match", [
    ("runtime.cpu_latency", "2 h", "at most 3600 s"), ("runtime.cpu_latency", "1 ns", "at least 1e-06 s"),
    ("control.ti", "1 ps", "at least 1e-06 s"), ("actuator.current_loop_time_constant", "1e-9 s", "at least")])
def test_every_time_key_lies_within_the_time_range(key, value, match):
    with pytest.raises(ConfigError, match=match):
        config.load(BENCH, {key: value})
    assert config.load(BENCH, {"runtime.cpu_latency": 0.0})["runtime.cpu_latency"] == 0.0   # 0: "poll"
    assert math.isinf(config.load(BENCH, {"control.ti": "inf"})["control.ti"])


# --- string lengths, file size and nesting ----------------------------------------------------------------
def test_a_huge_meta_name_is_one_line(capsys, tmp_path):
    """A 5 MB ``meta.name`` hung (the plot's title); a 500 KB one (under the file bound) is
    refused by the key's length, the 5 MB file by the file's size."""
    p = _config_with(tmp_path, "name =", 'name = "' + "A" * 500_000 + '"')
    err = one_line_error(capsys, ["move", "--config", str(p), "--stroke", "10mm", "--feed", "7000mm/min",
                                  "--tacc", "200ms", "--out", str(tmp_path / "o")], seconds=10)
    assert "meta.name" in err and "at most 200 characters" in err
    p = _config_with(tmp_path, "name =", 'name = "' + "A" * 5_000_000 + '"', "big.toml")
    err = one_line_error(capsys, ["move", "--config", str(p), "--stroke", "10mm", *MOVE], seconds=10)
    assert "big.toml" in err and "at most 1024 KiB" in err


@pytest.mark.parametrize("nest", ["[" * 5000 + "]" * 5000, "{a = " * 3000 + "1" + "}" * 3000, "[" * 9 + "]" * 9],
                         ids=["arrays 5000", "tables 3000", "arrays 9"])
def test_toml_nested_deeply_is_one_line_naming_the_file(capsys, tmp_path, nest):
    """A TOML array nested 5000 deep gave tomllib's RecursionError as a traceback."""
    p = tmp_path / "deep.toml"
    p.write_text(BENCH_TEXT + f"\n[meta2]\nx = {nest}\n", encoding="utf-8")
    err = one_line_error(capsys, ["move", "--config", str(p), "--stroke", "10mm", *MOVE])
    assert "deep.toml" in err and "nested too deeply" in err
    err = one_line_error(capsys, ["move", "--config", str(BENCH), "--set", f"meta.name={nest}", "--stroke", "10mm",
                                  *MOVE])
    assert "--set" in err and "nested too deeply" in err


# --- record files -------------------------------------------------------------------------------------------
def _record_lines(n=20):
    return ["# sample_period = 0.004 s", "t [s],x_cmd [mm],x_table [mm]"] + [
        f"{k * 0.004:g},{k * 0.1:g},{k * 0.1:g}" for k in range(n)]


@pytest.mark.parametrize("where", ["data", "header", "quoted", "text log"])
def test_a_csv_field_over_128_kib_is_one_line_naming_file_line_and_column(capsys, tmp_path, where):
    """A field over 128 KiB gave csv's "field larger than field limit" as a traceback."""
    big = "9" * 140_000
    lines = _record_lines()
    if where == "data":
        lines[7] = f"0.02,{big},0.5"
    elif where == "header":
        lines[1] = "t [s],x_cmd [mm]" + big + ",x_table [mm]"
    elif where == "quoted":
        lines[1] = 't [s],"x_cmd [mm]' + big + '",x_table [mm]'
    else:
        lines = ["time;pos;cmd"] + [f"{k};{k};{k}" for k in range(20)]
        lines[5] = f"4;{big};4"
    p = tmp_path / "r.csv"
    p.write_text("\n".join(lines) + "\n")
    err = one_line_error(capsys, ["compare", str(p), "--config", str(BENCH), "--out", str(tmp_path / "o")])
    line = {"data": 8, "header": 2, "quoted": 2, "text log": 6}[where]
    assert f"r.csv, line {line}, column " in err and "140" in err and "at most 256 characters" in err


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
def test_a_record_that_is_a_pipe_is_refused_not_read_forever(capsys, tmp_path):
    p = tmp_path / "r.csv"
    os.mkfifo(p)
    err = one_line_error(capsys, ["compare", str(p), "--config", str(BENCH), "--out", str(tmp_path / "o")])
    assert "not a regular file" in err


# --- map expressions ---------------------------------------------------------------------------------------
HOSTILE_MAPS = {"sum": "+".join(["x_cmd"] * 5000), "signs": "-" * 100_000 + "x_cmd",
                "power": "x_cmd**" * 5000 + "x_cmd", "parens": "(" * 5000 + "x_cmd" + ")" * 5000,
                "sum under the length bound": "+".join(["t"] * 200), "signs under it": "-" * 300 + "t",
                "power under it": "t**" * 100 + "t"}


@pytest.mark.parametrize("name", sorted(HOSTILE_MAPS))
def test_map_expressions_are_bounded_in_size_and_depth(name):
    """A 5000-term sum, 100 000 unary signs or a power 5000 deep overflowed the parser's stack
    (RecursionError, MemoryError): now one MeasurementError naming the expression (cut)."""
    expr = HOSTILE_MAPS[name]
    data = {"t": np.arange(5.0), "x_cmd": np.arange(5.0)}
    with no_hang(5), pytest.raises(MeasurementError) as exc:
        evaluate(parse_mapping([f"{expr}=x_table"]) and expr, data, "r.csv")
    msg = str(exc.value)
    assert msg.startswith("--map '" + expr[:20]) and len(msg) < 300
    assert "characters" in msg or "nested too deeply" in msg


def test_hostile_map_at_the_command_line_is_one_line(capsys, tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("\n".join(_record_lines()) + "\n")
    for expr in (HOSTILE_MAPS["power"], HOSTILE_MAPS["signs under it"]):
        err = one_line_error(capsys, ["compare", str(p), "--config", str(BENCH), "--map", f"t=t,x_cmd=x_cmd,"
                                      f"{expr}=x_table", "--out", str(tmp_path / "o")])
        assert "--map" in err


def test_ordinary_map_expressions_still_evaluate():
    data = {"qg": np.array([1.0, 2.0]), "pulses_N": np.array([3.0, 4.0]), "kp": np.array(2.0),
            "kv": np.array(0.5)}
    assert np.allclose(evaluate("qg+pulses_N/(kp*kv)", data), [4.0, 6.0])
    assert np.allclose(evaluate("-" * 20 + "qg", data), [1.0, 2.0])
    assert np.allclose(evaluate("+".join(["qg"] * 30), data), [30.0, 60.0])


# --- property-based fuzzers ----------------------------------------------------------------------------------
FAST = settings(max_examples=80, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                       HealthCheck.data_too_large, HealthCheck.large_base_example])
SLOW = settings(FAST, max_examples=2000)


def _all_keys() -> list[str]:
    keys = [k for k in config.SCHEMA if "*" not in k] + ["plant.m1", "plant.k2", "plant.c1", "plant.m9"]
    for known in config._SECTION_KEYS.values():
        try:
            keys += list(known())
        except Exception:
            pass
    return sorted(set(keys))


KEYS = _all_keys()
NUMBER = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**40, 10**40),
                   st.sampled_from([0, -0.0, 1e-320, 1e300, 10**30]))
UNIT = st.sampled_from(["", "mm", "m", "um", "s", "ms", "us", "ns", "ps", "h", "m/s", "mm/min", "m/s^2", "N*m",
                        "kg", "kg*m^2", "1/s", "Hz", "N*s/m", "N*m*s/rad", "V", "rad", "furlong", "m**2**3", "%"])
OP = st.sampled_from(["**", "^", "*", "/", "+", "-", " ", "e", "(", ")"])


@st.composite
def quantity_texts(draw):
    """Numbers and units joined by operators, powers (of powers) and parentheses, long texts."""
    kind = draw(st.integers(0, 3))
    if kind == 0:
        parts = draw(st.lists(st.one_of(NUMBER.map(str), UNIT, OP), min_size=1, max_size=12))
        return "".join(parts)
    if kind == 1:
        return f"{draw(NUMBER)} {draw(UNIT)}"
    if kind == 2:        # a long one, or a repeated pattern
        piece = draw(st.sampled_from(["9", "(", "**9", "^2", "mm", "-", " ", "1e9**"]))
        return piece * draw(st.integers(1, 200_000)) + draw(UNIT)
    return draw(st.text(max_size=40))


@st.composite
def nested(draw, depth=0):
    """A Python value as TOML would give it: scalars, long strings, lists and tables, nested."""
    if depth < 12 and draw(st.booleans()):
        inner = draw(st.lists(nested(depth + 1), max_size=3))
        return inner if draw(st.booleans()) else {f"k{i}": v for i, v in enumerate(inner)}
    return draw(st.one_of(NUMBER, st.booleans(), quantity_texts(),
                          st.builds(lambda c, n: c * n, st.characters(), st.integers(0, 300_000))))


def _config_ok(overrides):
    with no_hang(10):
        try:
            config.load(BENCH, overrides)
        except HilError as exc:
            assert "\n" not in str(exc) and len(str(exc)) < 1000, str(exc)[:300]


def fuzzed(strategies: dict):
    """The fuzzer ``fn`` twice: the default set's (few examples) and the slow set's (ten times
    as many, ``python -m pytest -m slow``)."""
    def make(fn):
        return FAST(given(**strategies)(fn)), pytest.mark.slow(SLOW(given(**strategies)(fn)))
    return make


def _config_values(key, value):
    """Every key of the schema and of the registered sections, any value: a Config or one line."""
    _config_ok({key: value})


test_fuzz_config_values, test_fuzz_config_values_long = fuzzed(
    dict(key=st.sampled_from(KEYS), value=nested()))(_config_values)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v) if math.isfinite(v) else ("nan" if v != v else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').encode("unicode_escape").decode("ascii") + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"


def _config_files(key, value, raw):
    """A config file with one key written as TOML (or raw text): a Config or one line."""
    section, _, name = key.rpartition(".")
    text = BENCH_TEXT + f"\n[{section}]\n{name} = {raw if raw is not None else _toml_value(value)}\n"
    with no_hang(10):
        try:
            config.loads(text, "fuzz.toml")
        except HilError as exc:
            assert "\n" not in str(exc).strip() or "not valid TOML" in str(exc), str(exc)[:300]


test_fuzz_config_files, test_fuzz_config_files_long = fuzzed(dict(
    key=st.sampled_from(KEYS), value=nested(),
    raw=st.one_of(st.none(), st.text(max_size=30),
                  st.builds(lambda c, n: c * n, st.sampled_from("[{\"'=\n"), st.integers(1, 20_000)))))(_config_files)


def _quantity_texts(text, kind):
    with no_hang(5):
        try:
            v = parse(text, kind, "--x")
        except HilError as exc:
            assert len(str(exc)) < 400
            return
    assert isinstance(v, float) and not math.isnan(v)


test_fuzz_quantity_texts, test_fuzz_quantity_texts_long = fuzzed(
    dict(text=quantity_texts(), kind=st.sampled_from(sorted(DIMENSIONS))))(_quantity_texts)


ATOM = st.one_of(st.sampled_from(["t", "x_cmd", "data[:,1]", "data(:,2)", "data[0,:]", "zz", "__header__", "1e300",
                                   "0", "2"]), NUMBER.map(str))


@st.composite
def map_expressions(draw):
    """Expressions of the record's columns: nested operators, signs, powers, MATLAB columns, and
    long flat chains (a sum of hundreds of terms, a power tower, a run of signs)."""
    def expr(depth):
        k = draw(st.integers(0, 5)) if depth < 6 else 0
        if k == 0:
            return draw(ATOM)
        if k == 1:
            return draw(st.sampled_from(["-", "+", "--"])) + expr(depth + 1)
        if k == 2:
            return "(" + expr(depth + 1) + ")"
        if k == 3:       # a long flat chain of atoms, or a run of signs
            n = draw(st.integers(2, 700))
            if draw(st.booleans()):
                return "-" * n + draw(ATOM)
            return draw(st.sampled_from(["+", "**", "*", "-"])).join(draw(ATOM) for _ in range(n))
        return expr(depth + 1) + draw(st.sampled_from(["+", "-", "*", "/", "**", "%", "//", "@", "."])) + \
            expr(depth + 1)
    return expr(0) if draw(st.integers(0, 4)) else draw(st.text(max_size=40))


def _map_expressions(expr, target):
    data = {"t": np.arange(6.0), "x_cmd": np.arange(6.0) * 1e-3, "data": np.arange(18.0).reshape(6, 3)}
    with no_hang(5):
        try:
            mapping = parse_mapping([f"{expr}={target}"])
            for source in mapping:
                v = evaluate(source, data, "fuzz.csv")
                assert v.ndim == 1
        except HilError as exc:
            assert len(str(exc)) < 600, str(exc)[:300]


def test_a_long_expression_not_allowed_is_one_short_line():
    # found by the long fuzz run: the expression and its offending part, both ~250 characters, gave a
    # message of 600
    _map_expressions("-(t+t+t+t+t+t+t+t+t+t+t+t+t+t+t+x_cmd+data[:,1]+data(:,2)+data[0,:]+__header__+1.175494351e-38"
                     "+-4.0454068980849224e+16+-3.0783188651777295e+218+-2.5321289377279046e+244)@((--1.3510798882109972"
                     "e+16+1000000000000000000000000000000))", "x_table")


test_fuzz_map_expressions, test_fuzz_map_expressions_long = fuzzed(dict(
    expr=map_expressions(),
    target=st.sampled_from(["x_table", "x_table[mm]", "torque", "zz", "x_cmd[kg]"])))(_map_expressions)


CELL = st.one_of(NUMBER.map(str), st.sampled_from(["", " ", '"1"', "nan", "inf", "1_000", "1,5", "\x00", "é"]),
                 st.builds(lambda c, n: c * n, st.sampled_from("9a\",; "), st.integers(1, 300_000)))
HEADERS = st.sampled_from(["t [s],x_cmd [mm],x_table [mm]", "# sample_period = 0.004 s\nt [s],x_cmd [mm]",
                           "time;pos", "t\tx_cmd", "t x_cmd x_table", '"t [s]","x_cmd [mm]"', ""])

_TMP = Path(tempfile.mkdtemp(prefix="redteam-"))


def _record_files(header, rows, sep, tail, suffix, mapping):
    """Any text under a record's name (any suffix): a Measurement or one line."""
    p = _TMP / f"r{suffix}"
    p.write_text(header + "\n" + "\n".join(sep.join(r) for r in rows) + tail, encoding="utf-8",
                 errors="surrogatepass")
    with no_hang(10):
        try:
            m = read_any(p, parse_mapping([mapping]) if mapping else None)
        except HilError as exc:
            assert "\n" not in str(exc) and len(str(exc)) < 1000, str(exc)[:300]
            return
    assert m.t.size >= 2
    for v in m.channels.values():
        assert np.all(np.isfinite(v))


test_fuzz_record_files, test_fuzz_record_files_long = fuzzed(dict(
    header=HEADERS, rows=st.lists(st.lists(CELL, min_size=1, max_size=4), max_size=15),
    sep=st.sampled_from([",", ";", "\t", " "]), tail=st.sampled_from(["", "\n", "1,2", "\r\n", "\x00"]),
    suffix=st.sampled_from([".csv", ".txt", ".mat", ".xlsx"]),
    mapping=st.sampled_from([None, "t=t,x_cmd=x_cmd", "t=t[ms],data[:,1]=x_cmd", "time=t,pos=x_cmd[mm]"])))(
    _record_files)
