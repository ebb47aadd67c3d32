"""hil fleet (issue 26): a fleet's records diagnosed, every axis judged against its own history.

The SPC rules on series with a closed-form answer (limits of a known baseline, a step and a ramp
flagged at the record they start); the manifest's forms and its one-line errors; then one tiny
fleet from ``hil synth --fleet`` (2 axes x 5 dates of 1.5 s, one axis's backlash stepping from
4 to 9 um on the fourth date) run through ``hil fleet run``: exactly that axis flagged on that
date, the rerun reusing every record, a new record diagnosed alone, an unreadable one a line in
the summary; the same figures on a Dask cluster on 127.0.0.1; the report in headless Chromium.
"""
from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
from contextlib import redirect_stdout
from io import StringIO
from pathlib import Path

import pytest
from conftest import CONFIG

from hil.cli import main
from hil.errors import ConfigError
from hil.fleet.manifest import read_manifest
from hil.fleet.spc import (
    change_point,
    control_limits,
    cusum_alarm,
    judge_series,
    new_effects,
    normal_effects,
    parse_threshold,
    usual_effects,
)

BENCH = str(CONFIG / "paper_bench.toml")
CHROMIUM = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)


# --- SPC: closed-form series ------------------------------------------------------------------------

def test_control_limits_of_a_known_baseline():
    lim = control_limits([1.0, 2.0, 3.0])
    assert lim.centre == pytest.approx(2.0) and lim.sigma == pytest.approx(1.0)     # sample sd (n - 1)
    assert lim.band(None) == pytest.approx((-1.0, 5.0))
    # a record's own standard error adds in quadrature: sqrt(1 + 0.75^2) = 1.25
    assert lim.band(0.75) == pytest.approx((2.0 - 3.75, 2.0 + 3.75))
    # a baseline that happens to agree exactly: the night-to-night scatter (1 %) is the floor
    assert control_limits([10.0, 10.0, 10.0]).sigma == pytest.approx(0.1)


def test_a_step_is_flagged_at_the_record_it_starts():
    vals = [1.0, 1.002, 0.998, 1.001, 0.999, 1.0, 1.05, 1.051, 1.049]
    j = judge_series(vals, [None] * len(vals), [0, 1, 2])
    assert j.flagged and j.first_moved == 6 and j.first_alarm == 6
    assert j.status[:3] == ["baseline"] * 3 and j.status[3:6] == ["ok"] * 3 and j.status[6] == "out"


def test_a_slow_ramp_is_dated_by_the_cusum_before_it_leaves_three_sigma():
    # centre 1, sigma 0.01 (the 1 % floor): z = 0 up to record 4, then 1, 2, 3, 4, ...
    vals = [1.0] * 5 + [1.0 + 0.01 * k for k in range(1, 6)]
    # the CUSUM (k 0.5, h 4): 0.5, 2.0, 4.5 > 4 -> alarm at record 7, its last zero at record 4
    assert cusum_alarm([0.0] * 5 + [1.0, 2.0, 3.0, 4.0, 5.0]) == (7, 5)
    j = judge_series(vals, [None] * len(vals), [0, 1, 2])
    assert j.flagged and j.first_moved == 5 and j.first_alarm == 7


def test_a_step_after_a_night_that_lay_high_is_dated_at_the_step():
    """The CUSUM's own estimate (the record after its last zero) would date it a week early: the
    night before the step lay 1.3 sigma high by chance; the least-squares change point does not."""
    vals = [1.0, 1.0, 1.0, 1.013, 1.4, 1.41]
    assert cusum_alarm([(v - 1.0) / 0.01 for v in vals[3:]])[1] == 0         # i.e. record 3
    j = judge_series(vals, [None] * len(vals), [0, 1, 2])
    assert j.flagged and j.first_alarm == 4 and j.first_moved == 4
    assert change_point([0, 0, 0, 1.3, 40.0, 41.0], 3, 4) == 4


def test_a_steady_axis_with_its_scatter_is_not_flagged():
    vals = [1.0, 1.01, 0.99, 1.005, 0.995, 1.01, 0.99, 1.0, 1.008, 0.992]
    j = judge_series(vals, [1e-5] * len(vals), [0, 1, 2])
    assert not j.flagged and j.first_moved is None and "out" not in j.status


