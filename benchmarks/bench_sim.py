"""Simulator speed: simulated seconds per wall second on one core, against a peer.

The case is the paper bench with its measured friction (config/paper_bench_friction.toml: 3 dof,
viscous and Coulomb friction with stiction, 62.5 us velocity loop, 4 ms position loop) running
a back-and-forth 100 mm move at 7 m/min. The peer is the same closed loop as python-control
objects (benchmarks/peer.py), run on a shorter stretch (it is slow) with friction off, where the
two must agree to 1e-9 m.

    python benchmarks/bench_sim.py [--json]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from hil import config  # noqa: E402
from hil.control import controller_from_config  # noqa: E402
from hil.plant_config import plant_from_config  # noqa: E402
from hil.profiles import MoveSpec, Trajectory  # noqa: E402
from hil.simulate import simulate  # noqa: E402


def best_of(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--peer-seconds", type=float, default=0.3, help="simulated seconds for the peer (slow)")
    args = ap.parse_args(argv)
    cfg = config.load(ROOT / "config" / "paper_bench_friction.toml")
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    traj = Trajectory()
    traj.move(MoveSpec(0.1, 7 / 60, t_acc=0.2, g0=0.5))
    traj.dwell(0.5)
    traj.move(MoveSpec(-0.1, 7 / 60, t_acc=0.2, g0=0.5))
    traj.dwell(0.5)
    _, x_cmd = traj.sample(ctrl.position_period)
    simulate(plant, ctrl, x_cmd)                         # compile (or load the cache)
    sim_seconds = x_cmd.size * ctrl.position_period
    cpu = best_of(lambda: simulate(plant, ctrl, x_cmd), args.repeat)
    rt_factor = sim_seconds / cpu

    # peer: friction off, a shorter stretch of the same move
    from peer import peer_simulate
    cfg0 = config.load(ROOT / "config" / "paper_bench.toml")
    plant0 = plant_from_config(cfg0)
    ctrl0 = controller_from_config(cfg0, plant0)
    n_peer = int(round(args.peer_seconds / ctrl0.position_period))
    xc = x_cmd[:n_peer]
    t0 = time.process_time()
    X = peer_simulate(list(plant0.chain.m), list(plant0.chain.k), list(plant0.chain.c), cfg0["friction.viscous"],
                      cfg0["plant.pitch"], ctrl0.position_period, ctrl0.velocity_period, ctrl0.kv, ctrl0.ffv,
                      ctrl0.kp, ctrl0.ti, ctrl0.output_limit, xc)
    peer_cpu = time.process_time() - t0
    peer_rt = xc.size * ctrl0.position_period / peer_cpu
    ours = simulate(plant0, ctrl0, xc)
    diff = float(np.max(np.abs(ours.x - X)))
    out = {"case": "paper_bench_friction, 100 mm at 7 m/min and back", "simulated_s": sim_seconds,
           "cpu_s": cpu, "realtime_factor": rt_factor, "ns_per_velocity_step": cpu / (x_cmd.size * ctrl.substeps) * 1e9,
           "peer": "python-control interconnect (friction off)", "peer_realtime_factor": peer_rt,
           "speedup_vs_peer": rt_factor / peer_rt, "max_trajectory_difference_m": diff, "target_realtime_factor": 1000,
           "cpu": os.cpu_count()}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"simulator: {sim_seconds:.2f} s simulated in {cpu * 1e3:.1f} ms CPU -> {rt_factor:,.0f} x real time "
              f"({out['ns_per_velocity_step']:.0f} ns per velocity step; target >= 1000 x)")
        print(f"peer ({out['peer']}): {peer_rt:.3f} x real time -> ours is {out['speedup_vs_peer']:,.0f} x faster")
        print(f"largest difference between the two trajectories: {diff:.2e} m (must be < 1e-9 m)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
