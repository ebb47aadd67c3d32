"""``hil emps``: the EMPS benchmark end to end, against its published reference model."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HELP = "EMPS record: effects added one by one, fitted parameters and errors beside the published reference"
DESCRIPTION = """\
Reads DATA_EMPS.mat (mapping t, qg -> x_cmd, qm -> x_motor, vir*gtau -> force), starts from
config/emps.toml (published M and Fv, no Coulomb friction, no offset), adds coulomb_friction and
constant_force, refits M, Fv, Fc and the offset jointly (output error, simulation in the loop),
then tries asymmetric_friction. Errors are relative 2-norm errors in %, 100 ||y - y_sim|| / ||y||,
of the position qm, of the velocity the controller sees (backward difference of the two-tap
filtered position) and of the force gtau*vir.

  hil emps --data ../shared/data/emps/DATA_EMPS.mat --out out/emps
"""

PUBLISHED = {"M": 95.1089, "Fv": 203.5034, "Fc": 20.3935, "offset": -3.1648,
             "errors": {"position": 0.0138, "velocity": 0.229, "force": 5.85}}
MAPPING = {"t": "t", "x_cmd": "qg", "x_motor": "qm", "force": "vir*gtau"}


def add_arguments(parser) -> None:
    parser.add_argument("--data", default="../shared/data/emps/DATA_EMPS.mat", help="the EMPS .mat record")
    parser.add_argument("--config", default=str(Path(__file__).resolve().parent.parent / "config" / "emps.toml"))
    parser.add_argument("--out", default="out/emps", metavar="DIR")
    parser.add_argument("--quick", action="store_true", help="fewer iterations (tests)")
    parser.add_argument("--json", action="store_true")


def velocity(q, dt):
    qf = np.r_[q[0], 0.5 * q[1:] + 0.5 * q[:-1]]
    return np.r_[0.0, np.diff(qf)] / dt


def errors(replay, cfg) -> dict:
    from .compare import relative_error
    m = replay.meas
    sim = replay.simulated(cfg)
    dt = replay.sample_period
    return {"position": relative_error(m["x_motor"], sim["x_motor"]),
            "velocity": relative_error(velocity(m["x_motor"], dt), velocity(sim["x_motor"], dt)),
            "force": relative_error(m["force"], sim["force"])}


def params_of(cfg) -> dict:
    out = {"M": cfg["plant.m1"], "Fv": cfg.get("friction.viscous", 0.0),
           "Fc": cfg.get("effects.coulomb_friction.level", 0.0),
           "offset": -cfg.get("effects.constant_force.force", 0.0)}
    if "effects.asymmetric_friction.level_pos" in cfg:
        out.update({k: cfg[f"effects.asymmetric_friction.{k}"] for k in
                    ("level_pos", "level_neg", "viscous_pos", "viscous_neg")})
    return {k: float(v) for k, v in out.items()}


def run_emps(data, config, quick=False, progress=None):
    from .compare import Replay
    from .config import load
    from .identify import fit_effects, joint_refit
    from .importers import read_mat
    meas = read_mat(data, MAPPING)
    cfg0 = load(config)
    rp = Replay(meas, cfg0)
    nfev = 15 if quick else 40
    rows = []
    pub = cfg0.with_values({"plant.m1": PUBLISHED["M"], "friction.viscous": PUBLISHED["Fv"],
                            "effects.coulomb_friction.level": PUBLISHED["Fc"],
                            "effects.constant_force.force": -PUBLISHED["offset"]})
    rows.append({"step": "published reference (our loop)", "params": params_of(pub), **errors(rp, pub)})
    rows.append({"step": "start model (M, Fv)", "params": params_of(cfg0), **errors(rp, cfg0)})
    cfg1, _ = fit_effects(rp, ["coulomb_friction"], max_nfev=nfev, progress=progress)
    rows.append({"step": "+ coulomb_friction", "params": params_of(cfg1), **errors(rp, cfg1)})
    cfg2, _ = fit_effects(rp.with_config(cfg1), ["constant_force"], max_nfev=nfev, progress=progress)
    rows.append({"step": "+ constant_force", "params": params_of(cfg2), **errors(rp, cfg2)})
    keys = ["plant.m1", "friction.viscous", "effects.coulomb_friction.level", "effects.constant_force.force"]
    # the force channel carries the friction and the offset (the position hardly sees 3 N): refit on it
    rpf = Replay(meas, cfg2, ["force"])
    cfg3 = joint_refit(rpf, cfg2, keys, max_nfev=nfev)
    rows.append({"step": "joint refit M, Fv, Fc, offset", "params": params_of(cfg3), **errors(rp, cfg3)})
    cfg4, _ = fit_effects(rp.with_config(cfg3), ["asymmetric_friction"], max_nfev=nfev, progress=progress)
    rows.append({"step": "+ asymmetric_friction", "params": params_of(cfg4), **errors(rp, cfg4)})
    return rp, rows, {"start": cfg0, "fitted": cfg3, "asymmetric": cfg4}


def table_markdown(rows) -> str:
    lines = ["| step | M kg | Fv N s/m | Fc N | offset N | position % | velocity % | force % |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        p = r["params"]
        extra = ""
        if "level_pos" in p:
            extra = (f" (Fc+ {p['level_pos']:.2f}, Fc- {p['level_neg']:.2f}, Fv+ {p['viscous_pos']:.1f}, "
                     f"Fv- {p['viscous_neg']:.1f})")
        lines.append(f"| {r['step']}{extra} | {p['M']:.3f} | {p['Fv']:.2f} | {p['Fc']:.3f} | {p['offset']:.3f} | "
                     f"{r['position']:.4f} | {r['velocity']:.3f} | {r['force']:.2f} |")
    e = PUBLISHED["errors"]
    lines.append(f"| published (Janot et al. 2019) | {PUBLISHED['M']} | {PUBLISHED['Fv']} | {PUBLISHED['Fc']} | "
                 f"{PUBLISHED['offset']} | {e['position']} | {e['velocity']} | {e['force']} |")
    return "\n".join(lines)


def run(args) -> int:
    from .cli import UserError
    from .compare import analyse
    from .measurement import MeasurementError
    from .plots_compare import comparison_figures, error_fall_figure
    from .report import write_report
    if not Path(args.data).exists():
        raise UserError(f"{args.data}: no such file (the EMPS record, see ../shared/data/emps/PROVENANCE.md)")
    try:
        rp, rows, cfgs = run_emps(args.data, args.config, args.quick,
                                  progress=lambda n: print(f"  fitting {n}", file=sys.stderr))
    except MeasurementError as exc:
        raise UserError(str(exc)) from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "emps_fitted.toml").write_text(cfgs["fitted"].to_toml(), encoding="utf-8")
    (out / "emps_asymmetric.toml").write_text(cfgs["asymmetric"].to_toml(), encoding="utf-8")
    a, b = analyse(rp, cfgs["start"]), analyse(rp, cfgs["fitted"])
    figs = comparison_figures(a, out, after=b)
    figs.append(error_fall_figure(rows[1:], out / "error_fall.png"))
    md = table_markdown(rows)
    (out / "table.md").write_text(md + "\n", encoding="utf-8")
    write_report(out / "report.html", "EMPS: start model against measurement, and the fitted model", a, figs, after=b,
                 notes=["Errors: relative 2-norm, 100 ||y - y_sim|| / ||y||."])
    if args.json:
        print(json.dumps({"rows": rows, "published": PUBLISHED, "out": str(out)}, indent=1))
    else:
        print(md)
        print(f"report: {out / 'report.html'}")
    return 0
