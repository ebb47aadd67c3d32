"""The sweep: grid runs, the tolerance answer, the dips and a proposed jerk, as one report.

:func:`run_sweep` runs one move per value of :class:`SweepSettings` (``values`` are jerks, or
acceleration times turned into jerks by Eq. 15-16) for each analysis asked, through an executor
(:mod:`hil.sweep.executors`) and the store (:mod:`hil.sweep.store`: runs already in
``runs.jsonl`` are reused). On the primary analysis' tip overshoot it then gives

- with a tolerance: the most conservative largest jerk and the admissible intervals, crossings
  refined by bisection with runs on the simulated plant (:mod:`hil.sweep.curve`), for the swept
  model and for a compared one (``estimate_error_pct`` = 100 (j_compare - j) / j_compare);
- the local minima, explained by the dominant tip frequency f_dom (f_dom T_r = k + 1/2), and the
  jerks where such cancellations are predicted;
- a proposal: the jerk minimizing the tip overshoot among moves no longer than a time budget
  (the grid, the predicted cancellation jerks, then a golden-section search in log jerk).

Refinement and proposal runs are marked ``refine``. The report's keys are the ``--json`` output
of ``hil sweep``. The dwell defaults to max(1 s, 10 periods of the lowest elastic mode); a shorter
one than :func:`min_dwell` is extended to it (:func:`sampling`).
"""
from __future__ import annotations

import logging
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable

import numpy as np
from tqdm import tqdm

from hil.errors import UserError
from hil.profiles import AxisLimits, MoveSpec, check_limits
from hil.sweep.curve import cancellation_jerks, local_minima, tolerance_answer, verify_intervals
from hil.sweep.executors import BackendExecutor, DaskExecutor, LocalExecutor
from hil.sweep.jerk import jmax_to_t_acc
from hil.sweep.model import fingerprint, model_of
from hil.sweep.run import ANALYSES, RUN_FIELDS, RunSpec, backend_trajectory, run_one
from hil.sweep.store import ResultStore

logger = logging.getLogger(__name__)

__all__ = ["SweepSettings", "default_dwell", "lowest_mode_hz", "min_dwell", "run_sweep", "sampling", "warm_up"]


@dataclass
class SweepSettings:
    """What to sweep (SI). ``values`` are t_acc (``by="t_acc"``, needs g0) or j_max values."""
    stroke: float
    feed: float
    values: list
    by: str = "j_max"
    g0: float | None = None
    dwell: float | None = None          # None: max(1 s, 10 periods of the lowest elastic mode)
    record_every: int = 8
    analysis: str = "mechatronic"       # mechatronic | transmission | both
    tolerance: float | None = None      # m, on the tip overshoot
    budget: float | None = None         # s, longest acceptable move time for the proposal
    budget_pct: float | None = 5.0      # or: percent over the fastest move of the range
    refine_rel: float = 0.002
    verify_rel: float = 0.01            # the answer checked by runs this close below it (0: not checked)
    verify_runs: int = 400              # at most this many checking runs (the spacing widens beyond)

    def analyses(self) -> list[str]:
        return list(ANALYSES) if self.analysis == "both" else [self.analysis]

    @property
    def primary(self) -> str:
        return "transmission" if self.analysis == "transmission" else "mechatronic"


def lowest_mode_hz(cfg) -> float | None:
    """The lowest elastic mode of the chain, Hz (None: a rigid chain)."""
    plant, _ = model_of(cfg)
    w, _ = plant.chain.modes()
    el = w[w > 1e-6]
    return float(el.min() / (2 * math.pi)) if el.size else None


def default_dwell(cfg) -> float:
    """The dwell after a move, s: max(1 s, 10 periods of the lowest elastic mode of the chain)."""
    f1 = lowest_mode_hz(cfg)
    return 1.0 if f1 is None else float(max(1.0, 10.0 / f1))


