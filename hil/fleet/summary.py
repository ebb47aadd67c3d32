"""The fleet judged: each axis's tracked parameters against its own history (hil.fleet.spc), its
normal effects, its findings, and the table of every (axis, date, effect, value, standard error).

Conventions: an axis's records in time order; its baseline is the records the manifest names
(``baseline`` true) or else its first ``n_baseline`` readable ones; a record with an error is left
out of the series and listed with its line. Values SI.
"""
from __future__ import annotations

import math

from hil.fleet.manifest import Entry
from hil.fleet.spc import K_SIGMA, SCATTER, control_limits, cusum_alarm, judge_series, new_effects, normal_effects
from hil.ident.unexplained import HALF_GAP

__all__ = ["judge_fleet", "rows", "usual_model", "N_BASELINE"]

N_BASELINE = 3


def _baseline(entries: list[Entry], n_baseline: int) -> list[int]:
    named = [i for i, e in enumerate(entries) if e.baseline]
    return named or list(range(min(n_baseline, len(entries))))


def judge_axis(axis: str, entries: list[Entry], figures: dict, thresholds: dict, n_baseline: int = N_BASELINE,
               scatter: float = SCATTER, confirm: dict | None = None) -> dict:
    """One axis: ``params`` (per tracked parameter, and per parameter of an effect of the axis's
    normal that is not tracked, its strength as the chain fitted it each night (``source``
    "chain"): centre, sigma, status per record, flagged, first_moved date, reasons), ``normal`` (effects of every baseline record), ``findings``
    (effects named after the baseline outside the normal, with their first date), ``errors``,
    ``verdict`` of the latest record and ``worst`` (the parameter that moved most, in sigma).

    ``confirm``: record id -> the strengths of the normal effects and of each finding fitted on
    every record of the axis (:func:`hil.fleet.batch.confirm_findings`); the normal's, where there,
    are judged instead of the chain's (``source`` "confirmed"). A finding whose every strength stays within the
    limits of the baseline nights (and within its thresholds) was there all along, too weak for the
    chain to name every night: it is kept in ``findings`` (``strength``: "as in the baseline") and
    its strengths in ``params`` (``source`` "confirmed"), but it is no flag; so is one that takes
    away less than half of the rise of what the usual model leaves unexplained
    (:func:`_takes_the_rise`). Where a finding moved, the usual effects' strengths are those fitted
    beside it (:func:`usual_model`), and their move counts only where the usual model alone sees it
    too (:func:`_steady_alone`)."""
    good = [e for e in entries if "error" not in figures.get(e.id, {"error": "not run"})]
    errors = [{"record": e.id, "error": figures.get(e.id, {}).get("error", "not run")}
              for e in entries if e not in good]
    out = {"axis": axis, "records": [e.id for e in good], "dates": [e.timestamp for e in good], "params": {},
           "normal": [], "findings": [], "errors": errors, "flags": [], "verdict": "no readable record",
           "worst": None}
    if not good:
        return out
    base = _baseline(good, n_baseline)
    figs = [figures[e.id] for e in good]
    named = [set(f.get("named", [])) for f in figs]
    normal = normal_effects(named, base)
    findings, finding_params = _findings(good, base, named, normal, confirm, thresholds, scatter)
    series = _tracked_series(figs)
    # every effect of the axis's normal has its strength judged as a tracked one, where the user did
    # not track it: from the axis's usual model fitted together on every night where the axis was
    # confirmed (hil.fleet.batch.confirm_findings), beside the findings that moved (usual_model),
    # else from the values the chain fitted each night
    beside = usual_model(findings)
    for name, (vals, ses) in _usual_series(good, confirm, beside).items():
        series.setdefault(name, (vals, ses, "confirmed"))
    for name, vals in _normal_series(figs, normal).items():
        if name not in series:
            series[name] = (vals, [None] * len(vals), "chain")
    steady = _steady_alone(good, base, confirm, thresholds, scatter) if beside != "normal" else set()
    _judge_all(out, series, good, base, thresholds, scatter, confirm, steady)
    for name, p in finding_params.items():
        out["params"].setdefault(name, p)
    out["normal"] = sorted(normal)
    out["findings"] = findings
    for f in findings:
        if f["strength"] == "as in the baseline":
            continue
        out["flags"].append({"parameter": f["effect"], "since": f["since"], "reason": "named by the chain, "
                             "not in the axis's normal" + (", its strength beyond the baseline's"
                                                           if f["strength"] == "moved" else ""),
                             "from": None, "to": None})
    if out["flags"]:
        out["verdict"] = "drift: " + ", ".join(f"{fl['parameter']} since {fl['since']}" for fl in out["flags"])
        if errors:
            out["verdict"] += f"; {len(errors)} of {len(entries)} records in error"
    elif errors:
        # a record that could not be diagnosed is never counted healthy: the axis is not "ok"
        out["verdict"] = f"records in error: {len(errors)} of {len(entries)} (the other {len(good)} ok)"
    else:
        out["verdict"] = "ok"
    return out


