"""Which torque the record holds (issue 24, item 2): a drive that logs its torque command, before an
actuator delay, is replayed to its noise floor only when the model samples the command too.

The records come from the independent simulator (plant_ivp), not from the kernel that replays them.
"""
import io
import json
import sys
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plant_ivp as ivp  # noqa: E402

from hil.config import load  # noqa: E402
from hil.ident import Replay  # noqa: E402
from hil.io.measurement import Measurement, write  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CFG_PATH = ROOT / "config" / "paper_bench.toml"
CFG = load(CFG_PATH)
BENCH = ivp.bench_from_config(CFG)


def _record(delay, torque="command", duration=1.6, seed=11):
    x = ivp.command_sequence(duration, BENCH.tp, seed, v_max=0.15)
    ch = ivp.simulate(BENCH, x, ivp.Hidden(delay=delay), torque=torque)
    noise = 0.01 * float(np.sqrt(np.mean(ch["torque"] ** 2)))
    return ivp.measure(ch, seed, force_noise=noise), noise


def _rms(y):
    return float(np.sqrt(np.mean(np.asarray(y) ** 2)))


@pytest.mark.parametrize("periods", [4, pytest.param(8, marks=pytest.mark.slow),
                                     pytest.param(16, marks=pytest.mark.slow)])
def test_command_logged_before_the_delay_replays_to_the_floor(periods):
    delay = periods * BENCH.tv
    rec, noise = _record(delay)
    meas = Measurement(rec, source=f"ivp delay {periods} Tv, command logged")
    true_delay = CFG.with_values({"effects.actuator_delay.delay": delay})
    said = Replay(meas, true_delay.with_values({"measurement.torque": "command"})).residuals()
    # the torque at its floor (the record's noise), the positions at theirs (0.5 um quantum, 0.1 um noise)
    assert _rms(said["torque"]) < 1.3 * noise
    for c in ("x_motor", "x_table"):
        assert _rms(said[c]) < 0.4e-6, c
    # sampled after the delay (what a record that does not say is taken to hold) the true delay
    # scores far worse on the torque: the convention the kernel had, which the issue measured
    unsaid = Replay(meas, true_delay).residuals()
    assert _rms(unsaid["torque"]) > 5 * noise


@pytest.mark.slow
def test_hil_compare_after_brings_the_torque_to_its_floor(tmp_path):
    from hil.cli import main
    delay = 4 * BENCH.tv
    rec, noise = _record(delay)
    path = write(tmp_path / "rec.csv", rec, {"sample_period": f"{BENCH.tp} s"})
    after = tmp_path / "after.toml"
    after.write_text(CFG_PATH.read_text(encoding="utf-8") + '\n[measurement]\ntorque = "command"\n\n'
                     '[effects.actuator_delay]\ndelay = "250 us"\n', encoding="utf-8")
    out = io.StringIO()
    with redirect_stdout(out):
        rc = main(["compare", str(path), "--config", str(CFG_PATH), "--after", str(after), "--json",
                   "--out", str(tmp_path / "cmp")])
    assert rc == 0
    d = json.loads(out.getvalue())
    before, aft = d["before"]["channels"]["torque"], d["after"]["channels"]["torque"]
    assert aft["rms"] < 1.3 * noise < before["rms"]


def test_synth_samples_the_command_when_the_config_says():
    # the project's own synth: with a 250 us delay the peak of the logged torque is the command's
    # (the nominal move's 11.7 N m scale), not the delayed current's at the tick (about half)
    from hil.ident import synthesize
    cfg = CFG.with_values({"effects.actuator_delay.delay": 4 * BENCH.tv})
    x = ivp.command_sequence(1.6, BENCH.tp, 11, v_max=0.15)
    cmd, _ = synthesize(cfg.with_values({"measurement.torque": "command"}), None, x_cmd=x[:-1], force_noise=0.0,
                        position_noise=0.0, resolution=0.0)
    act, _ = synthesize(cfg, None, x_cmd=x[:-1], force_noise=0.0, position_noise=0.0, resolution=0.0)
    ours = ivp.simulate(BENCH, x, ivp.Hidden(delay=4 * BENCH.tv), torque="command")
    k = ours["torque"].size
    assert np.max(np.abs(cmd["torque"][:k] - ours["torque"])) < 1e-3 * np.max(np.abs(ours["torque"]))
    assert np.max(np.abs(act["torque"][:k] - ours["torque_actual"])) < 1e-3 * np.max(np.abs(ours["torque"]))


@pytest.mark.slow
def test_diagnose_says_which_torque_an_unsaid_record_holds(tmp_path):
    # the config does not say; the drive logged its command before a 500 us delay: the chain under
    # the current (as before) cannot bring the torque down; under the command it finds the delay
    from hil.cli import main
    delay = 8 * BENCH.tv
    rec, noise = _record(delay)
    path = write(tmp_path / "rec.csv", rec, {"sample_period": f"{BENCH.tp} s"})
    out = io.StringIO()
    with redirect_stdout(out):
        rc = main(["diagnose", str(path), "--config", str(CFG_PATH), "--json", "--jobs", "1", "--max-steps", "2",
                   "--candidates", "actuator_delay,coulomb_friction,parameter:plant.m1", "--out",
                   str(tmp_path / "found.toml")])
    assert rc == 0
    d = json.loads(out.getvalue())
    ts = d["torque_sampling"]
    assert ts["record"] == "command" and ts["said"] is False and ts["key"] == "measurement.torque"
    assert ts["above_floor"]["command"] < 0.2 * ts["above_floor"]["actual"]
    named = [e for s in d["chain"] for e in s["effects"]]
    assert named[0] == "actuator_delay"
    assert d["chain"][-1]["params"]["actuator_delay"]["delay"] == pytest.approx(delay, rel=0.05)
    found = load(tmp_path / "found.toml")
    assert found["measurement.torque"] == "command"
