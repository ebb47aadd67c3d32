"""The HTML reports of hil compare, diagnose, emps, sweep, frf and tune: one self-contained file each,
read top to bottom, that travels (mailed, attached to a ticket, opened years later).

* One file: the style is inline and every figure is embedded as a base64 PNG ``data:`` URI;
  nothing is linked, no script runs.
* Laid out by Jinja2 templates (``hil/plots/templates``, autoescaped: a name with ``<`` or ``&``
  stays text); this module only prepares the numbers, as text in engineering units
  (hil.plots.engineering: um, mm, ms, N m, never SI e-notation).
* Every report starts with its title, its verdict (the sentence to read if nothing else is read,
  ``#verdict``) and where it comes from: the date (UTC), the project's version, the record and
  the config files.
* The estimation-against-validation errors of issue 15 have their place in every report: pass
  ``validation``, a list of tables ``{"title", "note", "header": [...], "rows": [[...]],
  "numeric": [column indices]}`` (cells as text, in engineering units); the section
  ``#validation`` follows the errors' table, and is left out when there is none.
"""
from __future__ import annotations

import base64
import datetime as _dt
import math
import struct
from pathlib import Path

from hil.ident.scores import fmt_fit
from hil.io.safe_write import write_atomic
from hil.plots.engineering import display_unit, eng, engineering_text, fmt, unit_label

__all__ = ["write_report", "write_diagnosis_report", "write_sweep_report", "write_frf_report", "write_tune_report",
           "render", "report_meta", "embed_png"]

TEMPLATES = Path(__file__).resolve().parent / "templates"

# what each figure of hil.plots.residual_figures shows, by its file's stem (without a tag)
CAPTIONS = {
    "overlay": "Measured and simulated channels against time, each with its residual (measured minus simulated) "
               "beneath on the same time axis; the legend gives each model's fit (NRMSE) %.",
    "residual": "The residual (measured minus simulated) against time.",
    "spectrum": "Amplitude spectrum of the residual (Hann window).",
    "scatter": "The residual against the commanded velocity, acceleration and position: a pattern names "
               "the effect (a step at v = 0: Coulomb friction; a slope against v: viscous; against x: "
               "position-dependent).",
    "correlation": "MATLAB resid: the residual's autocorrelation (left) and its cross-correlation with the commanded "
             "velocity (right); shaded: the 99 % confidence band of a white residual independent of the input.",
    "error_fall": "Relative errors as the effects are added one by one.",
    "sweep": "Overshoot against the maximum commanded jerk: table (left) and tool tip (right).",
    "bode_plant": "Measured frequency responses of the plant against the model (magnitude and phase).",
    "bode_loops": "Measured frequency responses of the velocity and position loops against the model.",
    "coherence": "Coherence of the measured responses (1: noise-free and linear).",
    "tune_loops": "The open velocity and position loops as measured, with the gains as given (grey) and as tuned: "
                  "the phase margin is read where the magnitude crosses 0 dB, the gain margin where the phase "
                  "crosses -180 deg.",
    "tune": "Left: the tool tip's distance from its target after the start of the move, as given and tuned, with "
            "the tolerance band (dotted: within it for good). Right: each shaper's residual vibration against the "
            "tip mode's frequency error, the error the choice tolerates shaded.",
}


def _environment():
    import jinja2
    return jinja2.Environment(loader=jinja2.FileSystemLoader(str(TEMPLATES)), autoescape=True,
                              undefined=jinja2.StrictUndefined, trim_blocks=False, lstrip_blocks=False,
                              keep_trailing_newline=True)


def render(template: str, **context) -> str:
    """The text of ``template`` (a file of hil/plots/templates) with ``context``."""
    return _environment().get_template(template).render(**context)


def _write(path: Path, text: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, text)
    return path


# --- pieces every report has -------------------------------------------------------------------

