"""Stability for every loop the configuration can describe (issue 18, item 2): the lifted model
with delays, speed from filtered positions and the current loop's lag, checked against the
compiled simulator sample by sample, its spectral radius against the simulated growth, and the
refusals (exit 2, one line naming the term) and schema bounds."""
import math

import numpy as np
import pytest
from conftest import CONFIG

from drivers.control import controller_from_config
from hil import config
from hil.closed_loop import closed_loop_response, lifted_loop, loop_stability
from hil.errors import ConfigError
from hil.plant_config import plant_from_config
from hil.simulate import simulate

CASES = [
    {},
    {"control.output_delay": 1},
    {"control.output_delay": 7},
    {"control.velocity_feedback": "position_difference"},
    {"control.velocity_feedback": "position_difference", "control.velocity_filter": [0.5, 0.5]},
    {"control.velocity_feedback": "position_difference", "control.velocity_filter": [0.25, 0.5, 0.25]},
    {"actuator.current_loop_time_constant": 0.2e-3},
    {"actuator.current_loop_time_constant": 3e-3},
    {"effects.time_delay.delay": "0.1 ms"},
    {"effects.time_delay.delay": "0.13 ms", "control.output_delay": 2, "control.acc_ff": 1.0,
     "actuator.current_loop_time_constant": 1e-3, "control.velocity_feedback": "position_difference",
     "control.velocity_filter": [0.25, 0.5, 0.25]},
    {"control.position_feedback": "motor", "control.output_delay": 3, "control.ti": "inf"},
    # the filter sections of the velocity loop (issue 52): a notch on the torque setpoint, a
    # low-pass on the speed feedback, a general biquad, with the other terms
    {"control.filters": [{"kind": "notch", "frequency": "86.6Hz", "width": "20Hz", "depth": "-20dB"}]},
    {"control.filters": [{"kind": "lowpass", "frequency": "600Hz", "at": "speed"},
                         {"kind": "notch", "frequency": "300Hz", "width": "60Hz", "depth": "-30dB"}],
     "control.output_delay": 2, "actuator.current_loop_time_constant": 0.2e-3},
    {"control.filters": [{"kind": "biquad", "b": [0.2, 0.3, 0.1], "a": [1.0, -0.5, 0.1]}],
     "control.velocity_feedback": "position_difference", "control.velocity_filter": [0.5, 0.5]},
]


def _lifted_response(plant, ctrl, x):
    """The table position at each tick from the lifted map, fed as the kernel feeds its law."""
    Phi, Gam, Gff, _ = lifted_loop(plant, ctrl)
    s = np.zeros(Phi.shape[0])
    R, Kv, Tp = ctrl.speed_scale, ctrl.kv, ctrl.position_period
    cmd = np.append(x, x[-1])
    out = []
    for k in range(x.size):
        out.append(s[plant.table])
        xfb = s[plant.table] if ctrl.position_feedback == "table" else s[0]
        w = R * (Kv * (cmd[k] - xfb) + ctrl.ffv * (cmd[k + 1] - cmd[k]) / Tp)
        a = (cmd[k + 1] - 2 * cmd[k] + (cmd[k - 1] if k > 0 else cmd[k])) / Tp ** 2
        s = Phi @ s + Gam * w + Gff * ctrl.acc_ff * a
    return np.array(out)


@pytest.mark.slow
@pytest.mark.parametrize("changes", CASES, ids=[str(i) for i in range(len(CASES))])
def test_lifted_loop_is_the_compiled_loop(bench, changes):
    """Small moves (no saturation, no friction): the lifted map reproduces the compiled kernel's
    table position at every tick to rounding, every loop term included."""
    cfg = bench.with_values(changes)
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    x = np.zeros(80)
    x[1:] = np.cumsum(np.r_[1e-6, 2e-6, 3e-6, 2e-6, np.zeros(75)])
    sim = simulate(plant, ctrl, x)
    lifted = _lifted_response(plant, ctrl, x)
    assert np.max(np.abs(lifted - sim.x_table)) < 1e-11 * np.max(np.abs(sim.x_table))


def test_default_loop_matches_the_former_model(bench):
    """Without the new terms the spectral radius is closed_loop_response's (the former check)."""
    for kp in (0.2, 0.47, 1.5):
        cfg = bench.with_values({"control.kp": kp})
        assert loop_stability(cfg)[1] == pytest.approx(closed_loop_response(cfg, [1.0]).spectral_radius, rel=1e-9)


@pytest.mark.parametrize("changes", [{"control.output_delay": 20}, {"control.output_delay": 40},
                                     {"actuator.current_loop_time_constant": 0.05},
                                     {"actuator.current_loop_time_constant": 0.9},
                                     {"control.velocity_feedback": "position_difference", "control.kp": 3.0},
                                     {"control.output_delay": 2, "control.kp": 1.5}])
