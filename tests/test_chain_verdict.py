"""The chain's answer is derived once, by a pure function of the first diagnosis and what the chain
did (issue 50, item 4: the verdict was rewritten in place at nine points of the loop), and the
chain's end is an enum whose texts are the JSON's ``final.end``."""
from types import SimpleNamespace

from conftest import CONFIG

from hil.config import load
from hil.ident.chain import End, chain_verdict

CFG = load(CONFIG / "paper_bench.toml")


def _step(n, *effects, swapped=None):
    return SimpleNamespace(step=n, effect=effects[0], effects=list(effects), swapped=swapped)


def _first(verdict, *also):
    return {"verdict": verdict, "also_missing": [{"effect": e} for e in also]}


def test_a_kept_verdict_stands():
    out = chain_verdict(_first("coulomb_friction", "constant_force"), [_step(1, "coulomb_friction", "constant_force")],
                        [], None, ["coulomb_friction", "constant_force"], [], set(), CFG)
    assert out == {"verdict": "coulomb_friction", "also_missing": [{"effect": "constant_force"}]}


def test_a_refused_verdict_gives_way_to_the_chains_first_finding():
    refused = [{"effects": ["mass_change", "constant_force"]}]
    out = chain_verdict(_first("mass_change", "constant_force", "backlash"), [_step(1, "backlash")], refused, None,
                        ["backlash"], [], {"mass_change", "constant_force"}, CFG)
    assert out == {"verdict": "backlash", "also_missing": []}


def test_the_look_alike_swap_sets_the_verdict_right():
    steps = [_step(1, "parameter:plant.m1"), _step(2, "torque_ripple"),
             _step(3, "mass_change", swapped="parameter:plant.m1")]
    out = chain_verdict(_first("parameter:plant.m1"), steps, [], None, ["mass_change", "torque_ripple"],
                        ["parameter:plant.m1"], set(), CFG)
    assert out["verdict"] == "mass_change"


def test_a_drift_within_the_tolerance_is_no_finding():
    within = {"step": 1}
    assert chain_verdict(_first("mass_change"), [], [], within, [], [], set(), CFG)["verdict"] == "none"
    out = chain_verdict(_first("mass_change"), [_step(2, "coulomb_friction")], [], within, ["coulomb_friction"], [],
                        set(), CFG)
    assert out["verdict"] == "coulomb_friction"


def test_a_verdict_that_left_the_model_gives_way_to_the_first_finding_still_in_it():
    out = chain_verdict(_first("viscous_friction", "constant_force"),
                        [_step(1, "viscous_friction", "constant_force"), _step(2, "coulomb_friction")], [], None,
                        ["constant_force", "coulomb_friction"], ["viscous_friction"], set(), CFG)
    assert out == {"verdict": "constant_force", "also_missing": []}


def test_the_ends_read_as_the_json_always_did():
    assert End.MAX_STEPS.text(4) == "max steps (4)"
    assert End.WITHIN_TOLERANCE.text(4) == "noise floor reached within the config's tolerance"
    assert {e for e in End if e.at_floor} == {End.NOISE_FLOOR, End.WITHIN_TOLERANCE}
    assert all(e.text(3).startswith("noise floor") == e.at_floor for e in End)