def min_dwell(cfg) -> tuple[float, str]:
    """The shortest dwell whose run still sees the overshoot, s, and why in words.

    The tip overshoots after the command has ended (its residual vibration: a move of the
    paper's bench at 25.56 m/s^3 overshoots 56.5 um in its dwell, 40.2 um up to the command's
    end), and the vibration's largest swings come in its first periods: 10 periods of the lowest
    elastic mode (the bench's latest peak came 1.8 periods after the command, jerks 1-2000
    m/s^3); a loop approaching from below settles with the position loop: 10 time constants
    1/kv (the 2-dof bench: 0.03 um below the target 0.2 s after the command)."""
    _, ctrl = model_of(cfg)
    f1 = lowest_mode_hz(cfg)
    loop = 10.0 / ctrl.kv
    if f1 is not None and 10.0 / f1 > loop:
        return 10.0 / f1, f"10 periods of the lowest elastic mode, {f1:.3g} Hz"
    return loop, f"10 time constants 1/kv of the position loop, kv {ctrl.kv:.3g} 1/s"


def sampling(s: SweepSettings, *cfgs) -> tuple[float, str | None]:
    """The dwell the runs take and a note when it is not the one asked for; refuses (one line) a
    record too sparse for the dominant frequency.

    A dwell shorter than :func:`min_dwell` (of every model swept) would miss the overshoot that
    comes after the command (issue 30: ``--dwell 0s`` answered 25.54 m/s^3 where the first
    crossing is 14.03): it is extended to that, and the note says so. ``record_every`` is at most
    one sample per position tick and 4 per period of the lowest elastic mode (the overshoot
    itself is always taken on the velocity-loop grid, hil.sweep.run)."""
    dwell = s.dwell if s.dwell is not None else default_dwell(cfgs[0])
    need, why = max(min_dwell(c) for c in cfgs if c is not None)
    note = None
    if dwell < need:
        note = (f"the dwell of {dwell:.3g} s was extended to {need:.3g} s ({why}): a shorter one misses the "
                f"overshoot that comes after the command")
        dwell = need
    for c in cfgs:
        if c is None:
            continue
        _, ctrl = model_of(c)
        top = ctrl.substeps
        f1 = lowest_mode_hz(c)
        if f1 is not None:
            top = max(1, min(top, int(1.0 / (4.0 * f1 * ctrl.velocity_period))))
        if not 1 <= s.record_every <= top:
            raise UserError(f"--record-every {s.record_every}: expected 1 .. {top} velocity steps per sample "
                            f"({top * ctrl.velocity_period * 1e3:.3g} ms: one sample per position tick and at least "
                            f"4 per period of the lowest elastic mode, for the dominant-frequency estimate)")
    return dwell, note


# the longest run (move and dwell) a sweep simulates, s: one run on the velocity-loop grid holds
# about 1.3 MB per simulated second (3 masses); a 100 m stroke asked for 33 min and never answered
MAX_RUN_S = 60.0


def check_run_length(s: SweepSettings, dwell: float) -> None:
    """Refuse (one line) a sweep whose longest run would last more than :data:`MAX_RUN_S`."""
    from hil.profiles import plan_move
    for v in s.values:
        spec = (MoveSpec(s.stroke, s.feed, t_acc=float(v), g0=s.g0) if s.by == "t_acc"
                else MoveSpec(s.stroke, s.feed, j_max=float(v), g0=s.g0))
        try:
            length = plan_move(spec).duration + dwell
        except ValueError as exc:
            raise UserError(f"--stroke {s.stroke:g} m, --feed {s.feed:g} m/s: {exc}") from None
        if not length <= MAX_RUN_S:
            raise UserError(f"--stroke {s.stroke * 1e3:g} mm at --feed {s.feed * 6e4:g} mm/min: a run of "
                            f"{length:.4g} s (move and dwell), at most {MAX_RUN_S:g} s per run: a shorter stroke "
                            f"or a higher feed")


