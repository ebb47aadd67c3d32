"""Sine-square profiles (Eq. 15-16) and the limit refusals."""
import math

import numpy as np
import pytest

from hil.profiles import AxisLimits, LimitError, MoveSpec, Trajectory, check_limits, plan_move

G0 = 30 / 60       # 30 m/min
VF = 15 / 60       # 15 m/min


@pytest.mark.parametrize("t_acc_ms, paper_jmax", [(60, 1370), (80, 771), (90, 610), (100, 493), (151, 216),
                                                  (200, 124), (250, 79), (280, 63), (300, 54)])
def test_paper_jerks_from_tacc(t_acc_ms, paper_jmax):
    m = plan_move(MoveSpec(0.59, VF, t_acc=t_acc_ms / 1e3, g0=G0))
    # Eq. 16 written out independently
    a_max = math.pi * G0 / (2 * t_acc_ms / 1e3)
    assert m.a_max == pytest.approx(a_max, rel=1e-12)
    assert m.j_max == pytest.approx((math.pi * G0 / (t_acc_ms / 1e3)) ** 2 / (2 * VF), rel=1e-12)
    assert m.ramp_time == pytest.approx(t_acc_ms / 1e3 * VF / G0, rel=1e-12)
    # the paper rounds its printed values loosely (1370.7 -> 1370, 123.4 -> 124, 54.8 -> 54)
    assert m.j_max == pytest.approx(paper_jmax, rel=0.02)


def test_derivatives_match_numerical_and_eq15():
    m = plan_move(MoveSpec(0.1, 7 / 60, t_acc=0.2, g0=G0), start=0.02)
    t = np.linspace(0, m.duration, 200001)
    x, v, a, j = m.position(t), m.velocity(t), m.acceleration(t), m.jerk(t)
    assert np.max(np.abs(np.gradient(x, t) - v)) < 1e-6 * m.peak_speed
    assert np.max(np.abs(np.gradient(v, t) - a)) < 1e-3 * m.a_max
    # the jerk of a sine-square profile steps at the phase boundaries: leave those instants out
    edges = np.array([0.0, m.ramp_time, m.ramp_time + m.cruise_time, m.duration])
    inner = np.min(np.abs(t[:, None] - edges[None, :]), axis=1) > 1e-4
    assert np.max(np.abs(np.gradient(a, t) - j)[inner]) < 2e-3 * m.j_max
    # Eq. 15 during the ramp: a(t) = pi G0/(2 t_acc) sin(pi G0 t/(V_f t_acc))
    tr = t[t < m.ramp_time]
    vf = 7 / 60
    assert np.allclose(m.acceleration(tr), math.pi * G0 / 0.4 * np.sin(math.pi * G0 * tr / (vf * 0.2)), atol=1e-9)
    assert np.allclose(m.jerk(tr), (math.pi * G0 / 0.2) ** 2 / (2 * vf) * np.cos(math.pi * G0 * tr / (vf * 0.2)),
                       atol=1e-6)
    assert x[0] == pytest.approx(0.02) and x[-1] == pytest.approx(0.12, abs=1e-15)
    assert m.position(m.duration + 5) == pytest.approx(0.12)


def test_short_stroke_keeps_the_given_quantity():
    # a_max given (by t_acc): the peak speed falls, a_max stays
    long = plan_move(MoveSpec(1.0, VF, t_acc=0.1, g0=G0))
    short = plan_move(MoveSpec(0.005, VF, t_acc=0.1, g0=G0))
    assert short.reduced and not long.reduced
    assert short.a_max == pytest.approx(long.a_max)
    assert short.peak_speed < VF and short.cruise_time == 0.0
    assert short.position(short.duration) == pytest.approx(0.005, rel=1e-12)
    # j_max given: j_max stays
    sj = plan_move(MoveSpec(-0.005, VF, j_max=100.0))
    assert sj.reduced and sj.j_max == pytest.approx(100.0)
    assert sj.position(sj.duration) == pytest.approx(-0.005, rel=1e-12)
    assert np.all(sj.velocity(np.linspace(0, sj.duration, 101)) <= 0)


def test_sequence_with_dwells_and_return():
    traj = Trajectory(start=0.1)
    traj.move(MoveSpec(0.05, 0.1, a_max=2.0))
    traj.dwell(0.5)
    traj.move(MoveSpec(-0.05, 0.1, a_max=2.0))
    t, x = traj.sample(0.004, settle=0.2)
    m1 = traj.moves[0]
    assert x[0] == pytest.approx(0.1)
    in_dwell = (t > m1.duration + 1e-9) & (t < m1.duration + 0.5)
    assert np.allclose(x[in_dwell], 0.15)
    assert x[-1] == pytest.approx(0.1)
    assert t[1] - t[0] == pytest.approx(0.004)
    assert t[-1] >= traj.duration + 0.2 - 1e-9


LIM = AxisLimits(-1.0, 1.0, 0.5, 20.0, 5000.0)


def test_limit_refusals_say_which_by_how_much_and_what_fits():
    traj = Trajectory()
    traj.move(MoveSpec(0.1, 0.25, t_acc=0.02, g0=G0))    # a_max 39.3 m/s^2, j_max 12337 m/s^3
    with pytest.raises(LimitError) as exc:
        check_limits(traj, LIM)
    msg = str(exc.value)
    assert "acceleration 39.27 m/s^2 exceeds limits.acceleration 20 m/s^2 by 96.3 %" in msg
    assert "t_acc >= 39.3 ms would fit" in msg
    assert "jerk 1.234e+04 m/s^3 exceeds limits.jerk 5000 m/s^3" in msg
    # what the message proposes does fit
    ok = Trajectory()
    ok.move(MoveSpec(0.1, 0.25, t_acc=0.0394, g0=G0))
    t_jerk = float(msg.split("t_acc >= ")[2].split(" ms")[0]) / 1e3
    ok2 = Trajectory()
    ok2.move(MoveSpec(0.1, 0.25, t_acc=max(t_jerk, 0.0394) + 1e-4, g0=G0))
    check_limits(ok2, LIM)


def test_travel_and_speed_refusals():
    traj = Trajectory(start=0.9)
    traj.move(MoveSpec(0.2, 0.6, a_max=5.0))
    with pytest.raises(LimitError) as exc:
        check_limits(traj, LIM)
    msg = str(exc.value)
    assert "end position 1100.000 mm is beyond limits.travel_max 1000.000 mm by 100.000 mm" in msg
    assert "a stroke of at most 100.000 mm from 900.000 mm would fit" in msg
    assert "speed 0.6 m/s exceeds limits.speed 0.5 m/s by 20.0 %" in msg
    assert "a feed of at most 30000 mm/min" in msg


def test_movespec_needs_exactly_one_rate():
    with pytest.raises(ValueError, match="exactly one of t_acc, a_max, j_max"):
        MoveSpec(0.1, 0.1, a_max=1.0, j_max=10.0)
    with pytest.raises(ValueError, match="t_acc needs the rapid speed g0"):
        MoveSpec(0.1, 0.1, t_acc=0.1)
