"""The fleet's report: one self-contained HTML page, each record's own page, and the values as
CSV and JSON.

The page: one row per axis (latest verdict, flags, worst drift), then per axis a trend plot of
each tracked parameter (inline SVG, no script, nothing linked): the values with their standard
error as bars, the control band (centre +- 3 sigma of each record) shaded, the centre dashed, a
threshold dotted, the flagged dates marked by a red line, each mark in a legend above it, the axes
titled; below it the links to each record's page (``records/AXIS_DATE.html``: what was flagged
that night, the chain's verdict, end and steps, the tracked values, a link back).
values.csv / values.json: every (axis, date, effect, value, stderr) in SI.
"""
from __future__ import annotations

import csv
import datetime as _dt
import html
import io
import math
from pathlib import Path

__all__ = ["write_report", "trend_svg"]

W, H, PAD_L, PAD_R, PAD_T, PAD_B = 700, 290, 96, 44, 44, 56

CSS = """body{font-family:sans-serif;margin:2em;max-width:900px;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:4px 8px;text-align:left}
.flag{color:#b00}.ok{color:#070}svg{border:1px solid #ddd;margin:0.5em 0}h2{margin-top:2em}"""


def _q(v, kind: str) -> str:
    from hil.units import DIMENSIONS, fmt
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return fmt(v, kind) if kind in DIMENSIONS and kind != "dimensionless" else f"{v:.4g}"


def _days(dates: list[str]) -> list[float]:
    d0 = _dt.datetime.fromisoformat(dates[0])
    return [(_dt.datetime.fromisoformat(d) - d0).total_seconds() / 86400 for d in dates]


def trend_svg(name: str, dates: list[str], p: dict, kind: str) -> str:
    """One tracked parameter's trend (see the module's conventions) as an SVG element."""
    xs = _days(dates)
    vals = [v if v is not None else float("nan") for v in p["values"]]
    ses = [s if s is not None else 0.0 for s in p["stderr"]]
    ys = [y for y in vals + p["lower"] + p["upper"] if y is not None and math.isfinite(y)]
    if p.get("threshold_value") is not None:
        ys.append(p["threshold_value"])
    if not ys:
        return ""
    lo, hi = min(ys), max(ys)
    span = hi - lo or abs(hi) or 1.0
    lo, hi = lo - 0.08 * span, hi + 0.08 * span
    x_hi = max(xs[-1], 1e-9)

    def X(x):
        return PAD_L + (W - PAD_L - PAD_R) * (x / x_hi if len(xs) > 1 else 0.5)

    def Y(y):
        return PAD_T + (H - PAD_T - PAD_B) * (1 - (y - lo) / (hi - lo))
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" role="img" '
           f'aria-label="{html.escape(name)} over time">']
    band = [f"{X(x):.1f},{Y(u):.1f}" for x, u in zip(xs, p["upper"])] + \
           [f"{X(x):.1f},{Y(v):.1f}" for x, v in reversed(list(zip(xs, p["lower"])))]
    out.append(f'<polygon points="{" ".join(band)}" fill="#cde" stroke="none"><title>control band</title></polygon>')
    out.append(f'<line x1="{PAD_L}" x2="{W - PAD_R}" y1="{Y(p["centre"]):.1f}" y2="{Y(p["centre"]):.1f}" '
               f'stroke="#579" stroke-dasharray="5,3"/>')
    if p.get("threshold_value") is not None:
        yt = Y(p["threshold_value"])
        out.append(f'<line x1="{PAD_L}" x2="{W - PAD_R}" y1="{yt:.1f}" y2="{yt:.1f}" stroke="#b00" '
                   f'stroke-dasharray="2,2"><title>{html.escape(p["threshold"] or "")}</title></line>')
    if p.get("first_moved"):
        xm = X(_days([dates[0], p["first_moved"]])[1])
        out.append(f'<line x1="{xm:.1f}" x2="{xm:.1f}" y1="{PAD_T}" y2="{H - PAD_B}" stroke="#d00" stroke-width="2">'
                   f'<title>first moved {html.escape(p["first_moved"])}</title></line>')
    pts = [(X(x), Y(v), Y(v - s), Y(v + s), st, d, v) for x, v, s, st, d in zip(xs, vals, ses, p["status"], dates)
           if math.isfinite(v)]
    out.append('<polyline fill="none" stroke="#333" points="' + " ".join(f"{a:.1f},{b:.1f}" for a, b, *_ in pts) + '"/>')
    for a, b, e0, e1, st, d, v in pts:
        colour = "#d00" if st in ("out", "threshold") else "#333"
        out.append(f'<line x1="{a:.1f}" x2="{a:.1f}" y1="{e0:.1f}" y2="{e1:.1f}" stroke="{colour}"/>'
                   f'<circle cx="{a:.1f}" cy="{b:.1f}" r="3" fill="{colour}"><title>{html.escape(d)}: '
                   f'{html.escape(_q(v, kind))} ({st})</title></circle>')
    out.append(_axes(xs, dates, lo, hi, X, Y, name, kind))
    out.append(_legend(p))
    out.append("</svg>")
    return "".join(out)


