"""The chain made faster with the same numbers (issue 26): each shortcut against the path it
replaces, bit for bit.

* the compiled loop specialised on the chain's size (sim_plant.kernel.mass_token) against the
  loop that reads the size from the matrix, for every structure the kernel compiles away or in
  (effects, dry friction, delays, the speed filter, measured inputs, one to four masses);
* a config changed by a few keys (hil.config.Config.with_values, the validated values kept)
  against the same raw values validated from scratch: the same values, types and key order;
* the replays' cache of simulations (hil.ident.replay.SimulationCache): a hit is the fresh
  simulation's arrays, a changed parameter misses, the replays of one record share it;
* the cycles compiled without reference counting (sim_plant.kernel.njit_cycle) against the same
  cycle compiled with it, for every structure above and every effect of the catalogue that acts in
  the loop.
"""
import functools
from pathlib import Path

import numpy as np
import pytest
from conftest import CONFIG

from drivers.control import controller_from_config
from hil.config import _validate, load
from hil.ident import Replay, synthesize
from hil.ident.replay import SimulationCache, _loop_key
from hil.io.measurement import Measurement
from hil.plant_config import candidate, configure, plant_from_config
from hil.simulate import Record, _cycles, _prepared, closed_loop_kernel, simulate
from sim_plant.kernel import _CYCLE_OPTIONS, mass_token

# compiles every variant of the loops afresh (a minute and more each set): the slow set, which CI runs
pytestmark = pytest.mark.slow

CFG = load(CONFIG / "paper_bench.toml")


def _command(ticks=400):
    s = np.linspace(0.0, 1.0, ticks)
    return 0.02 * np.sin(2 * np.pi * 1.5 * s) ** 3


def _with(cfg, **sets):
    return cfg.with_values(sets)


def _kernel(cfg, masses, x_cmd, **kw):
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    r = _prepared(plant, ctrl, x_cmd, None, None, kw.get("u_add"), kw.get("f_ext"), False,
                  kw.get("torque", "actual"))
    closed_loop_kernel(r.Ad, r.Bd, r.fric, r.codes, r.params, r.terms, r.p, r.state0, r.cmd, r.ubuf, r.hbuf,
                       r.rec, r.record_every, speed_filter=r.speed_filter, log_command=r.log_command,
                       masses=None if masses is None else mass_token(plant.n), **r.inputs)
    return r.rec


def _one_mass():
    raw = {k: v for k, v in CFG.values.items() if v is not None and not k.startswith(("plant.k", "plant.c"))
           and k not in ("plant.m2", "plant.m3")}
    return _validate(raw, "one mass")


def _four_masses():
    return CFG.with_values({"plant.m4": 2.0, "plant.k3": 2e4, "plant.c3": 5.0})


CASES = {
    "no effects": CFG,
    "backlash": configure(candidate("backlash", CFG), CFG, {"gap": 20e-6}),
    "dry friction": _with(CFG, **{"friction.coulomb": 2.0, "friction.static": 2.5}),
    "delays": configure(candidate("feedback_delay", CFG), configure(candidate("actuator_delay", CFG), CFG,
                                                                    {"delay": 150e-6}), {"delay": 300e-6}),
    "ripple and a mode": configure(candidate("torque_ripple+compliant_mode", CFG), CFG,
                                   {"torque_ripple.amplitude": 0.2, "torque_ripple.period": 2.5e-3,
                                    "torque_ripple.phase": 0.3, "compliant_mode.mass": 1.0,
                                    "compliant_mode.frequency": 60.0, "compliant_mode.damping_ratio": 0.05}),
    "speed filter": _with(CFG, **{"control.velocity_feedback": "position_difference",
                                  "control.velocity_filter": [0.5, 0.5]}),
    "2 dof": load(CONFIG / "paper_bench_2dof.toml"),
    "1 mass": _one_mass(),
    "4 masses": _four_masses(),
}


