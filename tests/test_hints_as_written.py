"""Docs and hints that work as written (issue 29, item 6): the record's sample period as the
tutorial states it, an outlier warning with its units, the chain's steps as the tutorial tells
them, a refusal's `hil reset` hint that clears the trip as given, `hil emps` saying where its
record is expected and how to give it, a trip's reason with the digits that tell its figures apart,
and a move plot whose title fits the figure."""
import json
import re
import shlex

import numpy as np
import pytest
from conftest import CONFIG, ROOT, SHARED

from hil.cli import main

BENCH = str(CONFIG / "paper_bench.toml")
EMPS = SHARED / "data" / "emps" / "DATA_EMPS.mat"


def _console_command(page: str, starts: str) -> list[str]:
    """The argv (after ``hil``) of the first ``$ hil ...`` line of a docs page that starts so."""
    for line in (ROOT / "docs" / page).read_text(encoding="utf-8").splitlines():
        if line.startswith(f"$ hil {starts}"):
            return shlex.split(line[len("$ hil "):])
    raise AssertionError(f"{page}: no command 'hil {starts}'")


def test_the_tutorial_states_the_record_s_sample_period(tmp_path, capsys):
    """The dry-run tutorial said one row per 0.5 ms; its move writes one per 4 ms."""
    text = " ".join((ROOT / "docs" / "tutorials" / "dry-run-and-sweep.md").read_text(encoding="utf-8").split())
    m = re.search(r"`out/move/move\.csv` \(one row per [^:]*?(\d+(?:\.\d+)?) ms", text)
    assert m, "the tutorial does not say how often the record has a row"
    argv = _console_command("tutorials/dry-run-and-sweep.md", "move") + ["--dwell", "0.2s", "--out", str(tmp_path)]
    assert main(argv) == 0
    capsys.readouterr()
    header = (tmp_path / "move.csv").read_text(encoding="utf-8").splitlines()
    period = next(float(ln.split("=")[1].split()[0]) for ln in header if ln.startswith("# sample_period"))
    t = np.loadtxt(tmp_path / "move.csv", delimiter=",", comments="#", skiprows=4, usecols=0, max_rows=50)
    assert float(m.group(1)) * 1e-3 == pytest.approx(period) == pytest.approx(float(np.median(np.diff(t))))


def test_an_outlier_warning_names_its_units():
    from hil.io.importers import data_warnings
    from hil.io.measurement import Measurement
    t = np.arange(2000) * 4e-3
    x = 0.01 * np.sin(t)
    x[500] += 0.05                                          # a 50 mm glitch on a table in metres
    tq = np.cos(t)
    tq[700] = 40.0
    w = data_warnings(Measurement({"t": t, "x_table": x, "torque": tq}, {}, "r.csv",
                                  {"x_table": "mm", "torque": "N*m"}))
    xw = next(s for s in w if "'x_table'" in s)
    tw = next(s for s in w if "'torque'" in s)
    assert re.search(r"beyond [0-9.]+ (um|mm) from the running median, sample\(s\) 501 \(e\.g\. 59\.09\d* mm\)", xw), xw
    assert re.search(r"beyond [0-9.]+ N m from the running median, sample\(s\) 701 \(e\.g\. 40 N m\)", tw), tw


def _trip(tmp_path, capsys, *extra):
    sets = ["--set", "limits.following_error_table=1 um", "--set", f"supervisor.latch_file={tmp_path / 'latch x.json'}"]
    rc = main(["move", "--config", BENCH, "--stroke", "10mm", "--feed", "3000mm/min", "--tacc", "200ms", "--dwell",
               "0.1s", "--out", str(tmp_path / "m"), *sets, *extra])
    return rc, capsys.readouterr(), sets


