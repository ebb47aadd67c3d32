"""Effects real benches show (issue 25, item 4): the controller's own settings as default
candidates of the diagnosis ("someone changed them on the drive"), with bounds from the sampled
loops' physics, found on records made with another setting at two strengths and on the maxon
LinA actuator's record (../shared/data, skipped where absent)."""
import math
from pathlib import Path

import pytest

from hil.closed_loop import loop_stability
from hil.config import load
from hil.ident import Replay, candidate_names, diagnose, synthesize
from hil.io.importers import parse_mapping, read_any
from hil.io.measurement import Measurement
from hil.plant_config import candidate, control_bounds, plant_from_config

ROOT = Path(__file__).resolve().parents[1]
CFG = load(str(ROOT / "config" / "paper_bench.toml"))
LINA = load(str(ROOT / "config" / "lina.toml"))
DATA = ROOT.parent / "shared" / "data"
LINA_RECORD = DATA / "maxon-linear-actuator-lina" / "pp-square-wave-10mm-0.5Hz.txt"
LINA_MAP = "data[:,0]=t[ms],data[:,2]=x_cmd[mm],data[:,3]=x_motor[mm]"   # the docs' map: column 2 the demand
CONTROL = ["parameter:control.kv", "parameter:control.ffv", "parameter:control.kp", "parameter:control.ti"]


# --- the controller's settings among the default candidates ----------------------------------------

def test_controller_settings_are_default_candidates_of_a_closed_loop_record():
    names = candidate_names(CFG, plant_from_config(CFG))
    assert all(n in names for n in CONTROL)
    # an open-loop record replays the recorded actuator: the loops never run, no controller setting
    assert not any(n.startswith("parameter:control.") for n in candidate_names(CFG, plant_from_config(CFG),
                                                                                open_loop=True))


def test_a_setting_the_config_lacks_is_no_candidate_and_a_filter_is_one():
    # Ti = inf is a P loop (nothing to re-identify); the current loop's lag where the config gives it
    cfg = CFG.with_values({"control.ti": math.inf, "actuator.current_loop_time_constant": 0.5e-3})
    names = candidate_names(cfg, plant_from_config(cfg))
    assert "parameter:control.ti" not in names
    assert "parameter:actuator.current_loop_time_constant" in names
    assert "parameter:actuator.current_loop_time_constant" not in candidate_names(CFG, plant_from_config(CFG))
    # a feed-forward of 0 is a setting too (the maxon workbook's)
    assert "parameter:control.ffv" in candidate_names(LINA, plant_from_config(LINA))


def test_bounds_of_the_gains_are_the_sampled_loops_stability_limits():
    tp, tv = CFG["control.position_period"], CFG["control.velocity_period"]
    assert control_bounds("control.kv", CFG) == (0.0, pytest.approx(2.0 / tp))
    assert control_bounds("control.ffv", CFG) == (0.0, 1.2)
    assert control_bounds("control.ti", CFG) == (tv, 3600.0)
    r = 2 * math.pi / CFG["plant.pitch"]
    mass = CFG["plant.m1"] + CFG["plant.m2"] + CFG["plant.m3"]
    assert control_bounds("control.kp", CFG)[1] == pytest.approx(2 * mass / (r * r * tv))
    # each an upper limit of the real loop (its lags only lower it): the model's lifted loop, a
    # second method, is unstable at the bound and stable at the config's value
    for key in ("control.kv", "control.kp"):
        hi = control_bounds(key, CFG)[1]
        assert loop_stability(CFG)[0]
        assert not loop_stability(CFG.with_values({key: hi}))[0], key
    # the fit's parameter carries them
    p = candidate("parameter:control.kv", CFG).params[0]
    assert (p.lower, p.upper, p.guess) == (0.0, pytest.approx(2.0 / tp), CFG["control.kv"])
    assert candidate("parameter:control.ffv", LINA).params[0].guess == 1.0    # from 0: the start is 1


# --- a feed-forward changed on the drive, at two strengths -------------------------------------------

@pytest.mark.parametrize("ffv", [0.7, 0.9])
def test_diagnose_names_a_changed_feed_forward(ffv):
    """Records of the paper bench (ffv 1 in the config) made with another feed-forward: among the
    controller's default candidates, and a mass and a delay that also make the table lag, the
    diagnosis names the feed-forward with its value."""
    ch, truth = synthesize(CFG, "parameter:control.ffv", {"value": ffv}, duration=4.0, seed=5)
    rp = Replay(Measurement(ch, source=f"synth ffv {ffv}"), CFG)
    names = [n for n in candidate_names(CFG, rp.plant) if n.startswith("parameter:control.")]
    assert names, "no controller setting among the default candidates"
    d = diagnose(rp, names + ["mass_change", "feedback_delay"], jobs=1, max_nfev=20)
    assert d["verdict"] == "parameter:control.ffv"
    best = d["candidates"][0]
    assert best.params["value"] == pytest.approx(ffv, rel=0.03)
    assert best.error_after < 0.2 * best.error_before


# --- the maxon LinA actuator's record -------------------------------------------------------------

@pytest.mark.skipif(not LINA_RECORD.exists(), reason=f"{LINA_RECORD} absent (../shared/data)")
def test_linear_actuator_diagnosis_names_its_feed_forward():
    """The issue's goal: on the LinA record, whose start model has the workbook's feed-forward 0,
    diagnose names the feed-forward with its fitted value and the tracking error falls by 80 %."""
    meas = read_any(LINA_RECORD, parse_mapping(LINA_MAP))
    rp = Replay(meas, LINA)
    d = diagnose(rp, jobs=1)
    assert d["verdict"] == "parameter:control.ffv"
    best = next(c for c in d["candidates"] if c.effect == "parameter:control.ffv")
    assert best.channel == "x_motor"
    assert 0.9 < best.params["value"] < 1.1
    assert best.error_after <= 0.2 * best.error_before
    assert "control.ffv 0 -> 1" in best.evidence
