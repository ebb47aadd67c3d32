"""Every bad input of issue 18 (items 7/8): one clear line on stderr and exit 2, nothing run;
degenerate records refused before any replay."""
import numpy as np
import pytest
import scipy.io
from conftest import CONFIG

from hil.cli import main

BENCH = str(CONFIG / "paper_bench.toml")
MOVE = ["move", "--config", BENCH, "--stroke", "10mm", "--feed", "7000mm/min"]


def _one_line(capsys, argv, word=None):
    rc = main(argv)
    cap = capsys.readouterr()
    assert rc == 2, (argv, cap.err)
    assert cap.err.count("\n") == 1 and "Traceback" not in cap.err, cap.err
    if word:
        assert word in cap.err, cap.err
    return cap.err


@pytest.mark.parametrize("extra,word", [
    (["--jmax", "inf"], "j_max must be positive and finite"),
    (["--tacc", "inf"], "t_acc must be positive and finite"),
    (["--amax", "inf"], "a_max must be positive and finite"),
    (["--tacc", "200ms", "--g0", "inf"], "g0 must be positive and finite"),
    (["--tacc", "200ms", "--dwell", "inf"], "dwell"),
    (["--tacc", "200ms", "--dwell=-1s"], "dwell"),
    (["--tacc", "200ms", "--dwell", "1e12s"], "dwell"),
    (["--amax", "1m/s^2", "--feed", "1e-6mm/min"], "lasts"),
    (["--tacc", "200ms", "--band=-1um"], "--band"),
    (["--tacc", "200ms", "--start", "1_000mm"], "'_' inside a number"),
    (["--tacc", "200ms", "--set", "control.kp=1e6"], "unstable"),
    (["--tacc", "200ms", "--set", "runtime.priority=1000"], "at most 99"),
    (["--tacc", "200ms", "--set", "control.output_delay=100000000"], "at most 1000"),
])
def test_move_bad_quantities(capsys, tmp_path, extra, word):
    _one_line(capsys, MOVE + extra + ["--out", str(tmp_path / "m")], word)
    assert not (tmp_path / "m").exists()


def test_move_out_naming_a_file_or_an_impossible_path(capsys, tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    _one_line(capsys, MOVE + ["--tacc", "200ms", "--out", str(f)], str(f))
    _one_line(capsys, MOVE + ["--tacc", "200ms", "--out", str(f / "sub")], str(f))
    assert f.read_text() == "x"


def _csv(path, t, cols, header=None):
    header = header or "t [s]," + ",".join(f"{n} [m]" for n in cols)
    rows = [",".join(repr(float(v)) for v in row) for row in zip(t, *cols.values())]
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def _mat(path, **vars):
    scipy.io.savemat(path, vars)
    return path


@pytest.fixture
def records(tmp_path):
    t = np.arange(500) * 0.004
    x = 0.01 * np.sin(t)
    big = x.copy()
    big[100] = 1e300
    r = {
        "zero": _csv(tmp_path / "zero.csv", t, {"x_cmd": 0 * t, "x_table": 0 * t}),
        "two": _csv(tmp_path / "two.csv", t[:2], {"x_cmd": x[:2], "x_table": x[:2]}),
        "big": _csv(tmp_path / "big.csv", t, {"x_cmd": x, "x_table": big}),
        "mm_as_m": _csv(tmp_path / "mm.csv", t, {"x_cmd": x * 1e5, "x_table": x * 1e5}),
        "ms": _csv(tmp_path / "ms.csv", t, {"x_cmd": x, "x_table": x}, header="t [ms],x_cmd [m],x_table [m]"),
        "under": tmp_path / "under.csv",
        "empty_t": _mat(tmp_path / "empty.mat", t=np.zeros(0), x_cmd=np.zeros(0)),
        "scalar_t": _mat(tmp_path / "scalar.mat", t=1.0, x_cmd=2.0),
        "str": _mat(tmp_path / "str.mat", t="hello", x_cmd=np.arange(10.0)),
        "cell": _mat(tmp_path / "cell.mat", t=t[:10], x_cmd=np.array([[1, "a"]], dtype=object), x_table=t[:10]),
        "complex": _mat(tmp_path / "cplx.mat", t=t, x_cmd=x * (1 + 1j), x_table=x),
        "dir": tmp_path,
    }
    r["under"].write_text("t [s],x_cmd [m],x_table [m]\n0,0,0\n0.00_4,1_000,0\n")
    return r


@pytest.mark.parametrize("name,word", [
    ("zero", "never moves"), ("two", "at least 10"), ("big", "beyond any reading"), ("mm_as_m", "unit"),
    ("ms", "sample period"), ("under", "is not a number"), ("empty_t", "empty"), ("scalar_t", "1 sample"),
    ("str", "text"), ("cell", "cell array"), ("complex", "complex"), ("dir", "folder"),
])
@pytest.mark.parametrize("command", ["compare", "diagnose"])
def test_degenerate_records_are_refused(capsys, tmp_path, records, name, word, command):
    _one_line(capsys, [command, str(records[name]), "--config", BENCH] +
              (["--out", str(tmp_path / "o")] if command == "compare" else []), word)


def test_map_header_is_not_a_variable(capsys, records):
    _one_line(capsys, ["compare", str(records["complex"]), "--config", BENCH, "--map", "__header__=force"],
              "no variable '__header__'")


def test_utf8_bom_is_accepted(tmp_path, capsys):
    t = np.arange(500) * 0.004
    x = 0.01 * np.sin(t)
    p = tmp_path / "bom.csv"
    _csv(p, t, {"x_cmd": x, "x_table": x})
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())
    from hil.io.measurement import read
    m = read(p)
    assert np.allclose(m["x_cmd"], x)