def _axes(xs, dates, lo, hi, X, Y, name: str, kind: str) -> str:
    """The frame, the ticks (every night's date where they fit, five values) and the axis titles."""
    from hil.units import SI_UNIT
    out = [f'<rect x="{PAD_L}" y="{PAD_T}" width="{W - PAD_L - PAD_R}" height="{H - PAD_T - PAD_B}" fill="none" '
           f'stroke="#999"/>']
    step = max(1, math.ceil(len(dates) / 6))
    shown = list(range(0, len(dates), step)) + ([len(dates) - 1] if (len(dates) - 1) % step else [])
    for i in shown:
        x = X(xs[i])
        out.append(f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{H - PAD_B}" y2="{H - PAD_B + 4}" stroke="#999"/>'
                   f'<text x="{x:.1f}" y="{H - PAD_B + 16}" font-size="10" text-anchor="middle">'
                   f'{html.escape(dates[i][:10])}</text>')
    for k in range(5):
        y = lo + (hi - lo) * k / 4
        out.append(f'<line x1="{PAD_L - 4}" x2="{PAD_L}" y1="{Y(y):.1f}" y2="{Y(y):.1f}" stroke="#999"/>'
                   f'<text x="{PAD_L - 6}" y="{Y(y) + 3:.1f}" font-size="10" text-anchor="end">'
                   f'{html.escape(_q(y, kind))}</text>')
    unit = SI_UNIT.get(kind, "")
    ytitle = f"{name}" + (f" [{unit}]" if unit and unit != "1" else "")
    yc = (PAD_T + H - PAD_B) / 2
    out.append(f'<text x="{(PAD_L + W - PAD_R) / 2:.1f}" y="{H - 8}" font-size="11" text-anchor="middle">'
               f'date of the record (night)</text>'
               f'<text x="12" y="{yc:.1f}" font-size="11" text-anchor="middle" transform="rotate(-90 12 {yc:.1f})">'
               f'{html.escape(ytitle)}</text>')
    return "".join(out)


def _legend(p: dict) -> str:
    """What each mark is, in a row above the plot."""
    items = [('<rect width="14" height="8" y="-7" fill="#cde"/>', "control band (centre +- 3 sigma)"),
             ('<line x2="14" y1="-3" y2="-3" stroke="#579" stroke-dasharray="5,3"/>', "centre (the baseline)"),
             ('<line x1="7" x2="7" y1="-9" y2="3" stroke="#333"/><circle cx="7" cy="-3" r="3" fill="#333"/>',
              "value +- standard error (red: flagged)")]
    if p.get("threshold_value") is not None:
        items.append(('<line x2="14" y1="-3" y2="-3" stroke="#b00" stroke-dasharray="2,2"/>', "threshold"))
    if p.get("first_moved"):
        items.append(('<line x1="7" x2="7" y1="-9" y2="3" stroke="#d00" stroke-width="2"/>', "first moved"))
    out, x = [], PAD_L
    for mark, text in items:
        out.append(f'<g transform="translate({x},{PAD_T - 14})">{mark}'
                   f'<text x="18" y="0" font-size="10">{html.escape(text)}</text></g>')
        x += 26 + 5.6 * len(text)
    return "".join(out)