def _judge_all(out: dict, series: dict, good: list[Entry], base: list[int], thresholds: dict, scatter: float,
               confirm: dict | None, steady: set = frozenset()) -> None:
    """Each series ({name: (values, standard errors, source)}) judged against its baseline: its
    entry in ``out["params"]``, a flag where it moved, and ``out["worst"]``. ``steady``: confirmed
    parameters whose move the usual model alone does not see (:func:`_steady_alone`)."""
    worst = None
    after = set(range(max(base) + 1, len(good))) if base else set()
    for name, (vals, ses, source) in sorted(series.items()):
        within = set()
        if source == "confirmed":
            within = _unconfirmed_moves(good, confirm, name, base, scatter) | (after if name in steady else set())
        try:
            j = judge_series(vals, ses, base, thresholds.get(name), scatter, within=within)
        except ValueError:
            continue            # no baseline value: nothing to judge against
        p = {"centre": j.limits.centre, "sigma": j.limits.sigma, "values": vals, "stderr": ses,
             "lower": j.lower, "upper": j.upper, "status": j.status, "flagged": j.flagged,
             "first_moved": good[j.first_moved].timestamp if j.first_moved is not None else None,
             "reasons": j.reasons, "source": source,
             "threshold": thresholds[name].text if name in thresholds else None}
        last = vals[-1]
        drift = abs(last - j.limits.centre) / j.limits.sigma if j.limits.sigma > 0 else 0.0
        p["drift_sigma"] = drift
        out["params"][name] = p
        if j.flagged:
            out["flags"].append({"parameter": name, "since": p["first_moved"], "reason": "; ".join(j.reasons),
                                 "from": j.limits.centre, "to": last})
        if math.isfinite(drift) and (worst is None or drift > worst[1]):     # a night without it: NaN
            worst = (name, drift, j.limits.centre, last)
    if worst is not None:
        out["worst"] = {"parameter": worst[0], "sigma": worst[1], "from": worst[2], "to": worst[3]}


def _findings(good: list[Entry], base: list[int], named: list[set], normal: set, confirm: dict | None,
              thresholds: dict, scatter: float) -> tuple[list[dict], dict]:
    """The effects named after the baseline outside the normal, each with its first date and its
    ``strength`` ("moved", "as in the baseline", or "not fitted": :func:`_confirmed`), and their
    parameters' judged series ({name: entry of ``params``})."""
    params: dict = {}
    found = [{"effect": k, "since": good[i].timestamp} for k, i in new_effects(named, base, normal).items()]
    for f in found:
        moved = _confirmed(f, good, base, confirm, thresholds, scatter, params)
        f["strength"] = "as in the baseline" if moved is False else "moved" if moved else "not fitted"
    return found, params


def _steady_alone(good: list[Entry], base: list[int], confirm: dict | None, thresholds: dict,
                  scatter: float) -> set[str]:
    """The usual model's parameters that do not move where it is fitted alone (``normal``). Beside a
    finding that moved (:func:`usual_model`) a usual effect's move counts only where it moves alone
    as well: a finding named for a look-alike of what appeared (a current loop's lag for a delay of
    1.5 ms) bends the usual effects' fit (a backlash's gap 3.9 -> 3.6 um) where they alone hold."""
    out = set()
    for name, (vals, ses) in _usual_series(good, confirm, "normal").items():
        try:
            j = judge_series(vals, ses, base, thresholds.get(name), scatter,
                             within=_unconfirmed_moves(good, confirm, name, base, scatter))
        except ValueError:
            continue
        if not j.flagged:
            out.add(name)
    return out


def usual_model(findings: list[dict]) -> str:
    """The confirm pass's model whose strengths of the usual effects are judged: the usual model
    beside the findings that moved where one did (hil.fleet.batch fits those again beside each
    other), else the usual model alone ("normal"). The usual model alone is wrong where a new effect
    acts: a constant force of 30 N on the table took its backlash's gap from 3.9 to 1.2 um there,
    and left it at 4.0 um fitted beside the force."""
    moved = sorted(f["effect"] for f in findings if f.get("strength") == "moved")
    return moved[0] if moved else "normal"


