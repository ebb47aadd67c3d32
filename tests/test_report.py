"""The pieces of the reports (issue 17): numbers in engineering units, merged spectral peaks, the
templates (escaping, the validation section, the EMPS tables without raw Markdown). The whole
reports, made by the commands and opened in a browser: tests/test_report_browser.py."""
from __future__ import annotations

import re

import numpy as np
import pytest

from hil.ident.residual import spectrum_peaks
from hil.plots.engineering import display_unit, eng, fmt

# --- engineering units -------------------------------------------------------------------------------


@pytest.mark.parametrize("value,unit,text", [
    (2.033e-4, "m", "203.3 um"), (1.028e-3, "m", "1.028 mm"), (0.0103, "m", "10.30 mm"), (1.5, "m", "1.500 m"),
    (0.35, "s", "350.0 ms"), (4e-3, "s", "4.000 ms"), (12.0, "s", "12.00 s"), (8.94, "N*m", "8.940 N m"),
    (0.0203, "N*m", "20.30 mN m"), (20.2386, "N", "20.24 N"), (0.005, "m/s", "5.000 mm/s"), (15.23, "Hz", "15.23 Hz"),
    (0.0, "m", "0 m"), (None, "m", "-"), (3.2e-9, "m", "0.003200 um"), (-2.5e-5, "m", "-25.00 um"),
])
def test_engineering_units(value, unit, text):
    assert eng(value, unit) == text


def test_no_e_notation_over_twenty_decades():
    for x in np.geomspace(1e-10, 1e10, 400):
        for v in (x, -x):
            s = fmt(v)
            assert "e" not in s.lower(), s
            # four significant digits: the number read back is the value to 0.05 % (or to the last
            # printed decimal, 1e-9, for the smallest)
            assert abs(float(s) - v) <= max(5e-4 * abs(v), 1e-9), (v, s)


def test_one_unit_for_a_column():
    # the unit in which the largest value reads at least 1: 0.2 mm and 3 um share um? no: mm
    assert display_unit("m", 2e-4, 3e-6) == ("um", 1e-6)
    assert display_unit("m", [2e-3, 3e-6]) == ("mm", 1e-3)
    assert display_unit("m/s^3", 500.0) == ("m/s^3", 1.0)
    assert display_unit("m") == ("m", 1.0)


@pytest.mark.parametrize("text,expected", [
    ("RMS x_motor error 4.51e-05 -> 2.1e-06 m (95 % less)", "RMS x_motor error 45.1 -> 2.1 um (95 % less)"),
    ("a mean of 0.0203 N*m in both directions", "a mean of 20.3 mN m in both directions"),
    ("k1 1.2e+08 N/m with the nut at 350 mm", "k1 120 N/um with the nut at 350 mm"),
    ("peak at 15.2 Hz, 3 samples, 0.5 mm, 2 m/s^2", "peak at 15.2 Hz, 3 samples, 0.5 mm, 2 m/s^2"),
    ("ratio 3.3e-05", "ratio 0.000033"),
])
def test_library_sentences_in_engineering_units(text, expected):
    from hil.plots.engineering import engineering_text
    assert engineering_text(text) == expected
    assert engineering_text(expected) == expected          # already engineering units: unchanged


# --- spectral peaks ---------------------------------------------------------------------------------

DT, N = 4e-3, 3000
BIN = 1 / (N * DT)
T = np.arange(N) * DT


@pytest.mark.parametrize("frac", [0.0, 0.1, 0.25, 0.4, 0.5])
def test_peak_frequency_and_amplitude_interpolated_between_bins(frac):
    f0, amp = (183 + frac) * BIN, 2.0e-6
    r = amp * np.sin(2 * np.pi * f0 * T + 0.3)
    (f, a), = spectrum_peaks(r, DT, n=1, merge_bins=3)
    (f_bin, a_bin), = spectrum_peaks(r, DT, n=1)
    assert abs(f - f0) < 0.03 * BIN            # the bin alone: up to half a bin off
    assert abs(f_bin - f0) == pytest.approx(min(frac, 1 - frac) * BIN, abs=1e-9)
    assert abs(a / amp - 1) < 0.05             # Hann's scalloping at the bin: up to -15 %
    # the Hann window's response half a bin off its centre and between, in closed form
    assert a_bin / amp == pytest.approx(np.sinc(frac) / (1 - frac ** 2), rel=2e-3)