@pytest.mark.parametrize("case", list(CASES))
def test_the_loop_compiled_for_the_chains_size_is_the_same_bits(case):
    """Unrolled over a size numba knows, the same arithmetic in the same order: every recorded
    channel equal to the loop that reads the size from the matrix."""
    cfg = CASES[case]
    x = _command()
    ref, got = _kernel(cfg, None, x), _kernel(cfg, True, x)
    for name, a, b in zip(Record._fields, ref, got):
        assert np.array_equal(a, b), (case, name)


def _counted_cycles():
    """hil.simulate's cycle compiled as plain njit: with numba's reference counting."""
    from numba import njit
    if not hasattr(_counted_cycles, "fn"):
        _counted_cycles.fn = njit(_cycles.py_func)
    return _counted_cycles.fn


@functools.cache
def _in_loop_effects() -> dict:
    from hil.ident.diagnosis import candidate_names
    from sim_plant.effects.base import RecordEffect
    plant = plant_from_config(CFG)
    out = {}
    for name in candidate_names(CFG, plant, include_parameters=False):
        eff = candidate(name, CFG)
        if not isinstance(eff, RecordEffect):
            out[name] = configure(eff, CFG, dict(getattr(eff, "synth_strength", None) or eff.guess(plant, {})))
    return out


def test_the_cycles_are_compiled_without_reference_counting():
    """The option is numba's, and the loops take it (a numba without it would run them with
    reference counting, slower: this fails first, as the sign of it)."""
    assert _CYCLE_OPTIONS == {"_nrt": False}
    assert _cycles.targetoptions.get("_nrt") is False
    from drivers.sim import coast_cycle, drive_cycle, torque_cycle
    assert all(f.targetoptions.get("_nrt") is False for f in (drive_cycle, torque_cycle, coast_cycle))


def _both_cycles(cfg, x, experiment=False, **kw):
    """The cycle without and with reference counting on the same inputs: per run (the value it
    returns, its record, and the state, loop state and buffers it leaves)."""
    from drivers.control import new_velocity_state
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    out = []
    for fn in (_cycles, _counted_cycles()):
        r = _prepared(plant, ctrl, x, None, None, kw.get("u_add"), kw.get("f_ext"), False, kw.get("torque", "actual"))
        n, steps = plant.n, x.size * ctrl.substeps
        rng = np.random.default_rng(5)
        exc = {"exc": 0.5 * np.sin(np.arange(steps) * 0.01), "noise_w": 1e-4 * rng.standard_normal(steps),
               "noise_x": 1e-7 * rng.standard_normal((steps, 3)), "out": np.zeros((steps, 10))} if experiment else {}
        state, s = r.state0.copy(), new_velocity_state()
        sat = fn(r.Ad, r.Bd, r.fric, r.codes, r.params, r.terms, r.p, state, np.zeros(2 * n), np.zeros(n), s, r.cmd,
                 r.ubuf, r.hbuf, r.rec, r.record_every, exc.get("exc"), False, exc.get("noise_w"),
                 exc.get("noise_x"), exc.get("out"), r.inputs.get("u_add"), r.inputs.get("f_ext"), False,
                 r.speed_filter, r.log_command, mass_token(n), r.enc)
        out.append((sat, r.rec, [state, s, r.ubuf, r.hbuf, exc.get("out")]))
    return out


def _measured_inputs(cfg, x) -> dict:
    """A record's measured inputs for the command ``x``: a pulsed command after the controller, a
    force on the table every velocity period, the torque command recorded."""
    plant = plant_from_config(cfg)
    steps = (x.size + 1) * controller_from_config(cfg, plant).substeps
    f_ext = np.zeros((steps, plant.n))
    f_ext[:, plant.table] = 40.0 * np.sin(np.arange(steps) * 1e-3)
    return {"u_add": np.where(np.arange(steps) % 3000 < 300, 0.4, 0.0), "f_ext": f_ext, "torque": "command"}


def _assert_same(case, runs):
    (sat_a, rec_a, left_a), (sat_b, rec_b, left_b) = runs
    assert sat_a == sat_b, case
    for name, a, b in zip(Record._fields, rec_a, rec_b):
        assert np.array_equal(a, b), (case, name)
    for a, b in zip(left_a, left_b):
        assert (a is None and b is None) or np.array_equal(a, b), case
    assert np.any(rec_a.x != 0.0)          # the loop ran
    assert left_a[4] is None or np.any(left_a[4] != 0.0)       # and the experiment's record with it


