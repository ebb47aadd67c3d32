"""The control law's order, anti-windup, friction, the two loop paths, the peer, the recorder."""
import json
import math

import numpy as np
import pytest
import scipy.linalg
from conftest import CONFIG
from fault_backends import FaultyPlant

from drivers.control import ControllerSettings, new_velocity_state, velocity_law
from drivers.sim import SimulatedPlant
from hil.errors import StopKind
from hil.io.measurement import read
from hil.io.recorder import Recorder
from hil.loop import ControlLoop
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory
from hil.runtime import record_channels, run_trajectory
from hil.simulate import simulate_config

P = 0.01
R = 2 * math.pi / P
M = [335.57, 392.97, 4.228]


def _discrete(Tv, c_motor=0.0076):
    """The bench's ZOH discretization, computed here from scratch (force input on mass 1)."""
    k1, k2, c1, c2 = 5.362e7, 3.706e4, 16789.0, 11.80
    K = np.array([[k1, -k1, 0], [-k1, k1 + k2, -k2], [0, -k2, k2]])
    C = np.array([[c1 + c_motor * R ** 2, -c1, 0], [-c1, c1 + c2, -c2], [0, -c2, c2]])
    Mi = np.diag(1 / np.array(M))
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [-Mi @ K, -Mi @ C]])
    B = np.zeros((6, 1))
    B[3, 0] = 1 / M[0]
    Ad = scipy.linalg.expm(A * Tv)
    # Bd = (sum_i (A Tv)^i / (i+1)!) Tv B: the series, since A is singular (free chain)
    Bd = sum(np.linalg.matrix_power(A * Tv, i) / math.factorial(i + 1) for i in range(30)) @ B * Tv
    return Ad, Bd


def test_first_ticks_by_hand(bench):
    """Tick 0: v_ref = Kv (x_cmd[0] - x2) + FFV (x_cmd[1] - x_cmd[0]) / Tp; the PI's first steps."""
    Tp, Tv, Kv, Kp, Ti = 0.004, 62.5e-6, 50.0, 0.47, 0.016
    x_cmd = np.array([0.0, 1e-4, 3e-4, 6e-4, 6e-4])
    res = simulate_config(bench, x_cmd, record_every=1)
    Ad, Bd = _discrete(Tv)
    x = np.zeros(6)
    I = 0.0
    taus = []
    for k in range(3):
        w_ref = (Kv * (x_cmd[k] - x[1]) + 1.0 * (x_cmd[k + 1] - x_cmd[k]) / Tp) * R
        for j in range(64):
            e = w_ref - x[3] * R
            I += e * Tv
            tau = Kp * (e + I / Ti)
            assert abs(tau) < 30
            taus.append(tau)
            x = Ad @ x + Bd[:, 0] * tau * R
    # tick 0 by hand: w_ref = 0.025 m/s * 2 pi / p = 15.70796 rad/s; tau = Kp (e + e Tv / Ti)
    assert res.u[0] == pytest.approx(0.47 * (15.707963267948966 + 15.707963267948966 * Tv / Ti), rel=1e-12)
    assert np.allclose(res.u[:len(taus)], taus, rtol=1e-9, atol=1e-12)
    assert res.t[64] == pytest.approx(Tp)


def test_anti_windup_conditional_integration():
    s = ControllerSettings(0.004, 1e-3, 50.0, 1.0, 1.0, 0.01, 2.0, 1.0)
    p = s.as_array()
    st = new_velocity_state()
    outs = [velocity_law(p, st, 10.0, 0.0, 0.0) for _ in range(5)]
    assert outs == [2.0] * 5
    # the first step integrated (nothing had saturated before), the following ones did not
    assert st[0] == pytest.approx(10.0 * 1e-3)
    # back inside the limit: integration resumes after the first unsaturated output
    u = velocity_law(p, st, 0.5, 0.0, 0.0)
    assert u == pytest.approx(1.0 * (0.5 + 0.01 / 0.01))
    velocity_law(p, st, 0.5, 0.0, 0.0)
    assert st[0] == pytest.approx(0.01 + 0.5e-3)