@pytest.mark.parametrize("sep", [2.0, 2.5, 3.0])
def test_one_peak_listed_once(sep):
    """Two lines closer than the Hann window resolves are one lobe: listed once (the bins alone list
    its two maxima as two peaks); a line far away stays a peak of its own."""
    r = (np.sin(2 * np.pi * 183.2 * BIN * T) + 0.8 * np.sin(2 * np.pi * (183.2 + sep) * BIN * T + 1)
         + 0.3 * np.sin(2 * np.pi * 482.4 * BIN * T))
    merged = [f / BIN for f, _ in spectrum_peaks(r, DT, n=3, merge_bins=3)]
    assert len([f for f in merged if abs(f - 184) < 4]) == 1
    assert any(abs(f - 482.4) < 0.05 for f in merged)
    bins = [f / BIN for f, _ in spectrum_peaks(r, DT, n=3)]
    if sep >= 2.5:
        assert len([f for f in bins if abs(f - 184) < 4]) == 2       # the old listing, for the record
    for i, f in enumerate(merged):
        assert all(abs(f - g) > 3 for g in merged[:i])


def test_default_listing_unchanged():
    """The diagnosis's starting values keep the bins (the numbers of issues 12-13 stay identical)."""
    r = np.sin(2 * np.pi * 15.2 * T)
    f, _ = spectrum_peaks(r, DT, n=1)[0]
    assert f == pytest.approx(round(15.2 / BIN) * BIN)


# --- the templates ----------------------------------------------------------------------------------

def _text(html: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))


def test_names_are_escaped_and_the_validation_section_has_its_place(tmp_path):
    from hil.plots.report import render, report_meta
    validation = [{"title": "Estimation <a> against validation <b>", "note": "errors in %",
                   "header": ["channel", "estimation", "validation"], "rows": [["x_motor", "1.2 %", "1.9 %"]],
                   "numeric": [1, 2]}]
    ctx = dict(title="<script>x</script>", verdict="a & b", verdict_label="Verdict",
               meta=report_meta("rec <1>.csv", [("model", "m&m.toml")]), notes=[],
               move={"header": ["stroke"], "rows": [["50.00 mm"]], "numeric": [], "caption": None},
               answers=None, run_tables=[], minima=[], figures=[], validation=validation)
    html = render("sweep.html.j2", **ctx)
    assert "<script>x" not in html and "&lt;script&gt;x&lt;/script&gt;" in html
    assert "rec &lt;1&gt;.csv" in html and "m&amp;m.toml" in html and "a &amp; b" in html
    sec = html[html.index('<section id="validation">'):]
    assert "Estimation &lt;a&gt; against validation &lt;b&gt;" in sec and '<td class="num">1.9 %</td>' in sec
    ctx["validation"] = []
    assert 'id="validation"' not in render("sweep.html.j2", **ctx)


def test_emps_tables_are_html_not_markdown():
    """The EMPS report's steps and diagnoses (raw Markdown before issue 17), from the structures
    hil.ident.emps returns; no record needed."""
    from hil.ident.emps import PUBLISHED
    from hil.plots.report import _emps_context, _environment
    rows = [{"step": "start model (M, Fv)", "params": {"M": 95.1, "Fv": 203.5, "Fc": 0.0, "offset": 0.0},
             "position": 0.1234, "velocity": 3.21, "force": 12.5},
            {"step": "+ asymmetric_friction", "params": {"M": 95.2, "level_pos": 20.1, "level_neg": 20.6,
                                                         "viscous_pos": 166.0, "viscous_neg": 240.0, "offset": -3.1},
             "position": 0.05, "velocity": 1.5, "force": 3.2, "inverse_force": 3.1}]
    diags = [{"on": "start model", "verdict": "coulomb_friction",
              "ranking": [{"effect": "coulomb_friction", "score": 812.5, "significant": True, "evidence": "step at v=0"},
                          {"effect": "constant_force", "score": -3.0, "significant": False, "evidence": ""}],
              "also_missing": [{"effect": "constant_force", "score": 40.0, "evidence": "offset"}],
              "combinations": []}]
    check = {"deviation": {"M": 0.5, "Fv": -1.2, "Fc": 2.0, "offset_N": 0.1}, "within_5_percent_and_0.5_N": True,
             "errors_match_or_beat_published": True}
    ctx = _emps_context({"rows": rows, "published": PUBLISHED, "check": check, "diagnoses": diags})
    env = _environment()
    t = env.get_template("emps.html.j2")
    html = "".join(t.blocks["lead"](t.new_context(dict(ctx, m=env.get_template("_macros.html.j2").module))))
    assert "verdict <strong>coulomb_friction</strong>" in html and "also missing: <strong>constant_force</strong>" in html
    assert "**" not in html and "|---" not in html
    assert "within 5 %" in ctx["verdict"]
    steps = ctx["steps"]
    assert steps["rows"][0][1:5] == ["95.100 kg", "203.50 N s/m", "0.000 N", "0.000 N"]
    assert steps["rows"][1][0].startswith("+ asymmetric_friction: Fc+ 20.10 N")
    assert any(r[0].startswith("published (Janot") for r in steps["rows"])
    assert ctx["diagnoses"][0]["verdict"] == "coulomb_friction"
    for r in steps["rows"]:
        assert not any("**" in str(c) or str(c).startswith("|") for c in r)
