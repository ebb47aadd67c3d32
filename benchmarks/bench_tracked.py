"""Accuracy and time of the fleet's tracked fit (hil.ident.tracking.fit_tracked: the tracked effects
on the night's plant) against its peer, the same effects fitted on the config's plant (its stage 1,
what ``hil fleet`` did before), on records of the independent simulator (tests/independent/
plant_ivp.py, solve_ivp, no code of this project).

Each record: the paper bench with a backlash (total play drawn from 3 to 15 um) and a Coulomb
friction (1 to 2.5 N m), every mass, stiffness and damping scattered by ``--scatter`` (normal,
relative), the same test move of ``--duration`` (a nightly check repeats one program); seeded by
its number. Printed per record: the truth, both fits and their times (one thread, as a fleet's
pool worker runs); then the median and largest relative errors of each, and the load average.

    python benchmarks/bench_tracked.py                          # records 10 to 36, 2 s, 1.5 % scatter
    python benchmarks/bench_tracked.py --first 0 --n 8 --duration 6s --json
"""
import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "independent"))

import plant_ivp as ivp  # noqa: E402

from hil.config import load  # noqa: E402
from hil.ident import Replay  # noqa: E402
from hil.ident.tracking import _greedy, fit_tracked  # noqa: E402
from hil.io.measurement import Measurement  # noqa: E402
from hil.simulate import batches_on_this_thread  # noqa: E402
from hil.units import parse_option  # noqa: E402

TRACK = ["backlash", "coulomb_friction"]
KEYS = {"backlash.gap": "gap", "coulomb_friction.level": "level"}


def load_avg() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def record(seed: int, duration: float, scatter: float, cfg):
    """One night: (measurement, truth {effect.param: value})."""
    bench = ivp.bench_from_config(cfg)
    rng = np.random.default_rng(seed)
    gap, level = rng.uniform(3e-6, 15e-6), rng.uniform(1.0, 2.5)
    night = bench.changed(**{k: tuple(v * (1.0 + scatter * rng.standard_normal()) for v in getattr(bench, k))
                             for k in "mkc"})
    x = ivp.command_sequence(duration, bench.tp, seed=0)
    ch = ivp.measure(ivp.simulate(night, x, ivp.Hidden(coulomb_pos=level, coulomb_neg=level, gap=gap)), seed)
    return Measurement(ch, source="plant_ivp"), {"backlash.gap": gap, "coulomb_friction.level": level}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--first", type=int, default=10, help="the first record's number (its seed)")
    ap.add_argument("--n", type=int, default=27, help="records")
    ap.add_argument("--duration", default="2s")
    ap.add_argument("--scatter", type=float, default=0.015, help="relative scatter of every m, k, c")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    cfg = load(ROOT / "config" / "paper_bench.toml")
    duration = parse_option(args.duration, "time", "--duration")
    rows = []
    before = load_avg()
    with batches_on_this_thread():
        for seed in range(args.first, args.first + args.n):
            meas, truth = record(seed, duration, args.scatter, cfg)
            t0 = time.perf_counter()
            peer, _ = _greedy(Replay(meas, cfg), TRACK, 40)
            t1 = time.perf_counter()
            got, _ = fit_tracked(Replay(meas, cfg), TRACK)
            t2 = time.perf_counter()
            row = {"record": seed, "truth": truth, "tracked": {k: got[k] for k in truth},
                   "config_plant": {k: peer[k] for k in truth}, "tracked_s": t2 - t1, "config_plant_s": t1 - t0}
            rows.append(row)
            if not args.json:
                print(f"{seed:3d}  " + "  ".join(
                    f"{KEYS[k]} {truth[k]:.4g}: {got[k]:.4g} ({100 * (got[k] / truth[k] - 1):+.1f} %) against "
                    f"{peer[k]:.4g} ({100 * (peer[k] / truth[k] - 1):+.0f} %)" for k in truth)
                      + f"  {t2 - t1:.1f} s against {t1 - t0:.1f} s", flush=True)

    def errors(which, k):
        return np.array([abs(r[which][k] / r["truth"][k] - 1.0) for r in rows])
    summary = {KEYS[k]: {w: {"median": float(np.median(errors(w, k))), "max": float(np.max(errors(w, k)))}
                         for w in ("tracked", "config_plant")} for k in KEYS}
    times = {w: float(np.median([r[f"{w}_s"] for r in rows])) for w in ("tracked", "config_plant")}
    after = load_avg()
    if args.json:
        print(json.dumps({"records": rows, "errors": summary, "median_s": times, "load_before": before,
                          "load_after": after, "duration_s": duration, "scatter": args.scatter}, indent=1))
        return 0
    for k, s in summary.items():
        print(f"{k}: relative error median {100 * s['tracked']['median']:.1f} %, largest {100 * s['tracked']['max']:.1f} %"
              f" (on the config's plant: {100 * s['config_plant']['median']:.0f} %, "
              f"{100 * s['config_plant']['max']:.0f} %)")
    print(f"median time {times['tracked']:.1f} s against {times['config_plant']:.1f} s "
          f"({times['tracked'] / times['config_plant']:.1f} x); {before} before, {after} after")
    return 0


if __name__ == "__main__":
    sys.exit(main())
