"""An effect the axis cannot have is refused with its reason, never a candidate (issue 50, item 3):
the HSM150 motor alone turns without end (``plant.endless``), and a cable carrier fitted to it was
starred significant (a force changing over 5866 rad of a free-spinning rotor)."""
import dataclasses
import json

import pytest
from conftest import CONFIG

from hil.cli import main
from hil.config import load
from hil.errors import ConfigError
from hil.ident.diagnosis import by_reason, candidate_names, not_tried
from hil.plant_config import plant_from_config
from sim_plant.effects import CATALOGUE

HSM = str(CONFIG / "hsm150.toml")
ALONG_TRAVEL = {"cable_carrier", "screw_elongation", "stiffness_along_travel", "stiffness_along_travel_fixed_fixed"}


def test_only_an_endless_axis_loses_the_effects_along_its_travel():
    bench = plant_from_config(load(CONFIG / "paper_bench.toml"))
    assert not_tried(bench) == {}
    endless = not_tried(dataclasses.replace(bench, endless=True))
    assert set(endless) == ALONG_TRAVEL
    assert all("plant.endless" in why for why in endless.values())
    # applicable is the hook's answer, and the default candidates are the applicable ones
    for name, eff in CATALOGUE.items():
        assert eff.applicable(bench) and eff.applicable(dataclasses.replace(bench, endless=True)) == \
            (name not in ALONG_TRAVEL)


def test_the_motor_alone_says_why_each_effect_is_not_tried():
    cfg = load(HSM)
    plant = plant_from_config(cfg)
    assert plant.endless and plant.n == 1
    why = not_tried(plant)
    names = candidate_names(cfg, plant, open_loop=True)
    assert not set(why) & set(names) and set(why) | {n for n in names if n in CATALOGUE} == set(CATALOGUE)
    groups = by_reason(why)
    assert set(groups[next(w for w in groups if "plant.endless" in w)]) == ALONG_TRAVEL
    assert {"backlash", "pitch_error", "load_dependent_friction"} <= set(
        groups[next(w for w in groups if "transmission link" in w)])


def test_a_config_that_puts_a_cable_carrier_on_an_endless_axis_is_refused():
    cfg = load(HSM, overrides={"effects.cable_carrier.force": 1.0})
    with pytest.raises(ConfigError, match=r"hsm150\.toml: effects\.cable_carrier: cannot act on this axis: "
                                          r"the axis turns without end \(plant\.endless\)"):
        plant_from_config(cfg)


@pytest.mark.parametrize("argv", [["diagnose", "--candidates", "coulomb_friction,cable_carrier"],
                                  ["fit", "--add", "cable_carrier", "--out", "never.toml"],
                                  ["synth", "--effect", "cable_carrier", "--out", "never.csv"]])
def test_asking_for_it_by_name_is_one_line(hsm_record, argv, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    record = [] if argv[0] == "synth" else [hsm_record]
    assert main([argv[0], *record, "--config", HSM, "--open-loop", *argv[1:]]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cable_carrier: cannot act on this axis: the axis turns without end" in err[0], err
    assert not (tmp_path / "never.toml").exists() and not (tmp_path / "never.csv").exists()


@pytest.mark.slow         # a full diagnosis: 11 s at load 2
def test_diagnose_json_lists_what_it_did_not_try(hsm_record, capsys):
    assert main(["diagnose", hsm_record, "--config", HSM, "--open-loop", "--no-chain", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert set(d["not_tried"]) >= ALONG_TRAVEL | {"backlash"}
    assert not {c["effect"] for c in d["candidates"]} & set(d["not_tried"])
    assert main(["diagnose", hsm_record, "--config", HSM, "--open-loop", "--no-chain",
                 "--candidates", "coulomb_friction", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["not_tried"] == {}
