"""Property-based fuzzing (issue 18): the command-line parsers, the file readers and the config
loader, driven by hypothesis, may answer a bad input only with the project's own errors (one line,
exit 2 at the command line), never a traceback, and never hang.

Bounded: a fixed number of examples per property (``derandomize``: the same examples every run),
the whole file well under a minute in CI."""
import math

import numpy as np
import pytest
import scipy.io
from conftest import CONFIG
from hang_guard import no_hang

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from hil import config  # noqa: E402
from hil.errors import HilError  # noqa: E402
from hil.io.importers import parse_mapping, read_mat  # noqa: E402
from hil.io.measurement import parse_text  # noqa: E402
from hil.units import DIMENSIONS, parse  # noqa: E402

FAST = settings(max_examples=150, deadline=2000, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
SLOW = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**30, 10**30),
                    st.sampled_from([0, -0.0, 1e300, -1e300, 1e-320, 5e-324]))
UNITS = st.sampled_from(["", "mm", "m", "um", "s", "ms", "m/s", "mm/min", "m/s^2", "m/s^3", "N*m", "kg", "1/s",
                         "Hz", "rad/s", "N", "V", "degC", "furlong", "m**1000", "m/0", "__class__", "{}", "%"])
QUANTITY_TEXT = st.one_of(
    st.builds(lambda n, u, sep: f"{n}{sep}{u}", NUMBERS, UNITS, st.sampled_from(["", " ", "_", "e"])),
    st.text(max_size=30),
    st.sampled_from(["inf", "-inf", "nan", "1_000", "1e999", "-5mm", "--5", "1..2", "0x10", "１０mm", "\ufeff1",
                     "1e-6mm/min", "10um" * 50]))


@FAST
@given(text=QUANTITY_TEXT, kind=st.sampled_from(sorted(DIMENSIONS)))
def test_units_parse(text, kind):
    try:
        v = parse(text, kind, "--x")
    except HilError:
        return
    assert isinstance(v, float) and not math.isnan(v)


CELL = st.one_of(st.builds(repr, NUMBERS), st.text(alphabet="0123456789.-+eE_ infa", max_size=8))
HEADERS = st.sampled_from(["t [s],x_cmd [m],x_table [m]", "t [ms],x_cmd [mm],x_table [mm],torque [N*m]",
                           "\ufefft [s],x_cmd [m]", "t,x_cmd,x_table", "t [s],x_cmd [m],x_cmd [m]",
                           "t [s],x_cmd [kg]", "# sample_period = 0.004 s\nt [s],x_cmd [m],x_motor [m]", "", "t [s"])


@FAST
@given(header=HEADERS, rows=st.lists(st.lists(CELL, min_size=1, max_size=5), max_size=12),
       junk=st.text(max_size=20))
def test_csv_reader(header, rows, junk):
    text = header + "\n" + "\n".join(",".join(r) for r in rows) + junk
    try:
        m = parse_text(text, "fuzz.csv")
    except HilError:
        return
    assert m.t.size >= 2 and np.all(np.diff(m.t) > 0)
    for v in m.channels.values():
        assert np.all(np.isfinite(v))


MAT_VALUES = st.one_of(
    st.builds(lambda n: np.arange(float(n)) * 0.004, st.integers(0, 30)),
    st.builds(lambda n: np.zeros(n), st.integers(0, 5)),
    NUMBERS.filter(lambda v: isinstance(v, float) or abs(v) < 2**62),
    st.text(max_size=5).filter(lambda s: s != ""),
    st.builds(lambda n: np.ones((n, 2)), st.integers(1, 4)),
    st.builds(lambda n: np.arange(float(n)) * (1 + 1j), st.integers(1, 5)),
    st.just(np.array([[1, "a"]], dtype=object)),
    st.just({"a": 1.0}),
)