def test_anti_windup_limits_overshoot_after_saturation(bench):
    """A hard acceleration against a low torque limit: with conditional integration the table
    overshoots far less than a PI that integrates through the saturation would."""
    traj = Trajectory()
    traj.move(MoveSpec(0.02, 0.25, a_max=15.0))
    traj.dwell(0.3)
    _, x_cmd = traj.sample(0.004)
    cfg = bench.with_values({"control.output_limit": "8 N*m"})
    res = simulate_config(cfg, x_cmd)
    assert np.max(np.abs(res.u)) == pytest.approx(8.0)
    over_aw = np.max(res.x_table) - 0.02
    # reference without anti-windup: the same loop written out, integrating always
    plant = plant_from_config(cfg)
    Ad, Bd = plant.chain.discretize(62.5e-6).A, plant.chain.discretize(62.5e-6).B
    x = np.zeros(6)
    I = 0.0
    cmd = np.append(x_cmd, x_cmd[-1])
    xs = []
    for k in range(len(x_cmd)):
        w_ref = (50 * (cmd[k] - x[1]) + (cmd[k + 1] - cmd[k]) / 0.004) * R
        xs.append(x[1])
        for _ in range(64):
            e = w_ref - x[3] * R
            I += e * 62.5e-6
            tau = min(max(0.47 * (e + I / 0.016), -8.0), 8.0)
            x = Ad @ x + Bd[:, 0] * tau * R
    over_windup = np.max(xs) - 0.02
    assert over_aw < 0.5 * over_windup


def test_stiction_holds_and_slips(bench):
    """Below the friction level the axis sticks exactly (no creep); above it accelerates at
    (tau - tau_c) / J_total."""
    cfg = bench.with_values({"friction.coulomb": "2.2 N*m", "friction.static": "2.2 N*m",
                             "friction.viscous": "0 N*m*s/rad"})
    sim = SimulatedPlant(cfg, plant_from_config(cfg), closes="none")
    sim.home_at(0.0)
    sim.enable()
    from drivers.base import Setpoint
    for _ in range(16000):                      # 1 s at 2.0 N m < 2.2 N m
        sim.write_setpoint(Setpoint(output=2.0))
        sim.sync()
    assert sim.x[0] == 0.0 and sim.x[3] == 0.0
    steps = 8000
    for _ in range(steps):                      # 0.5 s at 3.0 N m
        sim.write_setpoint(Setpoint(output=3.0))
        sim.sync()
    J_total = sum(M) / R ** 2
    alpha = (3.0 - 2.2) / J_total               # rad/s^2 of the motor
    t = steps * 62.5e-6
    assert sim.x[3] * R == pytest.approx(alpha * t, rel=2e-3)


@pytest.mark.parametrize("changes", [{"control.acc_ff": 0.0}, {"control.acc_ff": 1.0},
                                     {"effects.time_delay.delay": "2 ms"},
                                     {"effects.time_delay.delay": "2 ms", "control.output_delay": 3},
                                     {"effects.actuator_delay.delay": "0.25 ms"},
                                     {"effects.feedback_delay.delay": "1.3 ms"},
                                     {"effects.feedback_delay.delay": "9 ms", "control.position_feedback": "motor"},
                                     {"effects.stiffness_along_travel.k_start": "6e7 N/m",
                                      "effects.stiffness_along_travel.k_end": "4e7 N/m",
                                      "effects.stiffness_along_travel.x_start": "0 mm",
                                      "effects.stiffness_along_travel.x_end": "20 mm"}],
                         ids=["0.0", "1.0", "time_delay", "time_delay+output_delay", "actuator_delay",
                              "feedback_delay", "feedback_delay_motor", "stiffness_along_travel"])
