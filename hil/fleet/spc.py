"""Statistical process control of a fleet: every record judged against its own axis's history.

Pure functions on plain lists (no I/O), so that each rule is tested on a series with a known answer.

Conventions: a *series* is one tracked parameter of one axis (``backlash.gap``), its records in
time order: ``values`` (SI), ``stderrs`` (the fit's standard error of each value, SI; NaN or None:
none) and ``dates`` (text, ISO 8601 as the manifest gives them).

Control limits (:func:`control_limits`) come from the axis's *baseline* records (the first
``n_baseline``, or those the manifest names): the centre is their mean; the spread is the
night-to-night scatter of a healthy axis, which is far larger than one fit's standard error
(parameters move by about a percent with temperature and load), so it is the larger of the
baseline's sample standard deviation and ``scatter`` x |centre|. Each record's own standard error
is added in quadrature: sigma_i = sqrt(s^2 + se_i^2). A record is out of control when
|x_i - centre| > k sigma_i (Shewhart, k = 3 by default) or when a one-sided CUSUM of
z_i = (x_i - centre) / sigma_i (reference 0.5, decision interval 4, either side) alarms (a slow
drift crosses the CUSUM's interval before it leaves 3 sigma). The date it *first moved*
(:func:`change_point`) is the least-squares change point of the standardised deviations from the
end of the baseline to the last record, no later than the first alarm: a step (zero, then one
level) or a ramp (zero, then a line from zero), whichever fits better (a step estimate alone dates
a ramp late, the CUSUM's own estimate, the record after its last zero, dates a step early when the
night before it happened to lie high).

A physical threshold (``backlash.gap > 10um``) flags a record whose value is beyond it, whatever
its history says.

An effect that the diagnosis chain names on every baseline record is the axis's *normal*
(:func:`normal_effects`); only an effect named later, not in the normal, on two records in a row
or on the latest one, is a finding (:func:`new_effects`).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from hil.errors import ConfigError

__all__ = ["Limits", "Threshold", "control_limits", "judge_series", "change_point", "cusum_alarm", "parse_threshold", "normal_effects",
           "usual_effects", "new_effects", "K_SIGMA", "CUSUM_K", "CUSUM_H", "SCATTER"]

K_SIGMA = 3.0          # Shewhart limits: centre +- 3 sigma
CUSUM_K = 0.5          # CUSUM reference value (in sigma): detects a shift of about 1 sigma
CUSUM_H = 4.0          # CUSUM decision interval (in sigma)
SCATTER = 0.01         # the least night-to-night scatter of a healthy axis, relative to the centre


@dataclass
class Limits:
    """The control limits of one series: centre and the baseline's spread ``sigma`` (SI), before
    each record's own standard error is added."""
    centre: float
    sigma: float
    n_baseline: int

    def band(self, stderr: float | None = None, k: float = K_SIGMA) -> tuple[float, float]:
        """(lower, upper) limit for a record with standard error ``stderr``."""
        s = self.sigma_for(stderr)
        return self.centre - k * s, self.centre + k * s

    def sigma_for(self, stderr: float | None) -> float:
        se = stderr if stderr is not None and math.isfinite(stderr) else 0.0
        return math.sqrt(self.sigma ** 2 + se ** 2)


@dataclass
class Threshold:
    """A physical limit on a tracked parameter: ``name`` (``effect.param``), ``op`` ``>`` or ``<``,
    ``value`` (SI) and the text as written."""
    name: str
    op: str
    value: float
    text: str

    def crossed(self, x: float) -> bool:
        return x > self.value if self.op == ">" else x < self.value


@dataclass
class SeriesJudgement:
    """What :func:`judge_series` finds: per record, ``status`` ("baseline", "ok", "out", "threshold")
    and the band; ``flagged`` and ``first_moved`` (index) when the series left its limits."""
    limits: Limits
    status: list[str]
    lower: list[float]
    upper: list[float]
    flagged: bool = False
    first_moved: int | None = None
    first_alarm: int | None = None
    threshold_first: int | None = None
    reasons: list[str] = field(default_factory=list)


