"""Effects catalogue: every effect configures, simulates, and changes the response where it should."""
import numpy as np
import pytest

from hil.config import load
from hil.plant_config import candidate, configure, record_effects
from hil.simulate import simulate_config
from sim_plant.effects import CATALOGUE

CFG = load("config/paper_bench.toml")
X = np.concatenate([np.zeros(50), np.linspace(0, 0.02, 250), np.full(100, 0.02), np.linspace(0.02, 0, 250)])


def test_catalogue_names():
    want = {"coulomb_friction", "viscous_friction", "stribeck_friction", "asymmetric_friction", "constant_force",
            "backlash", "actuator_delay", "pitch_error", "torque_ripple", "compliant_mode", "mass_change",
            "feedback_delay", "channel_skew", "tip_skew", "stiffness_along_travel"}
    assert want <= set(CATALOGUE)
    # time_delay is the old name of actuator_delay: it still resolves, but is not listed twice
    assert "time_delay" not in CATALOGUE and candidate("time_delay") is CATALOGUE["actuator_delay"]


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_effect_changes_response(name):
    from hil.ident.synth import HIDDEN_DEFAULTS
    base = simulate_config(CFG, X).channels()
    cfg = configure(candidate(name), CFG, HIDDEN_DEFAULTS[name])
    r = simulate_config(cfg, X).channels()
    for eff, vals in record_effects(cfg):       # an artefact of the recording acts on the channels recorded
        r = eff.apply_record(r["t"], r, vals)
    diff = max(np.max(np.abs(r[c] - base[c])) for c in ("x_motor", "x_table", "x_tip"))
    assert diff > 1e-7 or np.max(np.abs(r["torque"] - base["torque"])) > 1e-3


def test_constant_force_static_deflection():
    # a constant force F on a P-I loop at rest: the integrator takes it, the torque settles at F p / 2 pi
    F = 400.0
    x = np.zeros(2000)
    r = simulate_config(configure(candidate("constant_force"), CFG, {"force": F}), x)
    assert r.u[-1] == pytest.approx(-F * 0.01 / (2 * np.pi), rel=1e-3)


@pytest.mark.parametrize("F", [250.0, -90.0])
def test_constant_force_on_the_table_leans_it_on_the_screw(F):
    # the same torque at rest, but the force now passes through the screw: the table sits F / k1
    # ahead of the motor (the tip, with no force of its own, follows the table); on the motor, no offset
    x = np.zeros(4000)
    on_table = simulate_config(configure(candidate("constant_force"), CFG, {"force": F, "place": 1.0}), x)
    assert on_table.u[-1] == pytest.approx(-F * 0.01 / (2 * np.pi), rel=1e-3)
    ch = on_table.channels()
    assert ch["x_table"][-1] - ch["x_motor"][-1] == pytest.approx(F / CFG["plant.k1"], rel=1e-3)
    assert ch["x_tip"][-1] - ch["x_table"][-1] == pytest.approx(0.0, abs=1e-3 * abs(F) / CFG["plant.k1"])
    ch = simulate_config(configure(candidate("constant_force"), CFG, {"force": F}), x).channels()
    assert abs(ch["x_table"][-1] - ch["x_motor"][-1]) < 1e-3 * abs(F) / CFG["plant.k1"]


def test_constant_force_place_is_written_by_name():
    cfg = configure(candidate("constant_force"), CFG, {"force": 10.0, "place": 1.0})
    assert cfg["effects.constant_force.place"] == "table"


def test_parameter_effect_sets_key():
    eff = candidate("parameter:c2", CFG)
    assert eff.name == "parameter:plant.c2"
    assert configure(eff, CFG, {"value": 40.0})["plant.c2"] == 40.0


ASYM = {"effects.asymmetric_friction.level_pos": 2.0, "effects.asymmetric_friction.level_neg": 1.0,
        "effects.asymmetric_friction.viscous_pos": 0.01, "effects.asymmetric_friction.viscous_neg": 0.02}


def test_an_effect_set_anew_leaves_the_written_config_and_nothing_moves():
    # asymmetric friction after Coulomb and viscous friction sets both anew: they leave, bit for bit
    # the same simulation (issue 25: the chain's config kept coulomb_friction.level beside it)
    from hil.plant_config import without_replaced
    cfg = CFG.with_values({"effects.coulomb_friction.level": 1.5, "effects.viscous_friction.coefficient": 0.01, **ASYM})
    clean = without_replaced(cfg)
    left = {k.split(".")[1] for k in clean.keys() if k.startswith("effects.") and clean.values[k] is not None}
    assert left == {"asymmetric_friction"}
    # and the motor's own friction and viscous damping, which it sets anew wherever it stands
    assert CFG["friction.viscous"] > 0 and clean["friction.viscous"] == 0.0
    a, b = simulate_config(cfg, X).channels(), simulate_config(clean, X).channels()
    assert all(np.array_equal(a[k], b[k]) for k in a)


def test_stribeck_friction_leaves_the_plants_dry_friction_and_keeps_its_damping():
    from hil.plant_config import without_replaced
    cfg = CFG.with_values({"friction.coulomb": 1.1, "effects.stribeck_friction.level": 1.3,
                           "effects.stribeck_friction.static": 1.8, "effects.stribeck_friction.velocity": 0.01})
    clean = without_replaced(cfg)
    assert clean["friction.coulomb"] == 0.0 and clean["friction.viscous"] == CFG["friction.viscous"]
    a, b = simulate_config(cfg, X).channels(), simulate_config(clean, X).channels()
    assert all(np.array_equal(a[k], b[k]) for k in a)


def test_an_effect_after_its_replacement_stays():
    # Coulomb friction after the asymmetric one sets the dry friction again: it counts, and stays
    from hil.plant_config import without_replaced
    cfg = CFG.with_values(ASYM).with_values({"effects.coulomb_friction.level": 1.5})
    assert without_replaced(cfg)["effects.coulomb_friction.level"] == 1.5
