"""CPU placement of the loop and the live scope (issue 27): ``runtime.loop_cpu`` pins the loop's
thread to one CPU while a run lasts, and the scope's server runs on the other CPUs, niced, so that
it can never take the loop's core; a ring file a SIGKILLed run left in /dev/shm is removed at the
next start. What is checked is what the kernel reports (``sched_getaffinity``, ``getpriority``) of
the thread and the process, not what the code meant to set."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import CONFIG

from drivers.control import controller_from_config
from drivers.sim import SimulatedPlant
from hil.cli import main
from hil.errors import ConfigError
from hil.loop import ControlLoop, check_loop_cpu, cpu_list
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory

ROOT = Path(__file__).resolve().parents[1]
BENCH = str(CONFIG / "paper_bench.toml")
affinity = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no thread affinity on this system")


def _cpus():
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        pytest.skip("one CPU: nothing to place apart")
    return cpus


def test_cpu_list_as_linux_writes_it():
    assert cpu_list({0, 1, 2, 3, 6}) == "0-3,6"
    assert cpu_list({5}) == "5" and cpu_list({1, 3, 4}) == "1,3-4" and cpu_list(set()) == ""


@affinity
def test_the_loop_runs_on_its_cpu_and_gets_its_cpus_back(bench):
    """The thread that runs the cycle is on ``loop_cpu`` alone while the run lasts (read in the
    cycle, through the progress hook the loop calls at tick 0), and has its CPUs back after it."""
    cpus = _cpus()
    pin = cpus[-1]
    traj = Trajectory()
    traj.move(MoveSpec(0.002, 0.05, a_max=3.0))
    _, x_cmd = traj.sample(0.004)
    sim = SimulatedPlant(bench, plant_from_config(bench), closes="none")
    sim.home_at(0.0)
    sim.enable()
    seen = []
    loop = ControlLoop(sim, controller_from_config(bench, sim.plant), loop_cpu=pin,
                       progress=lambda done: seen.append(os.sched_getaffinity(0)))
    before = os.sched_getaffinity(0)
    assert loop.run(x_cmd).status == "complete"
    assert seen and seen[0] == {pin}
    assert os.sched_getaffinity(0) == before == set(cpus)


def test_a_cpu_that_is_not_there_is_one_line_before_anything_moves(bench, capsys, tmp_path):
    missing = max(os.sched_getaffinity(0)) + 1 if hasattr(os, "sched_getaffinity") else 1
    if not hasattr(os, "sched_setaffinity"):
        pytest.skip("no thread affinity on this system")
    sim = SimulatedPlant(bench, plant_from_config(bench), closes="none")
    with pytest.raises(ConfigError, match=rf"^runtime.loop_cpu {missing}: no such CPU for this process "
                                          rf"\(it may run on CPU {cpu_list(os.sched_getaffinity(0))}\)$"):
        ControlLoop(sim, controller_from_config(bench, sim.plant), loop_cpu=missing)
    # at the command line, on the dry run and with the scope asked for: exit 2, one line, no scope started
    argv = ["move", "--config", BENCH, "--stroke", "2mm", "--feed", "1000mm/min", "--tacc", "200ms",
            "--set", f"runtime.loop_cpu={missing}", "--json", "--out", str(tmp_path)]
    for extra in ([], ["--scope", "--scope-hold", "0s"]):
        assert main(argv + extra) == 2
        cap = capsys.readouterr()
        # --json: the error as JSON on stdout (hil.cli), nothing else; no scope started
        assert json.loads(cap.out)["exit_code"] == 2 and "scope at" not in cap.err
        assert cap.err.strip().splitlines() == [
            f"hil move: error: runtime.loop_cpu {missing}: no such CPU for this process "
            f"(it may run on CPU {cpu_list(os.sched_getaffinity(0))})"]


def test_no_affinity_on_the_system_is_a_warning_and_no_pinning(monkeypatch):
    monkeypatch.delattr(os, "sched_setaffinity", raising=False)
    with pytest.warns(RuntimeWarning, match="runtime.loop_cpu 1: this system cannot pin a thread to a CPU"):
        assert check_loop_cpu(1) is None
    assert check_loop_cpu(None) is None


@affinity
def test_the_scope_server_runs_on_the_other_cpus_niced():
    """Every thread of the server's process (Bokeh's, tornado's) is off the loop's CPU and 10 steps
    nicer than this process; without a loop CPU, only the niceness."""
    from hil.scope.server import SERVER_NICE, ScopeProcess
    cpus = _cpus()
    own = os.getpriority(os.PRIO_PROCESS, 0)
    for loop_cpu, expected in ((cpus[0], set(cpus[1:])), (None, set(cpus))):
        server = ScopeProcess(loop_cpu=loop_cpu)
        try:
            server.start()
            pid = server.proc.pid
            tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
            assert len(tids) >= 2                           # the server's thread started after the placement
            assert all(os.sched_getaffinity(t) == expected for t in tids), loop_cpu
            assert all(os.getpriority(os.PRIO_PROCESS, t) == min(own + SERVER_NICE, 19) for t in tids)
        finally:
            server.stop()


def _ring_in_a_process(hold: bool):
    """A process that makes a run's scope (its ring in /dev/shm) and prints the ring's path; then
    waits to be killed (``hold``) or ends without cleaning up."""
    code = ("import sys, time\nfrom hil.scope.server import ScopeProcess\ns = ScopeProcess()\n"
            "s.ring.write(0.0, 1, 2, 3, 4, 5, 6, 7, 8)\nprint(s.path, flush=True)\n"
            + ("time.sleep(60)\n" if hold else ""))
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONPATH=str(ROOT)))
    return proc, Path(proc.stdout.readline().strip())


@pytest.mark.skipif(not Path("/dev/shm").is_dir(), reason="no /dev/shm")
def test_a_ring_left_by_a_killed_run_is_removed_at_the_next_start():
    """A run killed with SIGKILL cannot remove its ring's file: the next scope removes it; the ring
    of a run still alive (another process's) is left alone, and so is a file of another name."""
    from hil.scope.server import ScopeProcess
    killed, left = _ring_in_a_process(hold=True)
    alive, living = _ring_in_a_process(hold=True)
    other = Path("/dev/shm") / f"not-a-hil-ring-{os.getpid()}"
    other.write_bytes(b"x")
    try:
        killed.send_signal(signal.SIGKILL)
        killed.wait(10)
        assert left.exists() and left.stat().st_size > 0           # what the kill leaves behind
        server = ScopeProcess()
        try:
            assert not left.exists()
            assert living.exists() and other.exists() and Path(server.path).exists()
        finally:
            server.stop()
        assert not Path(server.path).exists()
    finally:
        alive.kill()
        alive.wait(10)
        other.unlink()
        killed.stdout.close()
        alive.stdout.close()
    time.sleep(0.1)
    ScopeProcess().stop()                        # the other one's ring too, once its process is gone
    assert not living.exists()


def _benchmark():
    import importlib.util
    spec = importlib.util.spec_from_file_location("bench_canopen_timing", ROOT / "benchmarks/bench_canopen_timing.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_benchmark_states_the_noise_of_its_repetitions():
    """bench_canopen_timing.py --scope --repeat: per figure, the spread is the larger of the two
    sides' (largest - smallest) and the difference of the means is judged against it (or, where
    the spread is smaller, against 1 us of lateness)."""
    bench = _benchmark()
    runs = []
    for scope, p50, p99, mx, miss in ((False, 0.1, 26, 185, 1), (True, 0.1000001, 39, 590, 0),
                                      (False, 0.1, 76, 367, 0), (True, 0.1, 23, 2092, 8)):
        runs.append({"scope": scope, "lateness_p50_us": p50, "lateness_p99_us": p99, "lateness_max_us": mx,
                     "cycles_without_answer": miss})
    out = bench.noise(runs)
    assert out["lateness_p99_us"] == {"without": [26, 76], "with": [39, 23], "spread": 50, "difference": -20.0,
                                      "within_noise": True}
    assert out["lateness_max_us"]["spread"] == 1502 and out["lateness_max_us"]["difference"] == 1065.0
    assert out["lateness_p50_us"]["within_noise"] is True                   # 1e-7 us apart: under the floor
    assert out["cycles_without_answer"]["spread"] == 8 and out["cycles_without_answer"]["within_noise"] is True
    # one side's spread is not the other's difference: 10/12 against 30/31 is beyond
    far = bench.noise([{**runs[0], "lateness_p99_us": 10}, {**runs[1], "lateness_p99_us": 30},
                       {**runs[2], "lateness_p99_us": 12}, {**runs[3], "lateness_p99_us": 31}])
    assert far["lateness_p99_us"]["spread"] == 2 and far["lateness_p99_us"]["within_noise"] is False
    assert bench.noise(runs[:2])["lateness_p99_us"]["within_noise"] is None     # one repetition: no noise known


@affinity
def test_a_cpu_gone_between_the_check_and_the_run_is_a_warning(monkeypatch):
    """The CPU checked before the drive was enabled but refused at the run's start (taken offline
    meanwhile): a warning, the run unpinned, nothing to give back."""
    from hil.loop import LoopCpu

    def refuse(tid, cpus):
        raise OSError(22, "Invalid argument")
    pin = LoopCpu(0)
    monkeypatch.setattr(os, "sched_setaffinity", refuse)
    with pytest.warns(RuntimeWarning, match=r"runtime.loop_cpu 0: the loop's thread could not be pinned "
                                            r"\(Invalid argument\); it runs on any CPU"):
        pin.hold()
    pin.release()
    assert pin._before is None
