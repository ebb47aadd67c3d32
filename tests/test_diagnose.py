"""Synthetic records with a hidden effect: diagnose names it, fit removes its error."""
import numpy as np
import pytest

from hil.compare import Replay
from hil.config import load
from hil.identify import diagnose, evaluate
from hil.measurement import Measurement
from hil.synth import HIDDEN_DEFAULTS, synthesize

CFG = load("config/paper_bench.toml")


def _replay(effect, duration=6.0, seed=3):
    ch, truth = synthesize(CFG, effect, duration=duration, seed=seed)
    return Replay(Measurement(ch, source=f"synth:{effect}"), CFG), truth


def test_coulomb_named_and_fitted():
    rp, truth = _replay("coulomb_friction")
    d = diagnose(rp, ["coulomb_friction", "viscous_friction", "constant_force", "parameter:plant.c2"], jobs=1)
    assert d["verdict"] == "coulomb_friction"
    c = d["candidates"][0]
    assert c.params["level"] == pytest.approx(2.2, rel=0.02)
    assert c.error_after <= 0.2 * c.error_before


def test_clean_data_gives_none():
    rp, _ = _replay(None)
    d = diagnose(rp, ["coulomb_friction", "constant_force", "parameter:plant.c2"], jobs=1)
    assert d["verdict"] == "none"


def test_paper_c2_discrepancy_points_at_c2():
    rp, _ = _replay("parameter:plant.c2")
    d = diagnose(rp, ["parameter:plant.c2", "parameter:plant.m3", "coulomb_friction", "compliant_mode"], jobs=1)
    assert d["verdict"] == "parameter:plant.c2"
    assert d["candidates"][0].params["value"] == pytest.approx(40.0, rel=0.1)


@pytest.mark.slow
@pytest.mark.parametrize("effect", sorted(HIDDEN_DEFAULTS))
def test_every_effect_ranked_first(effect):
    rp, _ = _replay(effect, duration=12.0)
    d = diagnose(rp)
    assert d["verdict"] == effect
    c = d["candidates"][0]
    assert c.error_after <= max(0.2 * c.error_before, 1.5 * rp.noise[c.channel])
