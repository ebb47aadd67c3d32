"""Issue 25, item 2: every chain step validated. ``hil emps --validate`` validates the chain's model
beside the output-error refits and reports every step's estimation and held-out errors side by
side (text, JSON, the report); without --validate the steps are judged on the record's held-out
moves. Skipped without the EMPS record (its validation record is written from it here: the same
record with no pulses, so that every validation figure must equal the estimation one)."""
import json
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "emps" / "DATA_EMPS.mat"
emps_record = pytest.mark.skipif(not DATA.exists(), reason=f"EMPS record not present at {DATA}")


def _no_pulses_record(tmp_path):
    import scipy.io
    d = scipy.io.loadmat(DATA)
    out = {k: d[k] for k in ("t", "qm", "qg", "vir", "gtau", "kp", "kv")}
    out["pulses_N"] = np.zeros_like(d["vir"])
    p = tmp_path / "DATA_EMPS_PULSES.mat"
    scipy.io.savemat(p, out)
    return p


@pytest.mark.slow
@emps_record
def test_emps_validate_validates_the_chain_and_every_step(tmp_path, capsys):
    from hil.cli import main
    from hil.commands.emps import CHAIN_MODEL
    val = _no_pulses_record(tmp_path)
    assert main(["emps", "--data", str(DATA), "--validate", str(val), "--quick", "--out", str(tmp_path / "e"),
                 "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["chain_final"]["held_out"] == "the validation records"
    assert d["chain"], "the chain added nothing"
    for s in d["chain"]:
        # the validation record is the estimation record: the held-out error after the step is the
        # estimation error, channel by channel, and the step's error on the record
        for c, e in s["estimation_error"].items():
            assert s["held_out"]["after"][c] == pytest.approx(e, rel=1e-9)
            assert s["error_after"][c] == pytest.approx(e, rel=1e-9)
    # the chain's model validated beside the refits: on this record its errors are its table row's
    steps = [r["step"] for r in d["rows"]]
    last_chain_row = d["rows"][steps.index("IDIM-LS on the force (inverse model)") - 1]
    chain_row = next(v for v in d["validation"] if v["model"] == CHAIN_MODEL)
    for k in ("position", "velocity", "force"):
        assert chain_row[k] == pytest.approx(last_chain_row[k], rel=1e-9)
    table = (tmp_path / "e" / "table.md").read_text()
    assert "| chain step | added | x_motor estimation m | force estimation N |" in table
    assert "held out: the validation records" in table
    import html
    report = html.unescape((tmp_path / "e" / "report.html").read_text())
    assert "The chain's steps: estimation and held-out errors" in report


@emps_record
@pytest.mark.slow
def test_emps_without_validate_judges_the_chain_on_held_out_moves(tmp_path, capsys):
    from hil.cli import main
    assert main(["emps", "--data", str(DATA), "--quick", "--out", str(tmp_path / "e"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["chain_final"]["held_out"] == "the record's moves in pairs, alternately estimation and held out"
    assert all("held_out" in s and "estimation_error" in s for s in d["chain"])


def test_chain_markdown_puts_estimation_and_held_out_side_by_side():
    """The table from a chain's entries (closed: the numbers are the entries' own)."""
    from hil.ident.emps import chain_markdown
    held = {"before": {"x_motor": 2e-6, "force": 20.0}, "after": {"x_motor": 1e-6, "force": 3.0},
            "fall": 0.9, "uncertainty": 0.01, "earned": True}
    ch = {"chain": [{"step": 1, "effects": ["coulomb_friction"], "estimation_error": {"x_motor": 9e-7, "force": 2.5},
                     "held_out": held}],
          "final": {"end": "no step earns its place on the held-out data", "held_out": "the validation records",
                    "rejected": {"effects": ["channel_skew"], "estimation_error": {"x_motor": 9e-7, "force": 2.4},
                                 "held_out": dict(held, after={"x_motor": 1e-6, "force": 3.3}, fall=-0.2,
                                                  earned=False)}}}
    text = chain_markdown(ch)
    assert "| 1 | coulomb_friction | 9e-07 | 2.5 | 2e-06 -> 1e-06 | 20 -> 3 | 90.0 +- 1.0 | yes |" in text
    assert "| refused | channel_skew | 9e-07 | 2.4 | 2e-06 -> 1e-06 | 20 -> 3.3 | -20.0 +- 1.0 | no |" in text


@pytest.mark.slow
def test_diagnose_report_shows_estimation_and_held_out_for_every_step(tmp_path, capsys):
    """The HTML report's chain table carries each step's estimation error and its held-out error
    before and after, the figures of the JSON's chain[] entries."""
    import html
    import re

    from hil.cli import main
    from hil.config import load
    from hil.ident import synthesize
    from hil.io.measurement import write
    from hil.plant_config import candidate, configure
    bench = str(Path(__file__).resolve().parents[1] / "config" / "paper_bench.toml")
    cfg = load(bench)
    truth = configure(candidate("coulomb_friction", cfg), cfg, {"level": 2.2})
    ch, _ = synthesize(truth, None, duration=6.0, seed=3)
    rec = tmp_path / "f.csv"
    write(rec, ch, {"sample_period": "0.004 s"})
    report = tmp_path / "d.html"
    assert main(["diagnose", str(rec), "--config", bench, "--candidates", "coulomb_friction,constant_force",
                 "--jobs", "1", "--max-steps", "2", "--report", str(report), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["chain"] and all("held_out" in s for s in d["chain"])
    text = html.unescape(re.sub(r"<[^>]+>", " ", report.read_text()))
    assert "held-out error (before -> after)" in text and "estimation error" in text
    for s in d["chain"]:
        h = s["held_out"]
        assert f"{100 * h['fall']:.1f} % (+- {100 * h['uncertainty']:.1f} %): earned" in text
