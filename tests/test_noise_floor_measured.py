"""Issue 25, item 3: the current/torque (force) floor from the standstill's measured noise, not only
the record's quantization (hil.ident.noise): the RMS of the measured channel, less a straight line
per settled standstill, the larger of it and the residual's; the end of the chain gives the error in
multiples of each part of the floor."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import CONFIG

from hil.config import load, loads
from hil.ident import Replay, synthesize
from hil.ident.synth import _ramp_move
from hil.io.measurement import Measurement

BENCH = load(CONFIG / "paper_bench.toml")
TP = BENCH["control.position_period"]
LINA = Path(__file__).resolve().parents[2] / "shared" / "data" / "maxon-linear-actuator-lina" / \
    "no-pp-square-wave-10mm-0.5Hz.txt"
KT = 42.9e-3 / 1000          # N m per mA (PROVENANCE.md: 42.9 mN m/A; the log's current in mA)


def _dwelling_command():
    """Four moves of 10-12 mm with 1.5 s standstills between them (long rests: a noise figure)."""
    parts, x = [np.full(int(1.0 / TP), 0.01)], 0.01
    for stroke in (0.01, -0.01, 0.012, -0.012):
        seg = _ramp_move(x, stroke, 0.05, 0.05, TP)
        x = float(seg[-1])
        parts += [seg, np.full(int(1.5 / TP), x)]
    return np.concatenate(parts)


@pytest.mark.parametrize("sigma", [0.1, 0.3])
def test_torque_floor_recovers_white_noise_of_known_sigma(sigma):
    xc = _dwelling_command()
    ch, _ = synthesize(BENCH, None, duration=xc.size * TP, seed=4, force_noise=sigma, x_cmd=xc)
    rp = Replay(Measurement(ch, source="noisy"), BENCH)
    assert rp.noise["torque"] == pytest.approx(sigma, rel=0.05)
    assert rp.noise_sources["torque"]["standstill"] == rp.noise["torque"]


@pytest.mark.parametrize("sigma", [0.003, 0.005])
def test_torque_floor_is_not_the_tips_ringing(sigma):
    """The paper bench's tip mode (15 Hz, damping ratio 0.015) rings for seconds after each move and
    its reaction moves the current at rest by some 0.015 N m after these gentle moves: the floor
    taken from the measured channel alone was that ringing (3-5 x a sensor noise of 0.003-0.005 N m;
    on the matrix's records 2-4 x); the model replays it, and the residual's rests hold the noise."""
    xc = _dwelling_command()
    ch, _ = synthesize(BENCH, None, duration=xc.size * TP, seed=4, force_noise=sigma, x_cmd=xc)
    rp = Replay(Measurement(ch, source="ringing"), BENCH)
    from hil.ident.noise import channel_standstill_noise
    ringing, _ = channel_standstill_noise(rp.meas.t, rp.meas["x_cmd"], rp.meas["torque"])
    assert ringing > 3 * sigma          # what the channel alone holds at rest
    assert rp.noise["torque"] == pytest.approx(sigma, rel=0.1)
    assert rp.noise_sources["torque"]["source"].startswith("standstill noise of the measured channel")


def test_a_standstill_creep_is_no_noise():
    """A holding torque that creeps at rest (a model error: the integrator's ramp) is taken out with
    the straight line of each segment: the floor stays at the sensor's noise."""
    xc = _dwelling_command()
    ch, _ = synthesize(BENCH, None, duration=xc.size * TP, seed=4, force_noise=0.1, x_cmd=xc)
    ch = dict(ch)
    ch["torque"] = ch["torque"] + 2.0 * ch["t"]           # 2 N m/s of drift: 40 x the noise over a rest
    rp = Replay(Measurement(ch, source="creep"), BENCH)
    from hil.ident.noise import channel_standstill_noise
    s, _ = channel_standstill_noise(rp.meas.t, rp.meas["x_cmd"], rp.meas["torque"])
    assert s == pytest.approx(0.1, rel=0.06)


LINA_CFG = """
[plant]
pitch = "0.28045 mm"
m1 = "1656 kg"
[actuator]
type = "rotary"
[control]
position_period = "0.4 ms"
velocity_period = "0.4 ms"
kv = "73.3 1/s"
ffv = 0.0
position_feedback = "motor"
kp = "3.861e-4 N*m*s/rad"
ti = "20.5 ms"
output_limit = "0.5148 N*m"
[sensors]
motor_resolution = "11.685 um"
[limits]
travel_min = "-6 mm"
travel_max = "6 mm"
speed = "60 mm/s"
acceleration = "5 m/s^2"
jerk = "1000 m/s^3"
"""


def _independent_standstill_rms(t, xc, y, settle=0.1, quiet=2.5):
    """Per stretch of a constant command (after its first ``settle`` s, at most half of it), the
    variance of y about its least-squares line; the stretches within ``quiet`` times the quietest
    pooled by their degrees of freedom."""
    edges = np.flatnonzero(np.diff(xc) != 0) + 1
    bounds = zip(np.r_[0, edges], np.r_[edges, xc.size])
    dt = float(np.median(np.diff(t)))
    est = []
    for a, b in bounds:
        a += min(int(round(settle / dt)), (b - a) // 2)
        if b - a < 8:
            continue
        k = np.arange(b - a, dtype=float)
        r = y[a:b] - np.polyval(np.polyfit(k, y[a:b], 1), k)
        est.append((float(r @ r) / (b - a - 2), b - a - 2))
    vmin = min(v for v, _ in est)
    q = [(v, n) for v, n in est if v <= quiet * vmin]
    return math.sqrt(sum(v * n for v, n in q) / sum(n for _, n in q))


@pytest.mark.skipif(not LINA.exists(), reason=f"the maxon LinA record is not present at {LINA}")
def test_linear_actuator_torque_floor_is_its_measured_standstill_noise(tmp_path, capsys):
    """The maxon log's current is in mA (1 mA quantization: 1.24e-5 N m RMS); at rest it hunts by
    some 0.02 N m, which no model follows: that is the floor."""
    from hil.cli import main
    cfg_path = tmp_path / "lina.toml"
    cfg_path.write_text(LINA_CFG)
    raw = np.loadtxt(LINA)
    t, xc, y = raw[:, 0] / 1e3, raw[:, 2] / 1e3, raw[:, 5] * KT
    want = _independent_standstill_rms(t, xc, y)
    cfg = loads(LINA_CFG)
    assert want > 1000 * KT / math.sqrt(12)
    assert main(["diagnose", str(LINA), "--config", str(cfg_path), "--map",
                 "data[:,0]=t[ms],data[:,2]=x_cmd[mm],data[:,3]=x_motor[mm],data[:,5]*4.29e-5=torque",
                 "--no-chain", "--candidates", "constant_force", "--jobs", "1", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["noise_floor"]["torque"] == pytest.approx(want, rel=0.1)
    assert d["noise_floor_source"]["torque"].startswith("standstill noise of the measured channel")
    assert cfg.rotary


def test_floor_parts_and_the_error_over_each():
    """The end of the chain: the error in multiples of each part of the floor, and 'within the
    run-to-run spread' where the repeated records' spread holds it (closed form on given parts)."""
    from types import SimpleNamespace

    from hil.ident.chain import floor_parts, floor_parts_text
    rp = SimpleNamespace(noise_sources={"x_motor": {"quantization": 12 ** 0.5 * 2e-4, "standstill": 1e-3},
                                        "torque": {"quantization": 0.0, "standstill": 0.02}},
                         spread={"x_motor": 7.0}, noise={"x_motor": 7.0, "torque": 0.02})
    out = floor_parts(rp, {"x_motor": 6.0, "torque": 0.025})
    assert out["floor_parts"]["x_motor"] == pytest.approx({"quantization": 2e-4, "standstill": 1e-3, "run_to_run": 7.0})
    assert out["error_over"]["x_motor"] == pytest.approx({"quantization": 3e4, "standstill": 6e3, "run_to_run": 6 / 7})
    assert out["error_over"]["torque"] == pytest.approx({"standstill": 1.25})
    assert out["within_run_to_run"] is True
    assert floor_parts(rp, {"x_motor": 11.0, "torque": 0.025})["within_run_to_run"] is False   # 11 > 1.5 x 7
    assert floor_parts(rp, {"x_motor": 6.0, "torque": 0.04})["within_run_to_run"] is False     # torque off its floor
    text = floor_parts_text(out, lambda c: {"x_motor": "rad", "torque": "N*m"}[c])
    assert text[0] == "floor: within the run-to-run spread"
    assert "x_motor: the error is 3e+04 x the quantization" in text[1] and "0.857 x the run-to-run spread" in text[1]
    rp.spread = {}
    assert floor_parts(rp, {"x_motor": 6.0, "torque": 0.025})["within_run_to_run"] is None


def test_chain_json_gives_the_floor_parts(tmp_path, capsys):
    from hil.cli import main
    from hil.io.measurement import write
    xc = _dwelling_command()
    ch, _ = synthesize(BENCH, "coulomb_friction", {"level": 1.5}, duration=xc.size * TP, seed=4, force_noise=0.1,
                       x_cmd=xc)
    rec = tmp_path / "f.csv"
    write(rec, ch, {"sample_period": f"{TP} s"})
    assert main(["diagnose", str(rec), "--config", str(CONFIG / "paper_bench.toml"), "--candidates",
                 "viscous_friction,constant_force", "--max-steps", "2", "--jobs", "1", "--json"]) == 0
    f = json.loads(capsys.readouterr().out)["final"]
    assert f["within_run_to_run"] is None
    assert f["floor_parts"]["torque"]["standstill"] == pytest.approx(f["noise_floor"]["torque"])
    for c, over in f["error_over"].items():
        for k, v in over.items():
            assert v == pytest.approx(f["error"][c] / f["floor_parts"][c][k])
