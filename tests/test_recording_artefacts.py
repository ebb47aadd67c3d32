"""Issue 25, item 2: a recording artefact (a channel's skew, a sensor offset) is reported as such by
the chain and written to the config's ``[measurement]``, never to the plant's ``[effects.*]``; the
written config reproduces the chain's numbers in ``hil compare`` (and in any replay)."""
import json
import tomllib

import numpy as np
import pytest
from conftest import CONFIG

from hil.config import load
from hil.errors import ConfigError
from hil.ident import Replay, synthesize
from hil.io.measurement import Measurement, write
from hil.plant_config import candidate, configure, record_effects

BENCH = str(CONFIG / "paper_bench.toml")
TS = 0.004


def _skewed_record(tmp_path, skew):
    cfg = load(BENCH)
    truth = configure(candidate("channel_skew", cfg), cfg, {"skew": skew})
    ch, _ = synthesize(truth, None, duration=3.0, seed=3)
    p = tmp_path / "skew.csv"
    write(p, ch, {"sample_period": f"{TS} s"})
    return str(p)


@pytest.mark.slow
def test_chain_writes_a_skew_to_measurement_and_compare_reproduces_its_error(tmp_path, capsys):
    from hil.cli import main
    rec = _skewed_record(tmp_path, 3 * TS)
    out = tmp_path / "written.toml"
    assert main(["diagnose", rec, "--config", BENCH, "--candidates", "channel_skew,constant_force", "--jobs", "1",
                 "--out", str(out), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    step = next(s for s in d["chain"] if "channel_skew" in s["effects"])
    assert step["recording_artefacts"] == ["channel_skew"]
    written = tomllib.loads(out.read_text())
    assert "channel_skew" in written["measurement"]                 # how the record was logged ...
    assert "channel_skew" not in written.get("effects", {})          # ... not the plant's physics
    fitted = load(out)["measurement.channel_skew"]
    assert fitted == pytest.approx(step["params"]["channel_skew"]["skew"], rel=1e-8)
    assert fitted == pytest.approx(3 * TS, abs=0.25 * TS)
    # the written config gives the chain's final error (the written value keeps 10 digits)
    assert main(["compare", rec, "--config", str(out), "--json"]) == 0
    c = json.loads(capsys.readouterr().out)
    for chan, err in d["final"]["error"].items():
        assert c["before"]["channels"][chan]["rms"] == pytest.approx(err, rel=1e-6), chan


def test_chain_text_says_recording_artefact(tmp_path, capsys):
    from hil.cli import main
    rec = _skewed_record(tmp_path, -2 * TS)
    assert main(["diagnose", rec, "--config", BENCH, "--candidates", "channel_skew", "--jobs", "1"]) == 0
    text = capsys.readouterr().out
    assert "channel_skew: a recording artefact, not physics (the config's [measurement]" in text


def test_measurement_section_replays_as_the_old_effects_section():
    """``[measurement] channel_skew`` is the artefact the old ``[effects.channel_skew]`` gave: the same
    replay, sample for sample; both at once is refused by name."""
    cfg = load(BENCH)
    ch, _ = synthesize(cfg, None, duration=1.0, seed=1)
    meas = Measurement(ch, source="synth")
    new = cfg.with_values({"measurement.channel_skew": "8 ms"})
    old = cfg.with_values({"effects.channel_skew.skew": "8 ms"})
    assert [(e.name, v) for e, v in record_effects(new)] == [("channel_skew", {"skew": 0.008})]
    rn, ro = Replay(meas, new).residuals(new), Replay(meas, old).residuals(old)
    for c in rn:
        np.testing.assert_array_equal(rn[c], ro[c])
    with pytest.raises(ConfigError, match=r"measurement\.channel_skew: the artefact is also given as "
                                          r"\[effects\.channel_skew\]"):
        record_effects(new.with_values({"effects.channel_skew.skew": "8 ms"}))
    with pytest.raises(ConfigError, match=r"measurement\.channel_skew: expected -0.2 \.\. 0.2, got 0.5"):
        record_effects(cfg.with_values({"measurement.channel_skew": "500 ms"}))


def test_fit_writes_an_offset_to_measurement(tmp_path, capsys):
    from hil.cli import main
    cfg = load(BENCH)
    truth = configure(candidate("force_offset", cfg), cfg, {"offset": 0.4})
    ch, _ = synthesize(truth, None, duration=2.0, seed=5)
    rec = tmp_path / "off.csv"
    write(rec, ch, {"sample_period": f"{TS} s"})
    out = tmp_path / "fitted.toml"
    assert main(["fit", str(rec), "--config", BENCH, "--add", "force_offset", "--out", str(out), "--json"]) == 0
    json.loads(capsys.readouterr().out)
    written = tomllib.loads(out.read_text())
    assert "effects" not in written
    assert load(out)["measurement.force_offset"] == pytest.approx(0.4, abs=0.05)
