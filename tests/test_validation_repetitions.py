"""Issue 25, HSM150 goal: a model fitted on one repetition of a test and validated on another. The
validation records that repeat a fitted record's test join the run-to-run spread (the floor of the
fitted records and of the held-out check), so that the chain can say "within the run-to-run
spread" when the repetitions are held out."""
import json

import numpy as np
import pytest
from conftest import CONFIG

from hil.cli import main
from hil.io.measurement import read, write

BENCH = str(CONFIG / "paper_bench.toml")


def _repetition(src, dst, sigma, seed):
    m = read(src)
    rng = np.random.default_rng(seed)
    ch = dict(m.channels)
    for c in ("x_motor", "x_table", "x_tip"):
        ch[c] = ch[c] + sigma * rng.standard_normal(ch[c].size)
    write(dst, ch)
    return read(dst)


def test_a_held_out_repetition_joins_the_spread(tmp_path, capsys):
    src = tmp_path / "base.csv"
    assert main(["synth", "--config", BENCH, "--duration", "2s", "--out", str(src)]) == 0
    a = _repetition(src, tmp_path / "a.csv", 5e-6, 1)
    b = _repetition(src, tmp_path / "b.csv", 5e-6, 2)
    other = read(src)                       # another command: another test, no spread from it
    other.channels["x_cmd"] = other.channels["x_cmd"] * 1.1
    write(tmp_path / "c.csv", other.channels)
    capsys.readouterr()
    assert main(["diagnose", str(tmp_path / "a.csv"), "--validate", str(tmp_path / "b.csv"), str(tmp_path / "c.csv"),
                 "--config", BENCH, "--candidates", "coulomb_friction", "--no-chain", "--jobs", "1", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)["run_to_run"]
    d = a["x_tip"] - b["x_tip"]             # two records: |a - b| / sqrt(2) at each sample
    assert r["spread"]["x_tip"] == pytest.approx(np.sqrt(np.mean(d * d) / 2), rel=1e-9)
    assert r["within"] is True


def test_the_held_out_check_uses_the_spread_across_the_sets():
    """The validation records' floor in the chain's held-out check holds the spread between them and
    the fitted records' repetitions (hil.ident.chain._holdout_parts)."""
    from hil.config import load
    from hil.ident import Replay, synthesize
    from hil.ident.chain import _holdout_parts
    from hil.io.measurement import Measurement
    cfg = load(BENCH)
    ch, _ = synthesize(cfg, None, duration=2.0, seed=1)
    rng = np.random.default_rng(3)
    rep = dict(ch, x_tip=ch["x_tip"] + 4e-6 * rng.standard_normal(ch["x_tip"].size))
    est, val = Replay(Measurement(ch, source="a"), cfg), Replay(Measurement(rep, source="b"), cfg)
    kind, records = _holdout_parts(est, [val])
    assert kind == "records"
    d = ch["x_tip"] - rep["x_tip"]
    assert records.spread["x_tip"] == pytest.approx(np.sqrt(np.mean(d * d) / 2), rel=1e-9)
    assert records.noise["x_tip"] == pytest.approx(np.hypot(val.noise["x_tip"], records.spread["x_tip"]), rel=1e-12)
