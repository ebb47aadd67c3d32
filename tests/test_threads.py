"""The diagnosis on threads (issue 26, item 5): candidates fitted at once on the idle cores
(hil.ident.parallel.in_threads), the fleet's tracked fit beside the chain (Beside), the simulated
channels shared by the threads (SimulationCache), the costs the objective knows (starts._costs) and
the idle cores counted without this process's own load (hil.simulate.batch_threads). Every
number must be one thread's, bit for bit: the references are the same calls with
``HIL_THREADS=1``."""
import math
import threading

import numpy as np
import pytest

from hil.config import load
from hil.ident import Replay, synthesize
from hil.ident.parallel import Beside, evaluate_many, in_threads
from hil.ident.replay import SimulationCache
from hil.ident.starts import _costs
from hil.io.measurement import Measurement
from hil.plant_config import candidate

CFG = load("config/paper_bench.toml")


@pytest.fixture(scope="module")
def replay():
    ch, _ = synthesize(CFG, "coulomb_friction", {"level": 1.5}, duration=2.0, seed=4)
    return Replay(Measurement(ch, source="synth:coulomb_friction"), CFG)


def test_in_threads_keeps_the_order_and_runs_each_item_alone(monkeypatch):
    from hil.simulate import batch_threads
    monkeypatch.setenv("HIL_THREADS", "2")
    seen, where = [], []

    def work(i):
        where.append((threading.get_ident(), batch_threads()))
        return i * i
    assert in_threads(work, range(7), progress=seen.append) == [i * i for i in range(7)]
    assert seen == list(range(7))                          # as the results arrive, in order
    assert all(n == 1 for _, n in where)                   # each item's batches on its own thread
    assert threading.get_ident() not in {t for t, _ in where}
    monkeypatch.setenv("HIL_THREADS", "1")
    where.clear()
    assert in_threads(work, [3]) == [9] and where == [(threading.get_ident(), 1)]


def test_in_threads_raises_an_items_error(monkeypatch):
    monkeypatch.setenv("HIL_THREADS", "2")

    def work(i):
        if i == 2:
            raise KeyError("item 2")
        return i
    with pytest.raises(KeyError, match="item 2"):
        in_threads(work, range(4))


@pytest.mark.parametrize("names", [["backlash", "coulomb_friction", "viscous_friction", "parameter:plant.k2"]])
def test_candidates_on_threads_are_one_threads(replay, names, monkeypatch):
    """The same candidates, bit for bit, fitted on two threads as on one."""
    work = [(n, 6, None, 2) for n in names]
    res0 = replay.residuals(CFG)
    out = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("HIL_THREADS", threads)
        replay.objective.known_costs.clear()
        out[threads] = evaluate_many(replay, work, res0, 1, None)
    for a, b in zip(out["1"], out["2"]):
        assert a.effect == b.effect and a.params == b.params and a.nfev == b.nfev and a.score == b.score
        assert np.array_equal(np.array(list(a.stderr.values())), np.array(list(b.stderr.values())), equal_nan=True)
        for c in a.res:
            assert np.array_equal(a.res[c], b.res[c])


def test_beside_runs_on_an_idle_core_else_when_asked(monkeypatch):
    from hil.simulate import batch_threads
    here = threading.get_ident()
    monkeypatch.setenv("HIL_THREADS", "2")
    on = Beside(lambda: (threading.get_ident(), batch_threads()))
    ident, threads = on.result()
    assert ident != here and threads == 1
    monkeypatch.setenv("HIL_THREADS", "1")
    lazy = Beside(lambda: threading.get_ident())
    assert lazy.result() == here
    for n in ("1", "2"):
        monkeypatch.setenv("HIL_THREADS", n)
        failing = Beside(lambda: 1 / 0)
        with pytest.raises(ZeroDivisionError):
            failing.result()
        failing.wait()                          # waits, drops the error