def report_meta(record: str | None = None, configs=(), extra=(), date: _dt.datetime | None = None) -> dict:
    """Where a report comes from: date (UTC), version, record, configs (pairs of role and file) and
    ``extra`` pairs, as the rows of the header's table."""
    from hil import __version__
    date = date or _dt.datetime.now(_dt.timezone.utc)
    stamp = date.astimezone(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    rows = [("date", stamp), ("hil version", __version__)]
    if record is not None:
        rows.append(("record", str(record)))
    rows += [(role, str(name)) for role, name in configs if name]
    rows += [(k, str(v)) for k, v in extra]
    return {"date": stamp, "version": __version__, "rows": rows}


def _png_size(data: bytes):
    """(width, height) of a PNG from its IHDR chunk, or None."""
    if data[:8] != b"\x89PNG\r\n\x1a\n" or len(data) < 24:
        return None
    return struct.unpack(">II", data[16:24])


def embed_png(path, caption: str | None = None) -> dict:
    """A figure for the templates: the PNG at ``path`` as a ``data:`` URI, with its caption (the
    one of CAPTIONS for its name when none is given) and its size."""
    path = Path(path)
    data = path.read_bytes()
    size = _png_size(data)
    stem = path.stem
    base = next((k for k in sorted(CAPTIONS, key=len, reverse=True) if stem.startswith(k)), stem)
    return {"src": "data:image/png;base64," + base64.b64encode(data).decode("ascii"),
            "alt": stem.replace("_", " "), "caption": caption if caption is not None else CAPTIONS.get(base, ""),
            "width": size[0] if size else None, "height": size[1] if size else None}


def _table(header, rows, numeric=(), caption=None) -> dict:
    return {"header": list(header), "rows": [list(r) for r in rows], "numeric": list(numeric), "caption": caption}


def _in(value, unit_scale) -> str:
    """``value`` in a display unit (name, SI per unit), with the unit."""
    if value is None:
        return "-"
    name, k = unit_scale
    return f"{fmt(value, 4, k)} {name}".rstrip()


def _pct(value, digits: int = 2) -> str:
    if value is not None and not math.isfinite(value):      # an NRMSE fit of a constant channel
        return "undefined"
    return "-" if value is None else f"{value:.{digits}f} %"


def _signed(value) -> str:
    return "-" if value is None else f"{value:+.2f}"


# --- model against measurement (compare, emps, diagnose) ---------------------------------------

def _models(analysis: dict, after: dict | None, names: tuple[str, str]):
    return [(names[0], analysis)] + ([(names[1], after)] if after else [])


def _errors_table(models) -> dict:
    chans = list(models[0][1]["channels"])
    rows = []
    for c in chans:
        ds = [a["channels"][c] for _, a in models]
        unit = ds[0]["unit"]
        u = display_unit(unit, *[[d["rms"], d["peak"], d["noise_floor"]] for d in ds])
        for (name, _), d in zip(models, ds):
            od = d.get("overshoot_difference")
            rows.append([c, name, _in(d["rms"], u), _in(d["peak"], u), _pct(d["fit"]), _pct(d["relative_error"], 3),
                         "-" if od is None else _in(od, display_unit(unit, od)), _in(d["noise_floor"], u)])
    return _table(["channel", "model", "RMS", "peak", "fit", "relative error", "overshoot difference",
                   "noise floor"], rows, numeric=range(2, 8))


def _phases_table(models, phases) -> dict:
    rows = []
    for c in models[0][1]["channels"]:
        ds = [a["channels"][c] for _, a in models]
        u = display_unit(ds[0]["unit"], *[list(d["phase_rms"].values()) for d in ds])
        for (name, _), d in zip(models, ds):
            rows.append([c, name] + [_in(d["phase_rms"].get(p), u) for p in phases])
    return _table(["channel", "model"] + list(phases), rows, numeric=range(2, 2 + len(phases)))


def _residual_table(analysis: dict) -> dict:
    rows = []
    for c, d in analysis["channels"].items():
        wh, cc, co = d["whiteness"], d["cross_correlation_command"], d["correlation"]
        peaks = d["spectrum_peaks"]
        pu = display_unit(d["unit"], *[p["amplitude"] for p in peaks]) if peaks else None
        peak_text = ", ".join(f"{fmt(p['frequency'], 4)} Hz ({_in(p['amplitude'], pu)})" for p in peaks) or "none"
        rows.append([c, f"{100 * wh['fraction_outside']:.0f} % ({'white' if wh['white'] else 'not white'})",
                     f"{cc['max']:.3f} at {fmt(cc['lag_s'] * 1e3, 3) if cc['lag_s'] else '0'} ms",
                     peak_text, _signed(co["velocity"]), _signed(co["acceleration"]), _signed(co["position"]),
                     _signed(co["sign_velocity"])])
    return _table(["channel", "autocorrelation outside the band (lags)", "largest cross-correlation with the input",
                   "spectral peaks (amplitude)", "corr. with v", "corr. with a", "corr. with x", "corr. with sign(v)"],
                  rows, numeric=(1, 2, 4, 5, 6, 7))


def compare_verdict(analysis: dict, after: dict | None = None) -> str:
    """The answer first: does the (fitted) model explain the record down to its noise floor
    (every channel's RMS residual within AT_FLOOR of the record's floor, as the diagnosis judges)?
    Then the evidence: the channels above it and by how much, the fit of each channel (before ->
    after), and where the residual is not white (structure a model could still explain)."""
    from hil.ident.unexplained import AT_FLOOR
    last = after or analysis
    who = "the fitted model" if after else "the model"
    above = {c: d["rms"] / d["record_floor"] for c, d in last["channels"].items()
             if d.get("record_floor") and d["rms"] > AT_FLOOR * d["record_floor"]}
    if not above and all(d.get("record_floor") for d in last["channels"].values()):
        answer = f"Yes: {who} explains the record down to its noise floor on every channel"
    elif above:
        answer = (f"No: {who} leaves " + ", ".join(f"{c} at {r:.3g} x its noise floor" for c, r in above.items())
                  + " (hil diagnose names what is missing)")
    else:
        answer = f"{who[0].upper()}{who[1:]}'s errors below (the record gives no noise floor to judge them against)"
    parts = []
    for c, d in analysis["channels"].items():
        s = f"{c} fit {fmt_fit(d['fit'])}"
        if after:
            s += f" -> {fmt_fit(after['channels'][c]['fit'])}"
        parts.append(s)
    coloured = [c for c, d in last["channels"].items() if not d["whiteness"]["white"]]
    tail = (f"; its residual is not white on {', '.join(coloured)}" + (
        " (at the noise floor: the sensor's own correlated noise, e.g. quantization)" if not above else
        " (structure left to explain)") if coloured else "; its residual is white on every channel")
    return answer + ". " + ", ".join(parts) + tail


def _compare_context(title, analysis, figures, after, names, notes, record, configs, validation, verdict,
                     verdict_label="Verdict", extra_meta=(), interactive=None) -> dict:
    models = _models(analysis, after, names)
    n = len(analysis["_arrays"]["t"]) if "_arrays" in analysis else None
    dt = analysis["sample_period"]
    extra = []
    if n:
        t = analysis["_arrays"]["t"]
        extra.append(("samples", f"{n} every {eng(dt, 's')} ({eng(float(t[-1] - t[0]), 's')})"))
    extra.append(("channels", ", ".join(f"{c} [{unit_label(d['unit'])}]" for c, d in analysis["channels"].items())))
    shifts = {c: s for c, s in analysis.get("shifts", {}).items() if s}
    if shifts:
        extra.append(("aligned by", ", ".join(f"{c} {eng(s, 's')}" for c, s in shifts.items())))
    figs = [embed_png(f) for f in figures]
    resid = next((f for f, p in zip(figs, figures) if Path(p).stem.startswith("correlation")), None)
    band = analysis["channels"][next(iter(analysis["channels"]))]["whiteness"]["band_99"] if analysis["channels"] else 0
    return dict(
        title=title, verdict=verdict or compare_verdict(analysis, after), verdict_label=verdict_label,
        meta=report_meta(record, configs, list(extra_meta) + extra), notes=list(notes or []),
        errors=_errors_table(models), phases=_phases_table(models, analysis["phases"]),
        residual_models=[{"name": name, "table": _residual_table(a)} for name, a in models],
        resid_figure=resid, figures=[f for f in figs if f is not resid],
        before_name=names[0], after_name=names[1] if after else None,
        maxlag=min(200, (n or 0) // 4), band=fmt(band, 3), samples=n or "-", input_name="commanded velocity",
        validation=validation or [], interactive=interactive)


def write_report(path: Path, title: str, analysis: dict, figures: list[Path], after: dict | None = None,
                 diagnosis: dict | None = None, notes: list[str] | None = None, *, record: str | None = None,
                 configs=(), validation: list | None = None, emps: dict | None = None, cfg=None,
                 names: tuple[str, str] = ("model", "fitted model"), interactive: str | None = None) -> Path:
    """Write the report of a comparison (``hil compare``; with ``emps``, of ``hil emps``; with
    ``diagnosis``, of ``hil diagnose``).

    Parameters
    ----------
    path : Path
        The HTML file written.
    title : str
        Its title.
    analysis, after : dict
        hil.ident.residual_analysis.analyse of the model, and of the fitted model (or None).
    figures : list of Path
        PNGs to embed (hil.plots.residual_figures.comparison_figures: the correlation figure, MATLAB resid's,
        goes to the residual analysis, the others to the figures).
    diagnosis : dict, optional
        The diagnosis as ``hil diagnose --json`` prints it (the verdict, the ranking, the chain).
    notes : list of str, optional
        Paragraphs under the header.
    record : str, optional
        The record's file; ``configs``: pairs (role, config file).
    validation : list of dict, optional
        Estimation-against-validation tables (module docstring).
    emps : dict, optional
        ``{"rows", "published", "check", "diagnoses"}`` of hil.ident.emps.run_emps.
    cfg : Config, optional
        The model's config (the units of the diagnosis's parameters).
    names : (str, str)
        What the two models are called.
    interactive : str, optional
        The interactive figure's file (hil.plots.interactive), relative to the report: linked from
        the figures' section.
    """
    ctx = _compare_context(title, analysis, figures, after, names, notes, record, configs, validation, None,
                           interactive=interactive)
    template = "compare.html.j2"
    if emps is not None:
        ctx.update(_emps_context(emps))
        template = "emps.html.j2"
    if diagnosis is not None:
        ctx.update(_diagnosis_context(diagnosis, cfg))
        template = "diagnose.html.j2"
    return _write(path, render(template, **ctx))


# --- hil diagnose --------------------------------------------------------------------------------

def _param_units(cfg, effect: str) -> dict:
    """SI unit of each parameter of the catalogue ``effect`` (empty when unknown)."""
    from hil.plant_config import candidate
    from hil.units import SI_UNIT
    try:
        eff = candidate(effect, cfg)
    except (KeyError, ValueError):
        return {}
    out = {}
    for p in getattr(eff, "params", ()):
        kind = p.kind_for(cfg.rotary)
        unit = SI_UNIT.get(kind, "") if isinstance(kind, str) else ""
        out[p.name] = {"1": "", "1/s": "Hz"}.get(unit, unit)
    return out


def _params_text(params: dict, units: dict) -> str:
    return ", ".join(f"{k} {eng(v, units.get(k, ''))}" for k, v in params.items())


VERDICT_WORDS = {"none": "none: the model matches the record down to the noise floor",
                 "unexplained": "unexplained: above the noise floor, and no catalogue effect explains it"}


def _diagnosis_context(d: dict, cfg=None) -> dict:
    from hil.ident.scores import MIN_SCORE
    units = {}

    def u(effect):
        if effect not in units:
            units[effect] = _param_units(cfg, effect) if cfg is not None else {}
        return units[effect]

    ranking = _table(["rank", "effect", "score (BIC fall)", "significant", "parameters", "evidence"],
                     [[i + 1, c["effect"], f"{c['score']:.1f}", "*" if c.get("significant") else "",
                       _params_text(c.get("params", {}), u(c["effect"])), engineering_text(c.get("evidence", ""))]
                      for i, c in enumerate(d["candidates"])], numeric=(0, 2))
    also = _table(["effect", "score (BIC fall) beside the verdict", "evidence"],
                  [[m["effect"], f"{m['score']:.1f}", engineering_text(m.get("evidence", ""))]
                   for m in d.get("also_missing", [])],
                  numeric=(1,))
    combos = _table(["effects", "against", "score", "share of its gain", "the richer one against the pair",
                     "named first"],
                    [[" + ".join(cb["effects"]), cb["explains"], f"{cb['score']:.1f}", f"{100 * cb['explained']:.0f} %",
                      f"{cb['rich_against_combination']:.1f}",
                      "the pair" if cb["preferred"] else cb["explains"]] for cb in d.get("combinations", [])],
                    numeric=(2, 3, 4))
    floor = d.get("noise_floor", {})
    chain, end, lines = None, "", []
    if d.get("chain") is not None:
        chans = list(floor)
        rows = [["start", "", ""] + [_floor_cell(d["error_before"][c], None, floor[c], d.get("_units", {}).get(c, "m"))
                                     for c in chans]]
        for s in d["chain"]:
            par = "; ".join(f"{n}: {_params_text(p, u(n))}" for n, p in s["params"].items() if n in s["effects"])
            added = " + ".join(s["effects"]) + (" (all refitted)" if s.get("refitted_together") else "")
            if s.get("recording_artefacts"):
                added += f" ({', '.join(s['recording_artefacts'])}: a recording artefact, not physics)"
            rows.append([str(s["step"]), added, par]
                        + [_floor_cell(s["error_before"][c], s["error_after"][c], floor[c],
                                       d.get("_units", {}).get(c, "m")) for c in chans])
        held = [s for s in d["chain"] + [d["final"].get("rejected")] if s and "held_out" in s]
        if held:
            # estimation and held-out (validation) errors side by side, every step (the refused one last)
            for r, s in zip(rows[1:], d["chain"]):
                r += _held_out_cells(s, chans, d)
            rows[0] += ["", "", ""]
            if d["final"].get("rejected") is not None and "held_out" in d["final"]["rejected"]:
                rj = d["final"]["rejected"]
                rows.append(["refused", " + ".join(rj["effects"]), ""] + [""] * len(chans)
                            + _held_out_cells(rj, chans, d))
        chain = _table(["step", "added", "parameters"] + [f"{c} RMS error (x noise floor)" for c in chans]
                       + (["estimation error", "held-out error (before -> after)", "held-out fall"] if held else []),
                       rows, numeric=range(3, 3 + len(chans)))
        f = d["final"]
        end = f"End: {f['end']}; " + ("every channel at its noise floor." if f["at_noise_floor"]
                                      else "the residual stays above the noise floor.")
        res = f.get("residual")
    else:
        res = d.get("residual")
    if res:
        from hil.ident.unexplained import describe
        lines = [engineering_text(x) for x in describe(res)]
    alternatives = _table(["effect", "score (BIC fall)", "it against the verdict", "the verdict against it", "evidence"],
                          [[a["effect"], f"{a['score']:.1f}", f"{a['against_verdict']:.1f}",
                            f"{a['verdict_against']:.1f}", engineering_text(a.get("evidence", ""))]
                           for a in d.get("alternatives") or []], numeric=(1, 2, 3))
    from hil.ident.diagnosis import by_reason
    not_tried = _table(["not tried", "why this axis cannot have them"],
                       [[", ".join(names), why] for why, names in by_reason(d.get("not_tried")).items()])
    return dict(ranking=ranking, also_missing=also if also["rows"] else None,
                combinations=combos if combos["rows"] else None, not_tried=not_tried if not_tried["rows"] else None,
                alternatives=alternatives if alternatives["rows"] else None,
                chain=chain, chain_end=end, unexplained=lines,
                min_score=f"{MIN_SCORE:g}", verdict=_diagnosis_verdict(d, u),
                verdict_label="Verdict (the effect the model misses)")


def _diagnosis_verdict(d: dict, units) -> str:
    """The verdict, with its score and fitted parameters when it is a candidate."""
    v = d["verdict"]
    top = next((c for c in d["candidates"] if c["effect"] == v), None)
    if top is None:
        return VERDICT_WORDS.get(v, v)
    par = _params_text(top.get("params", {}), units(v))
    return f"{v} (score {top['score']:.1f}{'; ' + par if par else ''})"


def _held_out_cells(s, chans, d) -> list[str]:
    """A chain step's estimation error, held-out error before and after it, and the held-out fall."""
    if "held_out" not in s:
        return ["", "", ""]
    h, unit = s["held_out"], d.get("_units", {})
    est = ", ".join(f"{c} {_in(s['estimation_error'][c], display_unit(unit.get(c, 'm'), s['estimation_error'][c]))}"
                    for c in chans if c in s["estimation_error"])
    out = ", ".join(f"{c} {_in(h['before'][c], display_unit(unit.get(c, 'm'), h['before'][c], h['after'][c]))} -> "
                    f"{_in(h['after'][c], display_unit(unit.get(c, 'm'), h['before'][c], h['after'][c]))}"
                    for c in chans if c in h["before"])
    return [est, out, f"{100 * h['fall']:.1f} % (+- {100 * h['uncertainty']:.1f} %): "
                      f"{'earned' if h['earned'] else 'not earned'}"]


def _floor_cell(before, after, floor, unit) -> str:
    u = display_unit(unit, before, after)
    f = max(floor, 1e-300)
    if after is None:
        return f"{_in(before, u)} ({before / f:.1f} x)"
    return f"{_in(before, u)} -> {_in(after, u)} ({after / f:.1f} x)"


def write_diagnosis_report(path: Path, title: str, diagnosis: dict, analysis: dict, figures: list[Path],
                           after: dict | None = None, *, record: str | None = None, configs=(), cfg=None,
                           validation: list | None = None) -> Path:
    """The report of ``hil diagnose``: the verdict, the ranking, the chain, and the residual analysis
    of the start model (``analysis``) and of the model with the chain (``after``).

    ``diagnosis`` is the JSON ``hil diagnose --json`` prints; ``cfg`` gives the parameters' units."""
    d = dict(diagnosis)
    d["_units"] = {c: analysis["channels"][c]["unit"] for c in analysis["channels"]}
    return write_report(path, title, analysis, figures, after=after, diagnosis=d, record=record, configs=configs,
                        validation=validation, cfg=cfg, names=("start model", "model with the chain"))


# --- hil emps ------------------------------------------------------------------------------------

def _emps_context(e: dict) -> dict:
    pub = e["published"]
    rows = []
    for r in e["rows"]:
        p = r["params"]
        inv = _pct(r.get("inverse_force")) if "inverse_force" in r else "-"
        if "level_pos" in p:
            step = (f"{r['step']}: Fc+ {fmt(p['level_pos'], 4)} N, Fc- {fmt(p['level_neg'], 4)} N, "
                    f"Fv+ {fmt(p['viscous_pos'], 4)} N s/m, Fv- {fmt(p['viscous_neg'], 4)} N s/m")
            rows.append([step, f"{p['M']:.3f} kg", "-", "-", f"{p['offset']:.3f} N", _pct(r["position"], 4),
                         _pct(r["velocity"], 3), _pct(r["force"]), inv])
            continue
        rows.append([r["step"], f"{p['M']:.3f} kg", f"{p['Fv']:.2f} N s/m", f"{p['Fc']:.3f} N", f"{p['offset']:.3f} N",
                     _pct(r["position"], 4), _pct(r["velocity"], 3), _pct(r["force"]), inv])
    er = pub["errors"]
    rows.append(["published (Janot et al. 2019, IDIM-LS)", f"{pub['M']} kg", f"{pub['Fv']} N s/m", f"{pub['Fc']} N",
                 f"{pub['offset']} N", f"{er['position']} %", f"{er['velocity']} %", f"{er['force']} %", "4.08 %"])
    rows.append(["published, asymmetric: Fc+ 20.144 N, Fc- 20.628 N, Fv+ 166.71 N s/m, Fv- 240.42 N s/m",
                 "95.154 kg", "-", "-", "-", "-", "-", "-", "3.11 %"])
    steps = _table(["step", "M", "Fv", "Fc", "offset", "position error", "velocity error", "force error",
                    "inverse-model force error"], rows, numeric=range(1, 9))
    chk = e.get("check")
    check, verdict = None, None
    if chk:
        dev = chk["deviation"]
        check = _table(["output-error fit against the published", "M", "Fv", "Fc", "offset",
                        "within 5 % and 0.5 N", "errors match or beat the published"],
                       [["deviation", f"{dev['M']:+.2f} %", f"{dev['Fv']:+.2f} %", f"{dev['Fc']:+.2f} %",
                         f"{dev['offset_N']:+.3f} N", "yes" if chk["within_5_percent_and_0.5_N"] else "no",
                         "yes" if chk["errors_match_or_beat_published"] else "no"]], numeric=range(1, 5))
        verdict = (f"the output-error fit lands {'within' if chk['within_5_percent_and_0.5_N'] else 'outside'} 5 % "
                   f"and 0.5 N of the published M, Fv, Fc and offset (M {dev['M']:+.2f} %, Fv {dev['Fv']:+.2f} %, "
                   f"Fc {dev['Fc']:+.2f} %, offset {dev['offset_N']:+.3f} N); its errors "
                   + ("match or beat" if chk["errors_match_or_beat_published"] else "do not match")
                   + " the published ones")
    diagnoses = []
    for d in e.get("diagnoses") or []:
        top = d["ranking"][0] if d["ranking"] else None
        combos = [f"{' + '.join(c['effects'])} against {c['explains']}: {100 * c['explained']:.0f} % of its gain; "
                  f"{c['explains']} scores {c['rich_against_combination']:.1f} against the pair -> "
                  + ("the pair named first" if c["preferred"] else f"{c['explains']} first")
                  for c in d.get("combinations", [])]
        diagnoses.append({
            "on": d["on"], "verdict": d["verdict"],
            "evidence": engineering_text(top["evidence"]) if top and top["effect"] == d["verdict"] else "",
            "also_missing": [{"effect": m["effect"], "score": f"{m['score']:.1f}",
                              "evidence": engineering_text(m["evidence"])}
                             for m in d.get("also_missing", [])],
            "combinations": combos,
            "ranking": _table(["rank", "effect", "score (BIC fall)", "significant"],
                              [[i + 1, c["effect"], f"{c['score']:.1f}", "*" if c["significant"] else ""]
                               for i, c in enumerate(d["ranking"])], numeric=(0, 2))})
    out = {"steps": steps, "check": check, "diagnoses": diagnoses}
    if verdict:
        out["verdict"] = verdict
        out["verdict_label"] = "Verdict"
    return out


# --- hil sweep -----------------------------------------------------------------------------------

def _run_rows(runs) -> list:
    def ms(v):
        return "-" if v is None else f"{fmt(v * 1e3, 4)} ms"

    def um(v):
        return "-" if v is None else f"{fmt(v, 4)} um"

    return [[f"{fmt(x['j_max'], 4)} m/s^3", f"{fmt(x['a_max'], 3)} m/s^2", ms(x.get("t_acc")),
             um(x.get("overshoot_table_um")), um(x.get("overshoot_tip_um")),
             um(x.get("peak_following_error_table_um")), um(x.get("peak_following_error_tip_um")),
             um(x.get("residual_tip_um")), ms(x.get("settling_time_tip"))]
            for x in sorted(runs, key=lambda r: r["j_max"])]


RUN_HEADER = ["j_max", "a_max", "t_acc", "overshoot table", "overshoot tip", "peak following error table",
              "peak following error tip", "residual tip", "settling time tip"]


def sweep_verdict(r: dict) -> str:
    """The report's headline: the answer to the question asked (hil.sweep.sweep.sweep_answer), as
    the text and the JSON give it."""
    from hil.sweep.sweep import sweep_answer
    return engineering_text((r.get("answer") or sweep_answer(r))["text"])


def write_sweep_report(path: Path, report: dict, figures=(), *, validation: list | None = None) -> Path:
    """The report of ``hil sweep`` (``report``: the sweep.json of hil.sweep.run_sweep)."""
    mv = report["move"]
    name = report.get("name") or report.get("config", "model")
    an = report.get("analysis", "mechatronic")
    move = _table(["stroke", "feed", "dwell", "recorded every", "analysis"],
                  [[eng(mv["stroke_m"], "m"), f"{fmt(mv['feed_m_per_s'] * 60, 4)} m/min", eng(mv["dwell_s"], "s"),
                    eng(mv["record_period_s"], "s"), an]])
    answers_rows = []
    if report.get("tolerance_um") is not None:
        mj = report.get("max_jerk")
        answers_rows.append([f"{name}: largest jerk within {fmt(report['tolerance_um'], 3)} um at the tip",
                             (f"{fmt(mj, 4)} m/s^3" if mj else "none in range")
                             + (f" (t_acc {fmt(report['max_jerk_t_acc'] * 1e3, 3)} ms)"
                                if mj and report.get("max_jerk_t_acc") else "")])
        answers_rows.append(["admissible j_max", ", ".join(f"{fmt(a, 4)} .. {fmt(b, 4)} m/s^3"
                                                          for a, b in report.get("admissible") or []) or "none"])
        if "max_jerk_compare" in report:
            mc = report["max_jerk_compare"]
            cname = report.get("compare_name") or report.get("compare_config")
            answers_rows.append([f"{cname}: largest jerk", (f"{fmt(mc, 4)} m/s^3" if mc else "none in range")
                                 + (f"; its estimate is off by {report['estimate_error_pct']:.1f} %"
                                    if report.get("estimate_error_pct") is not None else "")])
    p = report.get("proposal") or {}
    if p:
        answers_rows.append(["proposal", sweep_verdict({"proposal": p}) if p.get("j_max")
                             else engineering_text(p.get("note", ""))])
    if report.get("note"):
        answers_rows.append(["note", engineering_text(report["note"])])
    run_tables = [dict(_table(RUN_HEADER, _run_rows(report["runs"]), numeric=range(9)), title=f"{name}, {an}")]
    for key, title in (("runs_transmission", f"{name}, transmission (Section 3)"),
                       ("compare_runs", f"{report.get('compare_name') or report.get('compare_config')}, {an}"),
                       ("compare_runs_transmission",
                        f"{report.get('compare_name') or report.get('compare_config')}, transmission")):
        if report.get(key):
            run_tables.append(dict(_table(RUN_HEADER, _run_rows(report[key]), numeric=range(9)), title=title))
    minima = [f"j_max {fmt(m['j_max'], 4)} m/s^3: tip overshoot {fmt(m['overshoot_tip_um'], 3)} um"
              + (f"; {engineering_text(m['explanation'])}" if m.get("explanation") else "")
              for m in report.get("local_minima") or []]
    configs = [("config", report.get("config")), ("compared config", report.get("compare_config"))]
    st = report.get("stats", {})
    extra = [("runs", f"{st.get('computed', 0)} computed, {st.get('reused', 0)} taken from earlier runs")]
    title = f"Jerk sweep: {name}"
    ctx = dict(title=title, verdict=sweep_verdict(report), verdict_label="Answer",
               meta=report_meta(None, configs, extra), notes=[], move=move,
               answers=_table(["question", "answer"], answers_rows) if answers_rows else None,
               run_tables=run_tables, minima=minima, figures=[embed_png(f) for f in figures],
               validation=validation or [])
    return _write(path, render("sweep.html.j2", **ctx))


# --- hil frf -------------------------------------------------------------------------------------

def frf_verdict(report: dict) -> str:
    d = report.get("discrepancies") or []
    if not d:
        return "the measured modes agree with the model's (within 2 % in frequency and 20 % in damping)"
    return f"{len(d)} discrepanc{'y' if len(d) == 1 else 'ies'}: " + engineering_text(" ".join(d))


def _opt(v, unit, digits=3):
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{fmt(v, digits)} {unit}"


def write_frf_report(path: Path, report: dict, figures=(), *, config: str | None = None, title: str | None = None,
                     config_diff: str = "", validation: list | None = None) -> Path:
    """The report of ``hil frf`` (``report``: its JSON, hil.frf.FrfResult.as_dict)."""
    ex = report["excitation"]
    excitation = _table(["backend", "signal", "input", "lines", "period", "periods averaged", "saturated periods"],
                        [[ex["backend"], ex["signal"], ex["input"], ex["lines"], eng(ex["period_s"], "s"),
                          ex["periods"], ex.get("saturated_periods", 0)]], numeric=(3, 4, 5, 6))
    modes = _table(["mode", "response", "measured", "measured damping ratio", "model (same fit)",
                    "model damping ratio", "model eigenvalue", "eigenvalue damping ratio"],
                   [[m["mode"], m["response"], _opt(m["measured"]["frequency_hz"], "Hz", 4),
                     fmt(m["measured"]["damping_ratio"], 3), _opt(m["model"]["frequency_hz"], "Hz", 4),
                     fmt(m["model"]["damping_ratio"], 3), _opt(m["model_eigen"]["frequency_hz"], "Hz", 4),
                     fmt(m["model_eigen"]["damping_ratio"], 3)] for m in report.get("modes", [])],
                   numeric=range(2, 8))
    t = report.get("tuning", {})
    loops_rows = []
    for key, name in (("velocity_loop", "velocity loop"), ("position_loop", "position loop")):
        v = t.get(key) or {}
        loops_rows.append([name, _opt(v.get("crossover_hz"), "Hz"), _opt(v.get("phase_margin_deg"), "deg"),
                           _opt(v.get("gain_margin_db"), "dB"), _opt(v.get("bandwidth_hz"), "Hz")])
    loops = _table(["loop", "crossover", "phase margin", "gain margin", "bandwidth"], loops_rows, numeric=range(1, 5))
    a = t.get("acceleration_feed_forward")
    ff = (f"Following error per acceleration: {fmt(a['error_per_acc_now'] * 1e6, 3)} um/(m/s^2) now, "
          f"{fmt(a['error_per_acc_with_ff'] * 1e6, 3)} um/(m/s^2) with acc_ff = 1." if a else "")
    ctx = dict(title=title or f"Frequency responses: {config or 'model'}", verdict=frf_verdict(report),
               verdict_label="Verdict", meta=report_meta(None, [("config", config)]), notes=[],
               excitation=excitation, modes=modes,
               discrepancies=[engineering_text(x) for x in report.get("discrepancies") or []], loops=loops,
               feed_forward=ff, warnings=[engineering_text(w) for w in report.get("warnings") or []],
               config_diff=config_diff or "(none)",
               figures=[embed_png(f) for f in figures], validation=validation or [])
    return _write(path, render("frf.html.j2", **ctx))


# --- hil tune ------------------------------------------------------------------------------------

def write_tune_report(path: Path, report: dict, figures=(), *, config: str | None = None,
                      tolerance: float | None = None) -> Path:
    """The report of ``hil tune`` (``report``: its JSON, hil.tune.TuneResult.as_json): the answer,
    the changes with their reasons, the margins before and after, the commands tried with the one
    chosen first, the verification on the backend, the steps, the figures."""
    from hil.tune import value_text

    def ms(v, never="-"):
        return never if v is None else f"{v * 1e3:.0f} ms"

    def deg_db(v, unit):
        return "none in the band" if v is None else f"{v:.1f} {unit}"

    changes = _table(["key", "before", "after", "why"],
                     [[c["key"], value_text(c["key"], c["before"]), value_text(c["key"], c["after"]),
                       engineering_text(c["reason"])] for c in report.get("changes", [])])
    rows = []
    for loop, after in (report.get("margins_after") or {}).items():
        before = (report.get("margins_before") or {}).get(loop, {})
        rows.append([loop.replace("_", " ")] + [
            f"{deg_db(before.get(k), u)} -> {deg_db(after.get(k), u)}"
            for k, u in (("phase_margin_deg", "deg"), ("gain_margin_db", "dB"), ("crossover_hz", "Hz"))])
    margins = _table(["loop", "phase margin", "gain margin", "crossover"], rows, numeric=(1, 2, 3))
    choice = report.get("choice")
    same = (lambda c: choice is not None and c["t_acc_s"] == choice["t_acc_s"] and c["shaper"] == choice["shaper"])
    worst = (lambda c: math.inf if c["settle_worst_s"] is None else c["settle_worst_s"])
    cands = sorted(report.get("candidates", []), key=lambda c: (not same(c), worst(c), c["move_s"]))
    commands = _table(["command", "tip within the tolerance, mode as measured", "worst with the mode off",
                       "move", "chosen"],
                      [[f"t_acc {c['t_acc_s'] * 1e3:.0f} ms, shaper {c['shaper']}", ms(c["settle_s"], "not within"),
                        ms(c["settle_worst_s"], "not within"), ms(c["move_s"]), "yes" if same(c) else ""]
                       for c in cands],
                      numeric=(1, 2, 3))
    v = report.get("verified") or {}
    verified = _table(["backend", "status", "tuned move: tip within the tolerance", "move as given"],
                      [[v.get("backend", "-"), v.get("status", "-"), ms(v.get("settle_s"), "not within"),
                        ms(v.get("given_settle_s"), "not within")]], numeric=(2, 3)) if v else None
    modes = _table(["mode", "response", "frequency", "damping ratio"],
                   [[m.get("mode", ""), m.get("response", ""), _opt(m["measured"]["frequency_hz"], "Hz", 4),
                     fmt(m["measured"]["damping_ratio"], 3)] for m in report.get("modes") or []], numeric=(2, 3))
    tol = f"{tolerance * 1e6:g} um" if tolerance else None
    ctx = dict(title=f"Tuning: {config or 'model'}", verdict=engineering_text(report["answer"]),
               verdict_label="Answer", meta=report_meta(None, [("config", config), ("tuned config",
                                                                   report.get("tuned_config"))],
                                                        [("tolerance", tol)] if tol else ()),
               notes=[], changes=changes if changes["rows"] else None, margins=margins,
               modes=modes if modes["rows"] else None,
               mode_error=f"{100 * report.get('mode_error', 0.0):.3g} %", commands=commands, verified=verified,
               steps=report.get("steps", []), figures=[embed_png(f) for f in figures if f])
    return _write(path, render("tune.html.j2", **ctx))

