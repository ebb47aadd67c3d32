"""Cycle timing of the CANopen backend against the simulated CiA 402 drive, on the real-time clock,
as a user of a real axis sees it: lateness p50/p99/max of the loop's wake-ups, cycles without
their answer (the TPDOs of a SYNC not in when the next cycle reads its feedback), the longest
run of consecutive misses and whether the supervisor would have tripped on it
(``canopen.pdo_miss_limit`` consecutive misses), the host stalls (wake-ups of the loop more than
1 ms late) and the misses within 5 cycles behind one, the share of the CPU time the hypervisor took
from the virtual machine during the run (``/proc/stat`` steal; 0 on bare metal), late answers (they come after the next SYNC:
counted by the SYNC counter echo), the SYNC-to-answer time as the host takes it and, for the
drive in its own process, as the drive sends it.

Two transports: the in-process virtual bus (the drive's thread shares the interpreter with the
loop) and the drive in its own process (``hil drive-sim``) over python-can's socketcand
interface on 127.0.0.1. Each run idle and/or with one core kept busy by another process (a
bounded CPU burner this benchmark starts and stops itself). Default durations: 10 minutes at
250 Hz, 60 s at 1 kHz (``--duration`` for all). Goals (issue 14): 250 Hz, socketcand, idle and
one core busy: at most 1 cycle in 10 000 without its answer, never two in a row, p99 lateness
under 200 us; 1 kHz: fewer than 1 in 1 000, p99 under 200 us, never two in a row.

    python benchmarks/bench_canopen_timing.py --transport socketcand --rate 250 --duration 600 --burner
    python benchmarks/bench_canopen_timing.py --all          # the full protocol (about 45 minutes)
    python benchmarks/bench_canopen_timing.py --duration 10 --json
    python benchmarks/bench_canopen_timing.py --transport socketcand --rate 1000 --duration 30 --scope
    python benchmarks/bench_canopen_timing.py --transport socketcand --rate 1000 --duration 30 --scope \
        --repeat 2 --priority 50 --loop-cpu 1

``--scope`` (issue 27): each run twice in one invocation, without and then with the live scope
(the cycle writes every row into the scope's ring; its Bokeh server streams it to a page open in
headless Chromium, a real client in its own process): the lateness and the cycles without their
answer of both, and their ratio; the page's latency (from the cycle that wrote a row, as it ran,
to the frame that brought the row into the page, ms: the page records when its newest row
changes, on the same wall clock), its
frames per second, the server's CPU time (its process, as the commands start it) and the
browser's (all its processes) as a share of one core (/proc); ``--points N`` sets the page's points
per trace. ``--repeat N``: each pair (without, with) N times, interleaved; then per figure the
values of each side, their spread (largest minus smallest: the run-to-run noise of this machine)
and whether the difference of the means is within it. ``--peer`` adds to each pair a run without
the page but with one CPU-bound process where its server and browser run, as nice: the peer that
tells the page's own effect from what any work on those CPUs does to the loop on this machine
(on a VM whose virtual CPUs share a core, the loop's worst lateness grows with either).

``--loop-cpu N`` (``runtime.loop_cpu``): the loop's thread pinned to CPU N, as on a real-time PC;
the scope's server, the browser and the drive's process on the other CPUs, as the commands place
the server. The server and the browser run ``--nice`` steps nicer (default
hil.scope.server.SERVER_NICE, as the commands start the server; ``--nice 0``: as before it was).
``--drive-cpu N`` puts the simulated drive's process on CPU N instead: on a real axis the drive is
another machine, and on a 2-CPU machine ``--loop-cpu 1 --drive-cpu 1`` leaves CPU 0 to the page and
its server alone, as a real-time PC with the loop on an isolated CPU would (the drive then shares the
loop's CPU: it answers within about 100 us of a SYNC and sleeps, the loop waits for that answer anyway).
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.base import Setpoint  # noqa: E402
from drivers.canopen.backend import CanopenBackend  # noqa: E402
from hil import config  # noqa: E402
from hil.errors import ConfigError  # noqa: E402
from hil.loop import LoopCpu, RealTimeClock, check_loop_cpu  # noqa: E402
from hil.plant_config import plant_from_config
from hil.scope.server import SERVER_NICE, server_cpus  # noqa: E402

CONFIG = ROOT / "config/paper_bench_canopen.toml"
DEFAULT_SECONDS = {250: 600.0, 1000: 60.0}
# the goals of issue 14: (most cycles without answer per cycle, p99 lateness us); never two in a row
GOALS = {250: (1e-4, 200.0), 1000: (1e-3, 200.0)}
STALL_S, STALL_WINDOW = 1e-3, 5


def _pct(a, q):
    return float(np.percentile(a, q) * 1e6) if len(a) else float("nan")


def loop(cfg, seconds, spin, ring=None):
    """A standstill loop of ``seconds`` on the real-time clock (read, setpoint, SYNC, wait), as
    hil.loop.ControlLoop runs it: the clock's wait is the backend's receive; on
    ``runtime.loop_cpu`` where it is set. ``ring``: the live scope's ring, written every cycle as
    hil.loop.ControlLoop writes it."""
    be = CanopenBackend(cfg, lockstep=False)
    be.open()
    try:
        be.enable()
        clock = RealTimeClock(be.cycle_time, spin=spin, priority=cfg.get("runtime.priority", 0),
                              idle=be.receive_until, cpu_latency=cfg.get("runtime.cpu_latency", 0.0))
        spin = clock.spin
        n = int(round(seconds / be.cycle_time))
        pos = be.read_feedback().x_motor
        tripped = ""
        gc.collect()              # as hil.loop.ControlLoop: no collection inside the cycle
        gc.freeze()
        gc.disable()
        pin = LoopCpu(check_loop_cpu(cfg.get("runtime.loop_cpu")))
        pin.hold()
        clock.start()
        dt = be.cycle_time
        # when each cycle ran, on the wall clock the scope's page stamps its frames with (both sides)
        walls = np.zeros(n)
        missed_at = []
        try:
            for i in range(n):
                before = be.missed_total
                fb = be.read_feedback()
                if be.missed_total != before:     # the answer to the SYNC of cycle i - 1 is not in
                    missed_at.append(i)
                if fb.fault and not tripped:
                    tripped = fb.reason
                walls[i] = time.time()
                if ring is not None:
                    ring.write(i * dt, pos, fb.x_motor, fb.x_table, fb.x_tip, pos - fb.x_table, pos - fb.x_table,
                               0.0, fb.v_motor)
                be.write_setpoint(Setpoint(position=pos))
                be.sync()
                clock.wait()
            be.read_feedback()                   # the last SYNC's answer counts too
        finally:
            clock.stop()
            pin.release()
            gc.enable()
            gc.unfreeze()
        be.disable()
    finally:
        be.close()
    lat = np.array(clock.lateness)
    ans = np.array(be.answer_latency)
    # a host stall: a wake-up of the loop's thread more than 1 ms late (with --priority nothing in the
    # machine outranks it: the virtual CPU itself did not run); a miss behind one: a stall within the
    # STALL_WINDOW cycles before it
    stalls = np.flatnonzero(lat > STALL_S)
    behind = sum(1 for i in missed_at if np.any((stalls >= i - STALL_WINDOW) & (stalls < i)))
    limit = int(cfg.get("canopen.pdo_miss_limit", 2))
    rate = round(1 / be.cycle_time)
    out = {"rate_hz": rate, "seconds": seconds, "cycles": n,
           "lateness_p50_us": _pct(lat, 50), "lateness_p99_us": _pct(lat, 99), "lateness_max_us": _pct(lat, 100),
           "overruns": clock.overruns, "cycles_without_answer": be.missed_total,
           "host_stalls_over_1ms": int(stalls.size), "misses_behind_a_host_stall": int(behind),
           "longest_miss_run": be.miss_run_max, "late_answers": be.late_total,
           "supervisor_would_trip": be.miss_run_max >= limit, "pdo_miss_limit": limit, "first_fault": tripped,
           "sync_to_answer_p50_us": _pct(ans, 50), "sync_to_answer_p99_us": _pct(ans, 99),
           "sync_to_answer_max_us": _pct(ans, 100), "spin_us": spin * 1e6,
           "cpu_latency_held": clock.cpu_latency.was_held, "loop_cpu": cfg.get("runtime.loop_cpu"),
           "_walls": walls}
    if rate in GOALS:
        ratio, p99 = GOALS[rate]
        out["goals_met"] = bool(be.missed_total <= ratio * n and be.miss_run_max < 2 and out["lateness_p99_us"] < p99)
    return out


def steal_seconds() -> float | None:
    """CPU time the hypervisor took from this virtual machine so far, all CPUs (``/proc/stat``,
    the ``steal`` column; None off Linux): a run's share of it says whether the machine itself
    stalled under the loop."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc, sig=signal.SIGTERM, wait=10.0):
    """End a process this benchmark started: ``sig``, then kill after ``wait`` seconds."""
    if proc is None or proc.poll() is not None:
        return
    try:
        proc.send_signal(sig)
        proc.wait(wait)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