def test_stepwise_loop_equals_compiled_kernel(bench, changes):
    """The real-time loop's path (ControlLoop + per-cycle backend) and the compiled simulator run
    the same law: identical records (with and without the acceleration feed-forward, with a
    transport delay of the plant and the controller's output delay).

    The loop records the output it commands, the kernel the output reaching the current loop:
    they are the same values, the plant's transport delay apart."""
    bench = bench.with_values(changes)
    traj = Trajectory()
    traj.move(MoveSpec(0.01, 0.1, a_max=3.0))
    traj.dwell(0.05)
    _, x_cmd = traj.sample(0.004)
    fast = simulate_config(bench, x_cmd, record_every=1)
    sim = SimulatedPlant(bench, plant_from_config(bench), closes="none")
    sim.home_at(0.0)
    sim.enable()
    from drivers.control import controller_from_config
    ctrl = controller_from_config(bench, sim.plant)
    loop = ControlLoop(sim, ctrl, recorder=None)
    rows = []
    loop._record = lambda k, xc, vc, fb, out: rows.append((fb.x_table, fb.x_tip, out))
    loop.run(x_cmd)
    rows = np.array(rows)
    n_sub = ctrl.substeps
    transport = round((bench.get("effects.time_delay.delay", 0.0) + bench.get("effects.actuator_delay.delay", 0.0))
                      / ctrl.velocity_period)
    assert np.max(np.abs(rows[:, 0] - fast.x_table[::n_sub])) < 1e-12
    assert np.max(np.abs(rows[:, 1] - fast.x_tip[::n_sub])) < 1e-12
    assert np.max(np.abs(rows[:, 2] - fast.u[transport::n_sub])) < 1e-9


@pytest.mark.parametrize("changes", [{}, {"effects.feedback_delay.delay": "2.1 ms"}], ids=["plain", "feedback_delay"])
def test_velocity_and_position_mode_backends_run_the_same_law(bench, changes):
    bench = bench.with_values(changes)
    traj = Trajectory()
    traj.move(MoveSpec(0.005, 0.1, a_max=3.0))
    _, x_cmd = traj.sample(0.004, 0.05)
    fast = simulate_config(bench, x_cmd)
    from drivers.control import controller_from_config
    for closes in ("velocity", "both"):
        sim = SimulatedPlant(bench, plant_from_config(bench), closes=closes)
        sim.home_at(0.0)
        sim.enable()
        rows = []
        loop = ControlLoop(sim, controller_from_config(bench, sim.plant))
        loop._record = lambda k, xc, vc, fb, out: rows.append(fb.x_table)
        loop.run(x_cmd)
        assert np.max(np.abs(np.array(rows) - fast.x_table)) < 1e-12, closes


def test_agreement_with_python_control_peer(bench):
    """The compiled loop against python-control's discrete interconnection (friction off), with
    the torque limit reached so that the anti-windup is exercised too."""
    pytest.importorskip("control")
    from peer import peer_simulate
    traj = Trajectory()
    traj.move(MoveSpec(0.004, 0.1, a_max=12.0))
    _, x_cmd = traj.sample(0.004, 0.04)
    cfg = bench.with_values({"control.output_limit": "10 N*m"})
    res = simulate_config(cfg, x_cmd)
    assert np.max(np.abs(res.u)) == pytest.approx(10.0)
    X = peer_simulate(M, [5.362e7, 3.706e4], [16789.0, 11.80], 0.0076, P, 0.004, 62.5e-6, 50.0, 1.0, 0.47,
                      0.016, 10.0, x_cmd)
    assert np.max(np.abs(res.x - X)) < 1e-9


def test_recording_survives_a_fault(bench, tmp_path):
    traj = Trajectory()
    traj.move(MoveSpec(0.01, 0.1, a_max=3.0))
    # a backend that raises instead of reporting (against the fault rule): still a clean end
    backend = FaultyPlant(bench, at=64 * 20 + 6, reason="drive fault 0x2310 (over-current)", raises=True)
    rec = run_trajectory(bench, traj, backend=backend, out_file=tmp_path / "run.csv", settle=0.1)
    assert rec.status == "fault" and "0x2310" in rec.reason
    assert backend.stopped
    m = read(tmp_path / "run.csv")
    assert len(m) == 21                          # ticks 0..20 recorded, nothing lost
    status = json.loads((tmp_path / "run.json").read_text())
    assert status["status"] == "fault" and "over-current" in status["reason"] and status["rows"] == 21


def test_recording_survives_an_exception(tmp_path):
    names = record_channels(True)
    with pytest.raises(RuntimeError):
        with Recorder(tmp_path / "r.csv", names, {"sample_period": "0.004 s"}) as rec:
            for k in range(10):
                rec.append(**{n: k * 1e-3 for n in names})
            raise RuntimeError("boom")
    m = read(tmp_path / "r.csv")
    assert len(m) == 10 and m.meta["sample_period"] == "0.004 s"
    assert m["t"][-1] == pytest.approx(9e-3)
    st = json.loads((tmp_path / "r.json").read_text())
    assert st["status"] == "aborted" and st["reason"] == "RuntimeError: boom"