@pytest.mark.parametrize("case", list(CASES) + [f"effect {n}" for n in _in_loop_effects()])
def test_the_cycle_without_reference_counting_is_the_same_bits(case):
    """No reference counting changes no arithmetic: every recorded channel equal to the same cycle
    compiled with it (the work arrays allocated as closed_loop_kernel does), and the state, the
    loop's state and the delay and feedback buffers it leaves the same."""
    cfg = CASES[case] if case in CASES else _in_loop_effects()[case.split(" ", 1)[1]]
    _assert_same(case, _both_cycles(cfg, _command()))


def test_the_cycle_without_reference_counting_with_measured_inputs_and_an_experiment():
    """The measured inputs (a command after the controller, a row of external forces per period,
    the torque command recorded) and the frequency-response experiment's inputs (an excitation,
    the speed's and positions' noise, its per-period record ``out`` and the count of saturated
    periods it returns), with delays and a backlash: the same bits."""
    cfg = configure(candidate("actuator_delay", CFG), CASES["backlash"], {"delay": 150e-6})
    x = _command()
    _assert_same("measured inputs", _both_cycles(cfg, x, **_measured_inputs(cfg, x)))
    _assert_same("experiment", _both_cycles(CASES["delays"], x, experiment=True))


def test_the_size_specialised_loop_with_measured_inputs():
    """The measured inputs (a command after the controller, external forces) and the recorded
    command take the same path: the same bits."""
    cfg = CASES["backlash"]
    x = _command()
    kw = _measured_inputs(cfg, x)
    for a, b in zip(_kernel(cfg, None, x, **kw), _kernel(cfg, True, x, **kw)):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("changes", [
    {"effects.backlash.gap": 1.2e-5},
    {"plant.k2": 3.1e4, "plant.c2": 14.0},
    {"effects.coulomb_friction.level": "2 N*m", "effects.backlash.gap": "7 um"},
    {"measurement.channel_skew": 3e-4, "effects.channel_skew.delay": None},
    {"control.kv": 40.0, "friction.static": None},
    {"plant.m4": 2.0, "plant.k3": 2e4, "plant.c3": 5.0},
])
def test_a_changed_config_is_the_config_validated_from_scratch(changes):
    """with_values converts only the changed keys: the same values (types included) in the same
    order as the raw values validated anew."""
    base = CFG.with_values({"effects.backlash.gap": 5e-6})
    got = base.with_values(changes)
    raw = {k: v for k, v in base.values.items() if v is not None}
    for k, v in changes.items():
        if v is None:
            raw.pop(k, None)
        else:
            raw[k] = v
    ref = _validate(raw, base.source)
    assert list(got.values) == list(ref.values)
    for k, v in ref.values.items():
        assert type(got.values[k]) is type(v) and got.values[k] == v, k


def test_a_changed_config_is_checked_as_before():
    """Bad values and the chain's consistency are refused by name, as from scratch."""
    from hil.errors import ConfigError
    with pytest.raises(ConfigError, match="plant.k2"):
        CFG.with_values({"plant.k2": -1.0})
    with pytest.raises(ConfigError, match="plant.c3"):
        CFG.with_values({"plant.m4": 2.0, "plant.k3": 2e4})
    # the chain's checks run where a change touches the chain's keys (else the chain is the one
    # the config passed): a mass taken away, a tip or table mass beyond the chain
    with pytest.raises(ConfigError, match="unknown key 'plant.k2'"):
        CFG.with_values({"plant.m3": None})
    with pytest.raises(ConfigError, match="plant.tip_mass"):
        CFG.with_values({"plant.tip_mass": CFG.n_masses + 1})
    with pytest.raises(ConfigError, match="plant.table_mass"):
        CFG.with_values({"plant.k2": 3e4}).with_values({"plant.table_mass": 7})
    assert CFG.with_values({"plant.k2": 3e4}).n_masses == CFG.n_masses
    linear = CFG.with_values({"actuator.type": "linear", "actuator.gain": 100.0, "plant.pitch": None})
    assert linear.values["friction.viscous"] == CFG.values["friction.viscous"] and not linear.rotary