def _placed(cpus, nice=0):
    """A ``preexec_fn`` that puts a child (the browser, the drive) on ``cpus`` and ``nice`` steps
    lower before it execs, so that every process and thread it starts inherits it (None: as is)."""
    if not cpus and not nice:
        return None

    def place():
        if cpus:
            os.sched_setaffinity(0, cpus)
        if nice:
            os.nice(nice)
    return place


def start_burner(seconds, preexec_fn=None):
    """One core kept busy: a separate Python process spinning, bounded to ``seconds`` (placed by
    ``preexec_fn``: :func:`_placed`)."""
    code = f"import time\nend = time.monotonic() + {float(seconds)!r}\nwhile time.monotonic() < end:\n    pass\n"
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            preexec_fn=preexec_fn)


# the page records when the newest row it holds changes (every 5 ms), on the wall clock
RECORDER = r"""(() => {
  const src = Bokeh.documents[0].get_model_by_name('traces');
  window.__frames = []; let last = null;
  setInterval(() => {
    const t = src.data.t, n = t.length;
    if (n && t[n - 1] !== last) { last = t[n - 1]; window.__frames.push([performance.timeOrigin + performance.now(), last]); }
  }, 5);
  return 'recording';
})()"""
READY = "!!(window.Bokeh && Bokeh.documents.length && Bokeh.documents[0].get_model_by_name('traces'))"


