"""Units, config round trip, overrides, the schema document."""
import math

import pytest
from conftest import CONFIG

from hil import config
from hil.units import UnitError, parse, parse_list


@pytest.mark.parametrize("text, kind, si", [
    ("100mm", "length", 0.1), ("7000mm/min", "speed", 7 / 60), ("200ms", "time", 0.2),
    ("8.5e-4 kg*m^2", "inertia", 8.5e-4), ("0.0076 N*m*s/rad", "rot_damping", 0.0076), ("2.2 Nm", "torque", 2.2),
    ("2.2 N m", "torque", 2.2), ("10 um", "length", 1e-5), ("62.5 us", "time", 6.25e-5), ("50 1/s", "frequency", 50),
    ("5000 m/s^3", "jerk", 5000), ("243.45 V/(m/s)", "volt_per_speed", 243.45), ("30 m/min", "speed", 0.5),
    ("1", "jerk", 1.0), (3, "mass", 3.0)])
def test_units_to_si(text, kind, si):
    assert parse(text, kind) == pytest.approx(si, rel=1e-12)


def test_unit_errors_name_the_value_and_the_kind():
    with pytest.raises(UnitError, match=r"plant.pitch: '10 kg' is not a length"):
        parse("10 kg", "length", "plant.pitch")
    with pytest.raises(UnitError, match="cannot read 'ten mm' as a length"):
        parse("ten mm", "length")
    assert parse_list("60,80,90ms", "time") == pytest.approx([0.06, 0.08, 0.09])


def test_round_trip_through_toml(bench):
    again = config.loads(bench.to_toml(), "again")
    assert again.keys() == bench.keys()
    for k, v in bench.values.items():
        w = again.values[k]
        if isinstance(v, float):
            assert math.isclose(w, v, rel_tol=1e-12) or (math.isinf(v) and math.isinf(w)), k
        else:
            assert w == v, k


def test_overrides_and_dotted_names():
    cfg = config.load(CONFIG / "paper_bench.toml", {"plant.c2": "33 N*s/m", "control.kv": 40})
    assert cfg["plant.c2"] == 33.0 and cfg["control.kv"] == 40.0
    assert config.parse_assignment("plant.c2=33") == ("plant.c2", 33)
    assert config.parse_assignment("plant.c2=33 N*s/m") == ("plant.c2", "33 N*s/m")
    with pytest.raises(config.ConfigError, match=r"unknown key 'plant.c9' \(a chain of 3 masses has c1..c2\)"):
        config.load(CONFIG / "paper_bench.toml", {"plant.c9": 1})


def test_schema_document_is_in_step():
    text = (CONFIG / "SCHEMA.md").read_text(encoding="utf-8")
    assert text.endswith(config.schema_markdown())


@pytest.mark.parametrize("name", ["paper_bench", "paper_bench_2dof", "paper_bench_friction"])
def test_shipped_configs_load(name):
    cfg = config.load(CONFIG / f"{name}.toml")
    assert cfg["control.position_period"] == 0.004 and cfg["control.velocity_period"] == 6.25e-5
    assert cfg["limits.jerk"] == 5000 and cfg["nc.g0"] == 0.5