@pytest.fixture(scope="module")
def meas():
    ch, _ = synthesize(CFG, "backlash", {"gap": 12e-6}, duration=2.0, seed=5)
    return Measurement(ch, source="synth:backlash")


def _fresh_channels(meas, cfg):
    """The channels of a simulation of ``cfg`` by a replay with nothing cached."""
    return Replay(meas, CFG, sims=SimulationCache()).simulate(cfg).channels()


def test_a_cache_hit_is_the_fresh_simulation_bit_for_bit(meas):
    rp = Replay(meas, CFG)
    cfg = configure(candidate("backlash", CFG), CFG, {"gap": 9e-6})
    first = rp.residuals(cfg)
    hits, misses = rp._sims.hits, rp._sims.misses
    again = rp.residuals(cfg)
    assert rp._sims.hits == hits + 1 and rp._sims.misses == misses
    cached = rp._sims.get(_loop_key(cfg))
    fresh = _fresh_channels(meas, cfg)
    assert set(cached) == set(fresh)
    for c in fresh:
        assert np.array_equal(cached[c], fresh[c]), c
    for c in first:
        assert np.array_equal(first[c], again[c])
    # the batched path reads and fills the same cache
    many = rp.residuals_many([cfg])[0]
    for c in first:
        assert np.array_equal(first[c], many[c])


def test_a_changed_parameter_misses(meas):
    rp = Replay(meas, CFG)
    cfg = configure(candidate("backlash", CFG), CFG, {"gap": 9e-6})
    near = configure(candidate("backlash", CFG), CFG, {"gap": 9e-6 * (1 + 1e-12)})
    a = rp.residuals(cfg)
    misses = rp._sims.misses
    b = rp.residuals(near)
    assert rp._sims.misses == misses + 1
    assert _loop_key(near) != _loop_key(cfg)
    fresh = _fresh_channels(meas, near)
    cached = rp._sims.get(_loop_key(near))
    for c in fresh:
        assert np.array_equal(cached[c], fresh[c]), c
    assert any(not np.array_equal(a[c], b[c]) for c in a)


def test_the_replays_of_a_record_share_the_cache(meas):
    """with_config serves the new replay's base simulation from the cache: its residuals, weights
    and noise floor are those of a replay built from scratch."""
    rp = Replay(meas, CFG)
    cfg = configure(candidate("backlash", CFG), CFG, {"gap": 11e-6})
    rp.residuals(cfg)
    hits = rp._sims.hits
    shared = rp.with_config(cfg)
    assert shared._sims is rp._sims and rp._sims.hits > hits
    alone = Replay(meas, CFG, sims=SimulationCache()).with_config(cfg)
    assert shared.objective.weights == alone.objective.weights and shared.noise == alone.noise
    for c in alone.base_residuals:
        assert np.array_equal(shared.base_residuals[c], alone.base_residuals[c])


def test_the_cache_keeps_the_last_few():
    cache = SimulationCache(size=2)
    for i in range(3):
        cache.put(i, {"x": np.full(3, float(i))})
    assert cache.get(0) is None and cache.get(1) is not None and len(cache) == 2
    cache.put(3, {})          # 1 was used last: 2 goes
    assert cache.get(2) is None and cache.get(1) is not None


def test_simulate_is_the_unspecialised_loop():
    """simulate (the size specialised loop) against the loop reading the size from the matrix."""
    cfg = CASES["backlash"]
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    x = _command()
    res = simulate(plant, ctrl, x)
    rec = _kernel(cfg, None, x)
    assert np.array_equal(res.x, rec.x) and np.array_equal(res.u, rec.u)


