"""The chain's swap (hil.ident.chain._swap): the first step's look-alike (a candidate whose fit
corrects the residual as the verdict's does, cosine above 0.9, no more parameters) is judged in the
verdict's place once the later steps' effects are in the model.

A current loop's first-order lag and an actuator delay both shift the torque's phase: on a record
with an actuator delay beside a torque ripple the first diagnosis can rank the lag first (the
ripple not yet in the model), and the chain then named the lag and the ripple, the torque 6 x its
floor. The records come from the independent simulator (plant_ivp)."""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plant_ivp as ivp  # noqa: E402

from hil.config import load  # noqa: E402
from hil.ident import Replay, evaluate  # noqa: E402
from hil.ident.chain import _look_alike, diagnose_chain  # noqa: E402
from hil.io.measurement import Measurement  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CFG = load(ROOT / "config" / "paper_bench.toml").with_values({"measurement.torque": "actual"})
BENCH = ivp.bench_from_config(CFG)


def _replay(duration, seed, **hidden):
    x = ivp.command_sequence(duration, BENCH.tp, seed)
    rec = ivp.measure(ivp.simulate(BENCH, x, ivp.Hidden(**hidden), torque="actual"), seed)
    return Replay(Measurement(rec, source="plant_ivp"), CFG)


@pytest.mark.slow
def test_a_lag_and_a_delay_look_alike_a_friction_does_not():
    rp = _replay(2.0, 5, delay=0.4e-3)
    cands = [evaluate(rp, n) for n in ("current_loop_lag", "actuator_delay", "coulomb_friction")]
    for c in cands:          # as the diagnosis marks them (the friction explains almost nothing here)
        c.significant = c.score > 6.0
    d = {"candidates": sorted(cands, key=lambda c: -c.score)}
    lag, delay, friction = cands
    assert lag.significant and delay.significant
    assert _look_alike(d, "current_loop_lag", ["current_loop_lag"], set(), rp) is delay
    assert _look_alike(d, "actuator_delay", ["actuator_delay"], set(), rp) is lag
    # already in the model, or several effects in the step: none
    assert _look_alike(d, "current_loop_lag", ["current_loop_lag"], {"actuator_delay"}, rp) is None
    assert _look_alike(d, "current_loop_lag", ["current_loop_lag", "coulomb_friction"], set(), rp) is None


@pytest.mark.slow
def test_the_delay_replaces_the_lag_once_the_ripple_is_in():
    rp = _replay(4.0, 4002, delay=0.415e-3, ripple=((0.41, BENCH.pitch / 8, -2.045),))
    d = diagnose_chain(rp, jobs=1, holdout="moves")
    named = []
    for s in d["chain"]:
        gone = {x["effect"] for x in s.get("dropped", [])}
        named = [e for e in named + s["effects"] if e not in gone]
    assert sorted(named) == ["actuator_delay", "torque_ripple"]
    last = d["chain"][-1]["params"]
    assert last["actuator_delay"]["delay"] == pytest.approx(0.415e-3, rel=0.01)
    assert last["torque_ripple"]["amplitude"] == pytest.approx(0.41, rel=0.01)
    assert d["final"]["at_noise_floor"] and d["verdict"] in named
    swaps = [s for s in d["chain"] if s.get("swapped")]
    if swaps:          # the lag ranked first: the swap step names the delay and drops the lag
        (s,) = swaps
        assert s["effects"] == ["actuator_delay"] and s["dropped"][0]["effect"] == s["swapped"]
        assert s["held_out"]["earned"]
