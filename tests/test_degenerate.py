"""A fit that names another effect (``Effect.degenerate``, issue 24): a mode stiff to its frequency
bound or damped past ringing is a rigid mass or a damper, a 2-mass link at its range's bound is no
resonance, a controller setting moved by a fraction of a percent is another effect's shadow. Such a
fit is never significant, says why, and ranks after every fit that is its own."""
import json

import numpy as np
import pytest

from hil.config import load
from hil.ident import Replay, synthesize
from hil.ident.diagnosis import _rank_single
from hil.ident.fit import Candidate, evaluate
from hil.io.measurement import Measurement
from hil.plant_config import SETTING_TOLERANCE, candidate

CFG = load("config/paper_bench.toml")


@pytest.mark.parametrize("values,bound", [({"mass": 0.08, "frequency": 1000.0, "damping_ratio": 1.0}, True),
                                          ({"mass": 0.08, "frequency": 998.0, "damping_ratio": 0.02}, True),
                                          ({"mass": 0.5, "frequency": 60.0, "damping_ratio": 0.995}, True),
                                          ({"mass": 0.5, "frequency": 60.0, "damping_ratio": 0.02}, False),
                                          # a lightly damped mode is a mode: the lower bound is no other effect
                                          ({"mass": 0.5, "frequency": 60.0, "damping_ratio": 1e-4}, False)])
def test_a_mode_at_its_bound_is_no_mode(values, bound):
    assert bool(candidate("compliant_mode").degenerate(values)) is bound


def test_a_mode_above_the_records_nyquist_frequency_is_a_mass():
    # 4 ms samples show at most 125 Hz: a 165 Hz, undamped 0.08 kg "mode" (a clean record with the tip
    # drifted) is the tip's mass; the same mode on a 1 ms record is a mode
    v = {"mass": 0.082, "frequency": 164.8, "damping_ratio": 1e-4}
    assert "Nyquist" in candidate("compliant_mode").degenerate(v, None, 4e-3)
    assert not candidate("compliant_mode").degenerate(v, None, 1e-3)


@pytest.mark.parametrize("values,bound", [({"load_share": 0.02, "frequency": 93.0, "damping_ratio": 1.0}, True),
                                          ({"load_share": 0.5, "frequency": 1000.0, "damping_ratio": 0.1}, True),
                                          ({"load_share": 0.86, "frequency": 590.0, "damping_ratio": 0.0995}, False)])
def test_a_link_at_its_bound_is_no_resonance(values, bound):
    assert bool(candidate("flexible_transmission").degenerate(values)) is bound


@pytest.mark.parametrize("key", ["control.kv", "control.ffv", "control.ti"])
def test_a_setting_moved_by_a_sliver_is_not_a_finding(key):
    eff = candidate(f"parameter:{key}", CFG)
    v0 = CFG[key]
    assert eff.degenerate({"value": v0 * (1 + 0.3 * SETTING_TOLERANCE)}, CFG)
    assert eff.degenerate({"value": v0 * (1 - 0.9 * SETTING_TOLERANCE)}, CFG)
    # LinA's feed-forward, 1 -> 0.974 (issue 25), is an entry: a finding
    assert not eff.degenerate({"value": v0 * (1 - 2.6 * SETTING_TOLERANCE)}, CFG)
    # a plant parameter drifts by any amount: never judged so
    assert not candidate("parameter:plant.m2", CFG).degenerate({"value": CFG["plant.m2"] * 1.001}, CFG)


def _cand(name, score, degenerate=""):
    return Candidate(name, {}, "x_table", 1.0, 0.5, score, "", 0.5, not degenerate, degenerate=degenerate)


def test_a_degenerate_fit_ranks_after_the_fits_that_are_their_own():
    ranked = _rank_single([_cand("compliant_mode", 120.0, "a mode at its bound"), _cand("parameter:plant.m3", 90.0),
                           _cand("backlash", 10.0)])
    assert [c.effect for c in ranked] == ["parameter:plant.m3", "backlash", "compliant_mode"]


def test_evaluate_tells_a_sliver_of_kv_from_a_different_entry():
    # a record of the model with the tip 2 % heavier: kv takes a sliver of it (-0.02 %), not a finding;
    # a drive whose kv was entered 10 % lower: the fit finds it, a finding
    ch, _ = synthesize(CFG.with_values({"plant.m3": CFG["plant.m3"] * 1.02}), None, {}, duration=3.0, seed=2)
    c = evaluate(Replay(Measurement(ch, source="synth"), CFG), "parameter:control.kv")
    assert abs(c.params["value"] / CFG["control.kv"] - 1) < SETTING_TOLERANCE
    assert c.degenerate and not c.significant and c.degenerate in c.evidence
    assert json.loads(json.dumps(c.as_json()))["degenerate"] == c.degenerate
    kv = 0.9 * CFG["control.kv"]
    ch, _ = synthesize(CFG.with_values({"control.kv": kv}), None, {}, duration=3.0, seed=2)
    c = evaluate(Replay(Measurement(ch, source="synth"), CFG), "parameter:control.kv")
    assert c.params["value"] == pytest.approx(kv, rel=0.01)
    assert not c.degenerate and c.significant and np.isfinite(c.score)


@pytest.mark.parametrize("f,sample_period,above", [(590.0, 1e-3, True), (590.0, 4e-4, False), (480.0, 1e-3, False)])
def test_a_link_above_the_records_nyquist_frequency_cannot_ring_in_it(f, sample_period, above):
    # EMPS's chain took a 590 Hz link on 1 ms samples (Nyquist 500 Hz) as its fourth step, a sliver
    values = {"load_share": 0.86, "frequency": f, "damping_ratio": 0.0995}
    why = candidate("flexible_transmission").degenerate(values, None, sample_period)
    assert bool(why) is above
    if above:
        assert "above the record's Nyquist frequency (500 Hz)" in why
