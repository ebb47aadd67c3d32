"""Reports that travel (issue 17): every report kind the tool writes (compare, diagnose, EMPS,
sweep, FRF) is one self-contained HTML file, and opens in a real headless browser.

The reports are made by the commands themselves, on a synthetic record (``hil synth``: the bench
with a hidden Coulomb friction) and on the shared EMPS record (skipped when absent). Two checks
per kind:

* the file itself: every figure a ``data:`` URI, nothing linked, no script; the date, the
  project's version, the record and the config named; no SI e-notation in the text;
* in Chromium (Debian's package; skipped with the reason when none is installed, .ci/run installs
  it): a copy of the report with a probe script appended is loaded with ``--dump-dom``; the probe
  writes into the DOM whether every image decoded (naturalWidth > 0) and whether the title and the
  verdict have a box on the page; the text must hold no raw Markdown (verbatim config text in
  <pre>, where TOML's # starts a comment, aside). A screenshot of each report
  (the file as written) is kept under out/browser/ (a CI artefact).
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest
from conftest import CONFIG, ROOT, SHARED

import hil

# a browser per report: the slow set, which CI runs
pytestmark = pytest.mark.slow

BENCH = CONFIG / "paper_bench.toml"
# the shared record beside the clone (CI), or beside the folder of the work trees
EMPS = next((p for p in (SHARED / "data" / "emps" / "DATA_EMPS.mat",
                         ROOT.parents[1] / "shared" / "data" / "emps" / "DATA_EMPS.mat") if p.exists()),
            SHARED / "data" / "emps" / "DATA_EMPS.mat")
SCREENSHOTS = ROOT / "out" / "browser"
KINDS = ("compare", "diagnose", "emps", "sweep", "frf")
CHROMIUM = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)

# raw Markdown that a report must never show as text: bold, headings, links, table rows
MARKDOWN = re.compile(r"\*\*|__\w|^#{1,6} |\]\(|^\s*\|.*\|\s*$", re.M)
E_NOTATION = re.compile(r"(?<![\w.])\d+(\.\d+)?[eE][+-]?\d+\b")

PROBE = """<script>
window.addEventListener("load", function () {
  function box(sel) {
    var e = document.querySelector(sel);
    if (!e) return null;
    var r = e.getBoundingClientRect(), s = getComputedStyle(e);
    return {text: e.innerText, width: r.width, height: r.height, top: r.top + window.scrollY,
            shown: s.display !== "none" && s.visibility !== "hidden" && parseFloat(s.opacity) > 0};
  }
  var imgs = Array.prototype.slice.call(document.images);
  var probe = {
    title: document.title, h1: box("#title"), verdict: box("#verdict"), images: imgs.length,
    loaded: imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length,
    broken: imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); }).map(function (i) {
      return i.alt; }),
    // the text a reader sees, less the verbatim config text (<pre>: TOML, where # starts a comment)
    text: (function () {
      var c = document.body.cloneNode(true);
      Array.prototype.slice.call(c.querySelectorAll("pre")).forEach(function (e) { e.remove(); });
      document.body.appendChild(c);
      var t = c.innerText;
      c.remove();
      return t;
    })()
  };
  var pre = document.createElement("pre");
  pre.id = "browser-probe";
  pre.textContent = JSON.stringify(probe);
  document.body.appendChild(pre);
});
</script>"""


# --- the reports, made once by the commands ---------------------------------------------------------

@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("reports")


@pytest.fixture(scope="module")
def record(work):
    from hil.config import load
    from hil.ident.synth import synthesize
    from hil.io.measurement import write
    ch, _ = synthesize(load(BENCH), "coulomb_friction", duration=6.0, seed=3)
    return write(work / "bench <coulomb> & co.csv", ch)       # a name the HTML must escape


def _run(argv) -> str:
    from contextlib import redirect_stdout
    from io import StringIO

    from hil.cli import main
    buf = StringIO()
    with redirect_stdout(buf):
        rc = main([str(a) for a in argv])
    assert rc == 0
    return buf.getvalue()


@pytest.fixture(scope="module")
def reports(work, record):
    """kind -> (report path, names it must show: record and configs, words of its verdict), each
    made once, when first asked for."""
    made = {}

    def get(kind):
        if kind in made:
            return made[kind]
        if kind == "diagnose":
            # the chain adds the hidden friction; its config is the fitted model of the compare report
            out = json.loads(_run(["diagnose", record, "--config", BENCH, "--candidates",
                                   "coulomb_friction,constant_force,viscous_friction", "--max-steps", "2", "--jobs",
                                   "1", "--out", work / "fitted.toml", "--report", work / "diagnose.html", "--json"]))
            assert out["report"] == str(work / "diagnose.html") and out["verdict"] == "coulomb_friction"
            made[kind] = (work / "diagnose.html", [record.name, BENCH.name], [out["verdict"]])
        elif kind == "compare":
            get("diagnose")
            fitted = work / "fitted.toml"
            out = json.loads(_run(["compare", record, "--config", BENCH, "--after", fitted, "--out",
                                   work / "compare", "--json"]))
            assert out["report"].endswith("report.html") and out["after"] is not None
            made[kind] = (Path(out["report"]), [record.name, BENCH.name, fitted.name], ["fit"])
        elif kind == "emps":
            if not EMPS.exists():
                pytest.skip(f"EMPS record not present at {EMPS}")
            out = json.loads(_run(["emps", "--data", EMPS, "--quick", "--no-diagnose", "--out", work / "emps",
                                   "--json"]))
            made[kind] = (Path(out["out"]) / "report.html", [EMPS.name, "emps.toml"], ["published"])
        elif kind == "sweep":
            out = json.loads(_run(["sweep", "--config", BENCH, "--stroke", "50mm", "--feed", "6m/min", "--jmax",
                                   "20..1500m/s^3", "--points", "3", "--dwell", "0.3s", "--tolerance", "20um", "--jobs",
                                   "1", "--out", work / "sweep", "--no-progress", "--json"]))
            # asked with a tolerance: the headline answers it (hil.sweep.sweep.sweep_answer)
            made[kind] = (Path(out["files"]["report"]), [BENCH.name], ["within 20 um"])
        elif kind == "frf":
            out = json.loads(_run(["frf", "--config", BENCH, "--set", "plant.c2=11.8", "--sim-set", "plant.c2=40",
                                   "--periods", "2", "--out", work / "frf", "--json"]))
            made[kind] = (Path(out["report"]), [BENCH.name], ["discrepanc"])
        return made[kind]
    return get


# --- the file itself --------------------------------------------------------------------------------

class _Page(HTMLParser):
    """The visible text, the images' sources, and the tags that would fetch or run something."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.text, self.verbatim, self.images, self.fetching, self._skip, self._pre = [], [], [], [], 0, 0

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag in ("style", "script", "title"):
            self._skip += 1
        self._pre += tag == "pre"
        if tag == "img":
            self.images.append(a.get("src", ""))
        if tag in ("script", "link", "iframe", "object", "embed") or (tag != "img" and a.get("src")):
            self.fetching.append(tag)

    def handle_endtag(self, tag):
        if tag in ("style", "script", "title"):
            self._skip -= 1
        self._pre -= tag == "pre"

    def handle_data(self, data):
        if not self._skip:
            (self.verbatim if self._pre else self.text).append(data)


