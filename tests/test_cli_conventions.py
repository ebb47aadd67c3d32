"""Issue 17, the command line as a drive engineer reads it: engineering units in the text output
(hil.units.fmt), the fit's uncertainty and a config edited rather than rewritten
(hil.io.config_write), the diagnosis read top down, --log-level, --can-log (python-can's logger),
-i/-c, units on every quantity option and "did you mean"."""
import difflib
import json
import logging
import math
import re
from pathlib import Path
from types import SimpleNamespace

import can
import numpy as np
import pytest
from canopen_rig import channel

from hil.cli import main
from hil.config import load, loads
from hil.errors import ConfigError
from hil.plant_config import plant_from_config
from hil.units import fmt, fmt_uncertain, parse_angle_deg, parse_gain_db, round_to_uncertainty

ROOT = Path(__file__).resolve().parents[1]
BENCH = str(ROOT / "config" / "paper_bench.toml")
CANOPEN = "config/paper_bench_canopen.toml"


# --- units -----------------------------------------------------------------------------------

@pytest.mark.parametrize("value, kind, text", [
    (2.033e-4, "length", "203.3 um"), (1.028e-3, "length", "1.028 mm"), (0.1, "length", "100 mm"),
    (12.5, "length", "12.5 m"), (0.012, "time", "12 ms"), (62.5e-6, "time", "62.5 us"), (12.0, "time", "12 s"),
    (8.94, "torque", "8.94 N m"), (8.2, "frequency", "8.2 Hz"), (5.362e7, "stiffness", "53.62 N/um"),
    (3.706e4, "stiffness", "37.06 N/mm"), (11.8, "damping", "11.8 N s/m"), (20.2386, "force", "20.24 N"),
    (4.228, "mass", "4.228 kg"), (None, "length", "n/a"), (float("inf"), "time", "inf"),
])
def test_fmt_writes_engineering_units(value, kind, text):
    assert fmt(value, kind) == text


def test_fmt_fixed_unit_and_the_conversion_is_pints():
    import pint
    ureg = pint.UnitRegistry()
    assert fmt(0.0123, "time", unit="ms") == "12.3 ms"
    assert fmt(0.025, "speed", unit="mm/min") == f"{ureg.Quantity(0.025, 'm/s').to('mm/min').magnitude:.4g} mm/min"
    assert fmt(2.5, "speed", unit="mm/min") == "150000 mm/min"        # no e-notation for large values


@pytest.mark.parametrize("value, sigma, rounded, decimals", [
    (40.0912, 0.0374, 40.091, 3), (2.23456, 0.00012, 2.23456, 5), (12345.6, 230.0, 12350.0, -1),
    (1.5, None, 1.5, None), (1.5, float("nan"), 1.5, None)])
def test_rounded_to_two_digits_of_the_uncertainty(value, sigma, rounded, decimals):
    r, d = round_to_uncertainty(value, sigma)
    assert r == pytest.approx(rounded) and d == decimals


def test_fmt_uncertain():
    assert fmt_uncertain(40.0912, 0.0374, "damping") == "40.091 +- 0.037 N s/m"
    assert fmt_uncertain(1.2e-4, 3e-6, "length") == "120.0 +- 3.0 um"


# --- the standard error of a fit ----------------------------------------------------------------

def test_standard_errors_match_linear_regression():
    """A straight line fitted by least_squares: the Jacobian's standard errors are the closed form
    of linear regression, sqrt(diag(s^2 (X^T X)^-1)), s^2 = RSS / (n - 2)."""
    from scipy.optimize import least_squares

    from hil.ident.fit import standard_errors
    rng = np.random.default_rng(4)
    x = np.linspace(0.0, 2.0, 200)
    y = 3.0 * x - 0.5 + rng.normal(0.0, 0.1, x.size)
    scale = np.array([2.0, 0.25])          # fitted in scaled parameters, as hil.ident.fit does
    sol = least_squares(lambda z: (z[0] * scale[0]) * x + z[1] * scale[1] - y, [1.0, 1.0])
    X = np.column_stack([x, np.ones_like(x)])
    coef, rss, *_ = np.linalg.lstsq(X, y, rcond=None)
    want = np.sqrt(np.diag(rss[0] / (x.size - 2) * np.linalg.inv(X.T @ X)))
    assert sol.x * scale == pytest.approx(coef, rel=1e-6)
    assert standard_errors(sol, scale) == pytest.approx(want, rel=1e-4)


