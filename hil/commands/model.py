"""``hil model``: the plant model of a configuration: parameters, modes, damping, Bode plots."""
from __future__ import annotations

import math
from pathlib import Path

from hil.io.jsonout import JsonKey, dumps
from hil.io.safe_write import save_figure

HELP = "model summary: modes, damping ratios, Bode plots of TF1, TF2, TF3"
DESCRIPTION = """\
Print the lumped chain of a configuration: masses, stiffnesses, dampings, the undamped modal
frequencies of the elastic modes and their damping ratios (diag(Phi^T C Phi) / 2 omega), for the
mechanical chain alone and with the motor's viscous friction (friction.viscous, reflected to
linear units by (2 pi/p)^2 for a rotary actuator). Writes Bode plots of TF1 = x1/f, TF2 = x2/x1
and TF3 = x3/x2 (no TF3 for a 2-dof chain) to --out.

  hil model --config config/paper_bench.toml
  hil model --config config/paper_bench.toml --set plant.c2=33 --json
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
_CHAIN = "a chain of 2 masses or more"
JSON_KEYS = {
    "name": JsonKey("", "meta.name of the config"),
    "config": JsonKey("", "path of the config"),
    "actuator": JsonKey("", "`rotary` or `linear`"),
    "pitch_m": JsonKey("m", "screw pitch (table travel per motor turn); null for a linear actuator"),
    "masses_kg": JsonKey("kg", "the chain's masses m1..mN (plant.m1..)"),
    "stiffness_N_per_m": JsonKey("N/m", "stiffnesses k1..k(N-1)"),
    "damping_N_s_per_m": JsonKey("N*s/m", "dampings c1..c(N-1)"),
    "viscous_friction_N_s_per_m": JsonKey("N*s/m", "the motor's viscous friction on mass 1, in linear units"),
    "modes_hz": JsonKey("Hz", "undamped frequencies of the elastic modes"),
    "damping_ratios": JsonKey("1", "modal damping ratios of the chain alone"),
    "damping_ratios_with_friction": JsonKey("1", "the same with the motor's viscous friction"),
    "damped_modes_hz": JsonKey("Hz", "frequencies of the damped eigenvalues, friction included", when=_CHAIN),
    "damped_ratios": JsonKey("1", "damping ratios of the damped eigenvalues", when=_CHAIN),
    "overdamped_modes": JsonKey("", "elastic modes without a damped frequency (real eigenvalues: no oscillation); "
                                    "damped_modes_hz holds the others", when=_CHAIN),
    "plot": JsonKey("", "path of the Bode plots of TF1, TF2, TF3; null with --no-plot"),
    "closed_loop": JsonKey("Hz, dB", "the closed position loop: stable, spectral_radius, bandwidth_hz and "
                                     "peak_gain_db (table_ff, table_no_ff, tip_ff, ...), plot",
                           when="with --closed-loop"),
}


def add_arguments(parser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="axis configuration (TOML)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a parameter, e.g. plant.c2=33 or 'plant.m3=4.3 kg' (repeatable)")
    parser.add_argument("--out", default="out/model", metavar="DIR", help="folder for the plots (default: out/model)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    parser.add_argument("--no-plot", action="store_true",
                        help="no Bode plots: the numbers alone (a third of the time; for scripts and quick looks)")
    parser.add_argument("--closed-loop", action="store_true",
                        help="also report the closed position loop (needs the runtime's hil.closed_loop)")


def model_report(cfg) -> dict:
    """The numbers ``hil model`` reports, SI units, from a validated config."""
    from hil.plant_config import plant_from_config
    from sim_plant.chain import Chain

    plant = plant_from_config(cfg)
    ch = plant.chain
    bare = Chain(ch.m, ch.k, ch.c)
    w, _ = ch.modes()
    elastic = slice(1, None)          # mode 1 of a free chain is the rigid-body mode
    report = {
        "name": cfg.get("meta.name", ""),
        "config": cfg.source,
        "actuator": cfg.get("actuator.type", "rotary"),
        "pitch_m": plant.pitch,
        "masses_kg": list(ch.m),
        "stiffness_N_per_m": list(ch.k),
        "damping_N_s_per_m": list(ch.c),
        "viscous_friction_N_s_per_m": float(ch.c_ground[0]),
        "modes_hz": [float(x) for x in w[elastic] / (2 * math.pi)],
        "damping_ratios": [float(x) for x in bare.modal_damping_ratios()] if ch.n > 1 else [],
        "damping_ratios_with_friction": ([float(x) for x in ch.modal_damping_ratios(include_ground=True)]
                                         if ch.n > 1 else []),
    }
    if ch.n > 1:
        # no proportional-damping assumption: eigenvalues of the damped state matrix
        wd, zd = ch.damped_modes(include_ground=True)
        keep = wd > 1e-6 * max(wd.max(), 1.0)
        report["damped_modes_hz"] = [float(x) for x in wd[keep][-(ch.n - 1):] / (2 * math.pi)]
        report["damped_ratios"] = [float(x) for x in zd[keep][-(ch.n - 1):]]
        # an overdamped mode (plant.c2 = 3000 on the paper bench) has real eigenvalues: no damped
        # frequency, so fewer damped modes than elastic ones
        report["overdamped_modes"] = (ch.n - 1) - len(report["damped_modes_hz"])
    return report


def write_plots(cfg, report: dict, out_dir: Path) -> str:
    import numpy as np

    from hil.plant_config import plant_from_config
    from hil.plots.model import bode_figure
    from sim_plant.chain import Chain
    from sim_plant.transfer import chain_tfs

    # the mechanical chain, as in Table 1 and Fig. 9: the motor's friction is a disturbance there
    ch = plant_from_config(cfg).chain
    tfs = chain_tfs(Chain(ch.m, ch.k, ch.c))[:3]
    fmax = 10 * max(report["modes_hz"] or [100.0])
    f = np.logspace(np.log10(max(fmax / 1e4, 0.1)), np.log10(fmax), 2000)
    fig = bode_figure(tfs, f, title=f"{report['name'] or cfg.source}: transfer functions (Table 1, Eq. 6)",
                      modes_hz=report["modes_hz"])
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "bode_tf.png"
    save_figure(fig, path, dpi=110)
    return str(path)


def _text(r: dict) -> str:
    lines = [f"{r['name'] or 'model'} ({r['config']})",
             f"chain of {len(r['masses_kg'])} masses, {r['actuator']} actuator"
             + (f", pitch {r['pitch_m'] * 1e3:g} mm" if r["pitch_m"] else "")]
    from hil.units import fmt
    for sym, vals, kind in (("m", r["masses_kg"], "mass"), ("k", r["stiffness_N_per_m"], "stiffness"),
                            ("c", r["damping_N_s_per_m"], "damping")):
        if vals:
            lines.append("  " + "   ".join(f"{sym}{i} = {fmt(v, kind, 6)}" for i, v in enumerate(vals, 1)))
    lines.append(f"  motor viscous friction on mass 1: {fmt(r['viscous_friction_N_s_per_m'], 'damping', 6)} "
                 f"(linear units)")
    if not r["modes_hz"]:
        lines.append("no elastic mode (a single mass)")
    else:
        damped = list(zip(r.get("damped_ratios", []), r.get("damped_modes_hz", [])))
        paired = len(damped) == len(r["modes_hz"])      # one damped eigenvalue per mode: side by side
        lines.append("elastic modes: undamped frequency, damping ratio (chain alone | with viscous friction"
                     + (" | damped eigenvalues, friction included)" if paired else ")"))
        for i, f in enumerate(r["modes_hz"]):
            lines.append(f"  mode {i + 2}: {f:9.3f} Hz   zeta = {r['damping_ratios'][i]:.4f} | "
                         f"{r['damping_ratios_with_friction'][i]:.4f}"
                         + (f" | {damped[i][0]:.4f} at {damped[i][1]:.3f} Hz" if paired else ""))
        if not paired:
            lines.append("  damped eigenvalues, friction included: "
                         + ("; ".join(f"zeta {z:.4f} at {fd:.3f} Hz" for z, fd in damped) or "none oscillates")
                         + f"; {r['overdamped_modes']} mode(s) overdamped (real eigenvalues: no oscillation)")
    return "\n".join(lines)


_BANDWIDTHS = {"table_ff": "table, with feed-forward", "table_no_ff": "table, without feed-forward",
               "tip_ff": "tool tip, with feed-forward", "table_ff_tf3": "table, with feed-forward, TF3 included",
               "table_no_ff_tf3": "table, without feed-forward, TF3 included"}


def closed_loop_text(cl) -> str:
    """The closed position loop in lines a person reads (the JSON has the same numbers, SI)."""
    from hil.units import fmt
    if isinstance(cl, str):
        return cl
    lines = ["closed position loop:"]
    if "stable" in cl:
        rho = cl.get("spectral_radius")
        lines.append(f"  {'stable' if cl['stable'] else 'UNSTABLE'}"
                     + (f" (spectral radius of the sampled loop {rho:.4f})" if isinstance(rho, float) else ""))
    for k, v in (cl.get("bandwidth_hz") or {}).items():
        lines.append(f"  -3 dB bandwidth, {_BANDWIDTHS.get(k, k)}: {fmt(v, 'frequency') if v is not None else 'n/a'}")
    for k, v in (cl.get("peak_gain_db") or {}).items():
        lines.append(f"  peak gain, {_BANDWIDTHS.get(k, k)}: {v:.2f} dB")
    for k, v in cl.items():
        if k not in ("stable", "spectral_radius", "bandwidth_hz", "peak_gain_db", "plot"):
            lines.append(f"  {k.replace('_', ' ')}: {v}")
    if cl.get("plot"):
        lines.append(f"closed-loop plot: {cl['plot']}")
    return "\n".join(lines)


def run(args) -> int:
    from hil.config import load, parse_assignment
    from hil.errors import UserError

    overrides = dict(parse_assignment(s) for s in args.set)
    cfg = load(args.config, overrides)
    report = model_report(cfg)
    report["plot"] = None
    if not args.json:           # the answer first; the plots take longer than the numbers
        print(_text(report), flush=True)
    if not args.no_plot:
        try:
            report["plot"] = write_plots(cfg, report, Path(args.out))
        except OSError as exc:
            raise UserError(f"--out {args.out}: cannot write the plots ({exc.strerror or exc})") from None
    if args.closed_loop:
        from hil.closed_loop import closed_loop_report, closed_loop_response
        from hil.plots.model import closed_loop_figure
        response = closed_loop_response(cfg)
        report["closed_loop"] = closed_loop_report(response)
        report["closed_loop"]["plot"] = str(closed_loop_figure(response, Path(args.out)))
    if args.json:
        print(dumps(report, indent=2))
    else:
        if report["plot"]:
            print(f"Bode plots: {report['plot']}")
        if "closed_loop" in report:
            print(closed_loop_text(report["closed_loop"]))
    return 0

