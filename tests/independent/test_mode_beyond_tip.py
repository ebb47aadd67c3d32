"""A light mode beyond the measured tool tip (issue 50: the independent simulator's c07 and h15, a
1 kg and a 0.5 kg mass on a spring past the tip, which its sensor does not see: named a tip mass
`parameter:plant.m3`, or a mode with a damping c2 beside it). `compliant_mode` has a setting `tip`:
the tip measured on the mode's mass ("mode", as before) or kept where the model measures it
("kept"); the fit tries both and keeps the record's. Records of this project's own independent
simulator (plant_ivp), the mode's mass, frequency and damping drawn at random, the tip measured on
either side of it."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plant_ivp as ivp  # noqa: E402

from hil.cli import main  # noqa: E402
from hil.config import load  # noqa: E402
from hil.io.measurement import write  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CFG_PATH = ROOT / "config" / "paper_bench.toml"
BENCH = ivp.bench_from_config(load(CFG_PATH))


@pytest.mark.slow
@pytest.mark.parametrize("tip,seed", [("kept", 1), ("kept", 2), ("mode", 3)])
def test_a_mode_past_the_tip_or_carrying_it_is_named_with_its_side(tip, seed, tmp_path, capsys):
    rng = np.random.default_rng(seed)
    mass, freq, zeta = float(rng.uniform(0.3, 1.5)), float(rng.uniform(25.0, 70.0)), float(rng.uniform(0.02, 0.05))
    w = 2 * np.pi * freq
    bench = BENCH.changed(m=BENCH.m + (mass,), k=BENCH.k + (mass * w * w,), c=BENCH.c + (2 * zeta * mass * w,),
                          tip=len(BENCH.m) - 1 if tip == "kept" else len(BENCH.m))
    x = ivp.command_sequence(3.0, BENCH.tp, seed)
    path = tmp_path / "mode.csv"
    write(path, ivp.measure(ivp.simulate(bench, x), seed), {"sample_period": f"{BENCH.tp:g} s", "source": "plant_ivp"})
    capsys.readouterr()
    # the rival the independent records had named: the tip's mass, which a mode past it loads
    assert main(["diagnose", str(path), "--config", str(CFG_PATH), "--candidates", "compliant_mode,parameter:plant.m3",
                 "--max-steps", "2", "--jobs", "1", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["verdict"] == "compliant_mode", got["verdict"]
    params = got["chain"][0]["params"]["compliant_mode"]
    assert params["tip"] == ("mode", "kept").index(tip)         # the setting's number in the JSON
    assert (params["mass"], params["frequency"]) == pytest.approx((mass, freq), rel=0.03)
