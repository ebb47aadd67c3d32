"""Issue 24, item 3: a drive engineer's checklist as catalogue effects. Each at two strengths
against its closed form: the current loop's lag (its phase and gain at a frequency), the torque
constant's factor (the open-loop motion scaled by it), the screw's thermal elongation
(x_motor - x_table = -strain x at rest), a cable carrier's force (the torque at constant speed
changed by -(f0 + f1 x) / k); their regression starts recover what a record hides."""
import math
import re

import numpy as np
import pytest

from hil.config import load
from hil.plant_config import candidate, configure
from hil.simulate import simulate_config

CFG = load("config/paper_bench.toml")
TV = CFG["control.velocity_period"]
TP = CFG["control.position_period"]
K_LOAD = 2 * math.pi / CFG["plant.pitch"]         # N on the load per N m on the motor


def _with(name, values, cfg=CFG):
    return configure(candidate(name), cfg, values)


def _sine(t, y, f):
    X = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)])
    c, *_ = np.linalg.lstsq(X, y, rcond=None)
    return math.hypot(*c), math.atan2(c[1], c[0])


@pytest.mark.parametrize("tau", [5e-4, 2e-3])
def test_current_loop_lag_phase_and_gain_at_a_frequency(tau):
    # open loop: a 20 Hz torque command; the current follows through the lag, stepped per velocity period
    f, ticks = 20.0, 300
    n = ticks * int(round(TP / TV))
    u = 2.0 * np.sin(2 * np.pi * f * np.arange(n) * TV)
    cfg = _with("current_loop_lag", {"time_constant": tau})
    out = {s: simulate_config(cfg, np.zeros(ticks), u_add=u, open_loop=True, torque=s).channels()
           for s in ("command", "actual")}
    t = out["actual"]["t"]
    sel = t > 0.3
    a0, p0 = _sine(t[sel], out["command"]["torque"][sel], f)
    a1, p1 = _sine(t[sel], out["actual"]["torque"][sel], f)
    w = 2 * np.pi * f
    # the discrete first-order lag alpha / (1 - (1 - alpha) e^-jwT), alpha = 1 - exp(-T / tau), exactly
    alpha = 1 - math.exp(-TV / tau)
    h = alpha / (1 - (1 - alpha) * np.exp(-1j * w * TV))
    assert a1 / a0 == pytest.approx(abs(h), rel=1e-4)
    assert p0 - p1 == pytest.approx(-np.angle(h), abs=2e-4)
    # and the continuous closed form atan(w tau), 1 / sqrt(1 + (w tau)^2), within the step's half period
    assert p0 - p1 == pytest.approx(math.atan(w * tau), abs=w * TV)
    assert a1 / a0 == pytest.approx(1 / math.sqrt(1 + (w * tau) ** 2), rel=1e-3)


@pytest.mark.parametrize("factor", [0.93, 1.12])
def test_torque_constant_scales_the_open_loop_motion(factor):
    # the paper bench is linear (viscous friction only): a torque factor scales the motion from rest exactly
    ticks = 200
    n = ticks * int(round(TP / TV))
    u = np.where(np.arange(n) * TV < 0.2, 3.0, -3.0)
    base = simulate_config(CFG, np.zeros(ticks), u_add=u, open_loop=True).channels()
    eff = simulate_config(_with("torque_constant", {"factor": factor}), np.zeros(ticks), u_add=u,
                          open_loop=True).channels()
    for c in ("x_motor", "x_table", "x_tip"):
        assert np.allclose(eff[c], factor * base[c], rtol=1e-9, atol=1e-12 * np.max(np.abs(base[c])))


def _move_and_rest(cfg, x_end=0.06, speed=0.02):
    ramp = np.arange(0.0, x_end, speed * TP)
    x = np.concatenate([np.zeros(25), ramp, np.full(int(3.0 / TP), x_end)])
    return simulate_config(cfg, x).channels()


@pytest.mark.parametrize("strain", [60e-6, -150e-6])
def test_screw_elongation_at_rest(strain):
    ch = _move_and_rest(_with("screw_elongation", {"strain": strain, "x_ref": 0.0}))
    base = _move_and_rest(CFG)
    # at rest no force acts on the table: the nut sits where the table is, x1 (1 + strain) = x2 (less
    # what the tip's lightly damped mode still swings, the same with and without the effect)
    d = (ch["x_motor"][-1] - ch["x_table"][-1]) - (base["x_motor"][-1] - base["x_table"][-1])
    assert d == pytest.approx(-strain * ch["x_motor"][-1], rel=1e-3)


