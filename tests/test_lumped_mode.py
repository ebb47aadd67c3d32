"""A structural mode the model held rigidly (``compliant_mode``'s ``origin`` "lumped"): the mode's
mass is split off the body it hangs on, so the moving mass is kept; against the closed form of the
free 2-mass system."""
import math

import pytest
from conftest import CONFIG

from hil import config
from hil.plant_config import candidate, plant_from_config

CFG = config.load(CONFIG / "emps.toml")      # a rigid axis: one mass


def _split(origin, mass, f):
    plant = plant_from_config(CFG)
    eff = candidate("compliant_mode")
    out = eff.apply(plant, {"mass": mass, "frequency": f, "damping_ratio": 0.02,
                            "origin": eff.param("origin").number(origin)})
    return plant.chain.m[0], out


@pytest.mark.parametrize("origin,taken", [("new", 0.0), ("lumped", 1.0)])
def test_the_mode_splits_off_its_mass_and_rings_as_the_free_two_mass_system(origin, taken):
    m, f = 7.0, 23.0
    big, plant = _split(origin, m, f)
    host = big - taken * m
    assert plant.chain.m == pytest.approx((host, m), rel=1e-15)
    assert sum(plant.chain.m) == pytest.approx(big + (1 - taken) * m, rel=1e-15)
    assert plant.tip == 1
    # k = m (2 pi f)^2 on two free masses: w^2 = k (1/host + 1/m), f sqrt((host + m) / host)
    w = plant.chain.modes()[0]
    assert w[1] / (2 * math.pi) == pytest.approx(f * math.sqrt((host + m) / host), rel=1e-12)


def test_a_split_that_would_leave_no_mass_is_refused_naming_the_effect():
    big = plant_from_config(CFG).chain.m[0]
    with pytest.raises(ValueError, match="compliant_mode: .* leaves"):
        _split("lumped", big * 1.01, 10.0)


def test_a_mode_is_split_off_the_table_only():
    from sim_plant.effects.structure import CompliantMode
    assert CompliantMode.may_split(plant_from_config(CFG))          # a rigid axis: its one mass
    assert CompliantMode.may_split(plant_from_config(config.load(CONFIG / "paper_bench_2dof.toml")))
    assert not CompliantMode.may_split(plant_from_config(config.load(CONFIG / "paper_bench.toml")))


def test_a_config_written_before_the_key_adds_the_mass_as_it_did(tmp_path):
    from hil.plant_config import apply_effects, effect_values
    p = tmp_path / "old.toml"
    p.write_text((CONFIG / "emps.toml").read_text(encoding="utf-8")
                 + '\n[effects.compliant_mode]\nmass = "7 kg"\nfrequency = "23 Hz"\ndamping_ratio = 0.02\n', encoding="utf-8")
    cfg = config.load(p)
    assert effect_values("compliant_mode", cfg)["origin"] == 0.0
    plant = apply_effects(plant_from_config(CFG), cfg)
    assert plant.chain.m == pytest.approx((CFG["plant.m1"], 7.0), rel=1e-15)


def test_a_config_that_says_lumped_keeps_the_moving_mass(tmp_path):
    from hil.plant_config import apply_effects
    p = tmp_path / "lumped.toml"
    p.write_text((CONFIG / "emps.toml").read_text(encoding="utf-8")
                 + '\n[effects.compliant_mode]\nmass = "7 kg"\nfrequency = "23 Hz"\ndamping_ratio = 0.02\n'
                 'origin = "lumped"\n', encoding="utf-8")
    plant = apply_effects(plant_from_config(CFG), config.load(p))
    assert sum(plant.chain.m) == pytest.approx(CFG["plant.m1"], rel=1e-15)
