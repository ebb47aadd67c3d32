"""benchmarks/bench_diagnose.py --matrix: its JSON parses and its counts add up (not a verdict
threshold: the figures are what they are, docs/benchmarks.md records them)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_scoring_counts_named_extra_and_alarms():
    # the scoring alone, on hand-made diagnosis answers (no simulation)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import bench_diagnose as bd
    spec = {"kind": "pair", "effects": ["asymmetric_friction", "backlash"], "truth": {}}
    d = {"verdict": "coulomb_friction", "chain": [{"effects": ["coulomb_friction", "constant_force"], "params": {}},
                                                  {"effects": ["parameter:plant.m3"], "params": {}}]}
    out = bd.score(spec, d)
    assert out["missed"] == ["backlash"] and not out["all_named"] and out["extra"] == ["parameter:plant.m3"]
    clean = {"kind": "clean", "effects": [], "truth": {"parameter:plant.k1": {"value": 5.0e7},
                                                        "parameter:plant.c2": {"value": 12.0}}}
    d = {"verdict": "parameter:plant.k1", "chain": [
        {"effects": ["parameter:plant.k1"], "params": {}},
        {"effects": ["parameter:plant.c2"], "params": {"parameter:plant.k1": {"value": 5.04e7},
                                                       "parameter:plant.c2": {"value": 12.5}}}]}
    out = bd.score(clean, d)
    assert out["findings"] == ["parameter:plant.k1"] and out["false_alarms"] == ["parameter:plant.c2"]
    assert out["all_named"] and out["extra"] == []
    # an effect the config's drift left unpaid is out of the model: not named
    spec = {"kind": "single", "effects": ["coulomb_friction"], "truth": {}}
    d = {"verdict": "coulomb_friction", "chain": [{"effects": ["coulomb_friction"], "params": {}},
                                                  {"effects": ["compliant_mode"], "params": {}}],
         "final": {"tolerance": {"dropped": [{"effect": "compliant_mode", "params": {}, "score": 1.0}]}}}
    out = bd.score(spec, d)
    assert out["all_named"] and out["extra"] == []


@pytest.mark.slow
def test_small_matrix_json_adds_up():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.run([sys.executable, "benchmarks/bench_diagnose.py", "--matrix", "--n", "4", "--duration", "2",
                        "--jobs", "1", "--json"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-2000:]
    d = json.loads(p.stdout)
    rows, s = d["records"], d["summary"]
    assert s["records"] == len(rows) == 4
    eff = [r for r in rows if r["kind"] != "clean"]
    clean = [r for r in rows if r["kind"] == "clean"]
    assert s["effect_records"] == len(eff) == 3 and s["clean_records"] == len(clean) == 1
    assert s["all_named"] == sum(r["all_named"] for r in eff) == sum(not r["missed"] for r in eff)
    assert s["extra"] == sum(len(r["extra"]) for r in eff)
    assert s["false_alarms"] == sum(len(r["false_alarms"]) for r in clean)
    for r in rows:
        # every name the diagnosis gave is counted once: for a hidden effect, as extra, as alarm or as finding
        assert len(r["named"]) >= len(r["extra"]) + len(r["false_alarms"]) + len(r["findings"])
        assert set(r["missed"]) <= set(r["effects"])
        assert r["kind"] != "pair" or len(r["effects"]) == 2


def test_mass_change_on_a_clean_record_is_the_table_mass():
    # mass_change is parameter:plant.m2 by another name: on a clean record whose m2 drifted by
    # +8 kg, a mass_change of +7.9 kg names m2 within 0.03 % (a finding), one of -8 kg 4 % off (an alarm)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import bench_diagnose as bd
    clean = {"kind": "clean", "effects": [], "truth": {"mass_change": {"mass": 8.0, "table_mass": 400.0}}}
    for dm, finding in ((7.9, True), (-8.0, False)):
        out = bd.score(clean, {"verdict": "mass_change",
                               "chain": [{"effects": ["mass_change"], "params": {"mass_change": {"mass": dm}}}]})
        assert out["findings" if finding else "false_alarms"] == ["mass_change"], out


def test_drift_under_the_effects_keeps_the_draws_and_counts_a_true_drift_as_a_finding():
    # --drift: the same effects at the same strengths as without it, every mass, stiffness and
    # damping of the effect records moved by up to the fraction; a drift named within 1 % of its
    # true value is a finding, one further off an extra
    sys.path.insert(0, str(ROOT / "benchmarks"))
    sys.path.insert(0, str(ROOT / "tests" / "independent"))
    import bench_diagnose as bd
    import plant_ivp as ivp

    from hil.config import load
    bench = ivp.bench_from_config(load(ROOT / "config" / "paper_bench.toml"))
    plain, drifted = bd.draw_records(8, 5, bench), bd.draw_records(8, 5, bench, drift=0.03)
    for a, b in zip(plain, drifted):
        assert a["effects"] == b["effects"] and a["hidden"] == b["hidden"]
        if a["kind"] == "clean":
            assert a == b
            continue
        true = {k: v["value"] for k, v in b["truth"].items()
                if k.startswith("parameter:plant.") and k not in b["effects"]}
        assert 5 <= len(true) <= 7          # less those an effect sets anew
        for k, v in true.items():
            nominal = {"m": bench.m, "k": bench.k, "c": bench.c}[k[-2]][int(k[-1]) - 1]
            assert abs(v / nominal - 1.0) <= 0.03 + 1e-12
    assert bd.parse_fraction("3%") == bd.parse_fraction("0.03") == 0.03
    spec = next(s for s in drifted if s["kind"] == "single")
    k1 = spec["truth"]["parameter:plant.k1"]["value"]
    d = {"verdict": spec["effects"][0], "chain": [
        {"effects": [spec["effects"][0]], "params": {}},
        {"effects": ["parameter:plant.k1"], "params": {"parameter:plant.k1": {"value": 1.005 * k1}}},
        {"effects": ["parameter:plant.m1"], "params": {"parameter:plant.k1": {"value": 1.005 * k1},
                                                       "parameter:plant.m1": {"value": 5.0}}}]}
    out = bd.score(spec, d)
    assert out["findings"] == ["parameter:plant.k1"] and out["extra"] == ["parameter:plant.m1"]