class _DevTools:
    """A page's DevTools protocol (tornado's websocket client; tornado comes with bokeh)."""

    def __init__(self, ws_url):
        from tornado.ioloop import IOLoop
        from tornado.websocket import websocket_connect
        self.loop = IOLoop(make_current=False)
        self.conn = self.loop.run_sync(lambda: websocket_connect(ws_url), timeout=30)
        self.n = 0

    def evaluate(self, expression):
        self.n += 1
        mid = self.n

        async def call():
            await self.conn.write_message(json.dumps({"id": mid, "method": "Runtime.evaluate",
                                                      "params": {"expression": expression, "returnByValue": True}}))
            while True:
                reply = json.loads(await self.conn.read_message())
                if reply.get("id") == mid:
                    return reply["result"]["result"].get("value")
        return self.loop.run_sync(call, timeout=60)

    def close(self):
        self.conn.close()
        self.loop.close()


def _cpu_s(pid) -> float:
    """CPU time (user + system, s) of a process (Linux /proc)."""
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _tree_cpu_s(pid) -> float:
    """CPU time (s) of a process and every process below it that still lives (the browser's
    renderer, GPU and utility processes; Linux /proc)."""
    parent = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    parent[int(entry)] = int(fh.read().rsplit(")", 1)[1].split()[1])
            except OSError:
                pass
    tree, grew = {pid}, True
    while grew:
        below = {p for p, pp in parent.items() if pp in tree} - tree
        tree |= below
        grew = bool(below)
    total = 0.0
    for p in tree:
        try:
            total += _cpu_s(p)
        except OSError:          # ended meanwhile
            pass
    return total