class _Runner:
    """Runs specs through an executor and a store, with a progress bar."""

    def __init__(self, cfg, executor, store: ResultStore, progress: bool, backend: str = "model"):
        self.cfg, self.ex, self.store, self.progress = cfg, executor, store, progress
        self.fp = fingerprint(cfg)
        self.backend = backend

    def many(self, specs: list[RunSpec], desc: str) -> list[dict]:
        keys = [s.key(self.fp, self.backend) for s in specs]
        todo, seen = [], set()
        for k, s in zip(keys, specs):
            if k in self.store.done:
                self.store.reused += 1
            elif k not in seen:
                todo.append((k, s))
                seen.add(k)
        if todo:
            specs_by_key = dict(todo)
            with tqdm(total=len(todo), desc=desc, unit="run", file=sys.stderr, disable=not self.progress,
                      leave=False) as bar:
                for key, fig in self.ex.map(self.cfg, todo):
                    self.store.add(key, fig, specs_by_key[key])
                    bar.update(1)
        return [self.store.done[k] for k in keys]

    def one(self, spec: RunSpec) -> dict:
        k = spec.key(self.fp, self.backend)
        if k in self.store.done:
            self.store.reused += 1
        else:
            key, fig = self.ex.one(self.cfg, k, spec)
            self.store.add(key, fig, spec)
        return self.store.done[k]


def _specs(s: SweepSettings, analysis: str, dwell: float) -> list[RunSpec]:
    out = []
    for v in s.values:
        if s.by == "t_acc":
            out.append(RunSpec(analysis, s.stroke, s.feed, s.g0, float(v), None, dwell, s.record_every))
        else:
            out.append(RunSpec(analysis, s.stroke, s.feed, s.g0, None, float(v), dwell, s.record_every))
    return out


def _rows(specs, figs) -> list[dict]:
    rows = []
    for s, f in zip(specs, figs):
        row = {k: f.get(k) for k in RUN_FIELDS}
        row["refine"] = s.refine
        rows.append(row)
    rows.sort(key=lambda r: r["j_max"])
    return rows


def _model_side(runner: _Runner, s: SweepSettings, dwell: float, tag: str) -> dict:
    """Grid runs of every analysis, and the tolerance answer of the primary one."""
    side = {}
    for an in s.analyses():
        specs = _specs(s, an, dwell)
        side[an] = _rows(specs, runner.many(specs, f"{tag} {an}"))
    if s.tolerance is not None:
        rows = side[s.primary]
        j = [r["j_max"] for r in rows]
        y = [r["overshoot_tip_um"] * 1e-6 for r in rows]

        def f(jm):
            spec = RunSpec(s.primary, s.stroke, s.feed, s.g0, None, float(jm), dwell, s.record_every, True)
            return runner.one(spec)["overshoot_tip_um"] * 1e-6

        ans = tolerance_answer(j, y, s.tolerance, f, s.refine_rel, y_scale=1e6, y_unit="um")
        if ans["admissible"] and s.verify_rel:
            # every admissible interval checked by runs, not interpolated (curve.verify_intervals)
            def f_many(js):
                specs = [RunSpec(s.primary, s.stroke, s.feed, s.g0, None, float(v), dwell, s.record_every, True)
                         for v in js]
                return [r["overshoot_tip_um"] * 1e-6 for r in runner.many(specs, f"{tag} verify")]
            v = verify_intervals(j, y, s.tolerance, ans["admissible"], f, f_many, s.refine_rel, s.verify_rel,
                                 s.verify_runs)
            first = v["intervals"][0] if v["intervals"] and v["intervals"][0][0] == j[0] else None
            ans["verification"] = {"runs": v["runs"], "spacing_rel": v["spacing_rel"],
                                   "largest_overshoot_um": (v["largest_within"][0] * 1e6 if first
                                                            else y[0] * 1e6),
                                   "moved": v["moved"],
                                   "peaks": [{"j_max": p["j_max"], "overshoot_tip_um": p["overshoot"] * 1e6}
                                             for p in v["peaks"]],
                                   "bracket_rel": s.refine_rel}
            ans["admissible"] = v["intervals"]
            if first is not None and first[1] < j[-1]:
                # the first crossing, found by the runs (a grid within the tolerance everywhere
                # may hide an excursion: then the note asking for a wider range no longer holds)
                ans["max_jerk"], ans["note"] = first[1], None
            elif first is None:
                ans["max_jerk"] = None
        side["tolerance"] = ans
    return side


