"""A mode the model held rigidly in the table (``compliant_mode``'s ``origin`` "lumped"): a 2-dof model of
a 3-mass bench, the tip's mass lumped into the table's, as ``config/paper_bench_2dof.toml`` does.
The records come from the independent simulator (plant_ivp), the mode's mass, frequency and damping
drawn at random; the chain names ``compliant_mode`` with the mode's mass split off the table
(``origin`` "lumped"), its mass, frequency and damping those the record was made with."""
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plant_ivp as ivp  # noqa: E402

from hil.config import load  # noqa: E402
from hil.ident import Replay  # noqa: E402
from hil.ident.chain import diagnose_chain  # noqa: E402
from hil.io.measurement import Measurement  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BENCH = ivp.bench_from_config(load(ROOT / "config" / "paper_bench.toml"))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12])
def test_a_mode_the_model_lumped_into_the_table_is_split_off_it(seed):
    rng = np.random.default_rng(seed)
    m3, f, zeta = rng.uniform(2.0, 12.0), rng.uniform(10.0, 40.0), rng.uniform(0.01, 0.04)
    w = 2 * math.pi * f
    m2 = BENCH.m[1]
    bench = BENCH.changed(m=(BENCH.m[0], m2, m3), k=(BENCH.k[0], m3 * w * w), c=(BENCH.c[0], 2 * zeta * m3 * w))
    x = ivp.command_sequence(4.0, BENCH.tp, seed)
    rec = ivp.measure(ivp.simulate(bench, x, ivp.Hidden(), torque="actual"), seed)
    # the 2-dof model: the tip's mass rigidly on the table
    cfg = load(ROOT / "config" / "paper_bench_2dof.toml", {"plant.m2": m2 + m3})
    d = diagnose_chain(Replay(Measurement(rec, source="plant_ivp"), cfg), jobs=1, holdout="moves")
    named = [e for s in d["chain"] for e in s.effects]
    assert named == ["compliant_mode"], (seed, m3, f, zeta, named)
    v = d["chain"][0].params["compliant_mode"]
    assert v["origin"] == 1.0
    assert v["mass"] == pytest.approx(m3, rel=0.05)
    assert v["frequency"] == pytest.approx(f, rel=0.01)
    assert v["damping_ratio"] == pytest.approx(zeta, rel=0.2)