def test_a_physical_threshold_flags_whatever_the_history():
    kinds = {"backlash.gap": "length", "coulomb_friction.level": "torque"}
    th = parse_threshold("backlash > 10um", kinds, "fleet.thresholds")
    assert th.name == "backlash.gap" and th.value == pytest.approx(1e-5) and th.op == ">"
    vals = [11e-6, 11.1e-6, 10.9e-6, 11e-6]      # steady, but above the limit from the start
    j = judge_series(vals, [None] * 4, [0, 1, 2], threshold=th)
    assert j.flagged and j.threshold_first == 0 and j.first_moved == 0
    with pytest.raises(ConfigError, match=r"fleet.thresholds backlash.gap.*unit"):
        parse_threshold("backlash.gap > 10", kinds, "fleet.thresholds")
    with pytest.raises(ConfigError, match="pitch_error is not a tracked parameter"):
        parse_threshold("pitch_error > 1um", kinds, "--threshold")
    with pytest.raises(ConfigError, match="expected 'effect.parameter > value'"):
        parse_threshold("backlash >= 3um", kinds, "--threshold")


def test_an_effect_named_on_every_baseline_record_is_the_axis_normal():
    named = [{"backlash", "coulomb_friction"}, {"backlash"}, {"backlash", "viscous_friction"}, {"backlash", "x"}]
    assert normal_effects(named, [0, 1, 2]) == {"backlash"}
    # after the baseline: a stray verdict on one night is not a finding; two nights in a row are,
    # dated at the first; so is one on the latest record
    later = named[:3] + [{"backlash", "pitch_error"}, {"backlash"}, {"backlash", "feedback_delay"},
                         {"backlash", "feedback_delay"}, {"backlash", "constant_force"}]
    assert new_effects(later, [0, 1, 2], {"backlash"}) == {"feedback_delay": 5, "constant_force": 7}


def test_the_usual_model_is_what_the_chain_names_on_most_baseline_records():
    # a friction named Coulomb on two nights of three (load-dependent on the other) is no normal
    # effect, but the axis's strengths are fitted with it (hil.fleet.batch.confirm_findings)
    named = [{"backlash", "coulomb_friction"}, {"backlash", "load_dependent_friction"},
             {"backlash", "coulomb_friction", "x"}, {"backlash"}]
    assert normal_effects(named, [0, 1, 2]) == {"backlash"}
    assert usual_effects(named, [0, 1, 2]) == {"backlash", "coulomb_friction"}
    assert usual_effects(named, [0, 1]) == {"backlash"} and usual_effects(named, []) == set()


# --- the manifest -------------------------------------------------------------------------------------

def test_manifest_forms_and_their_errors(tmp_path):
    (tmp_path / "X1").mkdir()
    for p in ("X1/2026-03-09.csv", "X1/2026-03-02.csv", "Y2_2026-03-02.csv", "notes.csv"):
        (tmp_path / p).write_text("t,x\n")
    es = read_manifest(tmp_path)
    assert [(e.axis, e.timestamp) for e in es] == [("X1", "2026-03-02"), ("X1", "2026-03-09"), ("Y2", "2026-03-02")]
    m = tmp_path / "m.csv"
    m.write_text("record,axis,timestamp,baseline\nX1/2026-03-02.csv,X1,2026-03-02,true\n")
    (e,) = read_manifest(m)
    assert e.baseline and e.record == str(tmp_path / "X1/2026-03-02.csv") and e.config is None
    m.write_text("record,axis,timestamp\nX1/2026-03-02.csv,X1,2 March\n")
    with pytest.raises(ConfigError, match=r"m.csv: line 2: timestamp '2 March': expected ISO 8601"):
        read_manifest(m)
    m.write_text("record,axis,when\n")
    with pytest.raises(ConfigError, match=r"line 1: unknown column 'when'"):
        read_manifest(m)
    t = tmp_path / "m.toml"
    t.write_text('[[record]]\nrecord = "a.csv"\naxis = "X1"\ntimestamp = "2026-03-02"\n'
                 '[[record]]\nrecord = "b.csv"\naxis = "X1"\ntimestamp = "2026-03-02"\n')
    with pytest.raises(ConfigError, match="two records at 2026-03-02"):
        read_manifest(t)


