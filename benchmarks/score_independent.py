#!/usr/bin/env python3
"""The diagnosis scored on the records of ../shared/data/independent-sim/ (a simulator that shares
no code with the project, with answer keys): for each record, ``hil diagnose measured.csv --config
<its nominal config> --json --jobs 1``, and the effects the chain's final model holds against the
key's ``accepted_names`` (a name counts where it contains a listed word).

    python benchmarks/score_independent.py [--data ../shared/data/independent-sim] [--jobs 2] [--json]

Prints one line per record (hidden, named, extras) and the counts: records with every hidden effect
named, extra effects, false alarms on clean records; the time and the machine's load.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def named_effects(diag: dict) -> list[str]:
    """The effects the chain's final model holds: each step's, less those a later step dropped."""
    named: list[str] = []
    for step in diag.get("chain") or []:
        gone = {d.get("effect") for d in step.get("dropped") or []}
        named = [e for e in named + list(step.get("effects") or []) if e not in gone]
    return named


def score(truth: dict, named: list[str]) -> dict:
    hidden = truth.get("accepted_names") or []
    found = [any(w in n for alts in [h] for w in alts for n in named) for h in hidden]
    extras = [n for n in named if not any(w in n for h in hidden for w in h)]
    return {"hidden": truth.get("hidden_effect"), "named": named, "all_named": all(found),
            "missed": [h for h, f in zip(hidden, found) if not f], "extras": extras,
            "false_alarm": not hidden and bool(named)}


def run(case: Path) -> dict:
    truth = json.loads((case / "truth.json").read_text())
    cfg = ROOT / "config" / f"{truth['nominal_config']}.toml"
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "hil.cli", "diagnose", str(case / "measured.csv"), "--config", str(cfg),
                        "--json", "--jobs", "1"], capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        return {"case": case.name, "error": r.stderr.strip().splitlines()[-1:] or ["?"], "wall_s": wall}
    diag = json.loads(r.stdout)
    return {"case": case.name, "verdict": diag.get("verdict"), "wall_s": wall, **score(truth, named_effects(diag))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "independent-sim"))
    ap.add_argument("--jobs", type=int, default=2, help="records diagnosed at once (default 2)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    data = Path(args.data)
    if not (data / "index.json").is_file():
        print(f"{data}: no independent-sim records here", file=sys.stderr)
        return 2
    cases = sorted(p.parent for p in data.glob("*/*/truth.json"))
    load0, t0 = os.getloadavg()[0], time.perf_counter()
    with ThreadPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run, cases))
    wall = time.perf_counter() - t0
    ok = [r for r in rows if "error" not in r]
    summary = {"records": len(rows), "errors": len(rows) - len(ok),
               "all_named": sum(r["all_named"] for r in ok if r["hidden"] not in (None, "none")),
               "with_hidden": sum(1 for r in ok if r["hidden"] not in (None, "none")),
               "extras": sum(len(r["extras"]) for r in ok if not r["false_alarm"]),
               "clean": sum(1 for r in ok if r["hidden"] in (None, "none")),
               "false_alarms": sum(r["false_alarm"] for r in ok), "wall_s": wall,
               "load_start": load0, "load_end": os.getloadavg()[0]}
    if args.json:
        print(json.dumps({"summary": summary, "records": rows}, indent=1))
        return 0
    for r in rows:
        if "error" in r:
            print(f"{r['case']}: error: {r['error'][0]}")
            continue
        mark = "ok" if r["all_named"] and not r["extras"] and not r["false_alarm"] else "--"
        print(f"{mark} {r['case']}: hidden {r['hidden']}; named {', '.join(r['named']) or 'none'}"
              + (f"; missed {r['missed']}" if r["missed"] else "") + (f"; extras {r['extras']}" if r["extras"] else ""))
    s = summary
    print(f"every hidden effect named on {s['all_named']} of {s['with_hidden']} records; {s['extras']} extra effects; "
          f"{s['false_alarms']} false alarms on {s['clean']} clean records; {s['errors']} errors; "
          f"{s['wall_s']:.0f} s, load average {s['load_start']:.2f} -> {s['load_end']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
