#!/usr/bin/env python3
"""Hashes of what the project writes, to check that a refactor keeps every number identical
(issue 28: every record bit-identical before and after).

    python benchmarks/golden_outputs.py --tree PATH --out FILE.json   run the fixed command set from PATH
    python benchmarks/golden_outputs.py --diff A.json B.json           list what differs

A tree at another commit: ``git worktree add /tmp/base COMMIT`` (or ``git archive COMMIT | tar -x
-C /tmp/base``), then ``--tree /tmp/base``.

Each command runs in a fresh temporary folder with PYTHONPATH=PATH (the tree's `hil`), the cwd at
PATH for the configs. Records (.csv), TOML outputs and --json stdout are hashed; JSON keys that
hold times, paths or versions are removed first. The CANopen and serial moves run in lockstep /
setpoint-advance against their simulators in one process, so they are deterministic.
"""
import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

VOLATILE = {"elapsed", "elapsed_s", "wall_s", "time", "seconds", "duration_s", "out", "path", "paths", "files",
            "report", "record", "config", "version", "started", "finished", "timestamp", "figure", "figures",
            "plot", "plots", "html", "csv", "png", "file", "dir", "folder", "eta_s", "cpu_s", "rate",
            "timing", "lateness", "late_total", "stats", "host"}


def _clean(o):
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items() if k not in VOLATILE and not k.endswith(("_path", "_file", "_s_wall"))}
    if isinstance(o, list):
        return [_clean(v) for v in o]
    if isinstance(o, str) and ("/tmp" in o or "/work/" in o):
        return "<path>"
    return o


def _h(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()[:16]


CLI = "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"

COMMANDS = {
    "move": ["move", "--config", "config/paper_bench.toml", "--stroke", "100mm", "--feed", "7000mm/min",
             "--tacc", "200ms", "--out", "{tmp}/move", "--json"],
    "move_2dof": ["move", "--config", "config/paper_bench_2dof.toml", "--stroke", "50mm", "--feed", "5000mm/min",
                  "--tacc", "150ms", "--out", "{tmp}/move2", "--json"],
    "move_friction": ["move", "--config", "config/paper_bench_friction.toml", "--stroke", "50mm", "--feed",
                      "5000mm/min", "--tacc", "150ms", "--out", "{tmp}/movef", "--json"],
    "sweep": ["sweep", "--config", "config/paper_bench.toml", "--stroke", "100mm", "--feed", "7000mm/min",
              "--tacc", "100ms,200ms", "--jobs", "1", "--no-progress", "--no-plot", "--out", "{tmp}/sweep", "--json"],
    "frf": ["frf", "--config", "config/paper_bench.toml", "--periods", "2", "--settle", "1s", "--period", "1s",
            "--out", "{tmp}/frf", "--json"],
    "synth_backlash": ["synth", "--config", "config/paper_bench.toml", "--effect", "backlash", "--param", "gap=20um",
                       "--duration", "6s", "--seed", "3", "--out", "{tmp}/bl.csv", "--json"],
    "synth_friction": ["synth", "--config", "config/paper_bench.toml", "--effect", "coulomb_friction",
                       "--param", "level=2Nm", "--duration", "6s", "--seed", "4", "--out", "{tmp}/cf.csv", "--json"],
    "synth_delay_pulses": ["synth", "--config", "config/paper_bench.toml", "--effect", "actuator_delay",
                           "--param", "delay=250us", "--duration", "4s", "--seed", "5", "--pulses", "2Nm",
                           "--out", "{tmp}/dl.csv", "--json"],
    "compare": ["compare", "{tmp}/cf.csv", "--config", "config/paper_bench.toml", "--out", "{tmp}/cmp", "--json"],
    "diagnose": ["diagnose", "{tmp}/cf.csv", "--config", "config/paper_bench.toml", "--jobs", "1", "--no-chain",
                 "--json"],
    "diagnose_chain": ["diagnose", "{tmp}/bl.csv", "--config", "config/paper_bench.toml", "--jobs", "1",
                       "--max-steps", "2", "--out", "{tmp}/chain.toml", "--json"],
    "fit": ["fit", "{tmp}/cf.csv", "--config", "config/paper_bench.toml", "--add", "coulomb_friction",
            "--out", "{tmp}/fit.toml", "--json"],
}

RIGS = r'''
import hashlib, json, sys
sys.path.insert(0, "tests")
import numpy as np
from hil.profiles import MoveSpec, Trajectory
from hil.runtime import run_trajectory
out = {}
def move(stroke=0.02):
    tr = Trajectory(start=0.0); tr.move(MoveSpec(stroke=stroke, feed=0.1, a_max=2.0)); tr.dwell(0.15); return tr
from canopen_rig import rig
for mode in ("csp", "csv", "cst"):
    cfg, sim, be = rig(mode, prefix="golden")
    try:
        rec = run_trajectory(cfg, move(), backend=be, out_file=f"{TMP}/co_{mode}.csv", settle=0.0)
    finally:
        sim.close()
    out["canopen_" + mode] = [rec.status, rec.reason]
from hil import config
from drivers.serial.drive_sim import SimulatedSerialDrive
from drivers.serial.backend import SerialBackend
from hil.plant_config import plant_from_config
cfg = config.load("config/serial_ascii_example.toml")
d = SimulatedSerialDrive(cfg, plant_from_config(cfg), advance="setpoint")
try:
    b = SerialBackend(cfg, port=d.port, timeout=0.5, budget=2.0, retries=2, free_run=True)
    rec = run_trajectory(cfg, move(0.005), backend=b, out_file=f"{TMP}/serial.csv", settle=0.2)
    out["serial"] = [rec.status, rec.reason]
finally:
    d.stop()
print(json.dumps(out))
'''


def _run(tree: Path, args, tmp: str, env):
    args = [a.replace("{tmp}", tmp) for a in args]
    p = subprocess.run([sys.executable, "-c", CLI, *args], cwd=tree, env=env, capture_output=True, text=True,
                       timeout=900)
    return p


def collect(tree: Path) -> dict:
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        # a state directory of its own: a trip latched by anyone's run in the user's state would refuse the moves
        env = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg", HIL_NO_PROGRESS="1",
                   HIL_STATE_DIR=os.path.join(tmp, "state"))
        for name, args in COMMANDS.items():
            p = _run(tree, args, tmp, env)
            entry = {"rc": p.returncode}
            try:
                entry["json"] = _h(json.dumps(_clean(json.loads(p.stdout[p.stdout.index("{"):])),
                                              sort_keys=True).encode())
                entry["json_full"] = _clean(json.loads(p.stdout[p.stdout.index("{"):]))
            except (ValueError, json.JSONDecodeError):
                entry["stdout"] = p.stdout[-400:]
                entry["stderr"] = p.stderr[-400:]
            res[name] = entry
            print(f"{name}: rc {p.returncode}", file=sys.stderr)
        p = subprocess.run([sys.executable, "-c", f"TMP={tmp!r}\n" + RIGS], cwd=tree, env=env,
                           capture_output=True, text=True, timeout=900)
        res["rigs"] = {"rc": p.returncode, "stdout": p.stdout[-2000:], "stderr": p.stderr[-600:] if p.returncode else ""}
        print(f"rigs: rc {p.returncode}", file=sys.stderr)
        files = {}
        for f in sorted(Path(tmp).rglob("*")):
            if f.suffix in (".csv", ".toml", ".npz") and f.is_file():
                files[str(f.relative_to(tmp))] = _h(f.read_bytes())
        res["files"] = files
    return res


