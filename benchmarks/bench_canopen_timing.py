"""Cycle timing of the CANopen backend against the simulated CiA 402 drive, on the real-time clock:
lateness p50/p99/max, missed cycles (overruns, and SYNCs without their TPDO answer), the SYNC-to-
answer time (SYNC sent -> whole TPDO answer taken) and the SYNC-to-setpoint latency (SYNC k ->
RPDO k+1 computed from its answer), at 1 kHz and 250 Hz.

Two transports: the in-process virtual bus (the drive shares the interpreter with the loop) and a
separate process (``hil drive-sim``) over python-can's socketcand interface on 127.0.0.1.

    python benchmarks/bench_canopen_timing.py --seconds 60
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.base import Setpoint  # noqa: E402
from drivers.canopen.backend import CanopenBackend  # noqa: E402
from hil import config  # noqa: E402
from hil.loop import RealTimeClock  # noqa: E402


def _pct(a, q):
    return float(np.percentile(a, q) * 1e6) if len(a) else float("nan")


def run(cfg, seconds, transport):
    be = CanopenBackend(cfg, lockstep=False)
    be.open()
    be.enable()
    clock = RealTimeClock(be.cycle_time, priority=cfg.get("runtime.priority", 0))
    n = int(round(seconds / be.cycle_time))
    pos = be.read_feedback().x_motor
    clock.start()
    try:
        for _ in range(n):
            fb = be.read_feedback()
            be.write_setpoint(Setpoint(position=pos))
            be.sync()
            clock.wait()
    finally:
        clock.stop()
    be.disable()
    be.close()
    lat = np.array(clock.lateness)
    ans = np.array(be.answer_latency)
    spl = np.array(be.setpoint_latency[1:])
    return {"transport": transport, "rate_hz": round(1 / be.cycle_time), "cycles": n,
            "lateness_p50_us": _pct(lat, 50), "lateness_p99_us": _pct(lat, 99), "lateness_max_us": float(lat.max() * 1e6),
            "overruns": clock.overruns, "syncs_without_answer": be.missed_total, "late_answers": be.late_total,
            "sync_to_answer_p50_us": _pct(ans, 50), "sync_to_answer_p99_us": _pct(ans, 99),
            "sync_to_setpoint_p50_us": _pct(spl, 50), "sync_to_setpoint_p99_us": _pct(spl, 99),
            "last_fault": fb.fault}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0, help="per rate and transport (default 60)")
    ap.add_argument("--rates", default="1000,250", help="cycle rates in Hz (default 1000,250)")
    ap.add_argument("--transports", default="virtual,socketcand", help="virtual, socketcand or both (default)")
    ap.add_argument("--switch-interval", type=float, default=None, metavar="S",
                    help="sys.setswitchinterval in the host (and drive) process; default: the backend's choice")
    ap.add_argument("--priority", type=int, default=0,
                    help="runtime.priority: SCHED_FIFO priority of the loop thread (0 = normal scheduling)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.switch_interval is not None:
        sys.setswitchinterval(args.switch_interval)
    transports = args.transports.split(",")
    results = []
    load = [os.getloadavg()]
    for period in [f"{1000.0 / float(r):g} ms" for r in args.rates.split(",")]:
        over = {"control.position_period": period, "canopen.interface": "virtual", "canopen.channel": "bench",
                "runtime.priority": args.priority}
        cfg = config.load(ROOT / "config/paper_bench_canopen.toml", over)
        import can

        from drivers.canopen.drive_sim import DriveSim
        if "virtual" in transports:
            sim = DriveSim(cfg, bus=can.Bus(interface="virtual", channel="bench"), lockstep=False)
            try:
                results.append(run(cfg, args.seconds, "virtual (in process)"))
            finally:
                sim.close()
            load.append(os.getloadavg())
        if "socketcand" not in transports:
            continue
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "drive-sim", "--config",
                                 str(ROOT / "config/paper_bench_canopen.toml"), "--set",
                                 f"control.position_period={period}", "--port", str(port), "--json"]
                                + ([] if args.switch_interval is None else ["--switch-interval", str(args.switch_interval)]),
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                env=dict(os.environ, PYTHONPATH=str(ROOT)))
        try:
            proc.stdout.readline()                      # the server is up
            over.update({"canopen.interface": "socketcand", "canopen.channel": "can0", "canopen.port": port})
            results.append(run(config.load(ROOT / "config/paper_bench_canopen.toml", over), args.seconds,
                               "socketcand (separate process)"))
        finally:
            proc.terminate()
            proc.wait(5)
        load.append(os.getloadavg())
    info = {"load_average_1_5_15min": [tuple(round(x, 2) for x in l) for l in load], "cpus": os.cpu_count(),
            "switch_interval_s": sys.getswitchinterval()}
    if args.json:
        print(json.dumps({"machine": info, "results": results}, indent=2))
    else:
        print(f"{'transport':30s} {'rate':>5s} {'p50 us':>8s} {'p99 us':>8s} {'max us':>9s} {'overruns':>8s} "
              f"{'no answer':>9s} {'late':>5s} {'SYNC->ans p50/p99 us':>21s} {'SYNC->setpoint p50 us':>21s}")
        for r in results:
            print(f"{r['transport']:30s} {r['rate_hz']:5d} {r['lateness_p50_us']:8.1f} {r['lateness_p99_us']:8.1f} "
                  f"{r['lateness_max_us']:9.1f} {r['overruns']:8d} {r['syncs_without_answer']:9d} {r['late_answers']:5d} "
                  f"{r['sync_to_answer_p50_us']:10.0f}/{r['sync_to_answer_p99_us']:<10.0f} {r['sync_to_setpoint_p50_us']:21.0f}")
        print(f"{info['cpus']} CPUs; load average (1/5/15 min) before and after each run: "
              + ", ".join("/".join(f"{x:.2f}" for x in l) for l in info["load_average_1_5_15min"])
              + f"; switch interval {info['switch_interval_s'] * 1e6:.0f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
