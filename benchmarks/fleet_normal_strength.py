#!/usr/bin/env python3
"""A fleet as issue 53 describes it, from the independent simulator (tests/independent/plant_ivp,
which shares no code with the project's kernel), run through ``hil fleet run`` with the default
options (no ``--track``): does the fleet see a normal effect grow?

Four axes A-D, five weekly nights, every mass, stiffness and damping scattered by 1 % from night to
night, Coulomb friction 0.3 N m and backlash 4 um (scattered too) on every axis; axis B's friction
rises 0.3 -> 0.3 -> 0.9 -> 1.5 -> 2.2 N m. The chain names the friction on every night of B, so it
is B's normal; its strength must still be judged.

A second fleet (``--fleet second``, other seeds, dates and places): P's backlash 4 -> 9 -> 14 um
from night 4; a torque ripple of 0.3 N m (period 5 mm) appears on Q on night 4; R has a weak
ripple (0.05 N m) every night; S is steady with a friction of 0.6 N m. No axis but P and Q may be
flagged, each in its own effect on night 4.

    python benchmarks/fleet_normal_strength.py --out out/fleet53              (the defaults: every candidate)
    python benchmarks/fleet_normal_strength.py --out out/fleet53b --fleet second
    python benchmarks/fleet_normal_strength.py --out out/fleet53 --candidates backlash,coulomb_friction,viscous_friction --max-steps 2

Prints each axis's verdict, its normal and the strengths judged (the chain's values per night),
the time of the run and the machine's load. Quote them with the command and the load.
"""
from __future__ import annotations

import argparse
import datetime as dt
import hashlib
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "independent"))

LEVELS = {"B": [0.3, 0.3, 0.9, 1.5, 2.2], "S": [0.6] * 5}       # N m per night; every other axis 0.3
GAPS = {"P": [4e-6, 4e-6, 4e-6, 9e-6, 14e-6]}                     # m per night; every other axis 4 um
RIPPLES = {"Q": [0, 0, 0, 0.3, 0.3], "R": [0.05] * 5}             # N m per night (period 5 mm)
STEADY_LEVEL, GAP, SCATTER, NIGHTS = 0.3, 4e-6, 0.01, 5
FLEETS = {"first": ("ABCD", dt.date(2026, 3, 2), ""), "second": ("PQRS", dt.date(2026, 5, 4), "f54|")}


def _record(args):
    import numpy as np
    import plant_ivp as ivp

    from hil.config import load
    from hil.io.measurement import write
    out, axis, night, fleet = args
    bench = ivp.bench_from_config(load(ROOT / "config" / "paper_bench.toml"))
    _, start, salt = FLEETS[fleet]
    date = (start + dt.timedelta(days=7 * night)).isoformat()
    seed = int.from_bytes(hashlib.sha256(f"{salt}{axis}|{date}".encode()).digest()[:4], "little")
    b, scattered = ivp.scattered(bench, np.random.default_rng(seed), SCATTER)
    level, gap = scattered(LEVELS.get(axis, [STEADY_LEVEL] * NIGHTS)[night]), scattered(GAPS.get(axis, [GAP] * NIGHTS)[night])
    amp = RIPPLES.get(axis, [0] * NIGHTS)[night]
    ripple = ((scattered(amp), 0.005, 0.7),) if amp else ()
    x = ivp.command_sequence(2.0, bench.tp, seed=0)
    ch = ivp.measure(ivp.simulate(b, x, ivp.Hidden(coulomb_pos=level, coulomb_neg=level, gap=gap, ripple=ripple)),
                     seed % 100000)
    write(Path(out) / f"{axis}_{date}.csv", ch, {"sample_period": f"{bench.tp:g} s", "source": "plant_ivp"})


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/fleet53", help="folder of the records and of the run")
    ap.add_argument("--candidates", default=None, help="hil fleet run's --candidates (default: every one)")
    ap.add_argument("--max-steps", default=None, help="hil fleet run's --max-steps (default: its own)")
    ap.add_argument("--fleet", choices=sorted(FLEETS), default="first", help="which fleet (see above)")
    args = ap.parse_args()
    out = Path(args.out)
    records = out / "records"
    if not records.is_dir():
        records.mkdir(parents=True)
        with ProcessPoolExecutor(2) as pool:
            list(pool.map(_record, [(str(records), a, n, args.fleet) for a in FLEETS[args.fleet][0]
                                    for n in range(NIGHTS)]))
    argv = [sys.executable, "-m", "hil.cli", "fleet", "run", str(records), "--config",
            str(ROOT / "config" / "paper_bench.toml"), "--out", str(out / "run"), "--json"]
    if args.candidates:
        argv += ["--candidates", args.candidates]
    if args.max_steps:
        argv += ["--max-steps", args.max_steps]
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    r = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        print(r.stderr, file=sys.stderr)
        return r.returncode
    run = json.loads(r.stdout)
    print(f"{run['records']} records in {wall:.0f} s (load average {load0:.2f} at the start, "
          f"{os.getloadavg()[0]:.2f} at the end); errors: {len(run['errors'])}")
    for a in run["axes"]:
        print(f"{a['axis']}: {a['verdict']} (normal: {', '.join(a['normal']) or 'none'})")
        for name, p in a["params"].items():
            print(f"    {name} ({p.get('source', 'tracked')}): {', '.join(f'{v:.4g}' for v in p['values'])}"
                  f"{'  flagged since ' + p['first_moved'] if p['flagged'] else ''}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