def test_a_trip_reason_tells_its_figures_apart(tmp_path, capsys):
    """A 1 um window: the reason read '0.002 mm > 0.001 mm' (1.6 um rounded to mm)."""
    from hil.supervisor import exceeds
    assert exceeds(1.6e-6, 1e-6) == "1.6 um > 1 um"
    assert exceeds(1.0004e-6, 1e-6) == "1.0004 um > 1 um"
    assert exceeds(0.0352, 0.03) == "35.2 mm > 30 mm"
    rc, cap, _ = _trip(tmp_path, capsys, "--json")
    reason = json.loads(cap.out)["reason"]
    m = re.search(r"following error at the table: ([0-9.]+) um > 1 um", reason)
    assert rc == 3 and m and float(m.group(1)) > 1.0, reason


def test_the_reset_hint_repeats_the_sets_and_clears_the_trip(tmp_path, capsys):
    """A run with --set (here: where the latch lives) refused after a trip: the hint's 'hil reset
    --config FILE' without those --set looked at another latch (or drive) and cleared nothing."""
    from hil.config import load
    from hil.supervisor import Supervisor
    latch = tmp_path / "latch x.json"
    Supervisor(load(BENCH, {"supervisor.latch_file": str(latch)})).trip(0.1, "a trip of a real axis")
    assert latch.exists()
    rc, cap, sets = _trip(tmp_path, capsys)                # refused: the trip is latched
    assert rc != 0 and "motion refused" in cap.err
    hint = re.search(r"'(hil reset [^']*)' clears it", cap.err)
    assert hint, cap.err
    argv = shlex.split(hint.group(1))[1:]
    assert argv[:3] == ["reset", "--config", BENCH] and all(s in argv for s in sets[1::2])
    assert main(argv) == 0 and not latch.exists()           # the hint, as given, clears it
    capsys.readouterr()


def test_emps_outside_a_clone_says_where_the_record_is_expected(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["emps"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "DATA_EMPS.mat" in err and "--data" in err and "Get the EMPS record" in err and str(tmp_path) in err
    assert main(["emps", "--data", "nowhere.mat"]) == 2
    assert "nowhere.mat: no such file" in capsys.readouterr().err


def test_the_move_plot_s_title_fits_the_figure():
    """The CANopen walkthrough's move: a long config path and the figures of the move, and a stop's
    reason: every line of the title inside the figure."""
    from hil.plots.move import move_figure
    t = np.linspace(0, 1, 200)
    ch = {"t": t, "x_cmd": 0.02 * t, "x_table": 0.02 * t, "x_tip": 0.02 * t}
    title = ("config/paper_bench_canopen.toml: stroke 20 mm from 1.234 mm, feed 6000 mm/min, j_max 200 m/s^3 "
             "(backend canopen, node 1)")
    fig = move_figure(ch, title=title, stopped=("tripped", "following error at the table: 1.6 um > 1 um; "
                                                "the controlled stop (quick_stop) went out in the same cycle"))
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    width = fig.bbox.width
    texts = [fig.axes[0].title, fig._suptitle]
    for text in texts:
        box = text.get_window_extent(renderer)
        assert box.x0 >= 0 and box.x1 <= width, (text.get_text(), box, width)
    import matplotlib.pyplot as plt
    plt.close(fig)


@pytest.mark.slow
@pytest.mark.skipif(not EMPS.exists(), reason=f"EMPS record not present at {EMPS}")
def test_the_tutorial_tells_every_step_of_the_emps_chain(capsys):
    """The model-against-measurement tutorial's EMPS diagnosis: every effect the chain adds is named
    in the paragraph after the command (it left out the channel_skew step)."""
    page = "tutorials/model-against-measurement.md"
    argv = _console_command(page, "diagnose ../shared")
    argv = [str(ROOT / a) if a.startswith(("../", "config/")) else a for a in argv]
    argv = [a for a in argv if a not in ("--out", "out/emps_fitted.toml")] + ["--json"]
    assert main(argv) == 0
    chain = json.loads(capsys.readouterr().out)["chain"]
    text = (ROOT / "docs" / page).read_text(encoding="utf-8")
    para = text[text.index("The chain names"):text.index("## Where next")]
    for step in chain:
        for effect in step["effects"]:
            assert f"`{effect}`" in para, (effect, para)