class ScopePage:
    """The live scope of a run as the commands start it (hil.scope.server.ScopeProcess: the ring a
    shared mapping, the Bokeh server in its own process) with its page open in headless Chromium,
    streaming. ``loop_cpu``: the loop's CPU; the server and the browser go on the others; both
    ``nice`` steps nicer (the commands': hil.scope.server.SERVER_NICE)."""

    def __init__(self, loop_cpu=None, nice=SERVER_NICE, points=None):
        self.loop_cpu, self.nice = loop_cpu, nice
        self.points = points

    def __enter__(self):
        import shutil
        import tempfile
        import urllib.request

        from hil.scope.server import ScopeProcess
        chromium = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
        if chromium is None:
            raise SystemExit("--scope: no Chromium installed (Debian: apt-get install chromium)")
        self.server = ScopeProcess(loop_cpu=self.loop_cpu, nice=self.nice,
                                   **({"max_points": self.points} if self.points else {}))
        self.ring = self.server.ring
        url = self.server.start()
        self.profile = tempfile.mkdtemp(prefix="bench-scope-")
        port = _free_port()
        self.browser = subprocess.Popen([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                                         "--disable-background-networking", "--window-size=1400,1500",
                                         # a page in front, as on a person's screen: no timer throttling
                                         "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                                         "--disable-backgrounding-occluded-windows",
                                         f"--user-data-dir={self.profile}", f"--remote-debugging-port={port}", url],
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                        preexec_fn=_placed(server_cpus(self.loop_cpu), self.nice))
        end, ws = time.monotonic() + 60, None
        while ws is None and time.monotonic() < end:
            time.sleep(0.2)
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as r:
                    ws = next((p["webSocketDebuggerUrl"] for p in json.loads(r.read()) if "/scope" in p["url"]), None)
            except OSError:
                pass
        self.devtools = _DevTools(ws)
        while not self.devtools.evaluate(READY):
            if time.monotonic() > end:
                raise RuntimeError("the scope's page did not load in Chromium")
            time.sleep(0.2)
        self.devtools.evaluate(RECORDER)
        self.cpu0, self.wall0 = _cpu_s(self.server.proc.pid), time.monotonic()
        self.browser_cpu0 = _tree_cpu_s(self.browser.pid)
        return self

    def figures(self, res) -> dict:
        """After the run: the page's latency, frames per second, the server's CPU share."""
        cpu, wall = _cpu_s(self.server.proc.pid) - self.cpu0, time.monotonic() - self.wall0
        browser_cpu = _tree_cpu_s(self.browser.pid) - self.browser_cpu0
        time.sleep(1.0)                          # the last frames
        frames = json.loads(self.devtools.evaluate("JSON.stringify(window.__frames)"))
        walls = res["_walls"]
        run = [(now * 1e-3, int(round(t / res["period_s"]))) for now, t in frames if t <= res["seconds"]]
        lat = np.array([now - walls[i] for now, i in run if i < walls.size])
        return {"page_latency_p50_ms": float(np.percentile(lat, 50) * 1e3) if lat.size else None,
                "page_latency_p99_ms": float(np.percentile(lat, 99) * 1e3) if lat.size else None,
                "page_latency_max_ms": float(lat.max() * 1e3) if lat.size else None,
                "page_frames_per_s": len(run) / res["seconds"], "server_cpu_pct_of_one_core": 100.0 * cpu / wall,
                "browser_cpu_pct_of_one_core": 100.0 * browser_cpu / wall,
                "page_points_per_trace": self.server.max_points}

    def __exit__(self, *exc):
        import shutil
        self.devtools.close()
        _stop(self.browser, wait=10.0)
        self.server.stop()
        shutil.rmtree(self.profile, ignore_errors=True)


