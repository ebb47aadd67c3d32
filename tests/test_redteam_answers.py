"""Issue 30, the analysis commands: silently wrong answers and tracebacks of the red-team pass, each
as a test that failed before its fix, and a property-based fuzzer over these commands' arguments.

The sweep's own findings (its answer against --record-every and --dwell) are in
tests/test_sweep_verified.py. Every case here runs the command in-process through ``hil.cli.main``
(the broken pipe in a subprocess, where a pipe can close): an answer is exit 0, a mistake one line
and exit 2, a documented stop its exit code, and nothing else."""
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from conftest import CONFIG
from hang_guard import no_hang

from hil.cli import main
from hil.config import load

BENCH = str(CONFIG / "paper_bench.toml")


def _lines(text: str) -> list[str]:
    return [ln for ln in text.strip().splitlines() if ln.strip()]


def _one_line_error(capsys, argv, *words) -> str:
    rc = main(argv)
    err = _lines(capsys.readouterr().err)
    assert rc == 2 and len(err) == 1, (rc, err)
    for w in words:
        assert w in err[0], (w, err[0])
    return err[0]


# --- hil move --dwell 0s: settling and residual vibration cannot be measured -------------------------------

def test_move_without_dwell_does_not_claim_settled(tmp_path, capsys):
    """Before: 'settling table 0 ms tip 0 ms', 'residual tip vibration 0.00 um' next to a 1204 um
    overshoot: with no record after the command, neither can be measured."""
    argv = ["move", "--config", BENCH, "--stroke", "100mm", "--feed", "7000mm/min", "--jmax", "400m/s^3",
            "--dwell", "0s", "--out", str(tmp_path)]
    assert main(argv + ["--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["overshoot_tip_um"] > 1000
    assert d["residual_tip_um"] is None and d["settling_time_table"] is None and d["settling_time_tip"] is None
    assert d["observed_after_s"] == 0.0
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "cannot be measured" in out and "0 ms" not in out and "0.00 um" not in out
    # with a dwell the figures are there, and measured over it
    assert main(argv[:-4] + ["--dwell", "0.5s", "--out", str(tmp_path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["residual_tip_um"] > 100 and d["observed_after_s"] == pytest.approx(0.5, abs=0.005)


def test_settling_and_residual_of_a_record_ending_with_the_command():
    from hil.analysis import observed_after, residual_amplitude, settling_time
    t = np.arange(0.0, 1.0, 0.004)
    x = np.ones_like(t)
    assert settling_time(t, x, 1.0, 1e-6, t[-1]) is None        # one sample after: not measurable
    assert residual_amplitude(t, x, 1.0, t[-1]) is None
    assert observed_after(t, t[-1]) == 0.0
    assert settling_time(t, x, 1.0, 1e-6, 0.5) == 0.0           # a record after it, inside the band


# --- hil frf --gm: a margin must be one, and a suggested gain must pass hil move's check ------------------

@pytest.mark.parametrize("opt, value", [("--gm", "-6dB"), ("--gm", "0dB"), ("--pm", "-10deg"), ("--pm", "200deg")])
def test_frf_refuses_a_margin_that_is_none(opt, value, capsys, tmp_path):
    """Before: --gm -6dB suggested control.kv 408.8, which 'hil move' refuses as unstable."""
    _one_line_error(capsys, ["frf", "--config", BENCH, opt, value, "--out", str(tmp_path)], opt)


def test_an_unstable_suggested_gain_is_dropped(capsys):
    from types import SimpleNamespace

    from hil.commands.frf import keep_stable_gains
    # the gain 'hil frf --gm -6dB' suggested: 'hil move' refuses it (the check the tuning must respect)
    _one_line_error(capsys, ["move", "--config", BENCH, "--stroke", "5mm", "--feed", "3000mm/min", "--amax",
                             "2m/s^2", "--check", "--set", "control.kv=408.8"], "unstable")
    result = SimpleNamespace(tuning={"position_loop": {"kv_max": 408.8, "at_kv_max": {}},
                                     "velocity_loop": {"kp_max": 0.6, "at_kp_max": {}},
                                     "config_diff": 'control.kp = "0.6 N*m*s/rad"\ncontrol.kv = "408.8 1/s"'},
                             warnings=[])
    keep_stable_gains(result, lambda key, value: load(BENCH, {key: value}))
    assert "kv_max" not in result.tuning["position_loop"] and "control.kv" not in result.tuning["config_diff"]
    assert result.tuning["velocity_loop"]["kp_max"] == 0.6            # a stable one stays
    assert len(result.warnings) == 1 and "control.kv 408.8" in result.warnings[0]


# --- a dry run that trips latches nothing, and says so ------------------------------------------------------

def test_a_dry_run_trip_does_not_point_at_a_latch(tmp_path, capsys, state_dir):
    from hil.supervisor import latch_path
    rc = main(["move", "--config", BENCH, "--stroke", "20mm", "--feed", "6000mm/min", "--amax", "2m/s^2",
               "--dwell", "0.3s", "--set", "limits.following_error_table=1um", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 3 and "DID NOT COMPLETE" in out
    assert not latch_path(load(BENCH)).exists()
    assert "'hil status' shows the trip" not in out and "nothing is latched" in out
    assert main(["status", "--config", BENCH]) == 0 and "clear" in capsys.readouterr().out


# --- hil fit on an frf.json: lines validated -------------------------------------------------------------

def _frf_json(path: Path, f=None, scale: float = 1.0, phase: float | None = None) -> Path:
    """An frf.json in the format 'hil frf' writes, the paper bench's own model responses."""
    from drivers.control import controller_from_config
    from hil.frf.model import model_responses
    from hil.plant_config import plant_from_config
    cfg = load(BENCH)
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    f = np.geomspace(2.0, 200.0, 120) if f is None else f
    resp = {}
    for name in ("TF1p", "TF2"):
        h = model_responses(plant, ctrl, np.abs(f), tip_measured=False)[name] * scale
        resp[name] = {"frequency_hz": list(map(float, f)), "magnitude": list(map(float, np.abs(h))),
                      "phase_deg": list(map(float, np.degrees(np.angle(h)) if phase is None else np.full(f.size, phase))),
                      "coherence": [1.0] * f.size,
                      "magnitude_std": list(map(float, 0.01 * np.abs(h))), "derived": False}
    path.write_text(json.dumps({"responses": resp}))
    return path


@pytest.mark.parametrize("case, key", [("negative", "frequency_hz"), ("huge", "magnitude"), ("scale", "magnitude"),
                                       ("descending", "frequency_hz"), ("phase", "phase_deg")])
def test_fit_refuses_an_frf_file_that_is_no_measurement(case, key, tmp_path, capsys):
    """Before: negative frequencies fitted c2 = 10.45 N s/m, magnitudes of 1e300 c2 = 8.4e6, phases
    of 1e300 deg c2 = 65 (the model's 11.80)."""
    f = np.geomspace(2.0, 200.0, 120)
    path = {"negative": lambda p: _frf_json(p, f=-f), "huge": lambda p: _frf_json(p, scale=1e300),
            "scale": lambda p: _frf_json(p, scale=1e9), "descending": lambda p: _frf_json(p, f=f[::-1]),
            "phase": lambda p: _frf_json(p, phase=1e300)}[case](
        tmp_path / "frf.json")
    err = _one_line_error(capsys, ["fit", str(path), "--config", BENCH, "--add", "parameter:plant.c2", "--out",
                                   str(tmp_path / "fitted.toml")], str(path), f"responses.TF1p.{key}")
    assert not (tmp_path / "fitted.toml").exists(), err


def test_fit_of_the_models_own_responses_gives_its_c2(tmp_path, capsys):
    """The control: the model's responses fitted from c2 = 30 come back to the config's 11.80 N s/m."""
    path = _frf_json(tmp_path / "frf.json")
    assert main(["fit", str(path), "--config", BENCH, "--set", "plant.c2=30", "--add", "parameter:plant.c2",
                 "--out", str(tmp_path / "fitted.toml"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["params"]["value"] == pytest.approx(11.80, rel=1e-3)


# --- NRMSE fit of a constant channel -------------------------------------------------------------------------

def test_nrmse_of_a_constant_reference_is_undefined():
    from hil.ident.scores import fmt_fit, nrmse_fit
    y = np.full(401, 1e-4)                   # 0.1 mm: y - mean(y) is rounding only (1e-20 m)
    assert math.isnan(nrmse_fit(y, y * 0.9)) and fmt_fit(nrmse_fit(y, y * 0.9)).startswith("undefined")
    ramp = np.linspace(0.0, 1e-3, 401)
    assert nrmse_fit(ramp, ramp + 1e-5) == pytest.approx(100 * (1 - 1e-5 * 20.02498 / np.linalg.norm(
        ramp - ramp.mean())), rel=1e-3)


def _record(tmp_path, capsys) -> Path:
    out = tmp_path / "m"
    assert main(["move", "--config", BENCH, "--stroke", "10mm", "--feed", "6000mm/min", "--amax", "2m/s^2",
                 "--dwell", "0.3s", "--out", str(out)]) == 0
    capsys.readouterr()
    return out / "move.csv"


def _with_column(src: Path, dst: Path, name: str, value: str) -> Path:
    lines, idx = [], None
    for ln in src.read_text().splitlines():
        if ln.startswith("#") or not ln:
            lines.append(ln)
            continue
        cells = ln.split(",")
        if idx is None:
            idx = [c.split(" [")[0] for c in cells].index(name)
        else:
            cells[idx] = value
        lines.append(",".join(cells))
    dst.write_text("\n".join(lines) + "\n")
    return dst


@pytest.mark.slow
def test_compare_with_a_constant_tip_says_undefined(tmp_path, capsys):
    """Before: 'fit -4140097623904975872.00 %' for a tip channel stuck at one value."""
    rec = _with_column(_record(tmp_path, capsys), tmp_path / "const.csv", "x_tip", "0.1")
    assert main(["compare", str(rec), "--config", BENCH, "--out", str(tmp_path / "c")]) == 0
    tip = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("x_tip"))
    assert "fit undefined" in tip and "e+" not in tip.split("fit")[1].split("rel")[0]


@pytest.mark.slow
def test_compare_with_a_zero_tip_says_undefined_not_nan(tmp_path, capsys):
    """The red-team re-run: an all-zero measured channel printed 'rel nan %' (its RMS is zero)."""
    rec = _with_column(_record(tmp_path, capsys), tmp_path / "zero.csv", "x_tip", "0")
    assert main(["compare", str(rec), "--config", BENCH, "--out", str(tmp_path / "c")]) == 0
    tip = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("x_tip"))
    assert "nan" not in tip and "rel undefined" in tip, tip


def test_a_wide_record_is_read_in_linear_time(tmp_path):
    """The red-team re-run: the header's duplicate check searched a list per column, so 100 000
    columns took 53 s and 400 000 hung; 200 000 columns now read at once (the guard allows 60 s)."""
    from hil.io.measurement import parse_text
    n = 200_000
    head = "t [s],x_cmd [mm]," + ",".join(f"c{i}" for i in range(n))
    rows = "\n".join(",".join([str(k * 0.004), "0"] + ["0"] * n) for k in range(3))
    with no_hang(60):                    # the header check quadratic again
        m = parse_text(head + "\n" + rows + "\n", "wide.csv")
    assert len(m.channels) == n + 2 and m.channels["c199999"].size == 3


# --- --map onto a column the file has ------------------------------------------------------------------------

def test_a_map_replacing_a_files_column_warns_naming_both(tmp_path, capsys):
    from hil.io.importers import parse_mapping, read_any
    rec = _record(tmp_path, capsys)
    meas = read_any(rec, parse_mapping("x_tip=x_table"))
    hits = [w for w in meas.warnings if "x_tip=x_table" in w and "'x_table'" in w]
    assert len(hits) == 1
    # the channel holds the tip's values: what the map says, now said aloud
    plain = read_any(rec)
    assert np.array_equal(meas.channels["x_table"], plain.channels["x_tip"])
    assert "x_table" in {c for c in plain.channels} and not read_any(rec, parse_mapping("x_tip=x_tip")).warnings


# --- hil synth --out x.mat -------------------------------------------------------------------------------------

def test_synth_writes_a_real_mat_file(tmp_path, capsys):
    """Before: a CSV text under the .mat name. Now MATLAB v5, the same samples as the CSV."""
    base = ["synth", "--config", BENCH, "--duration", "2s", "--seed", "4"]
    assert main(base + ["--out", str(tmp_path / "r.mat")]) == 0
    assert main(base + ["--out", str(tmp_path / "r.csv")]) == 0
    capsys.readouterr()
    m = scipy.io.loadmat(str(tmp_path / "r.mat"))
    from hil.io.importers import read_any
    csv = read_any(tmp_path / "r.csv")
    for ch in ("t", "x_cmd", "x_table", "x_tip"):
        assert m[ch].reshape(-1) == pytest.approx(csv.channels[ch], rel=1e-8, abs=1e-12)
    assert str(m["hidden_effect"][0]) == "none"
    assert main(["compare", str(tmp_path / "r.mat"), "--config", BENCH, "--out", str(tmp_path / "c")]) == 0
    _one_line_error(capsys, base + ["--out", str(tmp_path / "r.xlsx")], "--out", ".mat")


# --- hil diagnose --no-chain --out -----------------------------------------------------------------------------

def test_diagnose_single_diagnosis_refuses_out(tmp_path, capsys):
    """Before: exit 0 and no file, nothing said."""
    rec = _record(tmp_path, capsys)
    for opt in (["--no-chain"], ["--max-steps", "1"]):
        _one_line_error(capsys, ["diagnose", str(rec), "--config", BENCH, *opt, "--out", str(tmp_path / "F.toml")],
                        "--out", "no config to write")
    assert not (tmp_path / "F.toml").exists()


# --- hil move | head -1 ------------------------------------------------------------------------------------------

def test_a_closed_stdout_ends_cleanly_after_the_run(tmp_path):
    """Before: BrokenPipeError, a traceback and exit 1 (a drive fault's code). The reader goes away
    before the command prints: the run completes and is recorded, the exit is 141, no traceback."""
    code = "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"
    import hil
    here = str(Path(hil.__file__).resolve().parents[1])     # the hil this test imports
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([here, os.environ.get("PYTHONPATH", "")]))
    p = subprocess.Popen([sys.executable, "-c", code, "move", "--config", BENCH, "--stroke", "10mm", "--feed",
                          "6000mm/min", "--amax", "2m/s^2", "--dwell", "0.3s", "--out", str(tmp_path)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path, env=env)
    p.stdout.close()                           # `| head -0`: the reader is gone before the first line
    err = p.stderr.read().decode()
    rc = p.wait(timeout=120)
    from hil.errors import STDOUT_CLOSED_EXIT
    assert rc == STDOUT_CLOSED_EXIT == 141 and "Traceback" not in err and "BrokenPipe" not in err, err
    status = json.loads((tmp_path / "move.json").read_text())
    assert status["status"] == "complete" and status["rows"] > 100


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full on this system")
def test_a_full_or_absent_stdout_is_one_line(tmp_path):
    """The red-team re-run: stdout on /dev/full gave OSError [Errno 28] with a traceback and exit 1
    (a drive fault's code), a closed stdout (>&-) an AttributeError. Now: one line and exit 2
    after the recorded run, and a run with no stdout at all completes (exit 0)."""
    code = "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"
    import hil
    here = str(Path(hil.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([here, os.environ.get("PYTHONPATH", "")]))
    argv = [sys.executable, "-c", code, "move", "--config", BENCH, "--stroke", "10mm", "--feed", "6000mm/min",
            "--amax", "2m/s^2", "--dwell", "0.3s", "--out", str(tmp_path)]
    with open("/dev/full", "w") as full:
        r = subprocess.run(argv, stdout=full, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=env, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().count("\n") == 0 and "No space left on device" in r.stderr
    assert json.loads((tmp_path / "move.json").read_text())["status"] == "complete"
    r = subprocess.run(argv[:-1] + [str(tmp_path / "closed")], stdout=None, stderr=subprocess.PIPE, text=True,
                       cwd=tmp_path, env=env, timeout=120, pass_fds=(), close_fds=True,
                       preexec_fn=lambda: os.close(1))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert json.loads((tmp_path / "closed" / "move.json").read_text())["status"] == "complete"


# --- hil model with an overdamped mode ---------------------------------------------------------------------------

def test_model_with_an_overdamped_mode(capsys, tmp_path):
    """Before: IndexError. plant.c2 = 3000 N s/m damps the 14.9 Hz tip mode past critical
    (zeta = c2 / (2 sqrt(k2 m3)) ~ 3000 / (2 sqrt(3.706e4 * 4.228)) = 3.8 for the tip on its plate)."""
    zeta_tip = 3000 / (2 * math.sqrt(3.7060e4 * 4.228))
    assert zeta_tip > 1
    argv = ["model", "--config", BENCH, "--set", "plant.c2=3000", "--out", str(tmp_path)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "1 mode(s) overdamped" in out
    assert main(argv + ["--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["overdamped_modes"] == 1 and len(d["damped_modes_hz"]) == 1
    assert d["damping_ratios"][0] == pytest.approx(zeta_tip, rel=0.05)


# --- hil compare --after a model of another actuator --------------------------------------------------------------

def test_compare_after_another_actuator_is_one_line(tmp_path, capsys):
    """Before: KeyError 'torque' (a traceback)."""
    rec = _record(tmp_path, capsys)
    _one_line_error(capsys, ["compare", str(rec), "--config", BENCH, "--after", str(CONFIG / "emps.toml"),
                             "--out", str(tmp_path / "c")], "--after", "linear")


# === the fuzzer: these commands' arguments ========================================================================

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

# examples per command in the default set (a sweep example runs its moves: the fewest), ~10 s in all
DEFAULT_EXAMPLES = {"move": 8, "sweep": 3, "frf": 8, "model": 6, "synth": 6}
LONG = settings(max_examples=150, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


NUMBER = st.one_of(st.sampled_from(["0", "-0", "-1", "1e300", "-1e300", "1e-300", "nan", "inf", "-inf", "1e999",
                                    "3", "0.5", "400", "64", "8", "100000000"]),
                   st.floats(allow_nan=True, allow_infinity=True).map(repr),
                   st.integers(-10**12, 10**12).map(str))
UNIT = st.sampled_from(["", "mm", "um", "m", "s", "ms", "mm/min", "m/s", "m/s^2", "m/s^3", "dB", "deg", "Hz",
                        "N*m", "%", "kg", "furlong"])
QUANTITY = st.builds(lambda n, sep, u: f"{n}{sep}{u}", NUMBER, st.sampled_from(["", " "]), UNIT)
VALUE = st.one_of(QUANTITY, st.builds(lambda a, b: f"{a}..{b}", QUANTITY, QUANTITY),
                  st.builds(lambda a, b: f"{a},{b}", QUANTITY, QUANTITY), st.text(max_size=12))

# each command: its valid base arguments, and the options the fuzzer replaces (one or two at a time)
SURFACES = {
    "move": (["--config", BENCH, "--stroke", "5mm", "--feed", "3000mm/min", "--amax", "2m/s^2", "--dwell", "0.1s"],
             ["--stroke", "--feed", "--amax", "--dwell", "--band", "--start"]),
    "sweep": (["--config", BENCH, "--stroke", "1mm", "--feed", "3000mm/min", "--jmax", "50,200m/s^3", "--no-plot",
               "--no-progress", "--jobs", "1"],
              ["--stroke", "--feed", "--jmax", "--points", "--dwell", "--record-every", "--budget", "--tolerance"]),
    "frf": (["--config", BENCH], ["--gm", "--pm", "--amplitude", "--band", "--period", "--speed", "--settle",
                                  "--noise", "--periods"]),
    "model": (["--config", BENCH], ["--set plant.c2", "--set plant.k2", "--set plant.m3", "--set control.kv"]),
    "synth": (["--config", BENCH, "--duration", "1s"], ["--duration", "--sample-period", "--pulses"]),
}


class _Measured(Exception):
    """hil frf got past its arguments: the measurement itself is not what this fuzzer is about."""


def _argv(command, tmp_path, picks):
    base, _ = SURFACES[command]
    argv = [command, *base]
    for opt, value in picks:
        if opt.startswith("--set "):
            argv += ["--set", f"{opt.split()[1]}={value}"]
        else:
            argv += [f"{opt}={value}"]
    out = tmp_path / ("r.csv" if command == "synth" else "out")
    return argv + ["--out", str(out)]


def _check_cli(command, picks, tmp_path, capsys, monkeypatch):
    import hil.frf
    monkeypatch.setattr(hil.frf, "measure", lambda *a, **k: (_ for _ in ()).throw(_Measured()))
    argv = _argv(command, tmp_path, picks)
    capsys.readouterr()               # this example's output only
    try:
        with no_hang(60):
            rc = main(argv)
    except _Measured:
        return
    except SystemExit as exc:         # argparse: a value its type= refuses (usage and one error line)
        assert exc.code == 2, argv
        return
    err = _lines(capsys.readouterr().err)
    # 0: an answer; 2: one line; 3: the sim supervisor tripped the move (documented, STOP_EXIT_CODES)
    assert rc in (0, 2, 3), (argv, rc, err)
    if rc == 2:
        errors = [ln for ln in err if "error:" in ln]
        assert len(errors) == 1 and "Traceback" not in "\n".join(err), (argv, err)


def _picks(command):
    _, options = SURFACES[command]
    return st.lists(st.tuples(st.sampled_from(options), VALUE), min_size=1, max_size=2,
                    unique_by=lambda p: p[0])


@pytest.mark.parametrize("command", sorted(SURFACES))
def test_fuzz_cli_arguments(command, tmp_path_factory, capsys, monkeypatch):
    """A few derandomized examples per command in the default set (about 10 s in all)."""
    @settings(max_examples=DEFAULT_EXAMPLES[command], deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
    @given(picks=_picks(command))
    def prop(picks):
        _check_cli(command, picks, tmp_path_factory.mktemp(command), capsys, monkeypatch)
    prop()


@pytest.mark.slow
@pytest.mark.parametrize("command", sorted(SURFACES))
def test_fuzz_cli_arguments_long(command, tmp_path_factory, capsys, monkeypatch):
    @LONG
    @given(picks=_picks(command))
    def prop(picks):
        _check_cli(command, picks, tmp_path_factory.mktemp(command), capsys, monkeypatch)
    prop()
