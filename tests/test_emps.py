"""The EMPS record through the chain (skipped without ../shared/data)."""
from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "emps" / "DATA_EMPS.mat"
pytestmark = pytest.mark.skipif(not DATA.exists(), reason=f"EMPS record not present at {DATA}")


def test_published_model_reproduces_errors():
    from hil.cmd_emps import MAPPING, PUBLISHED, errors
    from hil.compare import Replay
    from hil.config import load
    from hil.importers import read_mat
    m = read_mat(DATA, MAPPING)
    cfg = load("config/emps.toml")
    pub = cfg.with_values({"effects.coulomb_friction.level": PUBLISHED["Fc"],
                           "effects.constant_force.force": -PUBLISHED["offset"]})
    e = errors(Replay(m, cfg), pub)
    assert e["position"] < PUBLISHED["errors"]["position"]
    assert e["velocity"] < 1.25 * PUBLISHED["errors"]["velocity"]
    assert e["force"] < 1.25 * PUBLISHED["errors"]["force"]
    e0 = errors(Replay(m, cfg), cfg)
    assert e0["force"] > 4 * e["force"]      # the start model lacks the Coulomb friction
