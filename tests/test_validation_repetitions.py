"""Issue 50, floors that are about the estimation data only. Records are repetitions of one test
only when every measured input agrees (the command, u_add, an external force); their scatter is
the run-to-run spread of the records fitted together. A --validate record never sets or raises
the floor it is judged against (it did: the EMPS pulses' own response became "spread", and the
documented command answered "none" for a model missing 20 N of friction)."""
import json

import numpy as np
import pytest
from conftest import CONFIG

from hil.cli import main
from hil.io.measurement import Measurement, read, write

BENCH = str(CONFIG / "paper_bench.toml")


def _repetition(src, dst, sigma, seed):
    m = read(src)
    rng = np.random.default_rng(seed)
    ch = dict(m.channels)
    for c in ("x_motor", "x_table", "x_tip"):
        ch[c] = ch[c] + sigma * rng.standard_normal(ch[c].size)
    write(dst, ch)
    return read(dst)


def _diagnose(capsys, *argv) -> dict:
    capsys.readouterr()
    assert main(["diagnose", *map(str, argv), "--config", BENCH, "--candidates", "coulomb_friction", "--no-chain",
                 "--jobs", "1", "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_repetitions_fitted_together_give_the_spread_and_a_held_out_one_changes_no_floor(tmp_path, capsys):
    src = tmp_path / "base.csv"
    assert main(["synth", "--config", BENCH, "--duration", "2s", "--out", str(src)]) == 0
    a = _repetition(src, tmp_path / "a.csv", 5e-6, 1)
    b = _repetition(src, tmp_path / "b.csv", 5e-6, 2)
    both = _diagnose(capsys, tmp_path / "a.csv", tmp_path / "b.csv")
    d = a["x_tip"] - b["x_tip"]             # two records: |a - b| / sqrt(2) at each sample
    assert both["run_to_run"]["spread"]["x_tip"] == pytest.approx(np.sqrt(np.mean(d * d) / 2), rel=1e-9)
    alone = _diagnose(capsys, tmp_path / "a.csv")
    held = _diagnose(capsys, tmp_path / "a.csv", "--validate", tmp_path / "b.csv")
    assert "run_to_run" not in alone and "run_to_run" not in held
    assert held["noise_floor"] == alone["noise_floor"]


def _record(u_add=None, x_cmd_scale=1.0) -> Measurement:
    t = np.arange(0.0, 1.0, 1e-3)
    ch = {"t": t, "x_cmd": x_cmd_scale * 0.1 * np.sin(2 * np.pi * t), "x_motor": 0.1 * np.sin(2 * np.pi * t)}
    if u_add is not None:
        ch["u_add"] = u_add(t)
    return Measurement(ch, source="probe")


@pytest.mark.parametrize("a,b,same", [
    (_record(), _record(), True),
    (_record(), _record(x_cmd_scale=1.1), False),
    (_record(lambda t: (t % 0.2 < 0.01) * 1.0), _record(lambda t: (t % 0.2 < 0.01) * 1.0), True),
    (_record(lambda t: (t % 0.2 < 0.01) * 1.0), _record(), False),                   # pulses in one alone
    (_record(lambda t: (t % 0.2 < 0.01) * 1.0), _record(lambda t: (t % 0.25 < 0.01) * 1.0), False),
    (_record(lambda t: 0 * t), _record(lambda t: 0 * t), True),                     # zero in both
])
def test_records_repeat_a_test_only_when_every_input_agrees(a, b, same):
    from hil.ident.noise import same_test
    assert same_test(a, b, "x_cmd") is same and same_test(b, a, "x_cmd") is same


def test_the_held_out_check_keeps_the_validation_records_own_floor():
    """hil.ident.chain._holdout_parts: the fitted records never join the validation records' floor."""
    from hil.config import load
    from hil.ident import Replay, synthesize
    from hil.ident.chain import _holdout_parts
    cfg = load(BENCH)
    ch, _ = synthesize(cfg, None, duration=2.0, seed=1)
    rng = np.random.default_rng(3)
    rep = dict(ch, x_tip=ch["x_tip"] + 4e-6 * rng.standard_normal(ch["x_tip"].size))
    est, val = Replay(Measurement(ch, source="a"), cfg), Replay(Measurement(rep, source="b"), cfg)
    kind, records = _holdout_parts(est, [val])
    assert kind == "records" and records.spread == {}
    assert records.noise["x_tip"] == pytest.approx(val.noise["x_tip"], rel=1e-12)