def _explain_minima(rows, s: SweepSettings) -> tuple[list[dict], float | None, list[dict]]:
    j = [r["j_max"] for r in rows]
    y = [r["overshoot_tip_um"] for r in rows]
    fd = [r["f_dom_tip_hz"] for r in rows if r["f_dom_tip_hz"] and r["residual_tip_um"] and r["residual_tip_um"] > 0.01]
    f_dom = float(np.median(fd)) if fd else None
    mins = []
    for i in local_minima(j, y):
        r = rows[i]
        m = {"j_max": r["j_max"], "t_acc": r["t_acc"], "overshoot_tip_um": r["overshoot_tip_um"],
             "ramp_time": r["ramp_time"]}
        if f_dom:
            c = f_dom * r["ramp_time"]
            k = max(1, int(round(c - 0.5)))
            m.update(f_dom_hz=f_dom, cycles=c,
                     explanation=(f"the ramp lasts T_r = {r['ramp_time'] * 1e3:.1f} ms = {c:.2f} periods of the "
                                  f"dominant {f_dom:.2f} Hz; a sine-square ramp leaves no vibration at f_dom when "
                                  f"f_dom T_r = k + 1/2 (here nearest {k + 0.5:.1f}, jerk "
                                  f"{math.pi ** 2 * s.feed / (2 * ((k + 0.5) / f_dom) ** 2):.4g} m/s^3)"))
        mins.append(m)
    pred = cancellation_jerks(f_dom, s.feed, min(j), max(j)) if f_dom and j else []
    return mins, f_dom, pred


def _propose(runner: _Runner, rows, s: SweepSettings, dwell: float, predicted) -> dict:
    """The jerk minimizing the tip overshoot among moves no longer than the budget: the grid, the
    predicted cancellation jerks, then a golden-section search between the best point's neighbours."""
    an = s.primary

    def ev(jm):
        spec = RunSpec(an, s.stroke, s.feed, s.g0, None, float(jm), dwell, s.record_every, True)
        return runner.one(spec)

    fastest = min(r["duration"] for r in rows)
    budget = s.budget
    if budget is None and s.budget_pct is not None:
        budget = fastest * (1.0 + s.budget_pct / 100.0)

    def fits(f):
        return budget is None or f["duration"] <= budget * (1 + 1e-12)

    cands = [r for r in rows if fits(r)]
    for p in predicted:
        f = ev(p["j_max"])
        if fits(f):
            cands.append(f)
    if not cands:
        return {"j_max": None, "note": f"no move of the range fits the time budget of {budget:.4g} s "
                                       f"(the fastest takes {fastest:.4g} s): raise --budget or the jerk range"}
    grid = sorted(rows, key=lambda r: r["j_max"])
    best = min(cands, key=lambda r: (r["overshoot_tip_um"], -r["j_max"]))
    # golden-section search (log jerk) between the best point's grid neighbours
    js = [r["j_max"] for r in grid]
    lo = max([v for v in js if v < best["j_max"]], default=best["j_max"])
    hi = min([v for v in js if v > best["j_max"]], default=best["j_max"])
    if hi > lo:
        g = (math.sqrt(5) - 1) / 2
        a, b = math.log(lo), math.log(hi)
        c, d = b - g * (b - a), a + g * (b - a)

        def cost(x):
            f = ev(math.exp(x))
            return (f["overshoot_tip_um"] if fits(f) else math.inf), f

        fc, rc = cost(c)
        fdd, rd = cost(d)
        for _ in range(14):
            if fc <= fdd:
                b, d, fdd, rd = d, c, fc, rc
                c = b - g * (b - a)
                fc, rc = cost(c)
            else:
                a, c, fc, rc = c, d, fdd, rd
                d = a + g * (b - a)
                fdd, rd = cost(d)
            for r, fv in ((rc, fc), (rd, fdd)):
                if fv < best["overshoot_tip_um"]:
                    best = r
    out = {k: best.get(k) for k in ("j_max", "t_acc", "a_max", "duration", "overshoot_tip_um",
                                    "overshoot_table_um", "residual_tip_um")}
    out["budget_s"] = budget
    out["fastest_s"] = fastest
    out["analysis"] = an
    return out


