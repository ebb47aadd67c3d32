"""Issue 50, skill against baselines: every diagnosis reports its final error against the start
model and against "the axis is where it was told to be" (the following error x - x_cmd), and a
model no better than the command says so first."""
import json

import numpy as np
import pytest
from conftest import CONFIG

from hil.cli import main
from hil.io.measurement import read

BENCH = str(CONFIG / "paper_bench.toml")


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    path = tmp_path_factory.mktemp("skill") / "rec.csv"
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--duration", "2s", "--out", str(path)]) == 0
    return path


def _diagnose(capsys, record, *extra, json_out=True):
    capsys.readouterr()
    assert main(["diagnose", str(record), "--config", BENCH, "--candidates", "coulomb_friction", "--no-chain",
                 "--jobs", "1", *extra, *(["--json"] if json_out else [])]) == 0
    out = capsys.readouterr().out
    return json.loads(out) if json_out else out


def test_the_command_baseline_is_the_following_error_and_the_fit_its_nrmse(record, capsys):
    s = _diagnose(capsys, record)["skill"]
    m = read(record)
    for c in ("x_motor", "x_table", "x_tip"):
        e = m[c] - m["x_cmd"]
        assert s["baseline"]["command"][c] == pytest.approx(np.sqrt(np.mean(e * e)), rel=1e-9)
        assert s["fit_percent"]["command"][c] == pytest.approx(
            100 * (1 - s["error"][c] / s["baseline"]["command"][c]), rel=1e-12)
    assert s["fit_percent"]["start"]["x_motor"] == pytest.approx(0.0, abs=1e-9)     # no chain: the start model
    assert s["has_skill"] is True and s["no_skill"] == []


def test_a_model_no_better_than_the_command_says_so_first(record, capsys):
    # a start model without the feed-forward the record had: its lag (v / kv) exceeds the following error
    d = _diagnose(capsys, record, "--set", "control.ffv=0")
    s = d["skill"]
    assert s["has_skill"] is False and set(s["no_skill"]) == {"x_motor", "x_table", "x_tip"}
    assert all(s["fit_percent"]["command"][c] < 0 for c in s["no_skill"])
    text = _diagnose(capsys, record, "--set", "control.ffv=0", json_out=False)
    assert text.splitlines()[0].startswith("the model has no skill here: it predicts x_motor no better than the "
                                          "command itself")


def test_a_fit_at_the_edge_of_its_range_is_no_finding():
    """hil.ident.fit.at_range_edge: a value at a non-zero bound names the parameter and the bound;
    inside the range, or at a bound of zero (the effect absent), nothing."""
    from hil.ident.fit import at_range_edge
    from sim_plant.effects import CATALOGUE
    eff = CATALOGUE["torque_constant"]
    p = eff.param("factor")
    assert p.lower > 0
    assert "factor ended at the bound of its range" in at_range_edge(eff, {"factor": p.lower})
    assert "factor ended at the bound of its range" in at_range_edge(eff, {"factor": p.upper})
    assert at_range_edge(eff, {"factor": 0.5 * (p.lower + p.upper)}) == ""
    k = CATALOGUE["stiffness_along_travel"].param("k_start")       # a range over decades
    assert at_range_edge(CATALOGUE["stiffness_along_travel"], {"k_start": 100 * k.lower}) == ""
    coulomb = CATALOGUE["coulomb_friction"]
    assert coulomb.param("level").lower == 0 and at_range_edge(coulomb, {"level": 0.0}) == ""


def test_the_text_lists_the_first_candidates_and_all_of_them_with_all(record, capsys):
    """Answers first: the ranking in the text is cut to what decides (--all for the rest); the
    JSON always holds every candidate."""
    import re

    from hil.commands.diagnose import SHOWN_CANDIDATES

    def numbered(text):
        return [ln for ln in text.splitlines() if re.match(r"^\s*\d+[* ] ", ln)]
    argv = ["diagnose", str(record), "--config", BENCH, "--no-chain", "--jobs", "1",
            "--candidates", "coulomb_friction,viscous_friction,mass_change,backlash,torque_ripple,constant_force,"
                            "force_offset,channel_skew,tip_skew,stribeck_friction,asymmetric_friction"]
    capsys.readouterr()
    assert main(argv) == 0
    short = capsys.readouterr().out
    assert len(numbered(short)) == SHOWN_CANDIDATES and "more, down to score" in short and "--all" in short
    assert main([*argv, "--all"]) == 0
    full = capsys.readouterr().out
    assert main([*argv, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    others = len(d["candidates"]) - 1 - len(d["also_missing"])       # less the verdict and what is named beside it
    assert others > SHOWN_CANDIDATES and len(numbered(full)) == others and "more, down to score" not in full
