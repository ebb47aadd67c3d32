"""Achievable cycle rate of the serial backend over a pseudo-terminal, and the rate computed for real
baud rates from the bytes each cycle exchanges.

A cycle is two transactions (``read`` and ``set_position``), each a command line and a reply line.
A pseudo-terminal has no baud rate: what it measures is the host's and the simulated drive's
processing and scheduling. On a real line each byte costs (1 start + 8 data + parity + stop bits)
/ baud seconds, and the drive needs some time to answer each command (``--turnaround``).

    python benchmarks/bench_serial.py [--config config/serial_ascii_example.toml] [--cycles 3000]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.base import Setpoint  # noqa: E402
from drivers.serial.backend import SerialBackend  # noqa: E402
from drivers.serial.drive_sim import SimulatedSerialDrive  # noqa: E402
from drivers.serial.protocol import CommandSet, render_reply  # noqa: E402
from hil.config import load  # noqa: E402
from hil.plant_config import plant_from_config


def bytes_per_cycle(cs: CommandSet, worst: bool) -> int:
    """Bytes of one cycle's two transactions: typical values, or the widest the drive may send
    (positions of 10 digits and a sign)."""
    big = -1_000_000_000 if worst else 1_234_567
    out = len(cs.encode("read")) + len(cs.encode("set_position", position=big))
    fb = dict(x_motor=big, x_table=big, v_motor=big if worst else -12_345, output=-30000 if worst else 1234, fault=0)
    inp = len(cs.frame(render_reply(cs.replies["read"], fb))) + \
        len(cs.frame(render_reply(cs.replies["set_position"], {"echo": big})))
    return out + inp


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="config/serial_ascii_example.toml")
    ap.add_argument("--cycles", type=int, default=3000)
    ap.add_argument("--turnaround", type=float, default=200e-6,
                    help="drive response latency per command, s (default 200 us; see the drive's manual)")
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args(argv)
    cfg = load(args.config)
    cs = CommandSet.from_config(cfg)
    with SimulatedSerialDrive(cfg, plant_from_config(cfg), advance="setpoint") as drive:
        b = SerialBackend(cfg, port=drive.port, timeout=0.1, budget=0.3, free_run=True)
        b.open()
        b.enable()
        dt = np.empty(args.cycles)
        dr = np.empty(args.cycles)
        x = 0.0
        for k in range(args.cycles):
            t0 = time.perf_counter()
            b.read_feedback()
            t1 = time.perf_counter()
            b.write_setpoint(Setpoint(position=x))       # the simulated drive steps its plant (64 substeps)
            dt[k] = time.perf_counter() - t0
            dr[k] = t1 - t0
            x += 1e-7
        stats = b.stats.as_dict()
        b.disable()
        b.close()
    measured_bpc = (stats["bytes_in"] + stats["bytes_out"]) / stats["transactions"] * 2
    bits = 1 + 8 + (0 if cfg.get("serial.parity", "N") == "N" else 1) + int(cfg.get("serial.stopbits", 1))
    res = {"pty": {"cycles": args.cycles, "rate_hz": float(1 / dt.mean()), "cycle_p50_us": float(np.median(dt) * 1e6),
                   "cycle_p99_us": float(np.percentile(dt, 99) * 1e6), "cycle_max_us": float(dt.max() * 1e6),
                   "read_p50_us": float(np.median(dr) * 1e6), "read_p99_us": float(np.percentile(dr, 99) * 1e6),
                   "bytes_per_cycle": measured_bpc, "retries": stats["retries"]},
           "bits_per_byte": bits, "turnaround_s": args.turnaround, "baud": {}}
    for worst in (False, True):
        n = bytes_per_cycle(cs, worst)
        for baud in (9600, 115200, 1_000_000):
            wire = n * bits / baud
            t = wire + 2 * args.turnaround
            res["baud"].setdefault(str(baud), {})["worst" if worst else "typical"] = {
                "bytes": n, "wire_ms": wire * 1e3, "cycle_ms": t * 1e3, "rate_hz": 1 / t}
    print(f"pseudo-terminal: {res['pty']['rate_hz']:.0f} cycles/s (p50 {res['pty']['cycle_p50_us']:.0f} us, "
          f"p99 {res['pty']['cycle_p99_us']:.0f} us, max {res['pty']['cycle_max_us']:.0f} us), "
          f"{measured_bpc:.0f} bytes/cycle measured; read transaction alone p50 {res['pty']['read_p50_us']:.0f} us, "
          f"p99 {res['pty']['read_p99_us']:.0f} us")
    print(f"computed ({bits} bits/byte, {args.turnaround * 1e6:.0f} us turnaround per command):")
    print("     baud   bytes   wire ms  cycle ms   max rate Hz   (typical / worst-case widths)")
    for baud, r in res["baud"].items():
        for w in ("typical", "worst"):
            v = r[w]
            print(f"  {int(baud):>7d}  {v['bytes']:>6d}  {v['wire_ms']:8.2f}  {v['cycle_ms']:8.2f}  {v['rate_hz']:10.1f}"
                  f"   {w}")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
