"""Effects catalogue: every effect configures, simulates, and changes the response where it should."""
import numpy as np
import pytest

from hil.config import load
from hil.plant_config import candidate, configure, record_effects
from hil.sim_plant.effects import CATALOGUE
from hil.simulate import simulate_config

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


def test_parameter_effect_sets_key():
    eff = candidate("parameter:c2", CFG)
    assert eff.name == "parameter:plant.c2"
    assert configure(eff, CFG, {"value": 40.0})["plant.c2"] == 40.0