def test_the_discretization_on_one_blas_thread_is_the_same_bits():
    """The chain's matrix exponential on one OpenBLAS thread (sim_plant.blas_threads) is the
    one on the library's default threads, bit for bit, for chains of one to five masses."""
    import scipy.linalg

    from sim_plant.blas_threads import one_blas_thread
    from sim_plant.chain import Chain
    rng = np.random.default_rng(7)
    for _ in range(25):
        n = int(rng.integers(1, 6))
        ss = Chain(tuple(rng.uniform(0.5, 500.0, n)), tuple(rng.uniform(1e3, 1e8, n - 1)),
                   tuple(rng.uniform(0.0, 2e4, n - 1))).state_space("all")
        block = np.zeros((2 * n + n, 2 * n + n))
        block[:2 * n, :2 * n], block[:2 * n, 2 * n:] = ss.A, ss.B
        dt = float(rng.choice([62.5e-6, 1e-4, 4e-3]))
        threaded = scipy.linalg.expm(block * dt)
        with one_blas_thread():
            single = scipy.linalg.expm(block * dt)
        assert np.array_equal(threaded, single)


def _blas_threads_now() -> list[int]:
    """This thread's OpenBLAS thread count of each loaded library (the setter returns the old one)."""
    from sim_plant.blas_threads import blas_thread_setters
    out = []
    for fn in blas_thread_setters():
        n = fn(1)
        fn(n)
        out.append(n)
    return out


def test_the_chain_and_the_diagnosis_run_on_one_blas_thread():
    """hil.ident's diagnosis and chain (and hil fleet's record) hold the fits' BLAS to one thread,
    and give the caller's setting back on return."""
    from hil.ident.chain import diagnose_chain
    from hil.ident.diagnosis import diagnose
    from sim_plant.blas_threads import blas_thread_setters, one_blas_thread
    if not blas_thread_setters():
        pytest.skip("no OpenBLAS with openblas_set_num_threads_local in this process")
    for fn in (diagnose, diagnose_chain):
        assert getattr(fn, "__wrapped__", None) is not None, fn
    before = _blas_threads_now()
    seen = one_blas_thread()(_blas_threads_now)()
    assert seen == [1] * len(before) and _blas_threads_now() == before


def test_one_blas_thread_holds_while_any_thread_is_inside():
    """The setting is the process's (OpenBLAS's pthreads builds): a thread whose block ends while
    another's goes on must not give the process its BLAS threads back; the last block restores."""
    import threading

    from sim_plant.blas_threads import blas_thread_setters, one_blas_thread
    if not blas_thread_setters():
        pytest.skip("no OpenBLAS with openblas_set_num_threads_local in this process")
    before = _blas_threads_now()
    inside, leave = threading.Event(), threading.Event()

    def other():
        with one_blas_thread():
            inside.set()
            leave.wait(10)
    t = threading.Thread(target=other)
    with one_blas_thread():
        t.start()
        assert inside.wait(10)
    assert _blas_threads_now() == [1] * len(before)      # this block ended, the other's goes on
    leave.set()
    t.join()
    assert _blas_threads_now() == before


def test_the_fits_linear_algebra_on_one_blas_thread_is_the_same_bits():
    """The fits' BLAS work on one thread against the library's default threads: least squares on a
    tall matrix (a Jacobian's columns) and its products the same bits; the periods the position
    periodogram finds, with their amplitudes and phases (least squares), the same."""
    from hil.ident.residual import periodic_in_position
    from sim_plant.blas_threads import one_blas_thread
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 6.0, 2400)
    x = 0.1 * np.sin(2 * np.pi * 0.4 * t) ** 2
    r = 1e-6 * np.sin(2 * np.pi * x / 0.004) + 1e-7 * rng.standard_normal(t.size)
    J = rng.standard_normal((6000, 7))
    e = rng.standard_normal(6000)

    def work():
        return (periodic_in_position(x, r, t, n=3), np.linalg.lstsq(J, e, rcond=None)[0], J.T @ J, J.T @ e, e @ e)
    threaded = work()
    with one_blas_thread():
        single = work()
    assert threaded[0] == single[0] and len(single[0]) == 3
    for a, b in zip(threaded[1:], single[1:]):
        assert np.array_equal(a, b)