@pytest.mark.parametrize("f0,f1", [(200.0, -3000.0), (-80.0, 6000.0)])
def test_cable_carrier_torque_at_constant_speed(f0, f1):
    speed = 0.02
    x = np.concatenate([np.zeros(25), np.arange(0.0, 0.08, speed * TP)])
    base = simulate_config(CFG, x).channels()
    eff = simulate_config(_with("cable_carrier", {"force": f0, "slope": f1}), x).channels()
    t = base["t"]
    cruise = (t > 0.1 + 1.0) & (t < t[-1] - 0.1)           # a second after the start: the loop has settled
    want = -(f0 + f1 * eff["x_table"][cruise]) / K_LOAD
    got = eff["torque"][cruise] - base["torque"][cruise]
    assert np.max(np.abs(got - want)) < 0.01 * np.max(np.abs(want))


@pytest.fixture(scope="module")
def records():
    from hil.ident import Replay, synthesize
    from hil.io.measurement import Measurement

    made = {}

    def make(name):
        if name not in made:
            ch, truth = synthesize(CFG, name, duration=6.0, seed=3)
            made[name] = Replay(Measurement(ch, source=f"synth:{name}"), CFG), truth
        return made[name]
    return make


@pytest.mark.parametrize("name,param,rel", [("screw_elongation", "strain", 0.05), ("cable_carrier", "force", 0.1),
                                            ("cable_carrier", "slope", 0.1)])
def test_regression_start_recovers_the_hidden_value(records, name, param, rel):
    from hil.ident.starts import record_scales, starting_values
    rp, truth = records(name)
    res0 = rp.residuals(CFG)
    starts = starting_values(candidate(name), rp, res0, record_scales(rp, res0), CFG)
    assert starts[0][param] == pytest.approx(truth["params"][param], rel=rel)


def test_torque_constant_named_before_the_masses(records):
    """A torque-constant error is every mass divided by the factor: the diagnosis names the one
    parameter before any mass, and its evidence says what it mimics."""
    from hil.ident import diagnose
    rp, truth = records("torque_constant")
    d = diagnose(rp, ["torque_constant", "mass_change", "parameter:plant.m1", "parameter:plant.m2"], jobs=1)
    assert d["verdict"] == "torque_constant"
    c = d["candidates"][0]
    assert c.params["factor"] == pytest.approx(truth["params"]["factor"], rel=0.01)
    assert "the same motion as every mass divided by" in c.evidence


def test_evidence_reads_the_residual_before_the_fit(records):
    from hil.ident.evidence import evidence
    rp, truth = records("screw_elongation")
    ev = evidence("screw_elongation", truth["params"], rp, rp.residuals(CFG), "x_motor", 1e-6, 0.5e-6, [])
    # x_motor - x_table = -strain x: the residual's slope is -60 um per m; 60e-6 / 11.5e-6 per K = 5.2 K
    slope = float(re.search(r"x_motor - x_table residual changes ([-+0-9.e]+) um per m of travel", ev).group(1))
    assert slope == pytest.approx(-60.0, rel=0.05)
    assert "60 um per m longer than nominal: a steel screw 5.2 K warmer" in ev
    rp, truth = records("cable_carrier")
    ev = evidence("cable_carrier", truth["params"], rp, rp.residuals(CFG), "torque", 1.0, 0.5, [])
    # the torque residual's slope along the travel: -f1 / k = 3000 N/m / (2 pi / 10 mm) = 4.77 N m per m
    slope = float(re.search(r"torque residual moving changes along the travel, ([-+0-9.e]+) N m per m", ev).group(1))
    assert slope == pytest.approx(3000.0 / K_LOAD, rel=0.1)
    ev = evidence("current_loop_lag", {"time_constant": 5e-4}, rp, rp.residuals(CFG), "torque", 1.0, 0.5, [])
    # bandwidth 1 / (2 pi 0.5 ms) = 318.3 Hz; atan(2 pi 10 Hz 0.5 ms) = 1.8 deg
    assert "bandwidth 318.3 Hz; 1.8 deg of phase at 10 Hz" in ev
