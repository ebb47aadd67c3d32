"""The CANopen cycle's threads and its timing benchmark: while the loop runs, the loop's own thread
takes the answer from the bus (no notifier thread handles a PDO), start-up and SDO before and
after it run on canopen's notifier; benchmarks/bench_canopen_timing.py's ``--json`` output, from a
short run. No timing is asserted here (that is the benchmark's job)."""
import json
import math
import os
import subprocess
import sys
import threading
from pathlib import Path

import can
import canopen.network
import numpy as np
import pytest
from canopen_rig import channel, rig

from drivers.base import Fault
from drivers.canopen.backend import CanopenBackend
from drivers.canopen.drive_sim import DriveSim
from drivers.control import controller_from_config
from hil import config
from hil.loop import ControlLoop
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory
from hil.runtime import run_trajectory

ROOT = Path(__file__).resolve().parents[1]


class _Watch:
    """Who delivered the TPDOs: frames through canopen's listener (the notifier thread) while the
    loop cycles, and the threads that decoded them."""

    def __init__(self, monkeypatch, backend_box):
        self.via_listener_cycling = 0
        self.via_listener = 0
        self.decoders: set[str] = set()
        box = backend_box
        orig = canopen.network.MessageListener.on_message_received
        watch = self

        def on_message_received(listener, msg):
            be = box.get("be")
            if be is not None and msg.arbitration_id in be.answers.decode:
                watch.via_listener += 1
                if be.cycling:
                    watch.via_listener_cycling += 1
            return orig(listener, msg)

        monkeypatch.setattr(canopen.network.MessageListener, "on_message_received", on_message_received)

    def wrap(self, be):
        orig = be.answers.on_tpdo

        def on_tpdo(*a):
            if be.cycling:
                self.decoders.add(threading.current_thread().name)
            return orig(*a)

        be.answers.on_tpdo = on_tpdo


def _hold(cfg, ticks):
    ctrl = controller_from_config(cfg, plant_from_config(cfg))
    return ctrl, np.zeros(ticks)


def test_no_notifier_thread_handles_pdos_while_the_real_time_loop_runs(monkeypatch):
    """Wall clock: the drive on its own thread, the host's ControlLoop on the real-time clock for
    0.4 s. Every TPDO of the cyclic phase is taken by the loop's thread; start-up before and
    SDO after it go through the notifier."""
    box = {}
    watch = _Watch(monkeypatch, box)
    ch = channel("rt")
    cfg = config.load("config/paper_bench_canopen.toml", {"canopen.interface": "virtual", "canopen.channel": ch,
                                                            "canopen.pdo_miss_limit": 1000})
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=False)
    be = CanopenBackend(cfg, lockstep=False)
    box["be"] = be
    watch.wrap(be)
    try:
        be.open()
        assert not be.cycling and be.network.notifier is not None
        be.enable()
        assert be.cycling
        ctrl, x = _hold(cfg, 100)
        x += be.read_feedback().x_motor
        loop = ControlLoop(be, ctrl)
        res = loop.run(x)
        assert res.status == "complete", res.reason
        assert be.cycling                      # still the loop's until the shutdown
        be.disable()                           # SDO: the notifier again
        assert not be.cycling and be.network.notifier is not None
        assert be.status()["state"] == "READY TO SWITCH ON"
    finally:
        be.close()
        sim.close()
    assert watch.via_listener_cycling == 0
    assert watch.decoders == {threading.current_thread().name}
    # the drive answered (nearly) every SYNC, and the loop's thread took the answers
    assert be.pdo_frames_on_loop >= 3 * (be.syncs - be.missed_total - 2) > 0
    assert len(be.answer_latency) >= be.syncs - be.missed_total - 2


def test_no_notifier_thread_handles_pdos_in_a_lockstep_run(monkeypatch, tmp_path):
    """Lockstep (the tests' rig): the barrier after each SYNC is taken on the loop's thread too;
    every TPDO of the run but the last answer (it may come after the run) is the loop's."""
    box = {}
    watch = _Watch(monkeypatch, box)
    cfg, sim, be = rig()
    box["be"] = be
    watch.wrap(be)
    tr = Trajectory(start=0.0)
    tr.move(MoveSpec(stroke=0.01, feed=0.1, a_max=2.0))
    tr.dwell(0.05)
    try:
        rec = run_trajectory(cfg, tr, backend=be, out_file=tmp_path / "m.csv", settle=0.0)
    finally:
        sim.close()
    assert rec.status == "complete", rec.reason
    assert watch.via_listener_cycling == 0
    assert watch.decoders == {threading.current_thread().name}
    cycles = len(rec["t"])
    assert be.missed_total == 0 and be.pdo_frames_on_loop >= 3 * (cycles - 1)