@pytest.mark.parametrize("kind", KINDS)
def test_report_is_one_self_contained_file(kind, reports):
    path, names, words = reports(kind)
    html = path.read_text(encoding="utf-8")
    page = _Page()
    page.feed(html)
    text = " ".join(page.text)
    assert page.images, "a report without a figure"
    assert all(s.startswith("data:image/png;base64,") for s in page.images), "a figure linked, not embedded"
    assert not page.fetching, f"{kind}: tags that fetch or run: {page.fetching}"
    assert "url(" not in html and "http://" not in html and "https://" not in html
    assert f"hil version {hil.__version__}" in " ".join(text.split())
    assert re.search(r"date \d{4}-\d\d-\d\d \d\d:\d\d UTC", " ".join(text.split()))
    for n in names:
        assert n in text, f"{kind}: {n} not named"
    everything = text + " ".join(page.verbatim)
    assert not E_NOTATION.search(everything), f"{kind}: e-notation {E_NOTATION.search(everything).group()!r}"
    assert not MARKDOWN.search(text), f"{kind}: raw Markdown {MARKDOWN.search(text).group()!r}"
    assert "&lt;coulomb&gt;" in html or kind not in ("compare", "diagnose")     # escaped, not markup
    if kind in ("compare", "diagnose", "emps"):
        # MATLAB resid's figure in the residual analysis, and that analysis for both models
        sec = html[html.index('<section id="residual-analysis">'):html.index('<section id="figures">')]
        assert '<img src="data:image/png;base64,' in sec and 'alt="correlation"' in sec
        assert sec.count("<h3>") == 2