def test_hil_move_end_to_end(tmp_path, capsys):
    from hil.cli import main
    rc = main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "100mm", "--feed", "7000mm/min",
               "--tacc", "200ms", "--out", str(tmp_path), "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("overshoot_table_um", "overshoot_tip_um", "j_max", "a_max"):
        assert key in out
    assert out["j_max"] == pytest.approx(2 * (math.pi * 0.5 / 0.4) ** 2 / (7 / 60), rel=1e-9)
    assert (tmp_path / "move.png").stat().st_size > 10000
    m = read(tmp_path / "move.csv")
    # after the move the tip rings at the compliant mode (~15 Hz, the paper's Fig. 10d)
    t, tip = m["t"], m["x_tip"]
    after = t > 1.0
    d = tip[after] - tip[after].mean()
    spec = np.abs(np.fft.rfft(d * np.hanning(d.size), 8192))
    f = np.fft.rfftfreq(8192, t[1] - t[0])
    assert f[np.argmax(spec)] == pytest.approx(15.0, abs=1.0)


def test_hil_move_refuses_with_a_clear_line(capsys):
    from hil.cli import main
    rc = main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "100mm", "--feed", "7000mm/min",
               "--tacc", "20ms"])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("hil move: error: move refused before motion:") and err.count("\n") == 1
    assert "limits.acceleration" in err and "would fit" in err


def test_a_controlled_stop_that_failed_is_said_not_reported_as_done(bench, tmp_path, state_dir):
    """Issue 49, finding 4: after a drive lost mid-move the host warned that the quick stop failed,
    then its summary said "stopped with the configured controlled stop". The run's record says
    whether the stop got through (``controlled_stop``), and one that did is told apart."""
    traj = Trajectory()
    traj.move(MoveSpec(0.01, 0.1, a_max=3.0))
    lost = FaultyPlant(bench, at=64 * 20 + 6, reason="lost communication: no answer", raises=True,
                       kind=StopKind.LINK, stop_fails=True)
    rec = run_trajectory(bench, traj, backend=lost, out_file=tmp_path / "lost.csv", settle=0.1)
    assert rec.status == "fault" and lost.stopped
    assert rec.controlled_stop["ok"] is False and rec.controlled_stop["how"] == "quick_stop"
    assert "no answer to the quick stop" in rec.controlled_stop["error"]
    (state_dir / "latch.json").unlink()          # the trip latched: cleared as 'hil reset' would
    held = FaultyPlant(bench, at=64 * 20 + 6, raises=True)
    rec = run_trajectory(bench, traj, backend=held, out_file=tmp_path / "held.csv", settle=0.1)
    assert rec.controlled_stop == {"how": "quick_stop", "ok": True, "error": ""}
    (state_dir / "latch.json").unlink()
    done = run_trajectory(bench, traj, out_file=None, settle=0.1)
    assert done.status == "complete" and done.controlled_stop is None


def test_hil_move_says_a_failed_stop_in_text_json_and_exit_code(bench, tmp_path, capsys, monkeypatch, state_dir):
    """The command's side of it: the text says FAILED, the JSON ``controlled_stop.ok`` is false and
    the exit code is 6 (hil.errors.STOP_FAILED_EXIT), not the kind's own 4."""
    import hil.backends
    from hil.cli import main
    from hil.errors import STOP_FAILED_EXIT
    monkeypatch.setattr(hil.backends, "open_backend", lambda cfg, *a, **k: FaultyPlant(
        cfg, at=64 * 20 + 6, reason="lost communication: no answer", raises=True, kind=StopKind.LINK,
        stop_fails=True))
    argv = ["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "10mm", "--feed", "6000mm/min",
            "--tacc", "50ms"]
    assert main(argv + ["--out", str(tmp_path / "a")]) == STOP_FAILED_EXIT == 6
    out = capsys.readouterr().out
    assert "controlled stop (quick_stop) FAILED" in out and "stopped with the configured" not in out
    (state_dir / "latch.json").unlink()          # the trip latched: cleared as 'hil reset' would
    assert main(argv + ["--out", str(tmp_path / "b"), "--json"]) == 6
    got = json.loads(capsys.readouterr().out)
    assert got["controlled_stop"]["ok"] is False and got["stop"] == "link" and got["exit_code"] == 6
