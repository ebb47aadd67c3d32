"""Measured inputs besides the command (issue 15): a command added after the controller (u_add),
an external force, an open-loop run; and sensor offsets, named as offsets, not loads."""
import json
import math

import numpy as np
import pytest
from conftest import CONFIG

from hil.cli import main
from hil.config import load
from hil.ident import Replay, diagnose, synthesize
from hil.ident.fit import evaluate
from hil.ident.synth import pulse_train
from hil.io.measurement import Measurement, read
from hil.simulate import simulate_config

BENCH = str(CONFIG / "paper_bench.toml")
CFG = load(BENCH)


def _rms(r):
    return float(np.sqrt(np.mean(r * r)))


@pytest.mark.slow
@pytest.mark.parametrize("amplitude", [0.3, 1.0])
def test_pulses_after_the_controller_replay_to_the_noise_floor(tmp_path, capsys, amplitude):
    out = tmp_path / "pulses.csv"
    assert main(["synth", "--config", BENCH, "--pulses", f"{amplitude} N*m", "--duration", "4s", "--out", str(out),
                 "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["samples"] == 1000 and info["inputs"] == ["u_add"] and info["open_loop"] is False
    meas = read(out)
    assert meas.units["u_add"] == "N*m"
    np.testing.assert_allclose(meas["u_add"], pulse_train(meas.t, amplitude))
    rp = Replay(meas, CFG)
    res = rp.residuals()
    for c in rp.channels:       # with u_add: down to the record's noise floor on every channel
        assert _rms(res[c]) <= 1.5 * rp.noise[c], (c, _rms(res[c]), rp.noise[c])
    without = Measurement({k: v for k, v in meas.channels.items() if k != "u_add"}, source="no u_add")
    rp0 = Replay(without, CFG)
    res0 = rp0.residuals()
    # without it the residual is the loop's answer to the pulses: the P-I loop rejects a constant
    # disturbance after the controller, so the torque shows it at the edges (within ~ti) and the
    # positions sag during each pulse, far above their noise floors
    for c in ("x_motor", "x_table", "x_tip"):
        assert _rms(res0[c]) > 10 * rp0.noise[c], (c, _rms(res0[c]), rp0.noise[c])
    assert _rms(res0["torque"]) > 2.5 * rp0.noise["torque"]
    # compare reads it from the file the same way
    assert main(["compare", str(out), "--config", BENCH, "--out", str(tmp_path / "cmp"), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["before"]["channels"]["torque"]["rms"] <= 1.5 * rp.noise["torque"]
    assert rep["warnings"] == [] and rep["before"]["inputs"][0].startswith("u_add [N*m] added after the controller")
    assert "u_add [N*m] added after the controller" in (tmp_path / "cmp" / "report.html").read_text()


def test_output_that_excludes_u_add(tmp_path):
    # the drive logged its controller's own output: the config says so and the replay subtracts u_add
    cfg = CFG.with_values({"measurement.output_includes_u_add": False})
    ch, _ = synthesize(cfg, duration=3.0, inputs={"u_add": lambda t: pulse_train(t, 0.8)})
    meas = Measurement(ch, units={"u_add": "N*m"})
    res = Replay(meas, cfg).residuals()
    wrong = Replay(meas, CFG).residuals()
    assert _rms(res["torque"]) < 0.2 * _rms(wrong["torque"])


def test_u_add_in_newtons_on_a_linear_axis_is_divided_by_the_drive_gain():
    emps = load(CONFIG / "emps.toml")
    ch, _ = synthesize(emps, duration=3.0, sample_period=1e-3, inputs={"u_add": lambda t: pulse_train(t, 2.0)})
    volts = Measurement(dict(ch), units={"u_add": "V"})
    newtons = Measurement(dict(ch, u_add=ch["u_add"] * emps["actuator.gain"]), units={"u_add": "N"})
    a, b = Replay(volts, emps).residuals(), Replay(newtons, emps).residuals()
    np.testing.assert_allclose(a["x_motor"], b["x_motor"], atol=1e-12)


@pytest.mark.parametrize("mass", ["table", "tip"])
def test_external_force_enters_the_loop(mass):
    F = 300.0
    ch, truth = synthesize(CFG, duration=3.0, inputs={f"f_ext_{mass}": lambda t: pulse_train(t, F, 1.0, 0.4)})
    meas = Measurement(ch)
    rp = Replay(meas, CFG)
    for c in rp.channels:
        assert _rms(rp.residuals()[c]) <= 1.5 * rp.noise[c]
    rp0 = Replay(Measurement({k: v for k, v in ch.items() if k != f"f_ext_{mass}"}), CFG)
    # a P-I loop takes a step of load F up as torque F p / 2 pi: the replay without it misses that
    expect = F * CFG["plant.pitch"] / (2 * math.pi)
    assert _rms(rp0.residuals()["torque"]) > 0.2 * expect


@pytest.mark.slow
def test_none_inputs_leave_the_simulation_bit_identical():
    x = np.concatenate([np.zeros(50), np.linspace(0, 0.02, 300), np.full(200, 0.02)])
    a = simulate_config(CFG, x)
    from drivers.control import controller_from_config
    from hil.plant_config import plant_from_config
    from hil.simulate import simulate
    plant = plant_from_config(CFG)
    ctrl = controller_from_config(CFG, plant)
    steps = x.size * ctrl.substeps
    b = simulate(plant, ctrl, x, u_add=np.zeros(steps), f_ext=np.zeros((steps, plant.n)))
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.u, b.u)


def _torque_steps(t, level=3.0, period=2.0):
    """Torque steps +-level, alternating every half period (an identification run of a motor)."""
    return np.where(np.mod(t, period) < period / 2, level, -level)


def test_open_loop_torque_steps_replay_and_fit_friction(tmp_path, capsys):
    truth = 2.2                                          # N m, Coulomb friction on the motor
    rich = CFG.with_values({"effects.coulomb_friction.level": truth})
    ch, _ = synthesize(rich, duration=4.0, inputs={"u_add": _torque_steps}, open_loop=True)
    assert np.all(ch["x_cmd"] == 0) and "u_add" not in ch
    np.testing.assert_allclose(ch["torque"], _torque_steps(ch["t"]))
    meas = Measurement(ch, source="open-loop")
    rp = Replay(meas, rich, open_loop=True)
    assert "torque" not in rp.channels                    # the input, not an output
    for c in rp.channels:
        assert _rms(rp.residuals()[c]) <= 1.5 * rp.noise[c]
    # the model without friction: the motor runs away; the fit finds the level
    rp0 = Replay(meas, CFG, open_loop=True)
    cand = evaluate(rp0, "coulomb_friction")
    assert cand.params["level"] == pytest.approx(truth, rel=0.02)
    assert cand.error_after < 0.05 * cand.error_before
    # the command line: refused without --open-loop, with a line that says so; replayed with it
    p = tmp_path / "ol.csv"
    from hil.io.measurement import write
    write(p, ch)
    cfgp = tmp_path / "rich.toml"
    cfgp.write_text(rich.to_toml())
    rc = main(["compare", str(p), "--config", str(cfgp), "--out", str(tmp_path / "c")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--open-loop" in err[0]
    assert main(["compare", str(p), "--config", str(cfgp), "--open-loop", "--out", str(tmp_path / "c"),
                 "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert set(rep["before"]["channels"]) == {"x_motor", "x_table", "x_tip"}


def test_open_loop_record_from_hil_synth(tmp_path, capsys):
    out = tmp_path / "ol.csv"
    assert main(["synth", "--config", BENCH, "--open-loop", "--pulses", "3 N*m", "--pulse-period", "2 s",
                 "--pulse-width", "1 s", "--duration", "3s", "--out", str(out)]) == 0
    m = read(out)
    assert np.ptp(m["torque"]) == pytest.approx(3.0) and np.all(m["x_cmd"] == 0)
    assert m.meta["open_loop"].startswith("true")


@pytest.mark.parametrize("offset", [0.15, -0.4, 1.0])
def test_force_sensor_offset_is_named_as_an_offset(offset):
    # a current (torque) sensor offset: only the recorded channel moves, never the positions
    cfg = CFG.with_values({"effects.force_offset.offset": offset})
    ch, _ = synthesize(cfg, duration=6.0, seed=3)
    rp = Replay(Measurement(ch, source="offset"), CFG)
    d = diagnose(rp, ["force_offset", "constant_force", "coulomb_friction", "viscous_friction"], jobs=1)
    assert d["verdict"] == "force_offset"
    best = d["candidates"][0]
    assert best.params["offset"] == pytest.approx(offset, rel=0.03)
    assert best.evidence.startswith("a sensor offset, not a load")
    cf = next(c for c in d["candidates"] if c.effect == "constant_force")
    # a load fitted in its place leaves the start, where the integrator takes it up, unexplained
    assert cf.errors_after["torque"] > best.errors_after["torque"] and cf.score < best.score


def test_constant_load_is_not_named_an_offset():
    ch, _ = synthesize(CFG, "constant_force", duration=6.0, seed=3)
    rp = Replay(Measurement(ch, source="load"), CFG)
    d = diagnose(rp, ["force_offset", "constant_force"], jobs=1)
    assert d["verdict"] == "constant_force"
