"""Simulator speed: simulated seconds per wall second on one core, against a peer.

The case is the paper bench with its measured friction (config/paper_bench_friction.toml: 3 dof,
viscous and Coulomb friction with stiction, 62.5 us velocity loop, 4 ms position loop) running
a back-and-forth 100 mm move at 7 m/min. The peer is the same closed loop as python-control
objects (benchmarks/peer.py), run on a shorter stretch (it is slow) with friction off, where the
two must agree to 1e-9 m.

``--filters`` adds the same run with three filter sections in the loop (a notch at 86.6 Hz and a
low-pass at 1 kHz on the torque setpoint, a low-pass at 2 kHz on the speed feedback) against the
run without, in the same process (issue 52's target: no slower than 1.2 x).

``--effects`` adds, per effect of the catalogue (its synth strength on the paper bench, the same
move), the compiled loop's time per velocity step against its peer in the same run: the same cycle
(hil.simulate's ``_cycles``) compiled with numba's reference counting, as it was before
sim_plant.kernel.njit_cycle; the two records must be equal bit for bit.

    python benchmarks/bench_sim.py [--filters] [--effects] [--json]
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

from drivers.control import controller_from_config  # noqa: E402
from hil import config  # noqa: E402
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
    ap.add_argument("--filters", action="store_true", help="the same run with three filter sections, against without")
    ap.add_argument("--effects", action="store_true",
                    help="per catalogue effect: ns per velocity step, against the cycle compiled with reference counting")
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
    if args.filters:
        fc = cfg.with_values({"control.filters": [
            {"kind": "notch", "frequency": "86.6Hz", "width": "20Hz", "depth": "-20dB"},
            {"kind": "lowpass", "frequency": "1kHz"}, {"kind": "lowpass", "frequency": "2kHz", "at": "speed"}]})
        ctrl_f = controller_from_config(fc, plant)
        simulate(plant, ctrl_f, x_cmd)
        cpu_plain = best_of(lambda: simulate(plant, ctrl, x_cmd), args.repeat)
        cpu_f = best_of(lambda: simulate(plant, ctrl_f, x_cmd), args.repeat)
        out["filters"] = {"ns_per_velocity_step": cpu_f / (x_cmd.size * ctrl.substeps) * 1e9,
                          "ns_per_velocity_step_without": cpu_plain / (x_cmd.size * ctrl.substeps) * 1e9,
                          "ratio": cpu_f / cpu_plain, "target_ratio": 1.2}
    if args.effects:
        out["effects"] = effect_figures(x_cmd, args.repeat)
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"simulator: {sim_seconds:.2f} s simulated in {cpu * 1e3:.1f} ms CPU -> {rt_factor:,.0f} x real time "
              f"({out['ns_per_velocity_step']:.0f} ns per velocity step; target >= 1000 x)")
        print(f"peer ({out['peer']}): {peer_rt:.3f} x real time -> ours is {out['speedup_vs_peer']:,.0f} x faster")
        print(f"largest difference between the two trajectories: {diff:.2e} m (must be < 1e-9 m)")
        if args.filters:
            f = out["filters"]
            print(f"with three filter sections: {f['ns_per_velocity_step']:.0f} ns per velocity step, without "
                  f"{f['ns_per_velocity_step_without']:.0f} ns (same run): {f['ratio']:.2f} x (target <= 1.2 x)")
        if args.effects:
            print(f"\n{'effect':36s} {'ns/step':>8s} {'peer':>8s} {'ratio':>6s}  records equal")
            for e in out["effects"]:
                print(f"{e['effect']:36s} {e['ns_per_step']:8.1f} {e['peer_ns_per_step']:8.1f} {e['ratio']:6.2f}  "
                      f"{e['identical']}")
            tot = sum(e["ns_per_step"] for e in out["effects"]), sum(e["peer_ns_per_step"] for e in out["effects"])
            print(f"{'all':36s} {tot[0]:8.1f} {tot[1]:8.1f} {tot[1] / tot[0]:6.2f}")
    return 0


def effect_figures(x_cmd, repeat) -> list[dict]:
    """Per catalogue effect (not a recording's artefact, not a parameter): the compiled loop's CPU
    time per velocity step (best of ``repeat``), its peer's (the cycle compiled with reference
    counting, the work arrays allocated as closed_loop_kernel does), their ratio, and whether the
    two records are equal bit for bit."""
    from numba import njit

    import hil.simulate as sim
    from drivers.control import new_velocity_state
    from hil.ident.diagnosis import candidate_names
    from hil.plant_config import candidate, configure
    from sim_plant.effects.base import RecordEffect
    from sim_plant.kernel import mass_token
    peer = njit(sim._cycles.py_func)
    cfg = config.load(ROOT / "config" / "paper_bench.toml")
    plant = plant_from_config(cfg)
    out = []
    for name in candidate_names(cfg, plant, include_parameters=False):
        eff = candidate(name, cfg)
        if isinstance(eff, RecordEffect):        # acts on the record, not in the loop
            continue
        c = configure(eff, cfg, dict(getattr(eff, "synth_strength", None) or eff.guess(plant, {})))
        pl = plant_from_config(c)
        ct = controller_from_config(c, pl)
        runs = [sim._prepared(pl, ct, x_cmd, None, None, None, None, False, "actual") for _ in range(2)]
        masses = mass_token(runs[0].state0.size // 2)

        def ours(r=runs[0]):
            sim.closed_loop_kernel(r.Ad, r.Bd, r.fric, r.codes, r.params, r.terms, r.p, r.state0, r.cmd, r.ubuf,
                                   r.hbuf, r.rec, r.record_every, speed_filter=r.speed_filter,
                                   log_command=r.log_command, masses=masses, enc=r.enc)

        def theirs(r=runs[1]):
            n = r.state0.size // 2
            peer(r.Ad, r.Bd, r.fric, r.codes, r.params, r.terms, r.p, r.state0.copy(), np.zeros(2 * n), np.zeros(n),
                 new_velocity_state(), r.cmd, r.ubuf, r.hbuf, r.rec, r.record_every, None, False, None, None, None,
                 None, None, False, r.speed_filter, r.log_command, masses, r.enc)
        ours()
        theirs()
        same = all(np.array_equal(a, b) for a, b in zip(runs[0].rec, runs[1].rec))
        steps = x_cmd.size * ct.substeps
        a, b = best_of(ours, repeat) / steps * 1e9, best_of(theirs, repeat) / steps * 1e9
        out.append({"effect": name, "ns_per_step": a, "peer_ns_per_step": b, "ratio": b / a, "identical": same})
    return out


if __name__ == "__main__":
    sys.exit(main())
