"""One HTML report of a comparison (and a diagnosis), read top to bottom, with the PNGs."""
from __future__ import annotations

import html
from pathlib import Path

from hil.io.safe_write import write_atomic


def _fmt(v):
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return html.escape(str(v))


def write_report(path: Path, title: str, analysis: dict, figures: list[Path], after: dict | None = None,
                 diagnosis: dict | None = None, notes: list[str] | None = None) -> Path:
    a = analysis["channels"]
    b = after["channels"] if after else None
    rows = []
    for c, d in a.items():
        e = b[c] if b else {}
        rows.append(f"<tr><td>{c}</td><td>{d['unit']}</td><td>{_fmt(d['rms'])}</td><td>{_fmt(e.get('rms'))}</td>"
                    f"<td>{_fmt(d['peak'])}</td><td>{_fmt(e.get('peak'))}</td><td>{_fmt(d['fit'])}</td>"
                    f"<td>{_fmt(e.get('fit'))}</td><td>{_fmt(d['relative_error'])}</td>"
                    f"<td>{_fmt(e.get('relative_error'))}</td><td>{_fmt(d.get('overshoot_difference'))}</td>"
                    f"<td>{_fmt(d['noise_floor'])}</td></tr>")
    phase_rows = []
    for c, d in a.items():
        phase_rows.append(f"<tr><td>{c}</td>" + "".join(f"<td>{_fmt(v)}</td>" for v in d["phase_rms"].values()) + "</tr>")
    where = []
    for c, d in a.items():
        peaks = ", ".join(f"{p['frequency']:.1f} Hz" for p in d["spectrum_peaks"]) or "none"
        wh = d["whiteness"]
        where.append(f"<li><b>{c}</b>: spectrum peaks {peaks}; autocorrelation outside the 99 % band at "
                     f"{100 * wh['fraction_outside']:.0f} % of lags ({'white' if wh['white'] else 'not white'}); "
                     f"largest cross-correlation with the commanded velocity {d['cross_correlation_command']['max']:.2f} "
                     f"(band {wh['band_99']:.3f}); correlation with v {d['correlation']['velocity']:+.2f}, "
                     f"a {d['correlation']['acceleration']:+.2f}, x {d['correlation']['position']:+.2f}, "
                     f"sign(v) {d['correlation']['sign_velocity']:+.2f}</li>")
    diag = ""
    if diagnosis:
        items = "".join(f"<tr><td>{i + 1}</td><td>{html.escape(c['effect'])}</td><td>{_fmt(c['score'])}</td>"
                        f"<td>{html.escape(c['evidence'])}</td></tr>" for i, c in enumerate(diagnosis["candidates"]))
        diag = (f"<h2>Which effect is missing</h2><p>Verdict: <b>{html.escape(diagnosis['verdict'])}</b></p>"
                f"<table><tr><th>rank</th><th>effect</th><th>score (BIC fall)</th><th>evidence</th></tr>{items}</table>")
    figs = "".join(f'<p><img src="{html.escape(Path(f).name)}" style="max-width:100%"></p>' for f in figures)
    notes_html = "".join(f"<p>{html.escape(n)}</p>" for n in (notes or []))
    text = f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}td,th{{border:1px solid #ccc;padding:2px 6px}}
table{{border-collapse:collapse}}</style></head><body>
<h1>{html.escape(title)}</h1>{notes_html}
<h2>1. How far the model is from the measurement</h2>
<p>Residual = measured - simulated. Fit % = 100 (1 - ||y - y_hat|| / ||y - mean y||); relative error % =
100 ||y - y_hat|| / ||y||.{' Columns "after": the fitted model.' if b else ''}</p>
<table><tr><th>channel</th><th>unit</th><th>RMS</th><th>RMS after</th><th>peak</th><th>peak after</th>
<th>fit %</th><th>fit % after</th><th>rel. err %</th><th>rel. err % after</th><th>overshoot diff</th>
<th>noise floor</th></tr>{''.join(rows)}</table>
<h2>2. Where it fails</h2><p>RMS residual per motion phase:</p>
<table><tr><th>channel</th>{''.join(f'<th>{p}</th>' for p in analysis['phases'])}</tr>{''.join(phase_rows)}</table>
<ul>{''.join(where)}</ul>{diag}<h2>3. Figures</h2>{figs}</body></html>"""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, text)
    return path
