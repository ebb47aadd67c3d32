"""The EMPS benchmark end to end (``hil emps``), against its published reference model.

Reads DATA_EMPS.mat (mapping t, qg -> x_cmd, qm -> x_motor, vir*gtau -> force), starts from
config/emps.toml (the published M and Fv, no Coulomb friction, no offset), diagnoses, adds
coulomb_friction and constant_force (the verdict and the effect also missing), refits them
together, diagnoses again and fits the next verdict (asymmetric_friction); then the published
method, the inverse model on the force channel (IDIM-LS, hil.ident.inverse), refitted by output
error (M, Fv, Fc and the offset jointly, simulation in the loop), and asymmetric friction from its
inverse model. Errors are relative 2-norm errors in %, 100 ||y - y_sim|| / ||y||, of the position
qm, of the velocity the controller sees (backward difference of the two-tap filtered position)
and of the force gtau*vir. Published: Janot et al. 2019.

Validation (:func:`validate_emps`): the benchmark's validation record DATA_EMPS_PULSES.mat (the
same reference trajectory, with 0/5 V pulses added to the drive command after the controller; its
``vir`` includes them) is replayed through the models fitted on DATA_EMPS.mat, the pulses entering
as the ``u_add`` input (:data:`VALIDATION_MAPPING`, a table: a record with other names is read
with another), and its errors set beside the published validation figures
(:data:`PUBLISHED_VALIDATION`: position 0.0080 %, force 8.94 %).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from hil.config import load
from hil.ident.chain import diagnose_chain
from hil.ident.fit import evaluate, fit_effects, joint_refit
from hil.ident.inverse import idim_ls
from hil.ident.progress import expect
from hil.ident.replay import Replay
from hil.ident.scores import relative_error
from hil.io.importers import read_mat
from hil.plant_config import candidate, configure

logger = logging.getLogger(__name__)

__all__ = ["PUBLISHED", "MAPPING", "VALIDATION_MAPPING", "PUBLISHED_VALIDATION", "validate_emps",
           "validation_markdown", "DIAGNOSE_CANDIDATES", "EmpsResult", "run_emps", "velocity", "errors",
           "params_of", "with_rigid", "check_published", "table_markdown", "diagnosis_markdown", "chain_markdown"]

PUBLISHED = {"M": 95.1089, "Fv": 203.5034, "Fc": 20.3935, "offset": -3.1648,
             "errors": {"position": 0.0138, "velocity": 0.229, "force": 5.85}}
MAPPING = {"t": "t", "qg": "x_cmd", "qm": "x_motor", "vir*gtau": "force"}     # source = channel
# the validation record: the pulses (V, the drive command's unit) added after the controller are an
# input of the replay (u_add); vir, and so the force, includes them
VALIDATION_MAPPING = dict(MAPPING, pulses_N="u_add")
PUBLISHED_VALIDATION = {"position": 0.0080, "force": 8.94}      # % (Janot et al. 2019, on DATA_EMPS_PULSES)
DIAGNOSE_CANDIDATES = ["coulomb_friction", "stribeck_friction", "asymmetric_friction", "constant_force",
                       "viscous_friction", "time_delay", "mass_change", "parameter:actuator.gain"]


@dataclass
class EmpsResult:
    """What the chain gives: the replay of the record, one row per step (its label, ``params`` in the
    benchmark's names, the errors % of position, velocity and force, and for the inverse-model steps
    ``inverse_force``), the configs ``start``, ``fitted`` (output error from IDIM-LS) and
    ``asymmetric``, and the diagnoses (verdict, ranking, also missing, combinations)."""
    replay: Replay
    rows: list
    configs: dict
    diagnoses: list
    chain: dict | None = None        # what hil.ident.chain.diagnose_chain returned

    @property
    def check(self) -> dict:
        return check_published(self.rows)


def velocity(q, dt):
    """The velocity the EMPS controller sees: the backward difference of the two-tap filtered
    position (m/s)."""
    qf = np.r_[q[0], 0.5 * q[1:] + 0.5 * q[:-1]]
    return np.r_[0.0, np.diff(qf)] / dt


def errors(replay: Replay, cfg) -> dict:
    """Relative 2-norm errors % of the position qm, of the velocity the controller sees and of the
    force, of ``cfg`` replayed against the record."""
    m = replay.meas
    sim = replay.simulated(cfg)
    dt = replay.sample_period
    return {"position": relative_error(m["x_motor"], sim["x_motor"]),
            "velocity": relative_error(velocity(m["x_motor"], dt), velocity(sim["x_motor"], dt)),
            "force": relative_error(m["force"], sim["force"])}


def params_of(cfg) -> dict:
    """The rigid model's parameters M, Fv, Fc and offset of a config, in the benchmark's names and
    signs; with asymmetric friction its levels and viscous coefficients in place of Fv and Fc (it
    sets the motor's dry and viscous friction anew: the values the config still has for them are
    not in the model)."""
    out = {"M": cfg["plant.m1"], "Fv": cfg.get("friction.viscous", 0.0),
           "Fc": cfg.get("effects.coulomb_friction.level", 0.0),
           "offset": -cfg.get("effects.constant_force.force", 0.0)}
    if "effects.asymmetric_friction.level_pos" in cfg:
        del out["Fv"], out["Fc"]
        out.update({k: cfg[f"effects.asymmetric_friction.{k}"] for k in
                    ("level_pos", "level_neg", "viscous_pos", "viscous_neg")})
    return {k: float(v) for k, v in out.items()}


def with_rigid(cfg, p: dict):
    """``cfg`` with the rigid model's M, Fv, Fc and offset of ``p`` (the benchmark's names and signs)."""
    return cfg.with_values({"plant.m1": p["M"], "friction.viscous": p["Fv"],
                            "effects.coulomb_friction.level": p["Fc"],
                            "effects.constant_force.force": -p["offset"]})


def _ranking(d, n=4):
    return [{"effect": c.effect, "score": round(c.score, 1), "significant": c.significant,
             "evidence": c.evidence} for c in d["candidates"][:n]]


def _summary(d):
    return {"verdict": d["verdict"], "ranking": _ranking(d),
            "also_missing": [{"effect": m["effect"], "score": round(m["score"], 1), "evidence": m["evidence"]}
                             for m in d["also_missing"]],
            "combinations": [{k: c[k] for k in ("effects", "explains", "preferred", "score", "explained",
                                                "rich_against_combination")} for c in d["combinations"]]}


def run_emps(data, config, quick: bool = False, progress=None, diagnose_steps: bool = True,
             validate=()) -> EmpsResult:
    """The EMPS chain on a record.

    Parameters
    ----------
    data : path
        DATA_EMPS.mat.
    config : path
        The start model (config/emps.toml).
    quick : bool
        Fewer iterations and candidates, one process (tests).
    progress : callable, optional
        Called with the name of each effect as its fit starts.
    diagnose_steps : bool
        Diagnose before and after the first additions (else add coulomb_friction and
        constant_force directly).
    validate : list of paths
        Validation records (DATA_EMPS_PULSES.mat, read with :data:`VALIDATION_MAPPING`): every
        step of the chain earns its place on them (hil.ident.chain ``holdout``); without them, on
        the record's own held-out moves.

    Returns
    -------
    EmpsResult
    """
    meas = read_mat(data, MAPPING)
    cfg0 = load(config)
    rp = Replay(meas, cfg0)
    logger.info("EMPS: %d samples of %s", meas.t.size, data)
    nfev = 15 if quick else 40
    rows, diags = [], []
    pub = with_rigid(cfg0, PUBLISHED)
    rows.append({"step": "published reference (our loop)", "params": params_of(pub), **errors(rp, pub)})
    rows.append({"step": "start model (M, Fv)", "short": "start model", "params": params_of(cfg0), **errors(rp, cfg0)})
    jobs = 1 if quick else None
    cands = DIAGNOSE_CANDIDATES[:4] if quick else DIAGNOSE_CANDIDATES
    if diagnose_steps:
        # the diagnosis chain (hil.ident.chain): each verdict, with the effects also missing beside it,
        # added and fitted, everything found refitted together, diagnosed again
        # every step validated: on the validation records where given, else on the record's held-out moves
        holdout = [Replay(_validation_record(v), cfg0) for v in validate] or "moves"
        ch = diagnose_chain(rp, cands, max_steps=3, progress=progress, jobs=jobs, max_nfev=nfev, fit_nfev=nfev,
                            holdout=holdout)
        cfg_chain = cfg0
        for i, step in enumerate(ch["chain"]):
            rows += _step_rows(rp, cfg_chain, step.fits, step.joint, step.config, later=i > 0)
            cfg_chain = step.config
        labels = ["start model"] + ["+ " + " + ".join(e for s in ch["chain"][:i + 1] for e in s.effects)
                                    for i in range(len(ch["chain"]))]
        diags = [{"on": lab, **_summary(d)} for lab, d in zip(labels, ch["diagnoses"])]
        chain = ch
    else:
        # hil fit --add coulomb_friction --add constant_force: one after the other, then jointly
        cfg2, steps = fit_effects(rp, ["coulomb_friction", "constant_force"], max_nfev=nfev, progress=progress)
        rows += _step_rows(rp, cfg0, steps, None, cfg2)
        chain = None
    # the published method on the force channel (inverse model), then output error from there
    inv = idim_ls(meas.t, meas["x_motor"], meas["force"])
    cfg_inv = with_rigid(cfg0, inv["params"])
    rows.append({"step": "IDIM-LS on the force (inverse model)", "short": "IDIM-LS", "params": params_of(cfg_inv),
                 "inverse_force": inv["relative_error"], **errors(rp, cfg_inv)})
    keys = ["plant.m1", "friction.viscous", "effects.coulomb_friction.level", "effects.constant_force.force"]
    if progress:
        expect(progress, 2)                  # this refit and the asymmetric friction's
        progress("output-error refit of M, Fv, Fc, offset")
    cfg3 = joint_refit(rp.with_config(cfg_inv), cfg_inv, keys, max_nfev=nfev)
    rows.append({"step": "output-error refit of M, Fv, Fc, offset", "short": "OE refit M, Fv, Fc, offset", "params": params_of(cfg3), **errors(rp, cfg3)})
    # asymmetric friction: its inverse model as the start, then output error on top of the fit
    inv2 = idim_ls(meas.t, meas["x_motor"], meas["force"], asymmetric=True)
    q = inv2["params"]
    off = -cfg3["effects.constant_force.force"]     # the fit keeps its offset: take it out of the levels
    start = {"level_pos": max(q["Fc+"] + off, 0.0), "level_neg": max(q["Fc-"] - off, 0.0),
             "viscous_pos": q["Fv+"], "viscous_neg": q["Fv-"]}
    if progress:
        progress("asymmetric_friction")
    c4 = evaluate(rp.with_config(cfg3), "asymmetric_friction", max_nfev=nfev, start=start)
    cfg4 = c4.cfg
    rows.append({"step": "+ asymmetric_friction", "short": "+ asymmetric (IDIM start)", "params": params_of(cfg4), "inverse_force": inv2["relative_error"],
                 "inverse_params": q, **errors(rp, cfg4)})
    return EmpsResult(rp, rows, {"start": cfg0, "fitted": cfg3, "asymmetric": cfg4}, diags, chain)


def _step_rows(rp, cfg_before, fits, joint, cfg_after, later: bool = False) -> list:
    """The table's rows of one chain step (its ``fits``, ``joint`` refit and config after): each
    effect as it was fitted on top of the model, the effects of a combination refitted together,
    and everything found so far refitted together."""
    rows, cur = [], cfg_before
    for st in fits:
        if "+" in st.effect:
            label = f"{' + '.join(st.effect.split('+'))} refitted together"
            rows.append({"step": label, "short": "joint refit", "params": params_of(st.cfg), **errors(rp, st.cfg)})
            continue
        cur = configure(candidate(st.effect, cur), cur, st.params)
        label = f"+ {st.effect}" + (" (the next verdict, fitted on top)" if later else "")
        rows.append({"step": label, "short": f"+ {st.effect}", "params": params_of(cur), **errors(rp, cur)})
    if joint is not None:
        rows.append({"step": "everything found so far refitted together", "short": "chain refit",
                     "params": params_of(cfg_after), **errors(rp, cfg_after)})
    return rows


def check_published(rows) -> dict:
    """Where the output-error fit lands against the published values (relative % for M, Fv, Fc;
    N for the offset) and whether its errors match or beat the published simulation errors."""
    fit = next(r for r in rows if r["step"].startswith("output-error"))
    p = fit["params"]
    dev = {k: 100.0 * (p[k] / PUBLISHED[k] - 1.0) for k in ("M", "Fv", "Fc")}
    dev["offset_N"] = p["offset"] - PUBLISHED["offset"]
    ok = all(abs(dev[k]) <= 5.0 for k in ("M", "Fv", "Fc")) and abs(dev["offset_N"]) <= 0.5
    beat = all(fit[k] <= PUBLISHED["errors"][k] for k in ("position", "velocity", "force"))
    return {"deviation": dev, "within_5_percent_and_0.5_N": ok, "errors_match_or_beat_published": beat}


def table_markdown(rows) -> str:
    lines = ["| step | M kg | Fv N s/m | Fc N | offset N | position % | velocity % | force % | inverse-model force % |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        p = r["params"]
        inv = f"{r['inverse_force']:.2f}" if "inverse_force" in r else ""
        if "level_pos" in p:
            lines.append(f"| {r['step']}: Fc+ {p['level_pos']:.2f} N, Fc- {p['level_neg']:.2f} N, Fv+ "
                         f"{p['viscous_pos']:.1f}, Fv- {p['viscous_neg']:.1f} N s/m | {p['M']:.3f} | | | "
                         f"{p['offset']:.3f} | {r['position']:.4f} | {r['velocity']:.3f} | {r['force']:.2f} | {inv} |")
            continue
        lines.append(f"| {r['step']} | {p['M']:.3f} | {p['Fv']:.2f} | {p['Fc']:.3f} | {p['offset']:.3f} | "
                     f"{r['position']:.4f} | {r['velocity']:.3f} | {r['force']:.2f} | {inv} |")
    e = PUBLISHED["errors"]
    lines.append(f"| **published** (Janot et al. 2019, IDIM-LS) | {PUBLISHED['M']} | {PUBLISHED['Fv']} | "
                 f"{PUBLISHED['Fc']} | {PUBLISHED['offset']} | {e['position']} | {e['velocity']} | {e['force']} | 4.08 |")
    lines.append("| **published**, asymmetric: Fc+ 20.144, Fc- 20.628, Fv+ 166.71, Fv- 240.42 | 95.154 | | | | | | | 3.11 |")
    return "\n".join(lines)


def diagnosis_markdown(diags) -> str:
    """The verdict chain: per diagnosis the verdict with its evidence, the effects also missing, the
    combination against the richer effect, and the ranking (score, * significant)."""
    lines = []
    for d in diags:
        top = d["ranking"][0] if d["ranking"] else None
        ev = f" ({top['evidence']})" if top and top["effect"] == d["verdict"] else ""
        lines.append(f"- diagnosis on the {d['on']}: **verdict {d['verdict']}**{ev}")
        for m in d.get("also_missing", []):
            lines.append(f"  - also missing: **{m['effect']}** (score {m['score']:.1f} beside the verdict; {m['evidence']})")
        for c in d.get("combinations", []):
            lines.append(f"  - {' + '.join(c['effects'])} against {c['explains']}: {100 * c['explained']:.0f} % of its "
                         f"gain; {c['explains']} scores {c['rich_against_combination']:.1f} against the pair -> "
                         + ("the pair named first" if c["preferred"] else f"{c['explains']} first"))
        lines.append("  - ranking: " + "; ".join(f"{c['effect']} {c['score']:.1f}{' *' if c['significant'] else ''}"
                                                   for c in d["ranking"]))
    return "\n".join(lines)


def validate_emps(path, configs: dict, mapping: dict | None = None) -> list[dict]:
    """The errors % (position, velocity, force) of each of ``configs`` ({label: config}, fitted on
    DATA_EMPS.mat) on the validation record ``path``, read with ``mapping`` (default
    :data:`VALIDATION_MAPPING`). Refused with one line when this version has no ``u_add`` input
    (the pulses would be left out of the replay, the residual would be the pulse train)."""
    meas = _validation_record(path, mapping)
    cfg0 = next(iter(configs.values()))
    rp = Replay(meas, cfg0)
    return [{"model": label, "record": str(path), **errors(rp, cfg)} for label, cfg in configs.items()]


def _validation_record(path, mapping: dict | None = None):
    """The validation record read with ``mapping`` (default :data:`VALIDATION_MAPPING`), refused with
    one line where this version has no ``u_add`` input for its pulses."""
    from hil.errors import UserError
    from hil.io.measurement import CHANNELS
    mapping = dict(mapping or VALIDATION_MAPPING)
    if "u_add" in mapping.values() and "u_add" not in CHANNELS:
        raise UserError(f"{path}: the validation record's pulses need the u_add input channel, which this version "
                        f"does not have: not validated")
    return read_mat(path, mapping)


def chain_markdown(chain: dict) -> str:
    """The chain's steps, estimation and held-out (or validation) errors side by side: per step the
    RMS error of each channel on the data it was fitted on, and on the held-out data before and
    after the step, with the fall of the weighted error and whether the step earned its place
    (hil.ident.chain); a step the held-out data refused last."""
    steps = list(chain["chain"])
    final = chain["final"]
    if "rejected" in final:
        steps.append(dict(final["rejected"], step="refused"))
    held = [s for s in steps if "held_out" in s]
    if not held:
        return f"chain: {len(chain['chain'])} steps; no held-out data ({final.get('held_out', 'none')})"
    chans = list(held[0]["estimation_error"])
    unit = {"x_motor": "m", "force": "N"}
    lines = [f"| chain step | added | {' | '.join(f'{c} estimation {unit.get(c, c)}' for c in chans)} | "
             f"{' | '.join(f'{c} held out {unit.get(c, c)}' for c in chans)} | weighted fall % | earned |",
             "|---|---|" + "---:|" * (2 * len(chans) + 1) + "---|"]
    for s in held:
        h = s["held_out"]
        lines.append(f"| {s['step']} | {' + '.join(s['effects'])} | "
                     + " | ".join(f"{s['estimation_error'][c]:.4g}" for c in chans) + " | "
                     + " | ".join(f"{h['before'][c]:.4g} -> {h['after'][c]:.4g}" for c in chans)
                     + f" | {100 * h['fall']:.1f} +- {100 * h['uncertainty']:.1f} | {'yes' if h['earned'] else 'no'} |")
    lines.append(f"\nheld out: {final.get('held_out', '')}; end: {final['end']}")
    return "\n".join(lines)


def validation_markdown(rows) -> str:
    """The validation errors beside the published validation figures."""
    lines = ["| model (fitted on DATA_EMPS.mat), on the validation record | position % | velocity % | force % |",
             "|---|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['position']:.4f} | {r['velocity']:.3f} | {r['force']:.2f} |")
    p = PUBLISHED_VALIDATION
    lines.append(f"| **published** validation (Janot et al. 2019) | {p['position']} | | {p['force']} |")
    return "\n".join(lines)