# --- a tiny fleet, end to end -------------------------------------------------------------------------

SPEC = """\
axes = ["X1", "X2"]
start = "2026-03-02"
count = 5
every = "7 days"
duration = "1.5 s"
scatter = 0.01
[effects]
backlash = { gap = "4 um" }
[[drift]]
axis = "X2"
parameter = "backlash.gap"
from = "2026-03-23"
step = "5 um"
"""
RUN = ["--config", BENCH, "--track", "backlash", "--candidates", "backlash,coulomb_friction", "--max-steps", "1",
       "--threshold", "backlash.gap > 20um"]


def _cli(*argv) -> str:
    buf = StringIO()
    with redirect_stdout(buf):
        rc = main([str(a) for a in argv])
    assert rc == 0
    return buf.getvalue()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    work = tmp_path_factory.mktemp("fleet")
    (work / "spec.toml").write_text(SPEC)
    out = json.loads(_cli("synth", "--config", BENCH, "--fleet", work / "spec.toml", "--out", work / "records",
                          "--json"))
    assert out["fleet"]["records"] == 10 and out["fleet"]["drift"][0]["from"] == "2026-03-23"
    from hil.commands.synth import JSON_KEYS
    assert set(out) <= set(JSON_KEYS) and out["fleet"]["drift"][0]["step"] == pytest.approx(5e-6)
    run = json.loads(_cli("fleet", "run", work / "records", *RUN, "--out", work / "out", "--jobs", "2", "--json"))
    return work, run


def _keys_documented(obj):
    from hil.commands.fleet import JSON_KEYS
    assert set(obj) <= set(JSON_KEYS), set(obj) - set(JSON_KEYS)
    for a in obj.get("axes", []):
        assert {f"axes[].{k}" for k in a} <= set(JSON_KEYS), set(a)


@pytest.mark.slow
def test_the_drifting_axis_is_flagged_on_the_date_of_its_step(fleet):
    work, run = fleet
    _keys_documented(run)
    assert run["records"] == 10 and run["computed"] == 10 and run["reused"] == 0 and run["errors"] == []
    axes = {a["axis"]: a for a in run["axes"]}
    assert axes["X1"]["verdict"] == "ok" and axes["X1"]["flags"] == []
    (flag,) = axes["X2"]["flags"]
    assert flag["parameter"] == "backlash.gap" and flag["since"] == "2026-03-23"
    # the fitted strength against the truth (4 um, 9 um after the step; 1 % scatter)
    truth = json.loads((work / "records" / "truth.json").read_text())["records"]
    p = axes["X2"]["params"]["backlash.gap"]
    for date, v in zip(axes["X2"]["dates"], p["values"]):
        assert v == pytest.approx(truth[f"X2@{date}"]["backlash"]["gap"], rel=0.05), date
    assert p["first_moved"] == "2026-03-23" and p["status"][3:] == ["out", "out"]
    # the chain names backlash on every record: the axes' normal, not a finding
    assert axes["X1"]["normal"] == ["backlash"] and axes["X2"]["findings"] == []


@pytest.mark.slow
def test_a_rerun_reuses_every_record_and_a_new_one_is_diagnosed_alone(fleet, tmp_path):
    work, _ = fleet
    out = tmp_path / "out"
    shutil.copytree(work / "out", out)
    again = json.loads(_cli("fleet", "run", work / "records", *RUN, "--out", out, "--json"))
    assert again["computed"] == 0 and again["reused"] == 10
    assert again["axes"] == json.loads(_cli("fleet", "run", work / "records", *RUN, "--out", out, "--json"))["axes"]
    # a new night: one record more (a copy of X1's last under the next date), and one that cannot be read
    recs = tmp_path / "records"
    shutil.copytree(work / "records", recs)
    (recs / "manifest.csv").unlink()           # the folder's naming: AXIS_DATE.csv
    # (a comment line more: other bytes, so another key; a plain copy would be the stored record's own)
    (recs / "X1_2026-04-06.csv").write_text("# night = 6\n" + (recs / "X1_2026-03-30.csv").read_text())
    (recs / "X2_2026-04-06.csv").write_text("t [s],x_cmd [m]\n0,zero\n")
    text = _cli("fleet", "run", recs, *RUN, "--out", out)
    assert "12 records of 2 axes: 2 diagnosed now, 10 reused" in text
    assert re.search(r"error: .*X2_2026-04-06\.csv, line 2, column 'x_cmd': 'zero' is not a number", text), text
    assert text.count("error:") == 1 and "X2: drift: backlash.gap since 2026-03-23" in text