def run_sweep(cfg, settings: SweepSettings, *, compare_cfg=None, out_dir: str | Path | None = None,
              jobs: int | None = None, scheduler=None, backend: str | None = None, progress: bool = True,
              resume: bool = True, propose: bool = True, scope=None, can_log: str | None = None) -> dict:
    """Run a sweep and its analyses; returns the report (the issue's JSON object, and more).

    ``scheduler``: a dask.distributed address (or Client) to run on; ``jobs``: local processes
    (default: all cores); ``backend``: run the mechatronic moves on that runtime backend instead of
    the simulated plant; ``out_dir``: where ``runs.jsonl`` (resume) lives; ``scope``: a
    :class:`~hil.scope.ring.ScopeRing` the backend's runs write into (the live scope); ``can_log``:
    the backend's runs traced on the CAN bus, one file per run
    (:class:`~hil.sweep.executors.BackendExecutor`)."""
    logger.info("sweep of %s: %d values, analysis %s, backend %s", cfg.source, len(settings.values),
                settings.analysis, backend or "model")
    s = settings
    if s.by == "t_acc" and not s.g0:
        raise ValueError("a t_acc sweep needs the rapid speed g0 (nc.g0 in the config, or --g0)")
    if s.analysis not in ANALYSES + ("both",):
        raise ValueError(f"analysis: mechatronic, transmission or both, not {s.analysis!r}")
    dwell, dwell_note = sampling(s, cfg, compare_cfg)
    check_run_length(s, dwell)
    if backend and s.verify_rel:
        # hundreds of checking moves on an axis: the answer is checked on the simulated plant only
        s = replace(s, verify_rel=0.0)
    store = ResultStore(None if out_dir is None else Path(out_dir) / "runs.jsonl", resume=resume)
    if backend:
        lim = AxisLimits.from_config(cfg)
        for spec in _specs(s, "mechatronic", dwell):      # refuse before any motion
            check_limits(backend_trajectory(spec)[0], lim)
        ex = BackendExecutor(backend, out_dir, scope=scope, can_log=can_log)
    elif scheduler is not None:
        ex = DaskExecutor(scheduler)
    else:
        ex = LocalExecutor(jobs)
        # compile (or load from the cache) and build the models here, before the workers fork
        for c in (cfg, compare_cfg):
            if c is not None:
                warm_up(c, s.analyses())
    report = {"config": cfg.source, "name": cfg.get("meta.name", ""),
              "move": {"stroke_m": s.stroke, "feed_m_per_s": s.feed, "g0_m_per_s": s.g0, "dwell_s": dwell,
                       "record_period_s": s.record_every * model_of(cfg)[1].velocity_period, "swept": s.by},
              "analysis": s.analysis}
    try:
        runner = _Runner(cfg, ex, store, progress, backend or "model")
        main = _model_side(runner, s, dwell, "sweep")
        report["runs"] = main[s.primary]
        if s.analysis == "both":
            report["runs_transmission"] = main["transmission"]
        notes = [dwell_note] if dwell_note else []
        if s.tolerance is not None:
            t = main["tolerance"]
            report.update(tolerance_um=s.tolerance * 1e6, max_jerk=t["max_jerk"], admissible=t["admissible"],
                          verification=t.get("verification"))
            report["max_jerk_t_acc"] = (jmax_to_t_acc(t["max_jerk"], s.feed, s.g0)
                                        if t["max_jerk"] and s.g0 else None)
            if t["note"]:
                notes.append(t["note"])
        if compare_cfg is not None:
            cmp_runner = _Runner(compare_cfg, ex, store, progress, backend or "model")
            other = _model_side(cmp_runner, s, dwell, "compare")
            report["compare_config"] = compare_cfg.source
            report["compare_runs"] = other[s.primary]
            if s.analysis == "both":
                report["compare_runs_transmission"] = other["transmission"]
            if s.tolerance is not None:
                t = other["tolerance"]
                report.update(max_jerk_compare=t["max_jerk"], admissible_compare=t["admissible"],
                              verification_compare=t.get("verification"))
                if t["note"]:
                    notes.append("compare model: " + t["note"])
                mj, mc = report["max_jerk"], report["max_jerk_compare"]
                report["estimate_error_pct"] = (100.0 * (mc - mj) / mc if mj is not None and mc else None)
                if report["estimate_error_pct"] is None:
                    notes.append("estimate_error_pct needs max_jerk and max_jerk_compare")
        mins, f_dom, pred = _explain_minima(report["runs"], s)
        report["dominant_frequency_hz"] = f_dom
        report["local_minima"] = mins
        report["predicted_cancellation"] = pred
        if propose and report["runs"]:
            report["proposal"] = _propose(runner, report["runs"], s, dwell, pred)
        report["note"] = "; ".join(notes) if notes else None
        report["answer"] = sweep_answer(report)
    finally:
        ex.close()
    report["stats"] = {"computed": store.computed, "reused": store.reused}
    return report


