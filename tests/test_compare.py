import math
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from hil.ident import motion_phases, noise_floor, nrmse_fit, relative_error, spectrum_peaks


def test_fit_and_relative_error():
    y = np.sin(np.linspace(0, 10, 1000))
    assert nrmse_fit(y, y) == 100.0
    assert relative_error(y, 0.9 * y) == np.float64(10.0).round(6) or abs(relative_error(y, 0.9 * y) - 10.0) < 1e-9


def test_noise_floor_of_white_noise():
    rng = np.random.default_rng(0)
    r = rng.normal(0, 2e-6, 20000) + 1e-4 * np.sin(np.linspace(0, 6, 20000))
    assert abs(noise_floor(r) / 2e-6 - 1) < 0.05


def test_spectrum_peak_frequency():
    t = np.arange(3000) * 4e-3
    f, _ = spectrum_peaks(np.sin(2 * np.pi * 15.2 * t), 4e-3, n=1)[0]
    assert abs(f - 15.2) < 0.1


def test_phases_cover_moves():
    t = np.arange(1000) * 1e-3
    x = np.where(t < 0.5, 0.5 * t ** 2, 0.125 + 0.5 * (t - 0.5))
    ph = motion_phases(t, x)
    assert ph["acceleration"][100:400].mean() > 0.9
    assert ph["constant speed"][700:950].mean() > 0.9


# --- issue 29, item 5: figures as an engineer reads them ---------------------------------------------

BENCH = Path(__file__).resolve().parents[1] / "config" / "paper_bench.toml"


@pytest.fixture(scope="module")
def analyses():
    """The bench with a hidden Coulomb friction against the bench (model) and against the bench
    with that friction (the fitted model: near the record)."""
    from hil.config import load
    from hil.ident import Replay
    from hil.ident.residual_analysis import analyse
    from hil.ident.synth import synthesize
    from hil.io.measurement import Measurement
    cfg = load(BENCH)
    ch, _ = synthesize(cfg, "coulomb_friction", duration=3.0, seed=3)
    meas = Measurement({k: v for k, v in ch.items()}, source="synthetic.csv")
    rp = Replay(meas, cfg)
    fitted = load(BENCH, {"effects.coulomb_friction.level": "2 N*m"})
    return analyse(rp), analyse(rp, fitted)


def _fit_by_hand(y, yhat) -> float:
    """MATLAB's NRMSE fit, 100 (1 - ||y - yhat|| / ||y - mean(y)||), in plain Python sums."""
    y, yhat = [float(v) for v in y], [float(v) for v in yhat]
    mean = math.fsum(y) / len(y)
    num = math.sqrt(math.fsum((a - b) ** 2 for a, b in zip(y, yhat)))
    den = math.sqrt(math.fsum((a - mean) ** 2 for a in y))
    return 100.0 * (1.0 - num / den)


def test_overlay_has_the_residual_beneath_on_one_time_axis_and_the_fit_in_the_legend(analyses):
    from hil.plots.residual_figures import overlay_figure
    a, b = analyses
    fig = overlay_figure(a, b)
    chans = list(a["_arrays"]["measured"])
    axes = fig.axes
    assert len(axes) == 2 * len(chans)
    for ax in axes[1:]:                                   # zoom one, zoom all
        assert axes[0].get_shared_x_axes().joined(axes[0], ax)
    for i, c in enumerate(chans):
        top, under = axes[2 * i], axes[2 * i + 1]
        assert c in top.get_ylabel() and "residual" in under.get_ylabel()
        assert top.get_position().y0 > under.get_position().y0      # beneath
        legend = [t.get_text() for t in top.get_legend().get_texts()]
        shown = {}
        for text in legend:
            m = re.fullmatch(r"(model|fitted model): (-?[0-9.]+) %", text)
            if m:
                shown[m.group(1)] = float(m.group(2))
        y = a["_arrays"]["measured"][c]
        assert shown["model"] == pytest.approx(_fit_by_hand(y, a["_arrays"]["simulated"][c]), abs=0.006)
        assert shown["fitted model"] == pytest.approx(_fit_by_hand(y, b["_arrays"]["simulated"][c]), abs=0.006)
    import matplotlib.pyplot as plt
    plt.close(fig)


class _Scripts(HTMLParser):
    def __init__(self):
        super().__init__()
        self.scripts, self.fetching = [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "script":
            self.scripts.append(a)
        if a.get("src") or (tag == "link" and a.get("href")):
            self.fetching.append((tag, a.get("src") or a.get("href")))


def test_interactive_page_is_self_contained(analyses, tmp_path):
    """BokehJS inline: every script in the page, nothing fetched (no src, no stylesheet link)."""
    from hil.plots.interactive import write_interactive
    a, b = analyses
    path = write_interactive(a, tmp_path / "interactive.html", "bench <coulomb>", after=b)
    html = path.read_text(encoding="utf-8")
    page = _Scripts()
    page.feed(html)
    assert page.scripts and not page.fetching, page.fetching
    assert not re.search(r"<script[^>]+src\s*=\s*[\"']?https?:", html)
    assert "Bokeh" in html and "&lt;coulomb&gt;" in html
    for c, d in a["channels"].items():
        assert f"model: {d['fit']:.2f} %" in html


@pytest.mark.slow
def test_compare_links_the_interactive_page(tmp_path, capsys):
    import json

    from hil.cli import main
    from hil.config import load
    from hil.ident.synth import synthesize
    from hil.io.measurement import write
    ch, _ = synthesize(load(BENCH), "coulomb_friction", duration=3.0, seed=3)
    rec = write(tmp_path / "r.csv", ch)
    assert main(["compare", str(rec), "--config", str(BENCH), "--out", str(tmp_path / "cmp"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    live = Path(out["interactive"])
    assert live == tmp_path / "cmp" / "interactive.html" and live.stat().st_size > 100_000
    report = Path(out["report"]).read_text(encoding="utf-8")
    assert '<a href="interactive.html">' in report
