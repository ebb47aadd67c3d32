"""The starts' head bound (hil.ident.starts._bounded_costs, hil.ident.replay.Replay.head_costs): a
start's error on the record's first samples, from a simulation of those alone, is the first
samples' share of its whole error to the bit (the loop is causal), so the cheapest starts are the
ones the whole simulations of every start give, with the same costs.

The peer of each figure is the whole simulation of the same config (Replay.residuals), cut."""
import math

import numpy as np
import pytest

from hil.config import load
from hil.ident import Replay, synthesize
from hil.ident.starts import HEAD_SHARE, _bounded_costs, _costs
from hil.io.measurement import Measurement
from hil.plant_config import candidate, configure
from sim_plant.effects import CATALOGUE

CFG = load("config/paper_bench.toml")


def _replay(effect=None, values=None, cfg=CFG, sample_period=4e-3, seed=2, duration=3.0):
    ch, _ = synthesize(cfg, effect, values, duration=duration, seed=seed, sample_period=sample_period)
    return Replay(Measurement(ch, source="synth"), cfg)


def _head_of_whole(rp, cfg, share):
    """The peer: the whole simulation's weighted squared error on the first samples."""
    n = int(rp.meas.t.size * share)
    res, w = rp.residuals(cfg), rp.objective.weights
    return float(np.sum(np.concatenate([res[c][:n] * w[c] for c in w]) ** 2))


def _variants(effect, base=CFG):
    """``base`` with ``effect`` at the strength hil synth gives it."""
    eff = candidate(effect, base)
    vals = dict(getattr(eff, "synth_strength", None) or {p.name: p.guess for p in eff.params})
    return configure(eff, base, vals)


# the loop's structures a head must cut alike: delays (their buffers), the current loop, friction,
# a backlash's contact, a mode, a flexible link; and the controller's settings
EFFECTS = ["feedback_delay", "actuator_delay", "current_loop_lag", "coulomb_friction", "backlash", "compliant_mode",
           "torque_ripple", "flexible_transmission"]


@pytest.mark.parametrize("torque", ["actual", "command"])
def test_head_is_the_whole_simulations_first_samples(torque):
    base = CFG if torque == "actual" else CFG.with_values({"measurement.torque": "command"})
    rp = _replay("backlash", {"gap": 10e-6}, cfg=base)
    cfgs = [base] + [_variants(e, base) for e in EFFECTS] + [base.with_values({"control.kv": 0.8 * base["control.kv"]})]
    for share in (HEAD_SHARE, 0.3, 0.77):
        heads = rp.head_costs(cfgs, share)
        assert heads is not None
        for c, h in zip(cfgs, heads):
            assert h == _head_of_whole(rp, c, share), (share, c.source)


def test_head_on_a_record_slower_than_the_loop():
    # a record every 12 ms, the loop every 4 ms: the simulated channels are interpolated
    rp = _replay("coulomb_friction", {"level": 1.0}, sample_period=12e-3, duration=8.0)
    assert not rp.one_to_one
    cfgs = [CFG, _variants("backlash"), _variants("feedback_delay")]
    for share in (HEAD_SHARE, 0.5):
        heads = rp.head_costs(cfgs, share)
        for c, h in zip(cfgs, heads):
            assert h == _head_of_whole(rp, c, share)


def test_no_head_where_a_recording_artefact_reads_either_side():
    rp = _replay()
    skew = configure(candidate("channel_skew", CFG), CFG, {"skew": 8e-3})
    assert rp.head_costs([CFG, skew], HEAD_SHARE) is None
    assert rp.head_costs([CFG], 0.01) is None        # too few samples


def test_bounded_costs_keep_the_same_cheapest_with_the_same_costs():
    # a backlash record and the backlash's gap grid: most points are far worse than the best
    rp = _replay("backlash", {"gap": 20e-6}, seed=4)
    eff = CATALOGUE["backlash"]
    grid = [{"gap": g} for g in np.geomspace(2e-6, 200e-6, 25)]
    whole = _costs(eff, rp, grid, CFG)
    for keep in (1, 2, 5):
        got = _bounded_costs(eff, rp, grid, CFG, keep)
        assert list(np.argsort(got)[:keep]) == list(np.argsort(whole)[:keep])
        for i in np.argsort(whole)[:keep]:
            assert got[i] == whole[i]
        # every point left out costs more than the keep-th cheapest
        kth = sorted(whole)[keep - 1]
        assert all(w > kth for g, w in zip(got, whole) if g == math.inf)
        if keep == 1:
            assert sum(g == math.inf for g in got) >= len(grid) // 2       # the bound saves simulations
    # with known costs of other points: they count towards the keep cheapest
    half = len(grid) // 2
    first = _costs(eff, rp, grid[:half], CFG)
    rest = _bounded_costs(eff, rp, grid[half:], CFG, 2, known=first)
    both = first + rest
    assert list(np.argsort(both)[:2]) == list(np.argsort(whole)[:2])


def test_bounded_costs_of_a_start_that_cannot_be_configured():
    rp = _replay("backlash", {"gap": 20e-6}, seed=4)
    eff = CATALOGUE["backlash"]
    grid = [{"gap": -1.0}, {"gap": 20e-6}, {"gap": 150e-6}, {"gap": 2e-6}]
    got = _bounded_costs(eff, rp, grid, CFG, 1)
    assert got[0] == math.inf and got[1] == _costs(eff, rp, [grid[1]], CFG)[0]


@pytest.mark.parametrize("batch", ["1", "0"])
def test_a_cost_that_is_not_a_number_is_never_the_cheapest(batch, monkeypatch):
    # a loop that runs away late gives a finite head and a whole error that is not a number: it is
    # inf on both paths, and the bound keeps what the whole simulations keep
    monkeypatch.setenv("HIL_BATCH", batch)
    rp = _replay("backlash", {"gap": 20e-6}, seed=4)
    eff = CATALOGUE["backlash"]
    grid = [{"gap": 5e-6}, {"gap": 20e-6}, {"gap": 60e-6}, {"gap": 2e-6}]
    obj = rp.objective
    one, many = obj.residuals, obj.residuals_many

    def spoilt(cfg, r):
        return {c: np.full_like(v, np.nan) for c, v in r.items()} if cfg["effects.backlash.gap"] == 5e-6 else r
    monkeypatch.setattr(obj, "residuals", lambda cfg: spoilt(cfg, one(cfg)))
    monkeypatch.setattr(obj, "residuals_many", lambda cfgs: [spoilt(c, r) for c, r in zip(cfgs, many(cfgs))])
    whole = _costs(eff, rp, grid, CFG)
    assert whole[0] == math.inf and all(math.isfinite(c) for c in whole[1:])
    got = _bounded_costs(eff, rp, grid, CFG, 1)
    assert int(np.argmin(got)) == int(np.argmin(whole)) == 1 and got[1] == whole[1]