def _confirmed(finding: dict, good: list[Entry], base: list[int], confirm: dict | None, thresholds: dict,
               scatter: float, params: dict) -> bool | None:
    """Whether a finding's strength, fitted on every record (``confirm``), left the baseline's limits
    (True), stayed within them on every parameter (False), or could not be judged (None: no fit,
    a record's fit in error, no baseline value). The judged series go into ``params``."""
    if not confirm:
        return None
    figs = [confirm.get(e.id) for e in good]
    if any(f is None or "error" in f or finding["effect"] in f.get("failed", {}) for f in figs):
        return None
    prefix = finding["effect"] + "."
    names = sorted({k for f in figs for k in f.get("values", {}) if k.startswith(prefix)})
    if not names:
        return None
    moved = False
    for name in names:
        vals = [f.get("values", {}).get(name, float("nan")) for f in figs]
        ses = [f.get("stderr", {}).get(name) for f in figs]
        try:
            j = judge_series(vals, ses, base, thresholds.get(name), scatter,
                             within=_unconfirmed_moves(good, confirm, name, base, scatter, finding=True))
        except ValueError:
            return None
        moved = moved or j.flagged
        params.setdefault(name, {"centre": j.limits.centre, "sigma": j.limits.sigma, "values": vals, "stderr": ses,
                                 "lower": j.lower, "upper": j.upper, "status": j.status, "flagged": j.flagged,
                                 "first_moved": good[j.first_moved].timestamp if j.first_moved is not None
                                 else None, "reasons": j.reasons, "source": "confirmed",
                                 "threshold": thresholds[name].text if name in thresholds else None,
                                 "drift_sigma": abs(vals[-1] - j.limits.centre) / j.limits.sigma
                                 if j.limits.sigma > 0 else 0.0})
    return moved


def _unconfirmed_moves(good: list[Entry], confirm: dict | None, name: str, base: list[int], scatter: float,
                       finding: bool = False) -> set[int]:
    """The records (indices) after the baseline at which the move of ``name``'s effect is not
    confirmed (all of them, or none): by what the effect does to the record, its ``contribution``
    per channel (hil.fleet.batch.contribution), :func:`_channels_moved` with the records' noise
    floors (a change the record cannot resolve is none); and for a ``finding``, by the axis's usual
    model's ``unexplained`` residual (its RMS over the noise floor, per channel): a new effect is
    one the usual model needs, where it stops explaining the record as it did the baseline's. One
    channel alone can follow the night's plant (the tip's ringing moves with its stiffness); an
    effect that grew does more in all of them."""
    effect = name.rsplit(".", 1)[0]
    figs = [((confirm or {}).get(e.id) or {}) for e in good]
    if not base:
        return set()
    rest = set(range(max(base) + 1, len(good)))
    unexplained = [f.get("unexplained") for f in figs]
    if finding and all(unexplained):
        rose = _channels_moved(unexplained, [{}] * len(good), base, scatter)
        with_it = [f.get("unexplained_with", {}).get(effect) for f in figs]
        if rose is False or (rose and all(with_it) and not _takes_the_rise(unexplained, with_it, base, scatter)):
            return rest
    per = [f.get("contribution", {}).get(effect) for f in figs]
    moved = _channels_moved(per, [f.get("floor", {}) for f in figs], base, scatter)
    return rest if moved is False else set()


def _channels_moved(per: list, floors: list[dict], base: list[int], scatter: float) -> bool | None:
    """Whether figures per channel ({channel: SI} per record) left the baseline's: each channel
    standardised by the larger of its control limits' spread (hil.fleet.spc.control_limits) and
    the record's ``floors``, the mean over the channels beyond :data:`K_SIGMA` on a record
    after the baseline or alarming the CUSUM; None where a record has no figures."""
    if not per or any(not c for c in per):
        return None
    mean = _mean_z(per, _channel_limits(per, base, scatter), floors)
    after = max(base) + 1
    alarm, _ = cusum_alarm(mean[after:])
    return alarm is not None or any(math.isfinite(m) and abs(m) > K_SIGMA for m in mean[after:])


def _takes_the_rise(usual: list[dict], with_it: list[dict], base: list[int], scatter: float) -> bool:
    """Whether a finding takes away at least :data:`~hil.ident.unexplained.HALF_GAP` of the rise of
    the usual model's unexplained residual (``usual``, {channel: RMS over the floor} per record)
    over its baseline on some record after the baseline, with the finding beside the usual model
    (``with_it``), both standardised by the baseline's limits of ``usual``: the chain's own rule for
    a step, applied to the nights. A steady axis's night leaves more than its baseline's where its
    plant scattered further (the tip's ringing follows its stiffness); an effect fitted there takes
    up a little of it and is no cause of the rise."""
    lims = _channel_limits(usual, base, scatter)
    none = [{}] * len(usual)
    before, after = _mean_z(usual, lims, none), _mean_z(with_it, lims, none)
    return any(math.isfinite(b) and math.isfinite(a) and b > 0 and b - a >= HALF_GAP * b
               for b, a in zip(before[max(base) + 1:], after[max(base) + 1:]))


