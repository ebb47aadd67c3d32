"""``hil compare`` on long records (issue 18: it was quadratic in the record's length, 10^5 rows
20 s, 10^6 rows over 15 min, through np.correlate's full correlation for a +-200-sample window).

Prints the cross-correlation of the new way (hil.ident.residual.xcorr: a dot product per lag over
the window) against the old one (np.correlate, mode "full") measured in the same run on sizes the
old one finishes, then ``hil compare`` end to end on a synthetic record of ``--rows`` rows (10^6
by default) in a fresh process, with the load average before and after.

    python benchmarks/bench_compare.py [--rows 1000000]
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hil.config import load  # noqa: E402
from hil.ident.residual import xcorr  # noqa: E402
from hil.ident.synth import synthesize  # noqa: E402
from hil.io.measurement import write  # noqa: E402


def load_avg() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def old_xcorr(a, b, maxlag):
    a = (a - a.mean()) / (a.std() or 1.0)
    b = (b - b.mean()) / (b.std() or 1.0)
    n = a.size
    full = np.correlate(a, b, mode="full") / n
    return full[n - 1 - maxlag:n + maxlag]


def best_of(f, repeat=3):
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=1_000_000)
    a = ap.parse_args()
    print(load_avg())
    rng = np.random.default_rng(0)
    print("cross-correlation, +-200 lags (best of 3):")
    for n in (10_000, 30_000, 100_000):
        x, y = rng.normal(size=n), rng.normal(size=n)
        t_new = best_of(lambda: xcorr(x, y, 200))
        t_old = best_of(lambda: old_xcorr(x, y, 200), 1)
        print(f"  {n:>9d} samples: windowed {t_new * 1e3:8.2f} ms   np.correlate full {t_old * 1e3:10.1f} ms   "
              f"ratio {t_old / t_new:7.0f}")
    n = 1_000_000
    x, y = rng.normal(size=n), rng.normal(size=n)
    print(f"  {n:>9d} samples: windowed {best_of(lambda: xcorr(x, y, 200)) * 1e3:8.2f} ms   (np.correlate: not run)")
    cfg = load(ROOT / "config" / "paper_bench.toml")
    with tempfile.TemporaryDirectory() as tmp:
        ch, _ = synthesize(cfg, None, duration=a.rows * 4e-3, seed=1)
        rec = write(Path(tmp) / "long.csv", ch)
        env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main())", "compare",
                        str(rec), "--config", str(ROOT / "config" / "paper_bench.toml"), "--out", str(Path(tmp) / "o")],
                       check=True, env=env, stdout=subprocess.DEVNULL)
        print(f"hil compare, {ch['t'].size} rows, end to end: {time.perf_counter() - t0:.1f} s")
    print(load_avg())


if __name__ == "__main__":
    main()
