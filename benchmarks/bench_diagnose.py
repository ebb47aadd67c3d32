"""Time to diagnose a 12 s record (4 ms samples) against the whole catalogue (issue 5: < 30 s),
and the whole chain (issue 13): a 6 s record of the paper bench with two hidden effects (Coulomb
friction and a compliant mode) in < 10 s, the EMPS record in < 20 s.

Prints, beside the figures, the load average (1, 5, 15 min) before and after: on a busy machine
the figure means little. Figures: ``diagnose()`` in this process (the compiled loop already
loaded), the command ``hil diagnose --no-chain`` end to end in a fresh process (imports, reading
the file and loading the compiled loop included), and the chain ``diagnose_chain()``, with its
peer measured in the same run: one diagnosis of the same record (the chain's cost in diagnoses).
Optionally the EMPS record (``--emps``), its chain beside one diagnosis.

    python benchmarks/bench_diagnose.py [--effect coulomb_friction] [--jobs N] [--emps] [--chain-only]
"""
import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hil.config import load  # noqa: E402
from hil.ident import Replay, diagnose, synthesize  # noqa: E402
from hil.ident.chain import diagnose_chain  # noqa: E402
from hil.io.measurement import Measurement  # noqa: E402


def load_avg() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--effect", default="coulomb_friction")
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--emps", action="store_true", help="also the EMPS record against the whole catalogue")
    ap.add_argument("--chain-only", action="store_true", help="only the chain figures (and their peers)")
    a = ap.parse_args()
    cfg_path = ROOT / "config" / "paper_bench.toml"
    cfg = load(cfg_path)
    print(f"start: {load_avg()}  ({os.cpu_count()} CPUs)")
    chain_figures(cfg, a.jobs)
    if a.emps:
        emps_figures(a.jobs)
    if a.chain_only:
        return
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
        cmd = hil + ["diagnose", str(csv), "--config", str(cfg_path), "--json", "--no-chain"]
        if a.jobs:
            cmd += ["--jobs", str(a.jobs)]
        subprocess.run(cmd, check=True, cwd=ROOT, capture_output=True)
        print(f"hil diagnose (fresh process) 12 s record: {time.perf_counter() - t0:.1f} s  [{load_avg()}]")


def _cpu() -> float:
    """CPU seconds of this process and its reaped children (the worker processes), user + system."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _timed(f):
    """(result, wall s, CPU s): on a machine others load, the CPU seconds say more than the wall
    clock (on an idle machine with 2 CPUs the wall clock of a parallel run is about half of them)."""
    t0, c0 = time.perf_counter(), _cpu()
    out = f()
    return out, time.perf_counter() - t0, _cpu() - c0


def chain_figures(cfg, jobs) -> None:
    """The chain on a 6 s record of the paper bench (4 ms, four channels) with Coulomb friction and
    a compliant mode hidden, against one diagnosis of the same record."""
    from hil.plant_config import candidate, configure
    truth = configure(candidate("coulomb_friction", cfg), cfg, {"level": 2.2})
    truth = configure(candidate("compliant_mode", truth), truth, {"mass": 2.0, "frequency": 25.0,
                                                                  "damping_ratio": 0.02})
    ch, _ = synthesize(truth, None, duration=6.0, seed=3)
    rp = Replay(Measurement(ch, source="bench chain"), cfg)
    diagnose(rp, ["coulomb_friction"], jobs=1)          # compile (or load the cached compiled loop)
    d, tc, cc = _timed(lambda: diagnose_chain(rp, jobs=jobs))
    one, t1, c1 = _timed(lambda: diagnose(rp, jobs=jobs))
    steps = " then ".join(" + ".join(s["effects"]) for s in d["chain"])
    print(f"chain, 6 s paper bench record (coulomb_friction + compliant_mode hidden), {len(d['candidates'])} "
          f"candidates: {tc:.1f} s wall, {cc:.1f} CPU s ({steps}; end: {d['final']['end']})  [{load_avg()}]")
    print(f"  peer, one diagnosis of the same record: {t1:.1f} s wall, {c1:.1f} CPU s -> the chain costs "
          f"{cc / c1:.2f} diagnoses; target < 10 s: {'met' if tc < 10 else 'NOT met'} (wall)")


def emps_figures(jobs) -> None:
    """The chain on the EMPS record (24.8 s at 1 ms) with the whole catalogue, against one diagnosis."""
    from hil.ident.emps import MAPPING
    from hil.io.importers import read_mat
    data = ROOT.parent / "shared" / "data" / "emps" / "DATA_EMPS.mat"
    if not data.exists():
        data = Path("/work/shared/data/emps/DATA_EMPS.mat")
    rp = Replay(read_mat(data, MAPPING), load(ROOT / "config" / "emps.toml"))
    d, tc, cc = _timed(lambda: diagnose_chain(rp, jobs=jobs))
    one, t1, c1 = _timed(lambda: diagnose(rp, jobs=jobs))
    steps = " then ".join(" + ".join(s["effects"]) for s in d["chain"])
    print(f"chain, EMPS record (24.8 s at 1 ms), {len(d['candidates'])} candidates: {tc:.1f} s wall, {cc:.1f} CPU s "
          f"({steps}; end: {d['final']['end']})  [{load_avg()}]")
    print(f"  peer, one diagnosis of the EMPS record: {t1:.1f} s wall, {c1:.1f} CPU s -> the chain costs "
          f"{cc / c1:.2f} diagnoses; target < 20 s: {'met' if tc < 20 else 'NOT met'} (wall)")


if __name__ == "__main__":
    main()
