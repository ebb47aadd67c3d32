"""Benchmark: a 40-point jerk sweep of the paper's 590 mm move (15 m/min, 1..2000 m/s^3, log-spaced)
on config/paper_bench.toml, mechatronic analysis, recorded every 0.5 ms, 1 s dwell.

Wall time of the parallel sweep (all cores, process pool started inside the timing) against a
serial run of the same 40 moves in this process, both after compilation (the numba cache is
loaded by a warm-up first). Prints one line per repeat and the best of each.

  python benchmarks/bench_sweep.py [--repeat 5] [--jobs N]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil.config import load  # noqa: E402
from hil.sweep import SweepSettings, jerk_grid, run_sweep, warm_up  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--jobs", type=int, default=os.cpu_count())
    a = ap.parse_args()
    cfg = load(Path(__file__).resolve().parents[1] / "config" / "paper_bench.toml")
    s = SweepSettings(stroke=0.59, feed=0.25, values=jerk_grid(1.0, 2000.0, 40), by="j_max", g0=0.5,
                      dwell=1.0, record_every=8)
    t0 = time.perf_counter()
    warm_up(cfg, ["mechatronic"])
    print(f"warm-up (compile or load the numba cache, build the model): {time.perf_counter() - t0:.2f} s")
    par, ser = [], []
    ref = None
    for i in range(a.repeat):
        t0 = time.perf_counter()
        r = run_sweep(cfg, s, jobs=a.jobs, progress=False, propose=False)
        par.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        r1 = run_sweep(cfg, s, jobs=1, progress=False, propose=False)
        ser.append(time.perf_counter() - t0)
        assert r["runs"] == r1["runs"], "parallel and serial sweeps differ"
        ref = r
        print(f"repeat {i + 1}: parallel ({a.jobs} processes) {par[-1]:.3f} s, serial {ser[-1]:.3f} s")
    print(f"40-point sweep, 590 mm at 15 m/min, {len(ref['runs'])} runs: best parallel {min(par):.3f} s "
          f"on {a.jobs} processes ({os.cpu_count()} cores), best serial {min(ser):.3f} s, "
          f"speed-up {min(ser) / min(par):.2f}x; target < 2 s: {'met' if min(par) < 2.0 else 'MISSED'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
