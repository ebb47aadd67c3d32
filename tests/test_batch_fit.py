"""The batched evaluation of the fits (issue 26, item 5): several parameter sets' loops in one
compiled call (hil.simulate.simulate_many / closed_loop_batch), the finite-difference Jacobian's
columns in one call with scipy's own steps (hil.ident.fit). Every number must be the one-by-one
path's, bit for bit: the references are hil.simulate.simulate run per plant, scipy's own
approx_derivative and the fits with HIL_BATCH=0 (scipy's '2-point' scheme, one simulation per column)."""
import numpy as np
import pytest
from scipy.optimize._numdiff import approx_derivative  # what least_squares(jac="2-point") calls

from drivers.control import controller_from_config
from hil.config import load
from hil.ident import Replay, synthesize
from hil.ident.fit import evaluate, fd_steps, joint_refit
from hil.ident.starts import _costs
from hil.io.measurement import Measurement
from hil.plant_config import candidate, configure, plant_from_config
from hil.simulate import simulate, simulate_many

CFG = load("config/paper_bench.toml")
FIELDS = ("t", "x_cmd", "v_cmd", "x", "v", "u", "x_motor", "x_table", "x_tip")


def _command():
    return np.concatenate([np.zeros(50), 0.02 * (1 - np.cos(np.linspace(0, np.pi, 300))), np.full(150, 0.04)])


def _configs(effect, values):
    eff = candidate(effect, CFG)
    base = {p.name: p.guess for p in eff.params}
    return [configure(eff, CFG, dict(base, **v)) for v in values]


@pytest.mark.slow
@pytest.mark.parametrize("effect, values", [
    ("backlash", [{"gap": 1e-6}, {"gap": 8e-6}, {"gap": 3e-5}]),
    ("coulomb_friction", [{"level": 0.5}, {"level": 2.0}]),
    ("parameter:plant.k2", [{"value": 0.9 * CFG["plant.k2"]}, {"value": 1.1 * CFG["plant.k2"]}]),
])
@pytest.mark.parametrize("threads", ["1", "2"])
def test_simulate_many_is_simulate_bit_for_bit(effect, values, threads, monkeypatch):
    monkeypatch.setenv("HIL_THREADS", threads)
    cfgs = _configs(effect, values)
    plants = [plant_from_config(c) for c in cfgs]
    ctrls = [controller_from_config(c, p) for c, p in zip(cfgs, plants)]
    x = _command()
    u_add = np.where(np.arange(x.size * ctrls[0].substeps) % 4000 < 400, 0.3, 0.0)
    for kw in ({}, {"u_add": u_add, "torque": "command"}):
        many = simulate_many(plants, ctrls, x, x0=0.0, **kw)
        for got, p, c in zip(many, plants, ctrls):
            ref = simulate(p, c, x, x0=0.0, **kw)
            for f in FIELDS:
                assert np.array_equal(getattr(got, f), getattr(ref, f)), (effect, kw.keys(), f)


@pytest.mark.parametrize("x0, lo, hi, rel", [
    ([0.7, -2.0, 0.0, 1e-9], -np.inf, np.inf, 1e-3),
    ([0.9995, -0.5, 3.0, 1e-12], [0.0, -0.5, 0.0, 0.0], [1.0, 1.0, 3.0, 1.0], 1e-3),    # steps past a bound
    ([0.5, 1e-20, 2.0, 4.0], [0.0, 0.0, 1.999, 3.99], [0.5001, 1.0, 2.001, 4.0], 1e-2),   # neither side fits
])
def test_jacobian_steps_are_scipys(x0, lo, hi, rel):
    """fd_steps gives the steps of scipy's 2-point scheme: the Jacobian built from them is
    approx_derivative's, bit for bit (a nonlinear function, so that any other step shows)."""
    x0 = np.array(x0)

    def f(x):
        return np.array([np.sin(3 * x[0]) * x[1], np.exp(0.3 * x[2]) + x[3] ** 3, x[0] * x[1] * x[2] - x[3]])
    ref = approx_derivative(f, x0, method="2-point", rel_step=rel, bounds=(lo, hi), f0=f(x0))
    h = fd_steps(x0, lo, hi, rel)
    cols = [(f(x0 + np.eye(4)[i] * h[i]) - f(x0)) / ((x0[i] + h[i]) - x0[i]) for i in range(4)]
    assert np.array_equal(np.column_stack(cols), ref)