def _finite(x) -> bool:
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


def control_limits(values: list[float], scatter: float = SCATTER) -> Limits:
    """The limits from the baseline ``values``: centre = mean, sigma = max(sample standard
    deviation (n - 1), scatter * |centre|); NaN (a fit without a value) left out."""
    vals = [float(v) for v in values if _finite(v)]
    if not vals:
        raise ValueError("no baseline value to set control limits from")
    n = len(vals)
    centre = sum(vals) / n
    sd = math.sqrt(sum((v - centre) ** 2 for v in vals) / (n - 1)) if n > 1 else 0.0
    return Limits(centre, max(sd, scatter * abs(centre)), n)


def cusum_alarm(z: list[float], k: float = CUSUM_K, h: float = CUSUM_H) -> tuple[int | None, int | None]:
    """Tabular CUSUM of standardised deviations ``z`` on both sides: (index of the first alarm,
    change-point estimate: the record after the alarming side's last zero), or (None, None)."""
    hi = lo = 0.0
    last_hi = last_lo = -1
    for i, zi in enumerate(z):
        if not _finite(zi):
            continue
        hi = max(0.0, hi + zi - k)
        lo = max(0.0, lo - zi - k)
        if hi == 0.0:
            last_hi = i
        if lo == 0.0:
            last_lo = i
        if hi > h:
            return i, last_hi + 1
        if lo > h:
            return i, last_lo + 1
    return None, None


def change_point(z: list[float], start: int, latest: int) -> int:
    """The record a shift began at, from standardised deviations ``z`` (the baseline's centre is
    zero): the tau in [start, latest] of least squared error of a step (0 before tau, the mean of
    z[tau:] after) or a ramp (0 before, beta (i - tau + 1) from tau on, beta fitted), over every
    record from ``start`` on; the earliest on a tie."""
    idx = [i for i in range(start, len(z)) if _finite(z[i])]
    best = None
    for tau in range(start, latest + 1):
        before = sum(z[i] ** 2 for i in idx if i < tau)
        after = [(i, z[i]) for i in idx if i >= tau]
        if not after:
            continue
        mean = sum(v for _, v in after) / len(after)
        step = before + sum((v - mean) ** 2 for _, v in after)
        w = [(i - tau + 1, v) for i, v in after]
        beta = sum(a * v for a, v in w) / sum(a * a for a, _ in w)
        ramp = before + sum((v - beta * a) ** 2 for a, v in w)
        sse = min(step, ramp)
        if best is None or sse < best[0] - 1e-12 * max(1.0, abs(best[0])):
            best = (sse, tau)
    return start if best is None else best[1]


def judge_series(values: list[float], stderrs: list[float | None], baseline: list[int],
                 threshold: Threshold | None = None, scatter: float = SCATTER, k: float = K_SIGMA,
                 within=()) -> SeriesJudgement:
    """Judge one series (time order) against the limits of its ``baseline`` indices.

    A record after the baseline is ``out`` when it is beyond centre +- k sigma_i; the series is
    flagged when a record is out or the CUSUM alarms after the baseline (``first_alarm``: the
    earlier); ``first_moved`` is :func:`change_point` up to that alarm (never a baseline record).
    ``within``: indices of records that cannot tell their value from the baseline's centre (the
    record itself, replayed: hil.fleet.batch.told_apart): never out, and no deviation in the
    CUSUM. ``threshold`` flags any record beyond it (``threshold_first``).
    """
    lim = control_limits([values[i] for i in baseline], scatter)
    status, lower, upper, z = [], [], [], []
    first_out = None
    base = set(baseline)
    after = max(baseline) + 1 if baseline else 0
    for i, (x, se) in enumerate(zip(values, stderrs)):
        lo, hi = lim.band(se, k)
        lower.append(lo)
        upper.append(hi)
        s = lim.sigma_for(se)
        z.append((x - lim.centre) / s if _finite(x) and s > 0 and i not in within else float("nan"))
        if i in base:
            status.append("baseline")
        elif _finite(x) and not lo <= x <= hi and i not in within:
            status.append("out")
            if first_out is None and i >= after:
                first_out = i
        else:
            status.append("ok")
    out = SeriesJudgement(lim, status, lower, upper)
    # the CUSUM runs from the end of the baseline: the baseline defines zero
    alarm, _ = cusum_alarm(z[after:], k=CUSUM_K, h=CUSUM_H)
    alarm = None if alarm is None else alarm + after
    if first_out is not None or alarm is not None:
        out.flagged = True
        out.first_alarm = min(i for i in (first_out, alarm) if i is not None)
        out.first_moved = change_point(z, after, out.first_alarm)
        out.reasons.append("left its control limits")
    if threshold is not None:
        for i, x in enumerate(values):
            if _finite(x) and threshold.crossed(x):
                status[i] = "threshold"
                out.threshold_first = i if out.threshold_first is None else out.threshold_first
        if out.threshold_first is not None:
            out.flagged = True
            out.first_moved = out.threshold_first if out.first_moved is None else min(out.first_moved,
                                                                                      out.threshold_first)
            out.reasons.append(f"beyond {threshold.text}")
    return out