def _page(title: str, body: str) -> str:
    import hil
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{CSS}</style></head><body><h1 id=\"title\">{html.escape(title)}</h1>{body}"
            f"<p><small>hil version {html.escape(str(getattr(hil, '__version__', '')))}, date {stamp}</small></p>"
            f"</body></html>\n")


def _night_flags(axis: dict | None, date: str, kinds: dict) -> list[str]:
    """What the fleet flagged on this record's night: the flags whose drift began this night (the
    reason, from and to), then each parameter out of its band or past its threshold this night."""
    if not axis or date not in axis.get("dates", []):
        return []
    i = axis["dates"].index(date)
    out, named = [], set()
    for f in axis.get("flags", []):
        if f.get("since") == date:
            kind = kinds.get(f["parameter"], "")
            moved = (f": {_q(f['from'], kind)} -> {_q(f['to'], kind)}" if f.get("from") is not None
                     and f.get("to") is not None else "")
            out.append(f"{f['parameter']} {f['reason']}{moved} (flagged from this night on)")
            named.add(f["parameter"])
    for name, p in axis.get("params", {}).items():
        st = p["status"][i] if i < len(p["status"]) else None
        if st in ("out", "threshold") and name not in named:
            why = "past its threshold" if st == "threshold" else "outside its control band"
            out.append(f"{name} = {_q(p['values'][i], kinds.get(name, ''))}, {why}")
    return out


def _record_page(e: dict, fig: dict, kinds: dict, axis: dict | None = None) -> str:
    back = f'<p><a href="../report.html#axis-{html.escape(e["axis"])}">back to axis {html.escape(e["axis"])} in the ' \
           f'fleet report</a></p>'
    rows = [back, f"<p>Record: {html.escape(e['record'])}<br>Axis {html.escape(e['axis'])}, "
            f"{html.escape(e['timestamp'])}</p>"]
    flags = _night_flags(axis, e["timestamp"], kinds)
    if flags:
        rows.append('<p id="flags" class="flag">flagged this night: ' + "; ".join(html.escape(f) for f in flags)
                    + "</p>")
    elif axis is not None and "error" not in fig:
        rows.append('<p id="flags" class="ok">nothing flagged this night</p>')
    if "error" in fig:
        rows.append(f'<p id="verdict" class="flag">error: {html.escape(fig["error"])}</p>')
        return "".join(rows)
    if "verdict" in fig:
        rows.append(f'<p id="verdict">chain verdict: {html.escape(str(fig["verdict"]))}; end: '
                    f'{html.escape(str(fig.get("end")))}; named: {html.escape(", ".join(fig.get("named", [])) or "none")}'
                    f"</p>")
        rows.append("<table><tr><th>step</th><th>effects</th><th>score</th></tr>" + "".join(
            f"<tr><td>{s['step']}</td><td>{html.escape(', '.join(s['effects']))}</td><td>{s['score']:.1f}</td></tr>"
            for s in fig.get("chain", [])) + "</table>")
    else:
        rows.append('<p id="verdict">tracked fit only (no chain)</p>')
    rows.append("<table><tr><th>parameter</th><th>value</th><th>standard error</th></tr>" + "".join(
        f"<tr><td>{html.escape(k)}</td><td>{html.escape(_q(v, kinds.get(k, '')))}</td>"
        f"<td>{html.escape(_q(fig.get('stderr', {}).get(k), kinds.get(k, '')))}</td></tr>"
        for k, v in sorted(fig.get("values", {}).items())) + "</table>")
    return "".join(rows)