# --- in the browser ---------------------------------------------------------------------------------

def _chromium(args, profile: Path, timeout=120) -> subprocess.CompletedProcess:
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--hide-scrollbars", f"--user-data-dir={profile}", "--virtual-time-budget=10000", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed (Debian: apt-get install chromium; "
                                             ".ci/run installs it)")
@pytest.mark.parametrize("kind", KINDS)
def test_report_renders_in_chromium(kind, reports, tmp_path):
    path, names, words = reports(kind)
    html = path.read_text(encoding="utf-8")
    probed = tmp_path / "probed.html"
    probed.write_text(html.replace("</body>", PROBE + "\n</body>"), encoding="utf-8")
    r = _chromium(["--dump-dom", probed.as_uri()], tmp_path / "profile")
    assert r.returncode == 0, r.stderr[-2000:]
    m = re.search(r'<pre id="browser-probe">(.*?)</pre>', r.stdout, re.S)
    assert m, f"the page did not finish loading: {r.stdout[-500:]!r} {r.stderr[-1000:]!r}"
    import html as _html
    probe = json.loads(_html.unescape(m.group(1)))
    assert probe["images"] > 0 and probe["loaded"] == probe["images"], f"images not loaded: {probe['broken']}"
    for key in ("h1", "verdict"):
        box = probe[key]
        assert box and box["shown"] and box["width"] > 0 and box["height"] > 0, f"{key} not visible: {box}"
        assert box["top"] < 400, f"{key} not at the top of the page"
    assert probe["title"] and probe["title"] == probe["h1"]["text"].strip()
    for w in words:
        assert w in probe["verdict"]["text"], (w, probe["verdict"]["text"])
    assert not MARKDOWN.search(probe["text"]), f"raw Markdown: {MARKDOWN.search(probe['text']).group()!r}"
    # the screenshot, of the file as written (a CI artefact)
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    shot = SCREENSHOTS / f"{kind}.png"
    r = _chromium([f"--screenshot={shot}", "--window-size=1280,2400", path.as_uri()], tmp_path / "profile2")
    assert r.returncode == 0 and shot.stat().st_size > 10_000, r.stderr[-2000:]


# --- issue 29, item 5: the interactive page beside the compare report, offline ----------------------

LIVE_PROBE = """<script>
window.addEventListener("load", function () { setTimeout(function () {
  function canvases(n) {
    var c = n.tagName === "CANVAS" && n.width > 0 ? 1 : 0;
    if (n.shadowRoot) c += canvases(n.shadowRoot);
    for (var i = 0; i < n.children.length; i++) c += canvases(n.children[i]);
    return c;
  }
  var out = {bokeh: typeof Bokeh, roots: 0, canvases: canvases(document.body)};
  if (window.Bokeh && Bokeh.documents.length) out.roots = Bokeh.documents[0].roots().length;
  var pre = document.createElement("pre");
  pre.id = "browser-probe";
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
}, 3000); });
</script>"""


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed (Debian: apt-get install chromium; "
                                             ".ci/run installs it)")
def test_interactive_page_renders_offline_in_chromium(reports, tmp_path):
    """The report links interactive.html; Chromium, every request sent to a closed loopback proxy
    (nothing can be fetched), draws its panels: BokehJS is in the page."""
    path, _, _ = reports("compare")
    assert '<a href="interactive.html">' in path.read_text(encoding="utf-8")
    html = (path.parent / "interactive.html").read_text(encoding="utf-8")
    assert not re.search(r"<script[^>]*\ssrc=", html)
    probed = tmp_path / "probed.html"
    probed.write_text(html.replace("</body>", LIVE_PROBE + "\n</body>"), encoding="utf-8")
    r = _chromium(["--proxy-server=127.0.0.1:9", "--dump-dom", probed.as_uri()], tmp_path / "profile")
    assert r.returncode == 0, r.stderr[-2000:]
    m = re.search(r'<pre id="browser-probe">(.*?)</pre>', r.stdout, re.S)
    assert m, f"the page did not finish loading: {r.stdout[-500:]!r}"
    import html as _html
    probe = json.loads(_html.unescape(m.group(1)))
    assert probe["bokeh"] == "object" and probe["roots"] == 1, probe
    assert probe["canvases"] >= 2, probe
