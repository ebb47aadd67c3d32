"""A record whose moves run at one feed (issue 49, finding 3: `hil diagnose REC --candidates
coulomb_friction --no-chain` fitted a level of 4e-9 N m and said `unexplained` where `hil fit` found
2 N m). At one speed sign(v) and v are one column of the force residual's regression: the joint
split gave the Coulomb start a negative level (clipped to 0, a start the fit cannot leave) and the
viscous coefficient the rest. Records of the independent simulator (plant_ivp), levels drawn at
random: the Coulomb level is found within 2 % of the truth and named; the asymmetric friction's
per-direction start holds each direction's level."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plant_ivp as ivp  # noqa: E402

from hil.cli import main  # noqa: E402
from hil.config import load  # noqa: E402
from hil.ident import Replay  # noqa: E402
from hil.ident.fit import record_scales  # noqa: E402
from hil.ident.starts import StartContext  # noqa: E402
from hil.ident.synth import move_sequence  # noqa: E402
from hil.io.measurement import read, write  # noqa: E402
from sim_plant.effects.friction import force_levels_per_direction  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CFG_PATH = ROOT / "config" / "paper_bench.toml"
BENCH = ivp.bench_from_config(load(CFG_PATH))


def _slow_moves() -> np.ndarray:
    """The red team's command: `hil synth --duration 6s --seed 1`'s moves (hil.ident.synth's
    sequence: slow moves of at most 12 mm/s, whose sign(v) and v correlate at 0.98), one more tick."""
    x = move_sequence(6.0, BENCH.tp, 1)
    return np.append(x, x[-1])


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_a_coulomb_friction_at_one_feed_is_found_and_named(seed, tmp_path, capsys):
    level = float(np.random.default_rng(seed).uniform(1.0, 3.0))
    x = _slow_moves()
    rec = ivp.measure(ivp.simulate(BENCH, x, ivp.Hidden(coulomb_pos=level, coulomb_neg=level)), seed)
    v = np.diff(x) / BENCH.tp
    moving = np.abs(v) > 0.02 * np.abs(v).max()
    assert np.corrcoef(np.sign(v[moving]), v[moving])[0, 1] > 0.95       # the case: one speed
    path = tmp_path / "one_feed.csv"
    write(path, rec, {"sample_period": f"{BENCH.tp:g} s", "source": "plant_ivp"})
    capsys.readouterr()
    assert main(["diagnose", str(path), "--config", str(CFG_PATH), "--candidates", "coulomb_friction", "--no-chain",
                 "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["verdict"] == "coulomb_friction"
    assert got["candidates"][0]["params"]["level"] == pytest.approx(level, rel=0.02)



@pytest.mark.slow
def test_an_asymmetric_friction_at_one_feed_starts_per_direction(tmp_path):
    """The per-direction start (asymmetric_friction's) has the same one column in each direction:
    2 N m both ways had split into Fc+ 0.90 and Fc- -3.61 N m. Levels drawn at random, different per
    direction; the start's levels within 2 % of the truth, no slope invented."""
    up, down = np.random.default_rng(3).uniform(1.0, 3.0, 2)
    rec = ivp.measure(ivp.simulate(BENCH, _slow_moves(), ivp.Hidden(coulomb_pos=up, coulomb_neg=down)), 3)
    path = tmp_path / "one_feed.csv"
    write(path, rec, {"sample_period": f"{BENCH.tp:g} s", "source": "plant_ivp"})
    cfg = load(CFG_PATH)
    replay = Replay(read(path), cfg)
    res0 = replay.residuals(cfg)
    ctx = StartContext(replay, res0, cfg, record_scales(replay, res0))
    level_pos, level_neg, slope_pos, slope_neg = force_levels_per_direction(ctx)
    assert (level_pos, level_neg) == pytest.approx((up, down), rel=0.02)
    assert (slope_pos, slope_neg) == (0.0, 0.0)