def diff(a: dict, b: dict) -> list[str]:
    out = []
    for k in sorted(set(a) | set(b)):
        if k == "files":
            fa, fb = a.get(k, {}), b.get(k, {})
            for f in sorted(set(fa) | set(fb)):
                if fa.get(f) != fb.get(f):
                    out.append(f"file {f}: {fa.get(f)} -> {fb.get(f)}")
            continue
        ea, eb = a.get(k), b.get(k)
        if ea is None or eb is None:
            out.append(f"{k}: only in {'B' if ea is None else 'A'}")
            continue
        if ea.get("rc") != eb.get("rc"):
            out.append(f"{k}: rc {ea.get('rc')} -> {eb.get('rc')}")
        if ea.get("json") != eb.get("json") or ea.get("stdout") != eb.get("stdout"):
            ja, jb = ea.get("json_full"), eb.get("json_full")
            if isinstance(ja, dict) and isinstance(jb, dict):
                keys = [x for x in sorted(set(ja) | set(jb)) if ja.get(x) != jb.get(x)]
                out.append(f"{k}: json differs in keys {keys}")
            else:
                out.append(f"{k}: output differs")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tree", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--diff", nargs=2, type=Path)
    a = ap.parse_args()
    if a.diff:
        d = diff(json.loads(a.diff[0].read_text()), json.loads(a.diff[1].read_text()))
        print("\n".join(d) if d else "identical")
        return 1 if d else 0
    res = collect(a.tree.resolve())
    a.out.write_text(json.dumps(res, indent=1, sort_keys=True))
    bad = [k for k, v in res.items() if k != "files" and v.get("rc")]
    print(f"{len(res['files'])} files hashed; nonzero rc: {bad or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