def _channel_limits(per: list[dict], base: list[int], scatter: float) -> dict:
    """Each channel's control limits over the ``base`` records of ``per`` ({channel: SI} per record);
    a channel without a baseline figure is left out."""
    lims = {}
    for chan in per[0]:
        try:
            lims[chan] = control_limits([per[i].get(chan, math.nan) for i in base], scatter)
        except ValueError:
            continue
    return lims


def _mean_z(per: list[dict], lims: dict, floors: list[dict]) -> list[float]:
    """Per record, the mean over the channels of its figure's distance from the baseline's centre
    in the larger of the limits' spread and the record's floor (NaN: no channel to judge)."""
    out = []
    for c, floor in zip(per, floors):
        z = []
        for chan, lim in lims.items():
            v, s = c.get(chan, math.nan), max(lim.sigma, float(floor.get(chan, 0.0)))
            if math.isfinite(v) and s > 0:
                z.append((v - lim.centre) / s)
        out.append(sum(z) / len(z) if z else math.nan)
    return out


def _usual_series(good: list[Entry], confirm: dict | None, model: str = "normal") -> dict:
    """The strengths of the axis's usual model (its normal effects among them) fitted together on
    every record (``confirm``'s ``normal`` fit; ``model``: that of a finding beside it, where every
    record has it): ``effect.param`` -> (values, standard errors), the usual model's parameters only;
    {} where a record has none or its fit failed."""
    figs = [(confirm or {}).get(e.id) for e in good]
    if any(f is None or "error" in f or "normal" in f.get("failed", {}) for f in figs):
        return {}
    usual = [f.get("models", {}).get("normal") for f in figs]
    if any(fit is None for fit in usual):
        return {}
    fits = [f.get("models", {}).get(model) for f in figs]
    if any(fit is None for fit in fits) or any(model in f.get("failed", {}) for f in figs):
        fits = usual
    names = sorted({k for fit in usual for k in fit.get("values", {})})
    return {n: ([fit["values"].get(n, float("nan")) for fit in fits], [fit.get("stderr", {}).get(n) for fit in fits])
            for n in names}


def _tracked_series(figs: list[dict]) -> dict:
    """The tracked parameters' series: name -> (values, standard errors, "tracked")."""
    names = sorted({k for f in figs for k in f.get("values", {})})
    return {n: ([f.get("values", {}).get(n, float("nan")) for f in figs],
                [f.get("stderr", {}).get(n) for f in figs], "tracked") for n in names}


def _normal_series(figs: list[dict], normal) -> dict:
    """The chain's fitted strength of each normal effect per record: ``effect.param`` -> values
    (NaN where the chain's final model lacks it), from the last step's parameters (every effect the
    model holds after it)."""
    out: dict[str, list] = {}
    finals = []
    for f in figs:
        steps = f.get("chain") or []
        finals.append(steps[-1].get("params", {}) if steps else {})
    for eff in sorted(normal):
        params = sorted({p for fin in finals for p, v in (fin.get(eff) or {}).items()
                         if isinstance(v, (int, float)) and not isinstance(v, bool)})
        for p in params:
            out[f"{eff}.{p}"] = [float((fin.get(eff) or {}).get(p, float("nan"))) for fin in finals]
    return out


def judge_fleet(entries: list[Entry], figures: dict, thresholds: dict, n_baseline: int = N_BASELINE,
                scatter: float = SCATTER, confirm: dict | None = None) -> list[dict]:
    """Every axis judged (see :func:`judge_axis`), in axis order."""
    axes: dict[str, list[Entry]] = {}
    for e in entries:
        axes.setdefault(e.axis, []).append(e)
    return [judge_axis(a, es, figures, thresholds, n_baseline, scatter, confirm) for a, es in sorted(axes.items())]


def rows(entries: list[Entry], figures: dict) -> list[dict]:
    """Every (axis, date, effect, value, standard error) of the fleet, one dict each (SI)."""
    out = []
    for e in entries:
        f = figures.get(e.id, {})
        for name, v in sorted(f.get("values", {}).items()):
            out.append({"axis": e.axis, "date": e.timestamp, "effect": name, "value": v,
                        "stderr": f.get("stderr", {}).get(name), "record": e.record})
    return out