def test_the_simulation_cache_holds_under_threads():
    """Lookups, insertions and evictions from four threads at once: no lost entry or error, never
    more than its size, every hit the value put under its key."""
    cache = SimulationCache(16)
    errors = []

    def hammer(seed):
        rng = np.random.default_rng(seed)
        try:
            for _ in range(4000):
                k = int(rng.integers(40))
                got = cache.get(k)
                if got is not None and got["k"] != k:
                    errors.append((k, got))
                cache.put(k, {"k": k})
        except Exception as exc:                # noqa: BLE001 - the test reports any
            errors.append(exc)
    threads = [threading.Thread(target=hammer, args=(s,)) for s in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and len(cache) <= 16 and cache.hits + cache.misses == 16000


def test_known_costs_are_not_simulated_again(replay, monkeypatch):
    """A grid's costs come once from the loops; asked again (another candidate's grid, the fleet's
    tracked fit) they are the same numbers, with no loop run."""
    eff = candidate("coulomb_friction", CFG)
    starts = [{"level": v} for v in (0.5, 1.0, 1.5, 2.0)] + [{"level": -1.0}]
    replay.objective.known_costs.clear()
    first = _costs(eff, replay, starts, CFG)
    runs = []
    real = type(replay).residuals_many
    monkeypatch.setattr(type(replay), "residuals_many", lambda self, cfgs: runs.append(len(cfgs)) or real(self, cfgs))
    again = _costs(eff, replay, starts, CFG)
    assert again == first and runs in ([], [0])
    assert np.isfinite(first[:4]).all() and math.isinf(first[4])     # a level below its bound: refused
    # a start it does not know is simulated alone
    runs.clear()
    _costs(eff, replay, starts + [{"level": 1.25}], CFG)
    assert runs == [1]


def test_others_load_is_the_busy_cpus_less_this_process(monkeypatch):
    import hil.simulate as sim
    clock = {"t": 100.0, "cpu": 5.0, "pid": 4242, "busy": 1000.0}
    monkeypatch.setattr(sim.time, "monotonic", lambda: clock["t"])
    monkeypatch.setattr(sim.time, "process_time", lambda: clock["cpu"])
    monkeypatch.setattr(sim.os, "getpid", lambda: clock["pid"])
    monkeypatch.setattr(sim._OthersLoad, "_busy", staticmethod(lambda hz, cpus=None: clock["busy"]))
    others = sim._OthersLoad()
    assert others() is None                         # no span yet
    clock.update(t=100.3)
    assert others() is None
    clock.update(t=101.0, cpu=7.0, busy=1002.5)      # this process 2 s of CPU in 1 s, the CPUs 2.5 s
    assert others() == pytest.approx(0.5)
    clock.update(t=102.0, cpu=9.0, busy=1004.5)      # the span from 100 s: 0.5 s of others' time in 2 s
    assert others() == pytest.approx(0.25)
    clock.update(t=102.2, cpu=9.4, busy=1005.4)      # a span started again at 102 s: too short, the last
    assert others() == pytest.approx(0.25)
    clock.update(t=103.0, cpu=10.0, busy=1006.5)     # 1 s of others' time over the span from 102 s
    assert others() == pytest.approx(1.0)
    clock.update(t=120.0, cpu=10.0, busy=1046.5)     # nothing read for 17 s (workers ran): starts anew
    assert others() is None
    clock.update(t=120.6, cpu=10.1, busy=1046.7)
    assert others() == pytest.approx(0.1 / 0.6)
    clock.update(pid=4243)                          # a forked child starts a span of its own
    assert others() is None
    monkeypatch.setattr(sim._OthersLoad, "_busy", staticmethod(lambda hz, cpus=None: None))
    assert sim._OthersLoad()() is None              # no /proc/stat


def test_busy_time_of_the_cpus_this_process_may_use(tmp_path, monkeypatch):
    """The cpuN lines of /proc/stat of the allowed CPUs alone (a container's, a taskset's): user,
    nice, system, irq, softirq and steal; not idle nor iowait."""
    import builtins

    import hil.simulate as sim
    stat = tmp_path / "stat"
    stat.write_text("cpu  900 0 300 5000 10 0 0 0 0 0\n"
                    "cpu0 100 0 50 2000 5 1 2 3 0 0\n"
                    "cpu1 800 0 250 3000 5 0 0 0 0 0\n"
                    "intr 12345\n")
    real_open = builtins.open
    monkeypatch.setattr(builtins, "open", lambda f, *a, **k: real_open(stat if f == "/proc/stat" else f, *a, **k))
    assert sim._OthersLoad._busy(100.0, {0}) == pytest.approx(1.56)
    assert sim._OthersLoad._busy(100.0, None) == pytest.approx(12.06)
    assert sim._OthersLoad._busy(100.0, {5}) is None
    assert sim._OthersLoad._busy(0.0, None) is None


@pytest.mark.parametrize("load, others, threads", [
    (40.0, None, 1),        # a busy machine, by its load average
    (0.9, None, 2),         # by the load average less this process
    (1.9, None, 1),
    (1.9, 0.0, 2),          # the load average a minute late: the others quiet now
    (0.2, 0.6, 1),          # another process on most of a core
    (0.2, 0.3, 2),
    (8.0, 1.7, 1),
])
def test_batch_threads_count_the_others_load_alone(load, others, threads, monkeypatch):
    import hil.simulate as sim
    monkeypatch.delenv("HIL_THREADS", raising=False)
    monkeypatch.setattr("os.getloadavg", lambda: (load, 0.0, 0.0))
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setattr(sim, "_others_load", lambda: others)
    assert sim.batch_threads() == threads


def test_an_error_drops_the_items_not_started(monkeypatch):
    """As one by one: after an item's error (or Ctrl-C) the items still waiting do not run."""
    import time
    monkeypatch.setenv("HIL_THREADS", "2")
    ran = []

    def work(i):
        ran.append(i)
        if i == 0:
            raise KeyboardInterrupt
        time.sleep(0.05)
        return i
    with pytest.raises(KeyboardInterrupt):
        in_threads(work, range(40))
    assert len(ran) < 10