def sweep_answer(r: dict) -> dict:
    """The answer to the question the sweep was asked, one for the headline of the report, the text
    and the JSON: with a tolerance, the largest jerk keeping the tip within it (the proposal, which
    minimizes the overshoot within a move time, is another question); else the proposed jerk; else
    the smallest tip overshoot swept. {"question", "j_max" (m/s^3, None: none), "text"}."""
    p = r.get("proposal") or {}
    if r.get("tolerance_um") is not None:
        mj, tol = r.get("max_jerk"), r["tolerance_um"]
        t_acc = r.get("max_jerk_t_acc")
        text = (f"largest jerk keeping the tip within {tol:.3g} um: "
                + (f"{mj:.4g} m/s^3" + (f" (t_acc {t_acc * 1e3:.0f} ms)" if t_acc else "") if mj
                   else "none in the swept range"))
        return {"question": f"largest jerk keeping the tip within {tol:g} um", "j_max": mj, "text": text}
    if p.get("j_max"):
        text = (f"proposed j_max {p['j_max']:.4g} m/s^3" + (f" (t_acc {p['t_acc'] * 1e3:.0f} ms)" if p.get("t_acc")
                                                          else "")
                + f": tip overshoot {p['overshoot_tip_um']:.3g} um, move {p['duration']:.3f} s"
                + (f" (budget {p['budget_s']:.3f} s)" if p.get("budget_s") else ""))
        return {"question": "the jerk minimizing the tip overshoot within the move-time budget", "j_max": p["j_max"],
                "text": text}
    runs = r.get("runs") or []
    if not runs:
        return {"question": "overshoot against jerk", "j_max": None, "text": "no run"}
    best = min(runs, key=lambda x: x["overshoot_tip_um"])
    return {"question": "overshoot against jerk", "j_max": best["j_max"],
            "text": f"{len(runs)} moves swept; the smallest tip overshoot, {best['overshoot_tip_um']:.3g} um, at "
                    f"j_max {best['j_max']:.4g} m/s^3" + (f" ({p['note']})" if p.get("note") else "")}


def warm_up(cfg, analyses: Iterable[str] = ANALYSES) -> None:
    """Build the model and run a tiny move so that the compiled code is loaded in this process."""
    spec = MoveSpec(1e-3, 0.01, j_max=10.0)
    plant, ctrl = model_of(cfg)
    for an in analyses:
        rs = RunSpec(an, spec.stroke, spec.feed, None, None, spec.j_max, 0.02, 8)
        if an == "transmission" and plant.n < 2:
            continue
        run_one(cfg, rs)