def test_spectral_radius_is_the_simulated_growth(bench, changes):
    """An independent reading of the radius: the compiled loop's response to a small step grows
    or decays per tick as rho^k (the slowest mode dominates after a while). With the output limit
    out of the way the simulated ratio of late envelope peaks matches the eigenvalue's radius."""
    cfg = bench.with_values(dict(changes, **{"control.output_limit": 1e9, "limits.torque": 1e9}))
    stable, rho = loop_stability(cfg)
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    # a step of 1e-100 m (floating point keeps its relative precision): the loop stays linear (far from the output limit) while it grows 1e90 times
    K = int(90 / np.log10(rho)) + 100 if rho > 1 else 1500
    x = np.full(K, 1e-100)
    x[0] = 0.0
    e = simulate(plant, ctrl, x).x_table - 1e-100
    n = (K - 100) // 4 if rho > 1 else 400
    a, b = np.max(np.abs(e[-2 * n:-n])), np.max(np.abs(e[-n:]))
    assert (b / a) ** (1 / n) == pytest.approx(rho, abs=3e-3)
    assert stable is (rho < 1)


@pytest.mark.parametrize("setting,term", [
    ("control.output_delay=40", "control.output_delay 40"),
    ("actuator.current_loop_time_constant=0.9s", "actuator.current_loop_time_constant 900 ms"),
    ("control.kp=1e6", "control.kp 1e+06"),
])
def test_unstable_settings_are_refused_in_one_line(capsys, tmp_path, setting, term):
    from hil.cli import main
    rc = main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "10mm", "--feed", "7000mm/min",
               "--tacc", "200ms", "--out", str(tmp_path / "m"), "--set", setting])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "unstable" in err and term in err
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize("key,value,word", [
    ("control.output_delay", 100000000, "at most 1000"),
    ("runtime.priority", 1000, "at most 99"),
    ("actuator.current_loop_time_constant", "10 s", "at most 1 s"),
    ("control.kv", "1e300 1/s", r"at most 1e\+12"),
    ("control.velocity_filter", [0.1] * 9, "at most 8 numbers"),
    ("supervisor.frozen_cycles", 0, ">= 1"),
    ("control.position_period", "100 s", "at most 1 s"),
])
def test_schema_bounds(bench, key, value, word):
    with pytest.raises(ConfigError, match=word):
        config.load(CONFIG / "paper_bench.toml", {key: value})


def test_model_report_judges_the_whole_loop(bench):
    """closed_loop_response (hil model --closed-loop) reports the whole loop's radius where its
    frequency response leaves terms out, the former one otherwise."""
    cfg = bench.with_values({"control.output_delay": 40})
    r = closed_loop_response(cfg, [1.0])
    assert r.stable is False and r.spectral_radius == loop_stability(cfg)[1]


def test_a_p_velocity_loop_is_judged_without_its_idle_integral(bench, capsys, tmp_path):
    """control.ti = inf (no integral action, a P velocity loop: the schema's own spelling) was
    refused as unstable with "spectral radius 1 > 1": the integral still sums the error, but
    nothing reads it, so its eigenvalue is 1 exactly. The loop is judged by the rest: the radius
    is the one of the same loop with the longest integral time the schema allows (3600 s, whose
    integral's own eigenvalue 1 - 1e-6 set apart), and the move runs."""
    from hil.cli import main
    from hil.closed_loop import closed_loop_matrix
    for changes in ({}, {"control.position_feedback": "motor", "control.output_delay": 3}):
        stable, rho = loop_stability(bench.with_values({**changes, "control.ti": "inf"}))
        slow = bench.with_values({**changes, "control.ti": 3600.0})
        plant = plant_from_config(slow)
        ev = sorted(np.linalg.eigvals(closed_loop_matrix(plant, controller_from_config(slow, plant))),
                    key=lambda z: abs(z - 1))
        assert abs(ev[0] - 1) < 1e-5                        # the slow integral's own eigenvalue
        assert stable and rho == pytest.approx(max(abs(z) for z in ev[1:]), abs=1e-8)
    assert main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--set", "control.ti=inf", "--stroke", "10mm",
                 "--feed", "7000mm/min", "--tacc", "200ms", "--out", str(tmp_path)]) == 0
    assert "refused" not in capsys.readouterr().err
    # the shipped P-only axes: each was refused ("spectral radius 1 > 1"), the EMPS dry run included
    for name in ("emps.toml", "emps_2mass.toml", "hsm150.toml"):
        cfg = config.load(CONFIG / name)
        assert math.isinf(cfg["control.ti"]) and loop_stability(cfg)[0], name
    assert main(["move", "--config", str(CONFIG / "emps.toml"), "--stroke", "10mm", "--feed", "3000mm/min",
                 "--amax", "1m/s^2", "--check"]) == 0
