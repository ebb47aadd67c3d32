"""Start-up time of the command line: ``hil --help`` and ``hil model --config config/paper_bench.toml``.

Each is timed as N fresh processes of this Python running what the ``hil`` console script runs
(``from hil.cli import main``), with this tree first on the path; the median is reported beside
the median of a peer measured in the same run, ``python -c pass`` (the interpreter's own start-up),
and the load average, since the machine is shared. One untimed run first fills the bytecode and
numba caches: the times are those of a warm cache. Targets (issue 12): --help under 0.3 s, model
under 1 s.

    python benchmarks/bench_startup.py [-n 9] [--json]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HIL = ["-c", "import sys; from hil.cli import main; sys.exit(main())"]


def time_runs(args: list[str], n: int, env: dict) -> list[float]:
    """Wall times (s) of ``n`` fresh processes ``python ARGS``; fails on a non-zero exit."""
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, *args], env=env, cwd=ROOT, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return times


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", type=int, default=9, help="processes per command (default 9)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
               MPLBACKEND="Agg")
    # the warm cache the figures claim: a machine that sets PYTHONDONTWRITEBYTECODE would compile
    # every module of the tree again in each timed process (0.1 s of `hil model`)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    with tempfile.TemporaryDirectory() as out:
        cases = {"peer: python -c pass": ["-c", "pass"],
                 "hil --help": [*HIL, "--help"],
                 "hil model --config config/paper_bench.toml": [*HIL, "model", "--config", "config/paper_bench.toml",
                                                                "--out", out]}
        for args in cases.values():          # warm the caches (bytecode, numba, matplotlib's fonts)
            time_runs(args, 1, env)
        load_before = os.getloadavg()
        med = {name: statistics.median(time_runs(args, a.n, env)) for name, args in cases.items()}
        load_after = os.getloadavg()
    peer = med["peer: python -c pass"]
    result = {"n": a.n, "median_s": med, "ratio_to_peer": {k: v / peer for k, v in med.items()},
              "load_average_1min": [load_before[0], load_after[0]], "cpus": os.cpu_count(),
              "python": sys.version.split()[0]}
    if a.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"start-up, median of {a.n} fresh processes (Python {result['python']}, {result['cpus']} CPUs, "
          f"load average {load_before[0]:.2f} -> {load_after[0]:.2f})")
    for name, t in med.items():
        print(f"  {name:45s} {t:7.3f} s   {t / peer:6.1f} x peer")
    return 0


if __name__ == "__main__":
    sys.exit(main())
