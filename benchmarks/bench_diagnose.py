"""Time to diagnose a 12 s record (4 ms samples) against the whole catalogue (issue 5: < 30 s).

Prints, beside the figures, the load average (1, 5, 15 min) before and after: on a busy machine
the figure means little. Two figures: ``diagnose()`` in this process (the compiled loop already
loaded), and the command ``hil diagnose`` end to end in a fresh process (imports, reading the
file and loading the compiled loop included). Optionally the EMPS record (``--emps``).

    python benchmarks/bench_diagnose.py [--effect coulomb_friction] [--jobs N] [--emps]
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hil.config import load  # noqa: E402
from hil.ident import Replay, diagnose, synthesize  # noqa: E402
from hil.io.measurement import Measurement  # noqa: E402


def load_avg() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--effect", default="coulomb_friction")
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--emps", action="store_true", help="also the EMPS record against the whole catalogue")
    a = ap.parse_args()
    cfg_path = ROOT / "config" / "paper_bench.toml"
    cfg = load(cfg_path)
    ch, _ = synthesize(cfg, a.effect, duration=12.0, seed=1)
    rp = Replay(Measurement(ch, source="bench"), cfg)
    diagnose(rp, [a.effect], jobs=1)          # compile (or load the cached compiled loop)
    print(f"before: {load_avg()}  ({os.cpu_count()} CPUs)")
    t0 = time.perf_counter()
    d = diagnose(rp, jobs=a.jobs)
    print(f"diagnose() 12 s record, {len(d['candidates'])} candidates: {time.perf_counter() - t0:.1f} s, "
          f"verdict {d['verdict']}  [{load_avg()}]")
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "bench.csv"
        hil = [sys.executable, "-m", "hil.cli"]
        subprocess.run(hil + ["synth", "--config", str(cfg_path), "--effect", a.effect, "--seed", "1",
                              "--out", str(csv)], check=True, cwd=ROOT, capture_output=True)
        t0 = time.perf_counter()
        cmd = hil + ["diagnose", str(csv), "--config", str(cfg_path), "--json"]
        if a.jobs:
            cmd += ["--jobs", str(a.jobs)]
        subprocess.run(cmd, check=True, cwd=ROOT, capture_output=True)
        print(f"hil diagnose (fresh process) 12 s record: {time.perf_counter() - t0:.1f} s  [{load_avg()}]")
    if a.emps:
        from hil.ident.emps import MAPPING
        from hil.io.importers import read_mat
        data = ROOT.parent / "shared" / "data" / "emps" / "DATA_EMPS.mat"
        rp = Replay(read_mat(data, MAPPING), load(ROOT / "config" / "emps.toml"))
        t0 = time.perf_counter()
        d = diagnose(rp, jobs=a.jobs)
        print(f"diagnose() EMPS record (24.8 s at 1 ms), {len(d['candidates'])} candidates: "
              f"{time.perf_counter() - t0:.1f} s, verdict {d['verdict']}  [{load_avg()}]")


if __name__ == "__main__":
    main()