@pytest.fixture(scope="module")
def replay():
    ch, _ = synthesize(CFG, "backlash", {"gap": 12e-6}, duration=3.0, seed=2)
    return Replay(Measurement(ch, source="synth:backlash"), CFG)


def _same_candidate(a, b):
    assert a.params == b.params and a.nfev == b.nfev and a.score == b.score and a.evidence == b.evidence
    assert np.array_equal(np.array(list(a.stderr.values())), np.array(list(b.stderr.values())), equal_nan=True)
    for c in a.res:
        assert np.array_equal(a.res[c], b.res[c])


@pytest.mark.parametrize("name", ["backlash", "coulomb_friction+viscous_friction"])
def test_batched_fit_takes_the_one_by_one_path(replay, name, monkeypatch):
    """The fit (its grid of starts and its Jacobians batched) ends where scipy's own scheme does,
    evaluation for evaluation: the same parameters, standard errors, residuals and count."""
    monkeypatch.setenv("HIL_BATCH", "1")
    replay.objective.known_costs.clear()        # each path costs its grid itself
    batched = evaluate(replay, name, max_nfev=8)
    monkeypatch.setenv("HIL_BATCH", "0")
    replay.objective.known_costs.clear()
    _same_candidate(batched, evaluate(replay, name, max_nfev=8))


def test_batched_joint_refit_is_the_one_by_one(replay, monkeypatch):
    keys = ["plant.k2", "plant.c2"]
    out = {}
    for flag in ("1", "0"):
        monkeypatch.setenv("HIL_BATCH", flag)
        se: dict = {}
        cfg = joint_refit(replay, CFG, keys, max_nfev=6, stderr=se)
        out[flag] = ([float(cfg[k]) for k in keys], se)
    assert out["1"] == out["0"]


def test_a_failing_start_costs_infinity_the_others_theirs(replay, monkeypatch):
    """A start whose model cannot be built (a ValueError) costs infinity in the batch too, and the
    others keep the costs they have one by one."""
    eff = candidate("parameter:plant.k2", CFG)
    starts = [{"value": CFG["plant.k2"]}, {"value": -1.0}, {"value": 1.2 * CFG["plant.k2"]}]
    monkeypatch.setenv("HIL_BATCH", "1")
    replay.objective.known_costs.clear()
    got = _costs(eff, replay, starts, CFG)
    monkeypatch.setenv("HIL_BATCH", "0")
    replay.objective.known_costs.clear()
    assert got == _costs(eff, replay, starts, CFG)
    assert got[1] == np.inf and np.isfinite(got[0]) and np.isfinite(got[2])


def _batch_in_child(_):
    cfgs = _configs("backlash", [{"gap": 2e-6}, {"gap": 9e-6}, {"gap": 4e-5}])
    plants = [plant_from_config(c) for c in cfgs]
    res = simulate_many(plants, [controller_from_config(c, p) for c, p in zip(cfgs, plants)], _command(), x0=0.0)
    return [float(r.x_table[-1]) for r in res]


def test_a_worker_forked_after_a_batch_runs_batches(monkeypatch):
    """hil diagnose --jobs and hil fleet fork their workers after the main process has fitted: the
    batch must not use a threading runtime that kills a forked child (GNU OpenMP does)."""
    import multiprocessing as mp
    monkeypatch.setenv("HIL_THREADS", "2")
    here = _batch_in_child(None)
    with mp.get_context("fork").Pool(1) as pool:          # the child inherits HIL_THREADS=2
        assert pool.map_async(_batch_in_child, [0]).get(timeout=120) == [here]


def test_batch_threads_from_the_environment_or_the_idle_cores(monkeypatch):
    import hil.simulate as sim
    from hil.simulate import batch_threads
    monkeypatch.setattr(sim, "_others_load", lambda: None)     # the load average's rule
    monkeypatch.setenv("HIL_THREADS", "3")
    assert batch_threads() == 3
    monkeypatch.setenv("HIL_THREADS", "two")
    with pytest.raises(ValueError, match="HIL_THREADS"):
        batch_threads()
    monkeypatch.delenv("HIL_THREADS")
    monkeypatch.setattr("os.getloadavg", lambda: (40.0, 0.0, 0.0))
    assert batch_threads() == 1               # a busy machine: no threads that wait for each other
    monkeypatch.setattr("os.getloadavg", lambda: (0.9, 0.0, 0.0))
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1})
    assert batch_threads() == 2               # this process alone on two cores