def _looped(cfg, seconds, spin, scope: bool, nice=SERVER_NICE, points=None) -> dict:
    """The loop, without or with the live scope's page open and streaming (server and browser
    ``nice`` steps nicer)."""
    if not scope:
        res = loop(cfg, seconds, spin)
    else:
        with ScopePage(cfg.get("runtime.loop_cpu"), nice, points) as page:
            res = loop(cfg, seconds, spin, ring=page.ring)
            res["period_s"] = 1.0 / res["rate_hz"]
            res.update(page.figures(res))
    res.pop("_walls")
    return res


def run_one(transport, rate, seconds, burner, spin, priority, cpu_latency="0us", scope=False, loop_cpu=None,
            nice=SERVER_NICE, drive_cpu=None, points=None, peer=False):
    period = f"{1000.0 / rate:g} ms"
    # start-up over SDO is not what is measured: a generous answer time, so that a loaded machine (the
    # burner, a test run beside it) does not abort the configuration before the cycle starts
    over = {"control.position_period": period, "runtime.priority": priority, "runtime.cpu_latency": cpu_latency,
            "canopen.sdo_timeout": "5 s"}
    if loop_cpu is not None:
        over["runtime.loop_cpu"] = loop_cpu
    load_before, steal_before, t_before = os.getloadavg(), steal_seconds(), time.monotonic()
    burn, drive, sim, drive_stats = None, None, None, {}
    try:
        if burner or peer:   # a peer takes the page's CPU share without the page: where and as nice as it runs
            burn = start_burner(seconds + 60.0, _placed(server_cpus(loop_cpu), nice) if peer else None)
            time.sleep(0.5)
        if transport == "virtual":
            import can

            from drivers.canopen.drive_sim import DriveSim
            over.update({"canopen.interface": "virtual", "canopen.channel": f"bench{os.getpid()}"})
            cfg = config.load(CONFIG, over)
            sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=over["canopen.channel"]), lockstep=False)
            res = _looped(cfg, seconds, spin, scope, nice, points)
            from hil.commands.drive_sim import answer_stats
            drive_stats = answer_stats(sim.answer_times)
        else:
            port = _free_port()
            drive = subprocess.Popen([sys.executable, "-m", "hil.cli", "drive-sim", "--config", str(CONFIG), "--set",
                                      f"control.position_period={period}", "--port", str(port), "--json",
                                      "--priority", str(priority), "--cpu-latency", str(cpu_latency)],
                                     cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                     env=dict(os.environ, PYTHONPATH=str(ROOT)),
                                     # the drive is another machine on a real axis: off the loop's CPU,
                                     # or (--drive-cpu) where it leaves the page's CPUs to the page
                                     preexec_fn=_placed({drive_cpu} if drive_cpu is not None
                                                        else server_cpus(loop_cpu)))
            if not drive.stdout.readline():               # the server is up
                raise RuntimeError("hil drive-sim did not start")
            over.update({"canopen.interface": "socketcand", "canopen.channel": "can0", "canopen.port": port})
            res = _looped(config.load(CONFIG, over), seconds, spin, scope, nice, points)
            _stop(drive)
            line = drive.stdout.readline()
            drive_stats = json.loads(line) if line.strip() else {}
    finally:
        if sim is not None:
            sim.close()
        _stop(drive)
        _stop(burn, wait=5.0)
    steal_after, wall = steal_seconds(), time.monotonic() - t_before
    steal = None if steal_before is None or steal_after is None else steal_after - steal_before
    res.update({"steal_s": steal, "steal_pct": None if steal is None else 100.0 * steal / (wall * (os.cpu_count() or 1)),
                "transport": ("virtual (in process)" if transport == "virtual" else "socketcand (drive-sim process)")
                + (" +scope" if scope else " +busy page CPU" if peer else ""), "scope": scope, "peer": peer,
                "load": "one core busy" if burner else "page CPU busy" if peer else "idle",
                "scope_nice": nice if scope else None, "peer_nice": nice if peer else None,
                "drive_answer_p50_us": drive_stats.get("answer_p50_us"),
                "drive_answer_p99_us": drive_stats.get("answer_p99_us"),
                "drive_answer_max_us": drive_stats.get("answer_max_us"),
                "load_average_before": [round(x, 2) for x in load_before],
                "load_average_after": [round(x, 2) for x in os.getloadavg()]})
    return res