# --- the config edited, not rewritten --------------------------------------------------------

def _changed_lines(a: str, b: str) -> tuple[list[str], list[str]]:
    diff = list(difflib.unified_diff(a.splitlines(), b.splitlines(), lineterm="", n=0))
    return ([ln[1:] for ln in diff if ln.startswith("-") and not ln.startswith("---")],
            [ln[1:] for ln in diff if ln.startswith("+") and not ln.startswith("+++")])


def test_edit_keeps_comments_units_and_layout():
    from hil.io.config_write import changed_keys, edit_config_text
    text = Path(BENCH).read_text(encoding="utf-8")
    old = loads(text, BENCH)
    new = old.with_values({"plant.c2": 40.0912, "plant.k2": 3.1e4, "effects.coulomb_friction.level": 2.2345})
    keys = changed_keys(old, new)
    assert set(keys) == {"plant.c2", "plant.k2", "effects.coulomb_friction.level"}
    out = edit_config_text(text, new, keys, stderr={"plant.c2": 0.0374}, note="test")
    removed, added = _changed_lines(text, out)
    assert removed == ['k2 = "3.7060e4 N/m"   # thin plates', 'c2 = "11.80 N*s/m"']
    assert added[0].startswith('k2 = "31000 N/m"') and added[0].endswith("thin plates")   # its comment kept
    assert added[1] == 'c2 = "40.091 N*s/m" # test; +- 0.037 N*s/m (standard error); was "11.80 N*s/m"'
    assert '[effects.coulomb_friction]' in added and any(a.startswith('level = "2.2345') for a in added)
    back = loads(out, "edited")
    assert back["plant.c2"] == 40.091 and back["plant.k2"] == 3.1e4
    assert back["effects.coulomb_friction.level"] == pytest.approx(2.2345)
    for k in old.keys():                      # everything else reads as before
        if k not in keys:
            assert back.get(k) == old.get(k), k


@pytest.fixture(scope="module")
def c2_record(tmp_path_factory):
    """The README's worked case: the paper bench with c2 = 40 N s/m (synth, shorter)."""
    out = tmp_path_factory.mktemp("c2") / "c2.csv"
    assert main(["synth", "--config", BENCH, "--effect", "parameter:plant.c2", "--param", "value=40 N*s/m",
                 "--duration", "4s", "--out", str(out)]) == 0
    return out