_THRESHOLD = re.compile(r"^\s*([A-Za-z_][\w:.]*)\s*([<>])(?!=)\s*([^<>=]+?)\s*$")


def parse_threshold(text: str, kinds: dict[str, str], where: str) -> Threshold:
    """``"backlash.gap > 10um"`` (or ``"backlash > 10um"``: the effect's first parameter) as a
    :class:`Threshold`; ``kinds`` maps every tracked ``effect.param`` to its unit kind (hil.units).
    A name not tracked, a comparison other than > or <, or a value without its unit is refused
    naming ``where``."""
    from hil.units import DIMENSIONS, UnitError, parse_option
    m = _THRESHOLD.match(text)
    if not m:
        raise ConfigError(f"{where}: {text!r}: expected 'effect.parameter > value' or '< value', e.g. "
                          f"'backlash.gap > 10um'")
    name, op, value = m.groups()
    if name not in kinds:
        firsts = {k.split(".", 1)[0]: k for k in reversed(list(kinds))}
        if name in firsts:
            name = firsts[name]
        else:
            raise ConfigError(f"{where}: {text!r}: {name} is not a tracked parameter (tracked: "
                              f"{', '.join(kinds) or 'none'})")
    kind = kinds[name]
    try:
        v = parse_option(value, kind if kind in DIMENSIONS else "dimensionless", f"{where} {name}")
    except UnitError as exc:
        raise ConfigError(str(exc)) from None
    return Threshold(name, op, float(v), text.strip())


def normal_effects(named: list[set[str]], baseline: list[int]) -> set[str]:
    """The effects the chain names on every baseline record of an axis (its normal)."""
    sets = [named[i] for i in baseline if i < len(named)]
    return set.intersection(*sets) if sets else set()


def usual_effects(named: list[set[str]], baseline: list[int]) -> set[str]:
    """The effects the chain names on more than half of an axis's baseline records: the model its
    strengths are fitted in (hil.fleet.batch.confirm_findings). A friction the chain calls
    load-dependent on one night and Coulomb on the others is no normal effect, yet a backlash
    fitted without it takes it up."""
    sets = [named[i] for i in baseline if i < len(named)]
    return {e for e in set().union(*sets) if 2 * sum(e in s for s in sets) > len(sets)} if sets else set()


def new_effects(named: list[set[str]], baseline: list[int], normal: set[str]) -> dict[str, int]:
    """Effects outside the axis's normal that the chain names after the baseline and keeps naming:
    on two records in a row, or on the latest record (one stray verdict on a noisy night is not a
    finding). Effect -> index of the first record of its first such run."""
    after = max(baseline) + 1 if baseline else 0
    out: dict[str, int] = {}
    for eff in sorted(set().union(*named[after:]) - normal if named[after:] else set()):
        hits = [i for i in range(after, len(named)) if eff in named[i]]
        for i in hits:
            if i + 1 in hits or i == len(named) - 1:
                out[eff] = i
                break
    return out