def test_fit_refit_unknown_key_and_out_over_its_config(capsys, tmp_path, records):
    t = np.arange(500) * 0.004
    ok = _csv(tmp_path / "ok.csv", t, {"x_cmd": 0.01 * np.sin(t), "x_table": 0.01 * np.sin(t)})
    _one_line(capsys, ["fit", str(ok), "--config", BENCH, "--add", "coulomb_friction", "--refit", "plant.zz",
                       "--out", str(tmp_path / "f.toml")], "--refit plant.zz")
    cfg = tmp_path / "mine.toml"
    cfg.write_text((CONFIG / "paper_bench.toml").read_text())
    before = cfg.read_text()
    _one_line(capsys, ["fit", str(ok), "--config", str(cfg), "--add", "coulomb_friction", "--out", str(cfg)],
              "is an input")
    assert cfg.read_text() == before


def test_other_commands(capsys, tmp_path):
    _one_line(capsys, ["drive-sim", "--config", str(CONFIG / "paper_bench_canopen.toml"), "--port", "70000"],
              "--port 70000")
    _one_line(capsys, ["synth", "--config", BENCH, "--sample-period", "100s", "--out", str(tmp_path / "s.csv")],
              "--sample-period")
    _one_line(capsys, ["synth", "--config", BENCH, "--out", BENCH], "is an input")
    _one_line(capsys, ["sweep", "--config", BENCH, "--stroke", "590mm", "--feed", "15m/min", "--jmax", "1..2000m/s^3",
                       "--points", "100000000", "--out", str(tmp_path / "sw")], "--points")


def test_sweep_refuses_an_unstable_loop(capsys, tmp_path):
    _one_line(capsys, ["sweep", "--config", BENCH, "--stroke", "50mm", "--feed", "6m/min", "--jmax", "20..1500m/s^3",
                       "--points", "3", "--set", "control.output_delay=40", "--out", str(tmp_path / "sw"),
                       "--no-plot", "--no-progress"], "unstable")


def test_synth_samples_a_slow_loop_on_its_ticks_by_default(capsys, tmp_path):
    """hil synth without --sample-period on config/serial_ascii_example.toml (a 10 ms position loop)
    refused its own default of 4 ms ("must be a whole multiple of the position period"). The
    default is 4 ms where the loop's period divides it (the records of every other example stay
    as they were), else the shortest whole multiple of the period above it."""
    from hil.commands.synth import default_sample_period
    assert [default_sample_period(t) for t in (1e-3, 4e-3, 62.5e-6, 3e-3, 5e-3, 10e-3)] == \
        [0.004, 0.004, 0.004, 0.006, 0.005, 0.01]
    out = tmp_path / "s.csv"
    assert main(["synth", "--config", str(CONFIG / "serial_ascii_example.toml"), "--duration", "1s",
                 "--out", str(out), "--json"]) == 0
    import json
    assert json.loads(capsys.readouterr().out)["sample_period"] == 0.01


def test_a_huge_decibel_value_is_refused_without_a_numpy_warning(capsys):
    """"1e300dB" (the CLI fuzzer's) overflowed inside pint with "RuntimeWarning: overflow
    encountered in exp" on stderr before the one-line refusal."""
    import warnings

    from hil.units import parse
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert parse("1e300 dB", "dimensionless") == float("inf") and parse("20 dB", "dimensionless") == 100.0
        assert main(["move", "--config", BENCH, "--stroke", "10mm", "--feed", "7000mm/min", "--tacc", "200ms",
                     "--set", "control.ffv=1e300dB", "--check"]) == 2
    err = capsys.readouterr().err
    assert "control.ffv: expected a finite" in err and "Warning" not in err
