"""Speed of ``hil fleet`` (issue 26, item 5): records per minute on local processes and on a local
Dask cluster, the time of one record's chain against the record's length (it must grow linearly),
and the peak memory of each worker.

A synthetic fleet (hil.fleet.synth: the paper bench with backlash and Coulomb friction, 1 %
scatter) of ``--axes`` x ``--dates`` records of ``--duration``; every record diagnosed as
``hil fleet run`` does (hil.fleet.run.diagnose_record: the chain on ``--candidates`` with
``--max-steps``, the tracked fit of backlash and friction). Each executor starts from an empty
store, so every record is computed; the first record is run once beforehand in this process, so
that the kernels' compilation is not counted (forked workers inherit it; Dask workers compile on
their first record, which is counted: a cluster pays it once per worker).

    python benchmarks/bench_fleet.py                                # 2 x 3 records of 1.5 s, 2 workers
    python benchmarks/bench_fleet.py --axes 10 --dates 10 --duration 6s --candidates all   (issue's goal)
    python benchmarks/bench_fleet.py --lengths 1.5s,3s,6s --json
    python benchmarks/bench_fleet.py --chain-only --lengths 6s --candidates all --max-steps 4   (the 6 s chain)

The chain row has its peer in the same run: the longest record's chain again with the fits'
evaluations one by one (``HIL_BATCH=0``: scipy's own finite differences, one simulation per
Jacobian column and per grid point, hil.ident.objective) and the ratio of the two times; the two
runs' figures must be identical (checked). ``--chain-only`` skips the fleets.

``--against TREE`` (a checkout of the code before, e.g. ``git archive 2d13fa8 | tar -x -C /tmp/main``)
times ``hil diagnose RECORD --json`` (the whole catalogue, as a user runs it; fresh processes,
alternating, after one untimed run each that fills the compiled caches) on the longest record from
this tree and from TREE, and checks that the two print the same JSON.

Quote the figures with the command and the machine's load (printed).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _fleet(tmp: Path, axes: int, dates: int, duration: str):
    from hil.config import load
    from hil.fleet.manifest import read_manifest
    from hil.fleet.synth import read_spec, synthesize_fleet
    cfg = load(ROOT / "config" / "paper_bench.toml")
    spec_path = tmp / "spec.toml"
    names = ", ".join(f'"A{i}"' for i in range(axes))
    spec_path.write_text(f'axes = [{names}]\nstart = "2026-03-02"\ncount = {dates}\nevery = "1 day"\n'
                         f'duration = "{duration}"\nscatter = 0.01\n[effects]\nbacklash = {{ gap = "4 um" }}\n'
                         f'coulomb_friction = {{ level = "1.5 N*m" }}\n')
    synthesize_fleet(cfg, read_spec(spec_path, cfg), tmp / "records", str(ROOT / "config" / "paper_bench.toml"))
    return cfg, read_manifest(tmp / "records")


def _settings(args):
    from hil.fleet.run import Settings
    cands = None if args.candidates == "all" else tuple(args.candidates.split(","))
    return Settings(track=("backlash", "coulomb_friction"), candidates=cands, max_steps=args.max_steps)


def _rate(entries, cfg, settings, out, scheduler=None, jobs=None) -> tuple[float, float]:
    from hil.fleet.batch import run_fleet
    t0 = time.perf_counter()
    res = run_fleet(entries, {str(ROOT / "config" / "paper_bench.toml"): cfg},
                    str(ROOT / "config" / "paper_bench.toml"), settings, out, scheduler=scheduler, jobs=jobs)
    dt = time.perf_counter() - t0
    assert res.computed == len(entries), res
    bad = [f for f in res.figures.values() if "error" in f]
    assert not bad, bad[:1]
    return len(entries) / dt * 60.0, dt


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def batch_threads() -> int:
    from hil.simulate import batch_threads as threads
    return threads()


def _maxrss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--axes", type=int, default=2)
    ap.add_argument("--dates", type=int, default=3)
    ap.add_argument("--duration", default="1.5 s")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--candidates", default="backlash,coulomb_friction,viscous_friction",
                    help="the chain's candidates, or 'all' (the catalogue, as hil diagnose)")
    ap.add_argument("--max-steps", type=int, default=2)
    ap.add_argument("--lengths", default="1.5s,3s,6s", help="record lengths of the chain-time row")
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--chain-only", action="store_true", help="only the chain against length and its peer")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each chain timing (the best is kept)")
    ap.add_argument("--against", metavar="TREE", help="also time hil diagnose from this checkout (the code before)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    from hil.fleet.run import Task, diagnose_record, record_key
    if not args.lengths.strip():
        ap.error("--lengths: at least one record length")
    out: dict = {"load": os.getloadavg(), "cpus": os.cpu_count(), "records": args.axes * args.dates,
                 "duration": args.duration, "workers": args.workers, "candidates": args.candidates,
                 "max_steps": args.max_steps}
    settings = _settings(args)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cfg, entries = _fleet(tmp, 1, 1, "1.5 s")
        data = Path(entries[0].record).read_bytes()
        for batch in ("1", "0"):      # compile both paths' kernels before any timing
            os.environ["HIL_BATCH"] = batch
            diagnose_record(record_key(data, cfg, settings), Task(entries[0].record, "w", "0", ""), data, cfg,
                            settings)
        os.environ["HIL_BATCH"] = "1"
    # the threads of the timings that follow, as the idle cores are after the warm-up (the count at
    # the end would see the --against processes' load)
    out["batch_threads"] = batch_threads()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if not args.chain_only:
            _fleets(args, out, settings, tmp)
        out["chain_vs_length"], out["peer"] = _chains(args, settings, tmp)
        if args.against:
            out["against"] = _against(args, tmp)
    out["peak_rss_mib_main"] = _maxrss_mib()
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    _print(args, out)
    return 0


def _fleets(args, out, settings, tmp):
    """Records per minute on local processes and on a local Dask cluster, peak memory per worker."""
    from distributed import LocalCluster
    cfg, entries = _fleet(tmp, args.axes, args.dates, args.duration)
    rate, dt = _rate(entries, cfg, settings, tmp / "local", jobs=args.workers)
    out["local"] = {"records_per_min": rate, "seconds": dt,
                    "peak_rss_mib_per_worker": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0}
    if not args.no_dask:
        with LocalCluster(host="127.0.0.1", n_workers=args.workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster:
            from distributed import Client
            rate, dt = _rate(entries, cfg, settings, tmp / "dask", scheduler=cluster.scheduler_address)
            with Client(cluster.scheduler_address) as c:
                peaks = c.run(_maxrss_mib)
        out["dask"] = {"records_per_min": rate, "seconds": dt, "peak_rss_mib_per_worker": sorted(peaks.values())}


def _chains(args, settings, tmp):
    """One record's chain against its length (this process), and the longest one's peer: the same
    chain with ``HIL_BATCH=0``, alternated with it, the best of ``--repeat`` runs of each."""
    from hil.fleet.run import Task, diagnose_record, record_key
    chain, peer = [], {}
    lengths = args.lengths.split(",")
    for length in lengths:
        sub = tmp / f"len-{length}"
        sub.mkdir()
        cfg1, es = _fleet(sub, 1, 1, length)
        d = Path(es[0].record).read_bytes()
        key, task = record_key(d, cfg1, settings), Task(es[0].record, "A0", "0", "")
        modes = ("1", "0") if length == lengths[-1] else ("1",)
        best, cpu, figs = {}, {}, {}
        for _ in range(max(1, args.repeat)):
            for batch in modes:
                os.environ["HIL_BATCH"] = batch
                t0, c0 = time.perf_counter(), time.process_time()
                _, figs[batch] = diagnose_record(key, task, d, cfg1, settings)
                best[batch] = min(best.get(batch, math.inf), time.perf_counter() - t0)
                cpu[batch] = min(cpu.get(batch, math.inf), time.process_time() - c0)
        os.environ["HIL_BATCH"] = "1"
        chain.append({"duration": length, "samples": figs["1"].get("samples"), "seconds": best["1"],
                      "cpu_seconds": cpu["1"]})
        if "0" in best:
            assert "error" not in figs["1"], figs["1"]
            peer = {"duration": length, "batched_s": best["1"], "one_by_one_s": best["0"],
                    "batched_cpu_s": cpu["1"], "one_by_one_cpu_s": cpu["0"],
                    "ratio": best["0"] / best["1"], "identical": figs["0"] == figs["1"],
                    "verdict": figs["1"].get("verdict")}
            assert peer["identical"], "the batched chain's figures differ from the one-by-one chain's"
    return chain, peer


def _against(args, tmp):
    """``hil diagnose RECORD --config ... --jobs 1 --json`` from this tree and from ``--against``,
    fresh processes alternated, the best of ``--repeat`` wall times each; the JSON compared."""
    import subprocess
    length = args.lengths.split(",")[-1]
    sub = tmp / "against"
    sub.mkdir()
    _, es = _fleet(sub, 1, 1, length)
    cli = "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"
    trees = {"this": ROOT, "against": Path(args.against).resolve()}
    best, cpu, printed = {}, {}, {}
    for i in range(1 + max(1, args.repeat)):          # the first round fills each tree's compiled cache
        for name, tree in trees.items():
            cmd = [sys.executable, "-c", cli, "diagnose", str(es[0].record), "--config",
                   str(tree / "config" / "paper_bench.toml"), "--jobs", "1", "--json"]
            t0, c0 = time.perf_counter(), _children_cpu()
            done = subprocess.run(cmd, cwd=tree, env=dict(os.environ, PYTHONPATH=str(tree), HIL_BATCH="1"),
                                  capture_output=True, text=True, check=True)
            if i:
                best[name] = min(best.get(name, math.inf), time.perf_counter() - t0)
                cpu[name] = min(cpu.get(name, math.inf), _children_cpu() - c0)
            printed[name] = json.loads(done.stdout)
    return {"duration": length, "this_s": best["this"], "against_s": best["against"],
            "ratio": best["against"] / best["this"], "this_cpu_s": cpu["this"], "against_cpu_s": cpu["against"], "identical": printed["this"] == printed["against"],
            "verdict": printed["this"].get("verdict")}


def _print(args, out):
    fleet = "" if args.chain_only else f"{out['records']} records of {args.duration}, "
    print(f"load {out['load'][0]:.2f} {out['load'][1]:.2f} {out['load'][2]:.2f} on {out['cpus']} CPUs, "
          f"{out['batch_threads']} batch threads at the start; {fleet}candidates {args.candidates}, max steps {args.max_steps}")
    for c in out["chain_vs_length"]:
        print(f"one record of {c['duration']} ({c['samples']} samples): {c['seconds']:.2f} s "
              f"({c['cpu_seconds']:.2f} s CPU)")
    pe = out["peer"]
    print(f"the {pe['duration']} chain: batched {pe['batched_s']:.2f} s ({pe['batched_cpu_s']:.2f} s CPU), one by one "
          f"(HIL_BATCH=0) {pe['one_by_one_s']:.2f} s ({pe['one_by_one_cpu_s']:.2f} s CPU), ratio {pe['ratio']:.2f}, "
          f"figures identical: {pe['identical']} (verdict: {pe['verdict']})")
    if "against" in out:
        ag = out["against"]
        print(f"hil diagnose on the {ag['duration']} record (fresh processes): {ag['this_s']:.2f} s "
              f"({ag['this_cpu_s']:.2f} s CPU), from {args.against} {ag['against_s']:.2f} s "
              f"({ag['against_cpu_s']:.2f} s CPU), ratio {ag['ratio']:.2f}, JSON identical: {ag['identical']}")
    print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if "local" not in out:
        return
    lo = out["local"]
    print(f"local processes ({args.workers}): {lo['records_per_min']:.1f} records/min ({lo['seconds']:.1f} s), "
          f"peak RSS per worker {lo['peak_rss_mib_per_worker']:.0f} MiB")
    if "dask" in out:
        da = out["dask"]
        print(f"local Dask cluster ({args.workers} worker processes): {da['records_per_min']:.1f} records/min "
              f"({da['seconds']:.1f} s, the workers' compilation included), peak RSS per worker "
              f"{', '.join(f'{p:.0f}' for p in da['peak_rss_mib_per_worker'])} MiB")


if __name__ == "__main__":
    sys.exit(main())