def _table(results) -> str:
    head = (f"{'transport':31s} {'rate':>5s} {'load':13s} {'s':>5s} {'lateness p50/p99/max us':>24s} "
            f"{'no answer':>11s} {'run':>3s} {'trip':>4s} {'SYNC->ans p50/p99 us':>20s} {'drive p99':>9s} "
            f"{'goals':>5s} {'loadavg before/after':>21s} {'steal':>6s} {'stalls/behind':>13s}")
    rows = [head]
    for r in results:
        lat = f"{r['lateness_p50_us']:.0f}/{r['lateness_p99_us']:.0f}/{r['lateness_max_us']:.0f}"
        miss = f"{r['cycles_without_answer']}/{r['cycles']}"
        ans = f"{r['sync_to_answer_p50_us']:.0f}/{r['sync_to_answer_p99_us']:.0f}"
        drv = "-" if r["drive_answer_p99_us"] is None else f"{r['drive_answer_p99_us']:.0f}"
        goals = {True: "met", False: "NOT", None: "-"}[r.get("goals_met")]
        la = f"{r['load_average_before'][0]:.2f}/{r['load_average_after'][0]:.2f}"
        steal = "-" if r.get("steal_pct") is None else f"{r['steal_pct']:.1f}%"
        stalls = f"{r['host_stalls_over_1ms']}/{r['misses_behind_a_host_stall']}"
        rows.append(f"{r['transport']:31s} {r['rate_hz']:5d} {r['load']:13s} {r['seconds']:5.0f} {lat:>24s} "
                    f"{miss:>11s} {r['longest_miss_run']:3d} {'yes' if r['supervisor_would_trip'] else 'no':>4s} "
                    f"{ans:>20s} {drv:>9s} {goals:>5s} {la:>21s} {steal:>6s} {stalls:>13s}")
    return "\n".join(rows)


def _scope_line(without: dict, with_scope: dict) -> str:
    """The two runs of one setting side by side: the cycle's figures' ratio (with / without), the page's."""
    def ratio(key):
        a, b = without[key], with_scope[key]
        return f"{b / a:.2f}" if a else ("1.00" if b == a else "inf")
    w = with_scope
    ms = "/".join("-" if w[k] is None else f"{w[k]:.0f}" for k in ("page_latency_p50_ms", "page_latency_p99_ms",
                                                                    "page_latency_max_ms"))
    return (f"  scope: lateness p50/p99/max {ratio('lateness_p50_us')}/{ratio('lateness_p99_us')}/"
            f"{ratio('lateness_max_us')} x, cycles without answer {without['cycles_without_answer']} -> "
            f"{w['cycles_without_answer']}; page latency p50/p99/max {ms} ms, {w['page_frames_per_s']:.1f} frames/s, "
            f"server CPU {w['server_cpu_pct_of_one_core']:.1f} %, browser CPU {w['browser_cpu_pct_of_one_core']:.0f} % "
            f"of one core ({w['page_points_per_trace']} points a trace)")


NOISE_KEYS = ("lateness_p50_us", "lateness_p99_us", "lateness_max_us", "cycles_without_answer")
# a difference this small is none (a lateness under 1 us: the clock's own reading costs a tenth of it)
NOISE_FLOOR = {"lateness_p50_us": 1.0, "lateness_p99_us": 1.0, "lateness_max_us": 1.0, "cycles_without_answer": 0}