def test_cached_loops_are_dropped_when_the_stages_they_inline_change(tmp_path):
    """numba checks a cached loop against its own file alone: where drivers.control's or the kernel's
    sources change, or the codes of sim_plant.terms, the loops that inline them (control, simulate,
    drivers/sim) and the kernel's own (compiled with the codes as constants) are removed from the
    cache, once; other modules' caches stay."""
    from sim_plant.kernel import INLINED_SOURCES, SOURCES_STAMP, drop_stale_compiled_loops
    for f in INLINED_SOURCES:
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / f).write_text("def stage(): return 1\n")

    def cached():
        names = ["hil/__pycache__/simulate._cycles-151.py311.nbi", "hil/__pycache__/simulate._cycles-151.py311.3.nbc",
                 "drivers/__pycache__/control.position_stage-90.py311.nbi",
                 "drivers/__pycache__/sim.drive_cycle-60.py311.nbi",
                 "sim_plant/__pycache__/kernel.plant_step-200.py311.nbi",
                 "hil/sweep/__pycache__/transmission.f-1.py311.nbi"]
        for n in names:
            (tmp_path / n).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / n).write_text("")
        return names
    names = cached()
    assert sorted(Path(p).relative_to(tmp_path).as_posix() for p in drop_stale_compiled_loops(tmp_path)) == sorted(names[:5])
    assert (tmp_path / SOURCES_STAMP).is_file()
    assert all((tmp_path / n).exists() for n in names[5:])
    cached()
    assert drop_stale_compiled_loops(tmp_path) == []          # the same sources: the cache stands
    for changed in ("drivers/control.py", "sim_plant/terms.py"):
        (tmp_path / changed).write_text("def stage(): return 2\n")
        assert len(drop_stale_compiled_loops(tmp_path)) == 5
        assert drop_stale_compiled_loops(tmp_path) == []
        cached()


def test_the_inlined_sources_are_found_where_the_packages_are():
    """The guard reads the real files: each inlined source and each inlining module exists under the
    folder that holds the three packages (a path left behind by a move would make it guard nothing)."""
    import sim_plant.kernel as kernel
    from sim_plant.kernel import INLINED_SOURCES, INLINING_CACHES
    root = Path(kernel.__file__).resolve().parents[1]
    assert all((root / f).is_file() for f in INLINED_SOURCES)
    for prefix in INLINING_CACHES:
        folder, module = prefix.split("/__pycache__/")
        assert (root / folder / (module.rstrip(".") + ".py")).is_file(), prefix


def test_the_position_periodogram_is_scipys_lomb_scargle():
    """hil.ident.residual.position_periodogram (one sine and cosine per sample and frequency, the
    sums rotated to each frequency's tau) against scipy.signal.lombscargle's default (its sines and
    cosines evaluated at tau): the same values to rounding and the same peaks, over random sample
    positions, residuals (a periodic part at a random period, noise, a drift) and record lengths."""
    from scipy.signal import find_peaks, lombscargle

    from hil.ident.residual import position_periodogram
    rng = np.random.default_rng(11)
    for _ in range(12):
        n = int(rng.integers(40, 2600))
        x = np.sort(rng.uniform(0.0, rng.uniform(0.01, 0.5), n))
        period = rng.uniform(3.0, 30.0) * (x[-1] - x[0]) / n * 10
        y = rng.uniform(0, 2e-6) * np.sin(2 * np.pi * x / period + rng.uniform(0, 6.3)) \
            + rng.uniform(1e-9, 1e-6) * rng.standard_normal(n) + rng.uniform(-1e-6, 1e-6) * x / x[-1]
        y = y - y.mean()
        w = 2 * np.pi / np.geomspace(3 * np.max(np.diff(x)) + 1e-9, (x[-1] - x[0]) / 3, 1500)
        ours, scipys = position_periodogram(x, y, w), lombscargle(x, y, w)
        assert np.max(np.abs(ours - scipys)) <= 1e-10 * np.max(scipys)
        assert np.array_equal(find_peaks(ours)[0], find_peaks(scipys)[0])
