"""Bad configuration files give one clear error naming the file and the key (exact texts of
hil/config.py), and ``hil model`` turns them into one line on stderr, exit status 2."""
from pathlib import Path

import pytest

from hil.cli import main
from hil.config import ConfigError, load

BASE = Path("config/paper_bench.toml").read_text()
M2 = 'm2 = "392.97 kg"'


def write(tmp_path, text):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


CASES = {
    "unknown key": (BASE.replace("[plant]\n", "[plant]\nm9x = 1\n"),
                    "unknown key 'plant.m9x' (known keys in [plant]: plant.cN, plant.endless, plant.kN, plant.mN, plant.pitch, "
                    "plant.table_mass, plant.tip_mass, plant.tolerance)"),
    "unknown section": (BASE + "\n[foo]\nbar = 1\n", "unknown key 'foo.bar' (known sections: actuator, backend, canopen, control, effects, fleet, friction, "
                       "limits, measurement, meta, nc, noise, plant, runtime, sensors, serial, supervisor"),
    "missing required key": (BASE.replace('kv = "50 1/s"\n', ""),
                             "missing required key 'control.kv' (position-loop P gain Kv (1/s); a loop gain in 1/s)"),
    "missing chain key": (BASE.replace('k2 = "3.7060e4 N/m"   # thin plates\n', ""),
                          "missing required key 'plant.k2' (a chain of 3 masses needs k1..k2; stiffness)"),
    "extra chain key": (BASE.replace("[plant]\n", '[plant]\nk3 = "1 N/m"\n'),
                        "unknown key 'plant.k3' (a chain of 3 masses has k1..k2)"),
    "wrong type (string)": (BASE.replace('position_feedback = "table"', "position_feedback = 3"),
                            "control.position_feedback: expected a string, got 3"),
    "wrong type (boolean)": (BASE.replace(M2, "m2 = true"), "plant.m2: expected a mass (kg), got a boolean True"),
    "not a choice": (BASE.replace('position_feedback = "table"', 'position_feedback = "tip"'),
                     "control.position_feedback: expected one of table, motor, got 'tip'"),
    "negative mass": (BASE.replace(M2, "m2 = -1"), "plant.m2: expected a positive mass (kg), got -1"),
    "zero stiffness": (BASE.replace('k1 = "5.362e7 N/m"', "k1 = 0"),
                       "plant.k1: expected a positive stiffness (N/m), got 0"),
    "negative damping": (BASE.replace('c2 = "11.80 N*s/m"', "c2 = -1"),
                         "plant.c2: expected a damping >= 0 (N*s/m), got -1"),
    "NaN": (BASE.replace(M2, "m2 = nan"), "plant.m2: NaN is not a mass"),
    "NaN with unit": (BASE.replace(M2, 'm2 = "nan kg"'), "plant.m2: NaN is not a mass"),
    "wrong dimension": (BASE.replace(M2, 'm2 = "10 mm"'),
                        "plant.m2: '10 mm' is not a mass: its unit has dimension [length], expected [mass] (e.g. kg)"),
    "unknown unit": (BASE.replace(M2, 'm2 = "392 kgg"'),
                     "plant.m2: cannot read '392 kgg' as a mass (UndefinedUnitError: 'kgg' is not defined in the "
                     "unit registry)"),
    "rotary torque limit as force": (BASE.replace('output_limit = "30 N*m"', 'output_limit = "30 N"'),
                                     "control.output_limit: '30 N' is not a torque"),
    "invalid TOML": (BASE + "\n[plant\n", "not valid TOML: "),
}


@pytest.mark.parametrize("name", CASES)
def test_load_error_text(tmp_path, name):
    text, message = CASES[name]
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as exc:
        load(path)
    assert str(exc.value).startswith(f"{path}: ")
    assert message in str(exc.value)


@pytest.mark.parametrize("name", ["unknown key", "wrong dimension", "invalid TOML", "NaN"])
def test_cli_one_line(tmp_path, capsys, name):
    text, message = CASES[name]
    path = write(tmp_path, text)
    assert main(["model", "--config", str(path), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"hil model: error: {path}: ") and message in err
    assert err.count("\n") == 1


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="no such configuration file"):
        load(tmp_path / "none.toml")


def test_infinite_mass_rejected(tmp_path):
    with pytest.raises(ConfigError, match="plant.m2: expected a finite mass"):
        load(write(tmp_path, BASE.replace(M2, "m2 = inf")))