@pytest.mark.slow
@pytest.mark.realtime
def test_timing_benchmark_json_from_a_short_run():
    """Both transports at 250 Hz for 1 s, idle and with one core busy: four results with the
    figures the issue names, consistent with each other; no process left behind."""
    before = _drive_sims()
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks/bench_canopen_timing.py"), "--transport", "both",
                          "--rate", "250", "--duration", "1", "--burner", "--json"], cwd=ROOT, capture_output=True,
                         text=True, timeout=240, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert out.returncode == 0, out.stderr[-2000:]
    rep = json.loads(out.stdout)
    runs = rep["results"]
    assert [(r["transport"].split()[0], r["load"]) for r in runs] == [
        ("virtual", "idle"), ("virtual", "one core busy"), ("socketcand", "idle"), ("socketcand", "one core busy")]
    for r in runs:
        assert r["rate_hz"] == 250 and r["cycles"] == 250 and r["seconds"] == 1.0
        assert 0 <= r["longest_miss_run"] <= r["cycles_without_answer"] <= r["cycles"]
        assert r["supervisor_would_trip"] == (r["longest_miss_run"] >= r["pdo_miss_limit"] == 2)
        assert r["lateness_p50_us"] <= r["lateness_p99_us"] <= r["lateness_max_us"]
        assert r["sync_to_answer_p50_us"] > 0 and r["drive_answer_p50_us"] > 0
        assert isinstance(r["goals_met"], bool)
        assert len(r["load_average_before"]) == 3
        assert 0 <= r["misses_behind_a_host_stall"] <= r["cycles_without_answer"]
        assert 0 <= r["host_stalls_over_1ms"] <= r["cycles"]
        if os.path.exists("/proc/stat"):            # the hypervisor's share of the run: a share of all CPUs
            assert r["steal_s"] >= 0 and 0 <= r["steal_pct"] <= 100
    assert rep["machine"]["cpus"] == os.cpu_count()
    assert not _drive_sims() - before          # the benchmark stopped the drive it started


def _drive_sims() -> set[int]:
    """The ``hil drive-sim`` processes of this checkout (Linux /proc; empty elsewhere)."""
    out = set()
    if not os.path.isdir("/proc"):
        return out
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    cmd = f.read()
            except OSError:
                continue
            if b"drive-sim" in cmd and str(ROOT).encode() in cmd and int(pid) != os.getpid():
                out.add(int(pid))
    return out



def test_a_bus_that_fails_in_the_cyclic_phase_is_the_feedbacks_fault():
    """The fault rule of drivers.base: read_feedback never raises; a bus that fails while the loop's
    thread receives is ``lost communication`` in the next feedback."""
    ch = channel("rt")
    cfg = config.load("config/paper_bench_canopen.toml", {"canopen.interface": "virtual", "canopen.channel": ch})
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=False)
    be = CanopenBackend(cfg, lockstep=False)
    try:
        be.open()
        be.enable()
        assert not be.read_feedback().fault
        be.network.bus.shutdown()                 # the interface is gone
        be.receive_until(0.0)                     # the clock's wait: does not raise
        fb = be.read_feedback()
        assert fb.fault is Fault.LINK and fb.reason.startswith("lost communication: the CAN bus failed on receive")
    finally:
        be.network.bus = None                     # already shut down
        be.close()
        sim.close()


def test_the_cpu_latency_request_is_the_kernels_format_and_released(tmp_path):
    """drivers.rt.CpuLatencyRequest writes the PM QoS value as the kernel reads it (a native 32-bit
    integer of microseconds: Documentation/power/pm_qos_interface.rst) and holds it while open."""
    import struct

    from drivers.rt import CpuLatencyRequest
    dev = tmp_path / "cpu_dma_latency"           # a file stands in for the device
    dev.write_bytes(b"")
    req = CpuLatencyRequest(20e-6, path=str(dev))
    assert req.hold() is None and req.held
    assert struct.unpack("=i", dev.read_bytes()) == (20,)
    req.release()
    req.release()                                # safe twice
    assert not req.held and req.was_held
    assert CpuLatencyRequest(math.inf, path=str(dev)).hold() is None        # inf: no request made
    gone = CpuLatencyRequest(0.0, path=str(tmp_path / "no" / "device"))
    assert "No such file" in gone.hold() and not gone.held and gone.refused


def test_the_clock_asks_for_the_latency_only_with_a_priority(tmp_path, monkeypatch):
    from hil.loop import RealTimeClock
    assert RealTimeClock(4e-3, priority=0, cpu_latency=0.0).cpu_latency.latency is None
    clock = RealTimeClock(4e-3, priority=0, cpu_latency=0.0)
    clock.start()
    clock.stop()
    assert not clock.cpu_latency.was_held
    assert RealTimeClock(4e-3, priority=50, cpu_latency=0.0).cpu_latency.latency == 0.0
    assert RealTimeClock(4e-3, priority=50, cpu_latency=math.inf).cpu_latency.latency == math.inf
