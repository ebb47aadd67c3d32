"""A structural mode the model held rigidly (``compliant_mode``'s ``lumped``): the mode's mass is
split off the body it hangs on, so the moving mass is kept; against the closed form of the free
2-mass system."""
import math

import pytest
from conftest import CONFIG

from hil import config
from hil.plant_config import candidate, plant_from_config

CFG = config.load(CONFIG / "emps.toml")      # a rigid axis: one mass


def _split(lumped, mass, f):
    plant = plant_from_config(CFG)
    out = candidate("compliant_mode").apply(plant, {"mass": mass, "frequency": f, "damping_ratio": 0.02,
                                                     "lumped": lumped})
    return plant.chain.m[0], out


@pytest.mark.parametrize("lumped", [0.0, 0.4, 1.0])
def test_the_mode_splits_off_its_share_and_rings_as_the_free_two_mass_system(lumped):
    m, f = 7.0, 23.0
    big, plant = _split(lumped, m, f)
    host = big - lumped * m
    assert plant.chain.m == pytest.approx((host, m), rel=1e-15)
    assert sum(plant.chain.m) == pytest.approx(big + (1 - lumped) * m, rel=1e-15)
    assert plant.tip == 1
    # k = m (2 pi f)^2 on two free masses: w^2 = k (1/host + 1/m), f sqrt((host + m) / host)
    w = plant.chain.modes()[0]
    assert w[1] / (2 * math.pi) == pytest.approx(f * math.sqrt((host + m) / host), rel=1e-12)


def test_a_split_that_would_leave_no_mass_is_refused_naming_the_effect():
    big = plant_from_config(CFG).chain.m[0]
    with pytest.raises(ValueError, match="compliant_mode: .* leaves"):
        _split(1.0, big * 1.01, 10.0)


def test_a_config_written_before_the_key_adds_the_mass_as_it_did(tmp_path):
    from hil.plant_config import apply_effects, effect_values
    p = tmp_path / "old.toml"
    p.write_text((CONFIG / "emps.toml").read_text(encoding="utf-8")
                 + '\n[effects.compliant_mode]\nmass = "7 kg"\nfrequency = "23 Hz"\ndamping_ratio = 0.02\n', encoding="utf-8")
    cfg = config.load(p)
    assert effect_values("compliant_mode", cfg)["lumped"] == 0.0
    plant = apply_effects(plant_from_config(CFG), cfg)
    assert plant.chain.m == pytest.approx((CFG["plant.m1"], 7.0), rel=1e-15)


def test_a_mode_wholly_lumped_is_a_finding_not_an_effect_at_its_bound():
    from hil.ident.fit import at_range_edge
    mode = {"mass": 4.2, "frequency": 14.9, "damping_ratio": 0.015}
    assert at_range_edge(candidate("compliant_mode"), dict(mode, lumped=1.0)) == ""
    assert at_range_edge(candidate("compliant_mode"), dict(mode, lumped=0.0)) == ""
    assert "frequency ended at the bound" in at_range_edge(candidate("compliant_mode"),
                                                           dict(mode, lumped=1.0, frequency=1e3))
