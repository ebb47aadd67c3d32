"""The torque floor of a record the project's kernel did not make (issue 24): the independent
simulator's clean record of the paper bench, its torque with a white noise of 1 % of its RMS. The
tip (15 Hz, damping ratio 0.015) rings for seconds after each move and moves the current at rest;
the floor is the noise, not that ringing (hil.ident.noise: per rest the lesser of the channel's
variation and the residual's)."""
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from hil.config import load
from hil.ident import Replay
from hil.ident.noise import channel_standstill_noise
from hil.io.measurement import Measurement

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import plant_ivp as ivp  # noqa: E402

CFG = load(HERE.parents[1] / "config" / "paper_bench.toml")


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0])
def test_torque_floor_is_the_noise_not_the_ringing(seed):
    bench = ivp.bench_from_config(CFG)
    x = ivp.command_sequence(4.0, bench.tp, seed)
    ch = ivp.measure(ivp.simulate(bench, x, ivp.Hidden()), seed)
    sigma = 0.01 * math.sqrt(float(np.mean(np.asarray(ch["torque"]) ** 2)))     # measure()'s noise, to 1e-4
    rp = Replay(Measurement(ch, source="plant_ivp"), CFG)
    alone, _ = channel_standstill_noise(rp.meas.t, rp.meas["x_cmd"], rp.meas["torque"])
    assert alone > 2 * sigma                    # the channel at rest holds the tip's ringing
    # the floor: the noise, and the loop's answer to the encoders' steps (a part of it no model follows)
    assert 0.8 * sigma < rp.noise["torque"] < 1.6 * sigma