def test_fit_changes_only_the_fitted_key(c2_record, tmp_path, capsys):
    capsys.readouterr()
    out = tmp_path / "fitted.toml"
    assert main(["fit", str(c2_record), "--config", BENCH, "--add", "parameter:plant.c2", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    before, after = Path(BENCH).read_text(encoding="utf-8"), out.read_text(encoding="utf-8")
    removed, added = _changed_lines(before, after)
    assert removed == ['c2 = "11.80 N*s/m"'] and len(added) == 1          # one line, the comments kept
    m = re.fullmatch(r'c2 = "(?P<v>[0-9.]+) N\*s/m" # hil fit on c2\.csv; \+- (?P<s>[0-9.]+) N\*s/m '
                     r'\(standard error\); was "11\.80 N\*s/m"', added[0])
    assert m, added[0]
    value, sigma = float(m["v"]), float(m["s"])
    assert value == pytest.approx(40.0, rel=0.02) and 0 < sigma < 1.0
    # rounded to its uncertainty: as many decimals as the error's second significant digit
    assert len(m["v"].split(".")[1]) == len(m["s"].split(".")[1]) == 1 - math.floor(math.log10(sigma))
    assert load(out)["plant.c2"] == value
    # the text: the value with its error and unit, the errors in engineering units
    line = next(ln for ln in text.splitlines() if ln.startswith("plant.c2 = "))
    assert line == f"plant.c2 = {m['v']} +- {m['s']} N s/m  (standard error)"
    rms = [ln for ln in text.splitlines() if "RMS" in ln]
    assert any(re.search(r"x_tip: RMS [0-9.]+ (um|mm) -> [0-9.]+ (nm|um)", ln) for ln in rms), rms
    assert any(re.search(r"torque: RMS [0-9.]+ N m -> [0-9.]+ N m", ln) for ln in rms), rms


def test_fit_json_has_the_uncertainty_and_the_units(c2_record, tmp_path, capsys):
    capsys.readouterr()
    out = tmp_path / "fitted.toml"
    assert main(["fit", str(c2_record), "--config", BENCH, "--add", "parameter:plant.c2", "--out", str(out),
                 "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    f = d["fitted"]["plant.c2"]
    assert f["unit"] == "N*s/m" and f["value"] == pytest.approx(40.0, rel=0.02) and 0 < f["stderr"] < 1.0
    assert d["steps"][0]["stderr"]["value"] == pytest.approx(f["stderr"])
    assert d["units"]["error_before"]["x_tip"] == "m" and d["units"]["error_after"]["torque"] == "N*m"


# --- diagnose reads top down ------------------------------------------------------------------

def _cand(effect, score, significant=True):
    return SimpleNamespace(effect=effect, score=score, significant=significant, evidence=f"evidence of {effect}")


def test_diagnose_text_verdict_first_also_missing_once_rest_by_score():
    from hil.commands.diagnose import ranking_text
    cands = [_cand("coulomb_friction", 812.5), _cand("asymmetric_friction", 10196.2), _cand("constant_force", -3.0),
             _cand("viscous_friction", 40.0), _cand("parameter:plant.c2", 2.0, False)]
    combo = {"effects": ["coulomb_friction", "constant_force"], "explains": "asymmetric_friction", "preferred": True,
             "score": 10100.4, "explained": 0.98, "rich_against_combination": 3.1}
    d = {"verdict": "coulomb_friction", "candidates": cands, "combinations": [combo],
         "also_missing": [{"effect": "constant_force", "score": 950.0, "evidence": "an offset"}]}
    lines = ranking_text(d)
    assert lines[0].startswith("verdict: coulomb_friction (with constant_force: combination score 10100.4")
    assert lines[2].startswith("also missing: constant_force (score 950.0")       # its marginal score
    ranked = [ln for ln in lines if re.match(r"\s*\d+[* ] ", ln)]
    names = [ln.split()[1] for ln in ranked]
    assert names == ["asymmetric_friction", "viscous_friction", "parameter:plant.c2"]   # by score, each once
    scores = [float(re.search(r"score\s+(-?[0-9.]+)", ln).group(1)) for ln in ranked]
    assert scores == sorted(scores, reverse=True)
    assert "mimicked by coulomb_friction + constant_force" in ranked[0]
    text = "\n".join(lines)
    for name in ("coulomb_friction", "constant_force"):     # named in the verdict lines, not ranked again
        assert not any(n == name for n in names)
    assert text.count("combination coulomb_friction + constant_force") == 0   # the lead is in the verdict


def test_diagnose_command_text(c2_record, tmp_path, capsys):
    capsys.readouterr()
    out = tmp_path / "diag.toml"
    assert main(["diagnose", str(c2_record), "--config", BENCH, "--candidates",
                 "parameter:plant.c2,coulomb_friction", "--jobs", "1", "--max-steps", "2", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("verdict: parameter:plant.c2 (score ")
    assert re.search(r"x_tip [0-9.]+ (um|mm) \(", "\n".join(lines))       # the chain in engineering units
    removed, added = _changed_lines(Path(BENCH).read_text(encoding="utf-8"), out.read_text(encoding="utf-8"))
    assert removed == ['c2 = "11.80 N*s/m"'] and added[0].startswith('c2 = "') and "hil diagnose on c2.csv" in added[0]


# --- logging -----------------------------------------------------------------------------------

def test_log_level(capsys, tmp_path):
    assert main(["--log-level", "debug", "model", "--config", BENCH, "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert re.search(r"^DEBUG hil\.config: reading the configuration .*paper_bench\.toml", err, re.M), err
    assert logging.getLogger("canopen").level == logging.NOTSET        # no longer forced to CRITICAL
    assert main(["model", "--config", BENCH, "--out", str(tmp_path)]) == 0
    assert "DEBUG" not in capsys.readouterr().err
    assert logging.getLogger("canopen").level == logging.CRITICAL       # without --log-level: quiet bus libraries
    with pytest.raises(SystemExit):
        main(["--log-level", "verbose", "model", "--config", BENCH])
    assert "invalid choice: 'verbose'" in capsys.readouterr().err


# --- the CAN options -------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_can_log_records_the_bus_and_python_can_reads_it(tmp_path, capsys, suffix):
    from drivers.canopen.drive_sim import DriveSim
    ch = channel("canlog")
    cfg = load(CANOPEN, {"canopen.lockstep": True, "canopen.interface": "virtual", "canopen.channel": ch})
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    trace = tmp_path / f"bus{suffix}"
    try:
        rc = main(["move", "--config", CANOPEN, "--set", "canopen.lockstep=true", "-i", "virtual", "-c", ch,
                   "--backend", "canopen", "--stroke", "2mm", "--feed", "6000mm/min", "--amax", "2m/s^2",
                   "--dwell", "0.1s", "--out", str(tmp_path / "m"), "--json", "--can-log", str(trace)])
    finally:
        sim.close()
    assert rc == 0, capsys.readouterr().err
    summary = json.loads(capsys.readouterr().out)
    assert summary["status"] == "complete"
    assert summary["units"]["peak_torque"] == "N*m" and summary["units"]["settling_time_tip"] == "s"
    reader = can.ASCReader(str(trace)) if suffix == ".asc" else can.BLFReader(str(trace))
    frames = list(reader)
    node = cfg.get("canopen.node_id", 1)
    sent = {m.arbitration_id for m in frames if not m.is_rx}
    got = {m.arbitration_id for m in frames if m.is_rx}
    assert 0x80 in sent and 0x200 + node in sent and 0x600 + node in sent     # SYNC, RPDO1, SDO requests
    assert 0x180 + node in got and 0x580 + node in got                      # TPDO1, SDO answers
    from hil.io.measurement import read as read_measurement
    rows = read_measurement(tmp_path / "m" / "move.csv").t.size
    syncs = sum(1 for m in frames if m.arbitration_id == 0x80)
    assert syncs >= 0.9 * rows > 20                    # every cycle of the move, not the start-up only


def test_can_log_refuses_an_unknown_format(tmp_path, capsys):
    rc = main(["--can-log", str(tmp_path / "bus.xyz"), "model", "--config", BENCH, "--out", str(tmp_path)])
    assert rc == 2 and ".asc" in capsys.readouterr().err


def test_interface_channel_bitrate_options_and_python_can_config(monkeypatch):
    from hil.commands.move import load_config
    args = SimpleNamespace(config=BENCH, set=[], backend="canopen", interface="socketcan", channel="can1",
                           bitrate=500000)
    cfg = load_config(args)
    assert (cfg["canopen.interface"], cfg["canopen.channel"], cfg["canopen.bitrate"]) == ("socketcan", "can1", 500000)
    # python-can's own configuration (here its environment variables) for what neither gives
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", "fromenv")
    monkeypatch.setenv("CAN_BITRATE", "250000")
    args = SimpleNamespace(config=BENCH, set=[], backend="canopen", interface=None, channel=None, bitrate=None)
    cfg = load_config(args)
    assert (cfg["canopen.interface"], cfg["canopen.channel"], cfg["canopen.bitrate"]) == ("virtual", "fromenv", 250000)
    args.channel = "given"                # the option wins over python-can's configuration
    assert load_config(args)["canopen.channel"] == "given"


def test_drive_sim_offers_only_what_works(capsys):
    with pytest.raises(SystemExit):
        main(["drive-sim", "--config", CANOPEN, "--interface", "slcan"])
    assert "invalid choice: 'slcan'" in capsys.readouterr().err


# --- did you mean ------------------------------------------------------------------------------

def test_did_you_mean_for_commands(capsys):
    with pytest.raises(SystemExit):
        main(["diagnos", "x.csv"])
    assert "did you mean 'diagnose'?" in capsys.readouterr().err


@pytest.mark.parametrize("key, want", [("plant.c22", None), ("plant.pich", "plant.pitch"),
                                       ("control.kvv", "control.kv"), ("supervisor.stp", "supervisor.stop"),
                                       ("effects.coulomb_friction.levl", "effects.coulomb_friction.level")])
def test_did_you_mean_for_config_keys(key, want):
    with pytest.raises(ConfigError) as e:
        load(BENCH, {key: 1.0})
    msg = str(e.value)
    if want:
        assert f"did you mean {want!r}?" in msg
    else:
        assert "did you mean" not in msg or "plant.c2" in msg


def test_did_you_mean_in_a_config_file(tmp_path):
    p = tmp_path / "typo.toml"
    p.write_text(Path(BENCH).read_text(encoding="utf-8").replace("pitch =", "pich ="), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"unknown key 'plant\.pich' \(known keys in \[plant\]: .*\); "
                                          r"did you mean 'plant\.pitch'\?$"):
        load(p)


def test_did_you_mean_for_effects(capsys, tmp_path):
    rc = main(["synth", "--config", BENCH, "--effect", "colomb_friction", "--out", str(tmp_path / "s.csv")])
    assert rc == 2 and "did you mean 'coulomb_friction'?" in capsys.readouterr().err
    rc = main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "levle=2Nm",
               "--out", str(tmp_path / "s.csv")])
    assert rc == 2 and "did you mean 'level'?" in capsys.readouterr().err


# --- units on the options, and in the text ----------------------------------------------------

def test_synth_takes_units_and_prints_no_dict(tmp_path, capsys):
    out = tmp_path / "f.csv"
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "level=2Nm",
                 "--duration", "2s", "--sample-period", "8ms", "--out", str(out)]) == 0
    text = capsys.readouterr().out.strip()
    assert text == f"wrote {out}: 250 samples every 8 ms (2 s), hidden effect coulomb_friction: level = 2 N m"
    assert "{" not in text
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "level=2000 N*mm",
                 "--duration", "2000ms", "--out", str(out), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["params"]["level"] == pytest.approx(2.0) and d["samples"] == 500 and d["duration"] == pytest.approx(2.0)
    assert d["units"]["params"]["level"] == "N*m" and d["units"]["duration"] == "s"
    rc = main(["synth", "--config", BENCH, "--duration", "5 mm", "--out", str(out)])
    assert rc == 2 and "--duration" in capsys.readouterr().err



@pytest.mark.parametrize("text, deg", [("45", 45.0), ("45deg", 45.0), ("45 °", 45.0), ("30 degree", 30.0),
                                       (f"{math.pi / 4!r}rad", 45.0), ("0.5rad", math.degrees(0.5))])
def test_phase_margin_reads_angles(text, deg):
    assert parse_angle_deg(text, "--pm") == pytest.approx(deg, rel=1e-12)


@pytest.mark.parametrize("text, db", [("6", 6.0), ("6dB", 6.0), ("6 dB", 6.0), ("-3.5dB", -3.5), ("1e1 dB", 10.0)])
def test_gain_margin_reads_decibels(text, db):
    assert parse_gain_db(text, "--gm") == db


def test_frf_margins_take_units_and_refuse_others(tmp_path, capsys, monkeypatch):
    from hil import frf
    seen = {}

    def measure(*args, pm_min, gm_min_db, **kw):       # what the command hands the tuning
        seen.update(pm=pm_min, gm=gm_min_db)
        raise RuntimeError("stopped after the margins were read")
    monkeypatch.setattr(frf, "measure", measure)
    rc = main(["frf", "--config", BENCH, "--pm", "0.75rad", "--gm", "8 dB", "--out", str(tmp_path)])
    assert rc == 2 and seen == {"pm": pytest.approx(math.degrees(0.75)), "gm": 8.0}
    capsys.readouterr()
    for opt, bad in (("--pm", "45mm"), ("--gm", "6 N")):
        rc = main(["frf", "--config", BENCH, opt, bad, "--out", str(tmp_path)])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and err.count("\n") == 0 and opt in err and "Traceback" not in err

def test_move_text_in_engineering_units(tmp_path, capsys):
    assert main(["move", "--config", BENCH, "--stroke", "20mm", "--feed", "6000mm/min", "--tacc", "200ms",
                 "--dwell", "0.3s", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert re.search(r"^move 20 mm at 6000 mm/min on sim: j_max [0-9.]+ m/s\^3, a_max [0-9.]+ m/s\^2$", text, re.M)
    assert re.search(r"peak torque [0-9.]+ N m$", text, re.M), text
    assert re.search(r"settling \(\+-1 um\) table ([0-9.]+ ms|not settled)", text)
    assert not re.search(r"\d\.\d{5,}", text)            # no raw SI floats


def test_model_closed_loop_is_text_not_json(tmp_path, capsys):
    assert main(["model", "--config", BENCH, "--out", str(tmp_path), "--closed-loop"]) == 0
    text = capsys.readouterr().out
    assert "{" not in text and '"' not in text
    assert re.search(r"^  -3 dB bandwidth, table, with feed-forward: [0-9.]+ Hz$", text, re.M), text
    assert re.search(r"k1 = [0-9.]+ N/um", text) and re.search(r"m3 = 4\.228 kg", text)


@pytest.mark.slow
def test_compare_text_in_engineering_units(c2_record, tmp_path, capsys):
    capsys.readouterr()
    assert main(["compare", str(c2_record), "--config", BENCH, "--out", str(tmp_path)]) == 0
    lines = {ln.split()[0]: ln for ln in capsys.readouterr().out.splitlines() if " RMS " in ln}
    assert re.search(r"RMS +[0-9.]+ (um|mm)  peak +[0-9.]+ (um|mm)", lines["x_tip"]), lines["x_tip"]
    assert re.search(r"RMS +[0-9.]+ N m", lines["torque"])


# --- issue 29, item 3: a quantity option without its unit is refused, on every command ---------------

# what each command needs besides the option under test (a refusal comes before anything runs)
_BASE = {
    "move": ["--config", BENCH, "--stroke", "100mm", "--feed", "7000mm/min", "--tacc", "200ms", "--check"],
    "jog": ["--config", BENCH, "--backend", "sim", "--distance", "5mm"],
    "home": ["--config", CANOPEN],
    "sweep": ["--config", BENCH, "--stroke", "590mm", "--feed", "15m/min", "--jmax", "50,100m/s^3", "--no-plot",
              "--no-progress"],
    "frf": ["--config", BENCH],
    "tune": ["--config", BENCH, "--stroke", "100mm", "--feed", "7000mm/min"],
    "synth": ["--config", BENCH],
    "drive-sim": ["--config", CANOPEN, "--port", "0"],
    "serial-sim": ["--config", str(ROOT / "config" / "serial_ascii_example.toml")],
    "scope": ["record.csv"],
}
_ONE_OF = {"--tacc", "--amax", "--jmax"}          # move's and sweep's exclusive group


def _quantity_options():
    """(command, option, kind) of every option whose metavar names a quantity, from the parsers."""
    import argparse

    from hil.cli import build_parser
    kinds = {"LENGTH": "length", "SPEED": "speed", "TIME": "time", "ACCELERATION": "acceleration", "JERK": "jerk",
             "TIMES": "time", "JERKS": "jerk", "FORCE": "force", "AMPLITUDE": "torque", "QUANTITY": "",
             "FMIN..FMAX": "frequency", "TIME|PERCENT": "time"}
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    out = []
    for name, parser in sub.choices.items():
        for action in parser._actions:
            if action.option_strings and action.metavar in kinds:
                bare = {"FMIN..FMAX": "1..200", "TIMES": "60,80", "JERKS": "1..2000"}.get(action.metavar, "200")
                out.append((name, action.option_strings[-1], bare, any("--out" in a.option_strings
                                                                       for a in parser._actions)))
    return out


def test_every_quantity_option_is_found():
    """The walk over the parsers sees the options the issue names (and no command is left without its base)."""
    found = {(c, o) for c, o, _, _ in _quantity_options()}
    assert {("move", "--tacc"), ("move", "--stroke"), ("move", "--feed"), ("sweep", "--jmax"), ("frf", "--band"),
            ("synth", "--duration"), ("jog", "--distance"), ("home", "--offset"), ("drive-sim", "--seconds")} <= found
    assert {c for c, _ in found} <= set(_BASE)
    assert len(found) >= 30


@pytest.mark.parametrize("command,option,bare,has_out", _quantity_options())
def test_a_bare_number_is_refused_naming_the_units(command, option, bare, has_out, tmp_path, capsys, monkeypatch):
    """``--tacc 200`` ran as 200 s: every quantity option refuses a bare number in one line that
    names the units it takes (the config keeps its documented rule: a bare number is SI)."""
    monkeypatch.chdir(tmp_path)
    base = list(_BASE[command])
    if option in _ONE_OF:                                  # the option under test replaces its sibling
        for sibling in _ONE_OF & set(base):
            i = base.index(sibling)
            del base[i:i + 2]
    out = tmp_path / ("s.csv" if command == "synth" else "out")
    rc = main([command, *base, option, bare] + (["--out", str(out)] if has_out else []))
    err = capsys.readouterr().err.strip()
    first = bare.split(",")[0].split("..")[0]
    assert rc == 2 and "\n" not in err, err
    assert (f"{option} {first}: a " in err or f"{option} {first}: an " in err) and "needs its unit (" in err, err
    assert not out.exists()


@pytest.mark.parametrize("text, kind, units", [("200", "time", "s, ms, us"), ("100", "length", "mm, um, m"),
                                               ("40", "speed", "mm/min"), ("1e3", "jerk", "m/s^3")])
def test_parse_option_message(text, kind, units):
    from hil.units import UnitError, parse, parse_option
    with pytest.raises(UnitError) as exc:
        parse_option(text, kind, "--x")
    assert str(exc.value).startswith(f"--x {text}: a {kind} needs its unit (") and units in str(exc.value)
    assert parse(text, kind, "x") == float(text)           # the config's rule: bare is SI (config/SCHEMA.md)


@pytest.mark.parametrize("text, kind, si", [("200ms", "time", 0.2), ("0", "length", 0.0), ("inf", "time", math.inf),
                                            ("-0", "length", 0.0), ("3", "dimensionless", 3.0),
                                            ("7000mm/min", "speed", 7000e-3 / 60)])
def test_parse_option_keeps_what_no_unit_changes(text, kind, si):
    from hil.units import parse_option
    assert parse_option(text, kind, "--x") == pytest.approx(si)


def test_lists_and_ranges_take_the_unit_of_the_last_number(tmp_path, capsys):
    from hil.commands.sweep import parse_values
    from hil.errors import UserError
    from hil.units import UnitError
    assert parse_values("10,20,50m/s^3", "jerk", 40, "--jmax") == [10.0, 20.0, 50.0]
    assert parse_values("60..300ms", "time", 3, "--tacc") == pytest.approx([0.06, math.sqrt(0.06 * 0.3), 0.3])
    for text in ("10,20,50", "1..2000"):
        with pytest.raises((UnitError, UserError), match="needs its unit"):
            parse_values(text, "jerk", 40, "--jmax")


def test_synth_param_needs_its_unit(tmp_path, capsys):
    rc = main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "level=2",
               "--out", str(tmp_path / "s.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "--param level 2: a torque needs its unit (N*m)" in err, err


# --- issue 29, item 5: progress with its total and the time left, under --json too ---------------

def test_json_stdout_stays_pure_while_stderr_shows_progress_with_a_total(tmp_path, capsys):
    """A long diagnosis (or a 100 s hil emps) under --json: stdout is the JSON alone; stderr (not a
    terminal here: plain lines) counts the fits against their total, with the time left."""
    from hil.ident.synth import synthesize
    from hil.io.measurement import write
    ch, _ = synthesize(load(BENCH), "coulomb_friction", duration=4.0, seed=3)
    rec = write(tmp_path / "r.csv", ch)
    rc = main(["diagnose", str(rec), "--config", BENCH, "--candidates", "coulomb_friction,constant_force,viscous_friction",
               "--max-steps", "2", "--jobs", "1", "--json"])
    cap = capsys.readouterr()
    assert rc == 0 and json.loads(cap.out)["verdict"] == "coulomb_friction"
    lines = cap.err.strip().splitlines()
    assert lines, "no progress under --json"
    counts = [re.match(r"diagnose: (\d+)/(\d+) fits \((\d+) %\), [0-9:]+ s? ?elapsed, ETA [0-9:]+( s)?", ln)
              for ln in lines]
    assert all(counts), lines
    done, total = int(counts[-1].group(1)), int(counts[-1].group(2))
    assert done == total >= 3 and counts[0].group(2) == "3"      # the first diagnosis's three candidates


def test_progress_lines_are_throttled_and_count_to_the_total(capsys, monkeypatch):
    from hil.commands import progress
    monkeypatch.setattr(progress, "LINE_INTERVAL", 3600.0)
    with progress.bar("emps", None, total=4) as step:
        for name in "abcd":
            step(name)
        step.expect(2)
        step("e")
        step("f")
    err = capsys.readouterr().err.splitlines()
    # the first, and each time the count reaches the total (the rest within the interval)
    assert [ln.split(",")[0] for ln in err] == ["emps: 1/4 fits (25 %)", "emps: 4/4 fits (100 %)",
                                                "emps: 6/6 fits (100 %)"]


def test_fit_progress_counts_each_fit_once(tmp_path, capsys, monkeypatch):
    """hil fit --add A --add B: A, B and their joint refit, three steps of a total of three."""
    from hil.commands import progress
    from hil.ident.synth import synthesize
    from hil.io.measurement import write
    monkeypatch.setattr(progress, "LINE_INTERVAL", 0.0)
    ch, _ = synthesize(load(BENCH), "coulomb_friction", duration=3.0, seed=3)
    rec = write(tmp_path / "r.csv", ch)
    assert main(["fit", str(rec), "--config", BENCH, "--add", "coulomb_friction", "--add", "constant_force",
                 "--out", str(tmp_path / "f.toml"), "--json"]) == 0
    cap = capsys.readouterr()
    json.loads(cap.out)
    assert [ln.split(" (")[0] for ln in cap.err.splitlines()] == ["fit: 1/3 fits", "fit: 2/3 fits", "fit: 3/3 fits"]
