"""Candidates a record cannot tell apart are one finding with its alternatives (issue 50, item 3):
hil.ident.diagnosis.look_alikes against the BIC in closed form, N ln(s_a^2 / s_b^2), on white
residuals whose RMS differ by a known factor."""
import numpy as np
from conftest import CONFIG

from hil.config import load
from hil.ident.diagnosis import look_alikes
from hil.ident.fit import Candidate
from hil.plant_config import plant_from_config

N = 4000
NOISE = np.random.default_rng(7).standard_normal(N)


def _cand(effect, factor, significant=True, n_params=1):
    """A fit whose residual is the same white noise times ``factor``."""
    return Candidate(effect, {f"p{i}": 1.0 for i in range(n_params)}, "x", 1.0, factor, 100.0 - factor, "why",
                     significant=significant, res={"x": factor * NOISE})


def test_a_residual_within_the_bic_margin_is_an_alternative():
    lead = _cand("parameter:plant.m1", 1.0)
    # N ln(1.0005^2) = 4.0 (< 6): no telling apart; N ln(1.01^2) = 79.6: the record tells
    close, far = _cand("compliant_mode", 1.0005), _cand("torque_constant", 1.01)
    alts = look_alikes(lead, [lead, close, far], ["x"])
    assert [a["effect"] for a in alts] == ["compliant_mode"]
    a = alts[0]
    assert a["of"] == "parameter:plant.m1"
    assert abs(a["verdict_against"] - N * np.log(1.0005 ** 2)) < 0.5       # effective samples of white noise ~ N
    assert a["against_verdict"] < 0


def test_the_richer_look_alike_pays_for_its_extra_parameters():
    lead = _cand("parameter:plant.m1", 1.0)
    # three more parameters fit 0.2 % better: N ln(1/0.998^2) = 16.0 beats the BIC margin, less
    # 3 ln N = 24.9 it does not (nor the one fewer parameter's fit the richer one: N ln(0.998^2) < 0)
    rich = _cand("compliant_mode", 0.998, n_params=4)
    assert N * np.log(1 / 0.998 ** 2) > 6
    assert [a["effect"] for a in look_alikes(lead, [lead, rich], ["x"])] == ["compliant_mode"]


def test_the_same_physics_by_another_name_is_no_alternative():
    plant = plant_from_config(load(CONFIG / "paper_bench.toml"))
    lead = _cand("mass_change", 1.0)
    same_key = _cand("parameter:plant.m2", 1.0)        # mass_change is the table mass (m2) by another name
    other_place = _cand("parameter:plant.m1", 1.0)
    assert [a["effect"] for a in look_alikes(lead, [lead, same_key, other_place], ["x"], plant=plant)] == \
        ["parameter:plant.m1"]
    coulomb, stribeck = _cand("coulomb_friction", 1.0), _cand("stribeck_friction", 1.0, n_params=2)
    assert look_alikes(stribeck, [stribeck, coulomb], ["x"], plant=plant) == []    # Coulomb nests in Stribeck
    assert look_alikes(lead, [lead, _cand("torque_constant", 1.0, significant=False)], ["x"]) == []