@pytest.mark.slow
def test_bad_settings_are_one_line_with_exit_2(fleet, capsys):
    work, _ = fleet
    assert main(["fleet", "run", str(work / "records"), "--config", BENCH, "--track", "backlash", "--threshold",
                 "backlash.gap > 10", "--out", str(work / "bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--threshold backlash.gap" in err and "Traceback" not in err
    assert main(["fleet", "run", str(work / "records"), "--config", BENCH, "--track", "no_such_effect",
                 "--out", str(work / "bad")]) == 2
    assert "fleet.track" in capsys.readouterr().err
    # the config's own settings: [fleet] track and thresholds, named in the error
    cfg = work / "axis.toml"
    cfg.write_text(Path(BENCH).read_text() + '\n[fleet]\ntrack = "backlash"\nthresholds = "backlash.gap > 10"\n')
    assert main(["fleet", "run", str(work / "records"), "--config", str(cfg), "--out", str(work / "bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{cfg}: fleet.thresholds backlash.gap" in err and "unit" in err and len(err.splitlines()) == 1
    assert main(["fleet", "report", str(work / "nowhere")]) == 2
    assert "no fleet here" in capsys.readouterr().err


@pytest.mark.slow
def test_the_report_and_its_values(fleet):
    work, run = fleet
    out = json.loads(_cli("fleet", "report", work / "out", "--json"))
    _keys_documented(out)
    html = Path(out["report"]).read_text(encoding="utf-8")
    assert html.count("<svg") == 2 and "<script" not in html and "http" not in html.replace("http://www.w3.org", "")
    assert "first moved 2026-03-23" in html and 'href="records/X2_2026-03-23.html"' in html
    assert len(out["pages"]) == 10 and all(Path(p).exists() for p in out["pages"])
    rows = json.loads(Path(out["json"]).read_text())
    assert len(rows) == 10 and {r["effect"] for r in rows} == {"backlash.gap"}
    csv_rows = Path(out["csv"]).read_text().splitlines()
    assert csv_rows[0] == "axis,date,effect,value,stderr,record" and len(csv_rows) == 11
    x2 = [r for r in rows if r["axis"] == "X2"]
    assert [r["value"] for r in x2] == run["axes"][1]["params"]["backlash.gap"]["values"]
    assert all(r["stderr"] is not None and 0 < r["stderr"] < 0.05 * r["value"] for r in rows)


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed (Debian: apt-get install chromium)")
def test_the_report_renders_in_chromium(fleet, tmp_path):
    work, _ = fleet
    out = json.loads(_cli("fleet", "report", work / "out", "--json"))
    probe = """<script>window.addEventListener("load", function () {
      var t = document.querySelector("#title").getBoundingClientRect();
      var svgs = Array.prototype.slice.call(document.querySelectorAll("svg")).map(function (s) {
        var r = s.getBoundingClientRect(); return [r.width, r.height, s.querySelectorAll("circle title").length]; });
      var pre = document.createElement("pre"); pre.id = "browser-probe";
      pre.textContent = JSON.stringify({title: t.height, svgs: svgs,
        verdict: document.querySelector("#verdict").innerText}); document.body.appendChild(pre); });</script>"""
    page = tmp_path / "probed.html"
    page.write_text(Path(out["report"]).read_text().replace("</body>", probe + "</body>"))
    r = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                        "--no-first-run", "--disable-background-networking", f"--user-data-dir={tmp_path / 'p'}",
                        "--virtual-time-budget=10000", "--dump-dom", page.as_uri()],
                       capture_output=True, text=True, timeout=120)
    m = re.search(r'<pre id="browser-probe">(.*?)</pre>', r.stdout, re.S)
    assert m, r.stderr[-1000:]
    import html as _html
    got = json.loads(_html.unescape(m.group(1)))
    assert got["title"] > 0 and "1 flagged" in got["verdict"]
    assert len(got["svgs"]) == 2 and all(w > 100 and h > 100 and n == 5 for w, h, n in got["svgs"])


def _two_records(work, tmp_path) -> Path:
    man = tmp_path / "two.csv"
    man.write_text("record,axis,timestamp\n" + "".join(
        f"{work / 'records' / f'{a}_2026-03-30.csv'},{a},2026-03-30\n" for a in ("X1", "X2")))
    return man


def _same_as_local(work, folder, n=2):
    local = {r["key"]: r["figures"] for r in map(json.loads, (work / "out" / "results.jsonl").open())}
    there = {r["key"]: r["figures"] for r in map(json.loads, (folder / "results.jsonl").open())}
    assert len(there) == n and set(there) <= set(local)
    for k, fig in there.items():
        assert fig == local[k]                  # bit for bit: the same function on the same bytes
        assert math.isfinite(fig["values"]["backlash.gap"])


@pytest.mark.slow
def test_the_same_figures_on_a_local_dask_cluster(fleet, tmp_path):
    """--scheduler ADDRESS of a LocalCluster on 127.0.0.1 (its worker a thread of this process, the
    kernels compiled already): two records (one of each axis) equal the local run's figures."""
    distributed = pytest.importorskip("distributed")
    work, _ = fleet
    with distributed.LocalCluster(host="127.0.0.1", protocol="tcp", n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        on = json.loads(_cli("fleet", "run", _two_records(work, tmp_path), *RUN, "--out", tmp_path / "dask",
                             "--scheduler", cluster.scheduler_address, "--json"))
    assert on["computed"] == 2 and on["errors"] == []
    _same_as_local(work, tmp_path / "dask")


@pytest.mark.slow
def test_the_same_figures_on_a_dask_scheduler_and_worker_processes(fleet, tmp_path):
    """A scheduler and a worker started by Dask's own commands on 127.0.0.1 (a fresh process: it
    compiles the kernels, about 25 s); two records diagnosed there equal the local run's figures."""
    pytest.importorskip("distributed")
    import socket
    import sys
    import time
    work, _ = fleet
    man = _two_records(work, tmp_path)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    addr = f"tcp://127.0.0.1:{port}"
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                               "--port", str(port), "--no-dashboard"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    try:
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", addr, "--nthreads", "1",
                                       "--nworkers", "1", "--host", "127.0.0.1", "--no-dashboard"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client
        with Client(addr, timeout=30) as c:
            c.wait_for_workers(1, timeout=60)
        t0 = time.time()
        on = json.loads(_cli("fleet", "run", man, *RUN, "--out", tmp_path / "dask", "--scheduler", addr, "--json"))
        assert on["computed"] == 2 and time.time() - t0 < 120
    finally:
        for p in reversed(procs):
            p.terminate()
            p.wait(timeout=30)
    _same_as_local(work, tmp_path / "dask")


@pytest.mark.slow
def test_ctrl_c_loses_nothing_finished(fleet, tmp_path):
    """Ctrl-C (SIGINT to the process group, as a terminal sends it) in the middle of a run: the
    records stored before it are reused by the next run, which diagnoses only the rest."""
    import os
    import signal
    import sys
    import time
    work, _ = fleet
    out = tmp_path / "out"
    store = out / "results.jsonl"
    cmd = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))", "fleet", "run",
           str(work / "records"), *RUN, "--out", str(out), "--jobs", "1"]
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        t0 = time.time()
        while time.time() - t0 < 300 and not (store.exists() and store.read_text().count("\n") >= 2):
            time.sleep(0.2)
        os.killpg(p.pid, signal.SIGINT)
        assert p.wait(timeout=60) != 0
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    done = len([ln for ln in store.read_text().splitlines() if ln.strip()])
    assert 2 <= done < 10
    again = json.loads(_cli("fleet", "run", work / "records", *RUN, "--out", out, "--json"))
    assert again["reused"] >= 2 and again["computed"] == 10 - again["reused"]
    assert again["axes"] == json.loads((work / "out" / "fleet.json").read_text())["axes"]