@SLOW
@given(vars=st.dictionaries(st.sampled_from(["t", "x_cmd", "x_table", "qm", "qg", "force", "vir", "gtau"]),
                            MAT_VALUES, max_size=5),
       mapping=st.one_of(st.none(), st.sampled_from(["t=t,x_cmd=x_cmd", "__header__=force,t=t,x_cmd=x_cmd",
                                                      "vir*gtau=force,t=t,qg=x_cmd", "t=t[ms],x_cmd=x_cmd[mm]",
                                                      "t*1e300=t,x_cmd=x_cmd", "a=b=c", "t=zz"])))
def test_mat_reader(tmp_path_factory, vars, mapping):
    p = tmp_path_factory.mktemp("mat") / "r.mat"
    try:
        scipy.io.savemat(p, vars)
    except Exception:          # what scipy itself cannot write is no input of ours
        return
    try:
        m = read_mat(p, parse_mapping([mapping]) if mapping else None)
    except HilError:
        return
    assert m.t.size >= 2
    for v in m.channels.values():
        assert v.dtype.kind == "f" and np.all(np.isfinite(v))


KEYS = sorted(k for k in config.SCHEMA if "*" not in k) + ["plant.m1", "plant.k2", "plant.c9", "supervisor.history",
                                                            "supervisor.latch_file", "nope.key", "control"]
VALUES = st.one_of(NUMBERS, QUANTITY_TEXT, st.booleans(), st.lists(NUMBERS, max_size=10), st.none(),
                   st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


@SLOW
@given(overrides=st.dictionaries(st.sampled_from(KEYS), VALUES, min_size=1, max_size=3))
def test_config_loader_and_stability_check(overrides):
    from hil.closed_loop import check_loop_stability
    with no_hang(20):
        try:
            cfg = config.load(CONFIG / "paper_bench.toml", overrides)
            check_loop_stability(cfg)
        except HilError:
            return


@FAST
@given(assignment=st.text(max_size=40))
def test_set_assignment_parser(assignment):
    try:
        config.parse_assignment(assignment)
    except HilError:
        pass


MOVE_Q = st.one_of(QUANTITY_TEXT, st.sampled_from(["100mm", "7000mm/min", "200ms", "2m/s^2", "0mm", "-0.1m"]))


@SLOW
@given(stroke=MOVE_Q, feed=MOVE_Q, how=st.sampled_from(["--tacc", "--amax", "--jmax"]), value=MOVE_Q,
       dwell=MOVE_Q, band=MOVE_Q)
def test_cli_move_check(capsys, stroke, feed, how, value, dwell, band):
    from hil.cli import main
    with no_hang(20):
        rc = main(["move", "--config", str(CONFIG / "paper_bench.toml"), f"--stroke={stroke}", f"--feed={feed}",
                   f"{how}={value}", f"--dwell={dwell}", f"--band={band}", "--check"])
    cap = capsys.readouterr()
    assert rc in (0, 2), cap.err
    if rc == 2:
        assert cap.err.count("\n") == 1 and "Traceback" not in cap.err, cap.err


@SLOW
@given(points=st.integers(-5, 10**9), jmax=st.one_of(QUANTITY_TEXT, st.sampled_from(["1..2000m/s^3", "100..10m/s^3", "5,6,7m/s^3",
                                                                                     "0..1m/s^3", "1..inf"])),
       tol=MOVE_Q)
def test_cli_sweep_arguments(capsys, tmp_path_factory, points, jmax, tol, monkeypatch):
    """The sweep's argument checks (the sweep itself is not run: run_sweep is replaced)."""
    import hil.sweep
    from hil.cli import main
    monkeypatch.setattr(hil.sweep, "run_sweep", lambda *a, **k: (_ for _ in ()).throw(SystemExit(0)))
    out = tmp_path_factory.mktemp("sw")
    with no_hang(20):
        try:
            rc = main(["sweep", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "50mm", "--feed", "6m/min",
                       f"--jmax={jmax}", "--points", str(points), f"--tolerance={tol}", "--out", str(out),
                       "--no-plot", "--no-progress"])
        except SystemExit as exc:        # reached run_sweep: the arguments were accepted
            rc = exc.code
    cap = capsys.readouterr()
    assert rc in (0, 2), cap.err
    if rc == 2:
        assert cap.err.count("\n") == 1 and "Traceback" not in cap.err, cap.err