def _page_name(e: dict) -> str:
    """The record's page, ``records/AXIS_DATE.html``: one file name made from the data (a timestamp
    ``../../x`` in a fleet.json stays inside ``records/``)."""
    from hil.io.safe_write import safe_name
    return f"records/{safe_name(str(e['axis']) + '_' + str(e['timestamp']).replace(':', '-'))}.html"


def write_report(state: dict, out_dir) -> dict:
    """report.html, records/*.html, values.csv and values.json of a judged fleet (hil fleet run's
    fleet.json) in ``out_dir``; returns their paths."""
    from hil.fleet.manifest import Entry
    from hil.fleet.summary import rows
    from hil.io.safe_write import confined, write_atomic
    out = Path(out_dir)
    kinds = state.get("kinds", {})
    entries = state["entries"]
    figures = state["figures"]
    pages = []
    axes = {a["axis"]: a for a in state["axes"]}
    for e in entries:
        path = confined(out, _page_name(e))
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, _page(f"{e['axis']} at {e['timestamp']}", _record_page(e, figures.get(
            f"{e['axis']}@{e['timestamp']}", {"error": "not run"}), kinds, axes.get(e["axis"]))))
        pages.append(str(path))
    thresholds = state.get("settings", {}).get("thresholds", {})
    body = [f'<p id="verdict">{len(entries)} records of {len(state["axes"])} axes; '
            f'{sum(1 for a in state["axes"] if a["flags"])} flagged.</p>',
            "<table><tr><th>axis</th><th>latest verdict</th><th>flags</th><th>worst drift</th></tr>"]
    for a in state["axes"]:
        w = a.get("worst")
        worst = (f"{html.escape(w['parameter'])}: {html.escape(_q(w['from'], kinds.get(w['parameter'], '')))} -> "
                 f"{html.escape(_q(w['to'], kinds.get(w['parameter'], '')))} ({w['sigma']:.1f} sigma)") if w else "-"
        cls = "flag" if a["flags"] else "ok"
        flags = "; ".join(f"{f['parameter']} since {f['since']}" for f in a["flags"]) or "none"
        body.append(f'<tr><td><a href="#axis-{html.escape(a["axis"])}">{html.escape(a["axis"])}</a></td>'
                    f'<td class="{cls}">{html.escape(a["verdict"])}</td><td>{html.escape(flags)}</td>'
                    f"<td>{worst}</td></tr>")
    body.append("</table>")
    by_axis: dict[str, list] = {}
    for e in entries:
        by_axis.setdefault(e["axis"], []).append(e)
    for a in state["axes"]:
        body.append(f'<h2 id="axis-{html.escape(a["axis"])}">{html.escape(a["axis"])}</h2>')
        if a["normal"]:
            body.append(f"<p>normal (named on every baseline record): {html.escape(', '.join(a['normal']))}</p>")
        for name, p in a["params"].items():
            p = dict(p)
            if name in thresholds:
                from hil.fleet.spc import parse_threshold
                p["threshold_value"] = parse_threshold(thresholds[name], kinds, "threshold").value
            body.append(f"<h3>{html.escape(name)}</h3>" + trend_svg(name, a["dates"], p, kinds.get(name, "")))
        links = " ".join(f'<a href="{html.escape(_page_name(e))}">{html.escape(e["timestamp"])}</a>'
                         for e in by_axis.get(a["axis"], []))
        body.append(f"<p>records: {links}</p>")
        for er in a["errors"]:
            body.append(f'<p class="flag">error: {html.escape(er["error"])}</p>')
    report = out / "report.html"
    write_atomic(report, _page("Fleet report", "".join(body)))
    table = rows([Entry(**e) for e in entries], figures)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=["axis", "date", "effect", "value", "stderr", "record"], lineterminator="\n")
    w.writeheader()
    for r in table:
        w.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    write_atomic(out / "values.csv", buf.getvalue())
    from hil.io.jsonout import dumps
    write_atomic(out / "values.json", dumps(table, indent=1) + "\n")
    return {"report": str(report), "csv": str(out / "values.csv"), "json": str(out / "values.json"),
            "pages": pages}