def noise(runs) -> dict:
    """One setting's repetitions (``--repeat``), per figure of :data:`NOISE_KEYS`: the values
    without and with the page, the spread (the largest of either side's largest minus smallest
    value: how much two runs of the same thing differ on this machine), the difference of the
    means (with minus without) and whether it is within the spread, or under :data:`NOISE_FLOOR`
    (None with one repetition)."""
    out = {}
    for key in NOISE_KEYS:
        a = [r[key] for r in runs if not r["scope"] and not r.get("peer")]
        b = [r[key] for r in runs if r["scope"]]
        c = [r[key] for r in runs if r.get("peer")]
        spread = max(max(a) - min(a), max(b) - min(b)) if min(len(a), len(b)) > 1 else None
        diff = float(np.mean(b) - np.mean(a))
        out[key] = {"without": a, "with": b, "spread": spread, "difference": diff,
                    "within_noise": None if spread is None else bool(abs(diff) <= max(spread, NOISE_FLOOR[key]))}
        if c:                # --peer: the same CPU taken by a plain process instead of the page
            out[key].update({"peer": c, "difference_to_peer": float(np.mean(b) - np.mean(c))})
    return out


def _noise_lines(summary) -> list[str]:
    def f(x):
        return f"{x:.0f}" if abs(x) >= 10 or x == int(x) else f"{x:.1f}"
    lines = []
    for key, s in summary.items():
        verdict = {True: "within the noise", False: "BEYOND the noise", None: "-"}[s["within_noise"]]
        lines.append(f"  {key:22s} without {', '.join(map(f, s['without']))} | with {', '.join(map(f, s['with']))}"
                     f" | spread {'-' if s['spread'] is None else f(s['spread'])} | with - without "
                     f"{s['difference']:+.1f}: {verdict}"
                     + (f" | busy page CPU without the page {', '.join(map(f, s['peer']))}, with - busy "
                        f"{s['difference_to_peer']:+.1f}" if "peer" in s else ""))
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--transport", default="both", choices=("virtual", "socketcand", "both"),
                    help="virtual (drive in this process), socketcand (drive in its own process) or both (default)")
    ap.add_argument("--rate", default="250,1000", help="cycle rates in Hz, comma-separated (default 250,1000)")
    ap.add_argument("--duration", type=float, default=None, metavar="S",
                    help="seconds per run (default: 600 at 250 Hz, 60 at 1 kHz)")
    ap.add_argument("--burner", action="store_true", help="each run also with one core kept busy by another process")
    ap.add_argument("--burner-only", action="store_true", help="only the runs with one core busy")
    ap.add_argument("--all", action="store_true",
                    help="the full protocol: both transports, 250 Hz for 600 s and 1 kHz for 60 s, idle and with "
                         "one core busy (about 45 minutes)")
    ap.add_argument("--spin", type=float, default=None, metavar="S",
                    help="the clock's final spin before each deadline (default: hil.loop.RealTimeClock's, 5 %% of "
                         "the period, at most 200 us)")
    ap.add_argument("--priority", type=int, default=0,
                    help="runtime.priority: SCHED_FIFO priority of the loop thread (0 = normal scheduling)")
    ap.add_argument("--cpu-latency", default="0us", metavar="TIME",
                    help="with --priority: runtime.cpu_latency of the loop and hil drive-sim --cpu-latency, the CPUs' "
                         "wake-up latency held during the run (default 0us: idle CPUs poll; inf: no request)")
    ap.add_argument("--scope", action="store_true",
                    help="each run without and then with the live scope's page open and streaming (headless "
                         "Chromium): both, their ratio, the page's latency, frames per second, the server's CPU")
    ap.add_argument("--repeat", type=int, default=1, metavar="N",
                    help="with --scope: each pair (without, with the page) N times, interleaved, and the spread "
                         "between repetitions as the noise (default 1)")
    ap.add_argument("--peer", action="store_true",
                    help="with --scope: each repetition also without the page but with one CPU-bound process where "
                         "its server and browser would run (as nice): how much any work there moves the loop's "
                         "figures on this machine, the peer of the page's difference")
    ap.add_argument("--loop-cpu", type=int, default=None, metavar="N",
                    help="runtime.loop_cpu: the loop's thread pinned to CPU N; the scope's server, the browser and "
                         "the drive's process on the other CPUs (server and browser niced)")
    ap.add_argument("--drive-cpu", type=int, default=None, metavar="N",
                    help="socketcand: the drive's process on CPU N (default: the CPUs other than --loop-cpu). "
                         "With --loop-cpu N on a 2-CPU machine, --drive-cpu N leaves the other CPU to the page, "
                         "as on a real axis, where the drive is another machine")
    ap.add_argument("--nice", type=int, default=SERVER_NICE, metavar="N",
                    help=f"with --scope: how much nicer the scope's server and the browser run (default {SERVER_NICE}, "
                         f"as the commands start the server; 0: at the loop process's own niceness)")
    ap.add_argument("--points", type=int, default=None, metavar="N",
                    help="with --scope: the page's points per trace at most (default: the commands' "
                         "hil.scope.server.ScopeProcess max_points)")
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    args = ap.parse_args(argv)
    if args.all:
        args.transport, args.rate, args.duration, args.burner = "both", "250,1000", None, True
    if args.peer and (not args.scope or args.burner or args.burner_only):
        ap.error("--peer: with --scope, and without --burner or --all (the peer's process is the one busy CPU)")
    if args.points is not None and (args.points < 2 or not args.scope):
        ap.error(f"--points {args.points}: with --scope, 2 or more")
    transports = ("virtual", "socketcand") if args.transport == "both" else (args.transport,)
    loads = (True,) if args.burner_only else (False, True) if args.burner else (False,)
    spin = args.spin                 # None: the clock's default for the period
    if args.repeat < 1:
        ap.error(f"--repeat {args.repeat}: expected 1 or more")
    try:
        check_loop_cpu(args.loop_cpu, "--loop-cpu")
        check_loop_cpu(args.drive_cpu, "--drive-cpu")
    except ConfigError as exc:         # one line, no traceback
        ap.error(str(exc))
    if args.drive_cpu is not None and args.transport != "socketcand":
        ap.error("--drive-cpu: the drive has a process of its own only with --transport socketcand")
    results, summaries = [], []
    for rate in (int(float(r)) for r in args.rate.split(",")):
        seconds = args.duration if args.duration is not None else DEFAULT_SECONDS.get(rate, 60.0)
        for transport in transports:
            for burner in loads:
                first = len(results)
                for repetition in range(args.repeat if args.scope else 1):
                    kinds = ((False, True) + (("peer",) if args.peer else ())) if args.scope else (False,)
                    for kind in kinds:
                        results.append(run_one(transport, rate, seconds, burner, spin, args.priority,
                                               args.cpu_latency, kind is True, args.loop_cpu, args.nice,
                                               args.drive_cpu, args.points, peer=kind == "peer"))
                        results[-1]["repetition"] = repetition
                        if not args.json:
                            print(_table(results[-1:]).splitlines()[-1] if len(results) > 1 else _table(results[-1:]),
                                  flush=True)
                    if args.scope and not args.json:
                        print(_scope_line(*[r for r in results[-len(kinds):] if not r["peer"]]), flush=True)
                if args.scope and args.repeat > 1:
                    summaries.append({"transport": transport, "rate_hz": rate, "burner": burner,
                                      "noise": noise(results[first:])})
                    if not args.json:
                        print(f"  {args.repeat} repetitions; the noise: the spread of two runs of the same "
                              f"thing", flush=True)
                        print("\n".join(_noise_lines(summaries[-1]["noise"])), flush=True)
    info = {"cpus": os.cpu_count(), "switch_interval_s": sys.getswitchinterval(), "priority": args.priority,
            "kernel": os.uname().release, "loop_cpu": args.loop_cpu, "drive_cpu": args.drive_cpu,
            "scope_nice": args.nice}
    if args.json:
        print(json.dumps({"machine": info, "results": results, "scope_noise": summaries}, indent=2))
    else:
        print(f"{info['cpus']} CPUs, kernel {info['kernel']}; run: longest run of consecutive cycles without "
              f"their answer; trip: the supervisor would have tripped (canopen.pdo_miss_limit); drive p99: the "
              f"drive's own SYNC-to-answer; stalls/behind: wake-ups of the loop over 1 ms late, misses within 5 cycles "
              f"behind one; spin (us) " + ", ".join(f"{r['spin_us']:.0f}" for r in results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
