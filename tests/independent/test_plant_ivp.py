"""The independent simulator (plant_ivp) against the project's kernel and against closed forms.

Tolerances: solve_ivp runs at rtol 1e-9, atol 1e-12 m, so a velocity period's local error is at
most about rtol |x| + atol = 1e-9 * 0.05 m + 1e-12 m = 5e-11 m on these moves; the loop corrects
what accumulates. Positions must agree with the kernel (an exact zero-order-hold discretization)
to 1e-9 m, 20 times that local bound and well below anything a convention could hide: logging the
positions one velocity period later would differ by v Tv = 0.2 m/s * 62.5 us = 12.5 um.
"""
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plant_ivp as ivp  # noqa: E402

from hil.config import load  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CFG = load(ROOT / "config" / "paper_bench.toml")
BENCH = ivp.bench_from_config(CFG)
POS_TOL = 1e-9          # m, see the module docstring


def _nominal_move(duration=0.5, stroke=0.05, v=0.2, a=6.0, start=0.05):
    t = np.arange(int(round(duration / BENCH.tp)) + 1) * BENCH.tp
    x, _ = ivp.sine_square_move(t - start, stroke, v, a)
    return x


def _kernel(cfg, x_cmd):
    from hil.simulate import simulate_config
    # the kernel runs len(x) ticks and holds the command after the last sample: give it the ticks
    # the independent run has, plus the sample after them
    return simulate_config(cfg, x_cmd).channels()


@pytest.mark.parametrize("delay_periods", [0, 4])
def test_nominal_move_agrees_with_kernel(delay_periods):
    x = _nominal_move()
    delay = delay_periods * BENCH.tv
    cfg = CFG if not delay else CFG.with_values({"effects.actuator_delay.delay": delay})
    ours = ivp.simulate(BENCH, x, ivp.Hidden(delay=delay), torque="actual")
    ker = _kernel(cfg, x)
    k = ours["t"].size
    for c in ("x_motor", "x_table", "x_tip"):
        assert np.max(np.abs(ker[c][:k] - ours[c])) < POS_TOL, c
    # the kernel logs the torque after the delay (the current at the tick)
    assert np.max(np.abs(ker["torque"][:k] - ours["torque_actual"])) < 1e-6 * np.max(np.abs(ours["torque"]))
    if delay:
        # and the command differs from it by the delay: the convention is visible in the record
        assert np.max(np.abs(ours["torque_command"] - ours["torque_actual"])) > 0.05 * np.max(np.abs(ours["torque"]))


def test_modes_of_table_2():
    # reading notes: Table 2's values give undamped modes of 14.94 Hz and 86.63 Hz (3 dof)
    pl = ivp._Plant(BENCH.changed(c=(0.0, 0.0), viscous=0.0), ivp.Hidden())
    w2 = np.sort(np.linalg.eigvals(pl.KM).real)
    f = np.sqrt(np.clip(w2, 0, None)) / (2 * math.pi)
    assert f[0] == pytest.approx(0.0, abs=1e-6)
    assert f[1] == pytest.approx(14.94, abs=0.005)
    assert f[2] == pytest.approx(86.63, abs=0.005)


def test_two_mass_free_vibration_frequency():
    # two free masses on k1, no damping, no drive: x1 - x2 oscillates at sqrt(k (m1+m2)/(m1 m2)) / 2 pi
    m1, m2, k = 335.57, 392.97, 5.362e7
    bench = BENCH.changed(m=(m1, m2), k=(k,), c=(0.0,), viscous=0.0, tip=1)
    pl = ivp._Plant(bench, ivp.Hidden())
    y = np.zeros(4)
    y[0] = 1e-6
    t_end, dt = 0.1, 1e-4
    d = []
    for i in range(int(round(t_end / dt))):
        d.append(y[0] - y[1])
        y, _ = ivp._advance(pl, y, None, i * dt, (i + 1) * dt, 0.0)
    d = np.array(d)
    t = np.arange(d.size) * dt
    s = np.nonzero(np.diff(np.sign(d)) != 0)[0]
    # zero crossings, linear between the samples
    tz = t[s] - d[s] * dt / (d[s + 1] - d[s])
    f = 0.5 / np.mean(np.diff(tz))
    assert f == pytest.approx(ivp.two_mass_frequency(m1, m2, k), rel=1e-4)


@pytest.mark.parametrize("ffv", [0.0, 0.5])
def test_following_error_of_p_loop_with_feed_forward(ffv):
    # at constant speed V the PI velocity loop tracks v_ref exactly, so kv e + ffv V = V:
    # the table lags the command by (1 - ffv) V / kv
    v = 0.2
    x = _nominal_move(duration=0.62, stroke=0.11, v=v, a=6.0, start=0.02)
    ours = ivp.simulate(BENCH.changed(ffv=ffv), x)
    t = ours["t"]
    cruise = (t > 0.45) & (t < 0.55)          # the ramp ends at 0.02 + pi v / (2 a) = 0.072 s; cruise to ~0.57 s
    e = ours["x_cmd"][cruise] - ours["x_table"][cruise]
    assert np.mean(e) == pytest.approx((1 - ffv) * v / BENCH.kv, rel=2e-3, abs=2e-8)


def test_cruise_torque_carries_friction_and_force():
    # at constant speed the motor's torque balances Coulomb and viscous friction (Eq. 11) and the
    # constant force on the table, reflected through the pitch: fc + c_v w - F / r
    v, fc, force = 0.2, 2.2, 150.0
    x = _nominal_move(duration=0.5, stroke=0.09, v=v, a=6.0, start=0.02)
    ours = ivp.simulate(BENCH, x, ivp.Hidden(coulomb_pos=fc, coulomb_neg=fc, force=force))
    t = ours["t"]
    cruise = (t > 0.3) & (t < 0.4)
    r = BENCH.r
    expected = fc + BENCH.viscous * v * r - force / r
    assert np.mean(ours["torque"][cruise]) == pytest.approx(expected, rel=2e-3)


def test_friction_holds_the_axis_at_rest():
    # a force below the break-away level (as torque on the motor) does not move a motor held by dry friction
    ours = ivp.simulate(BENCH, np.zeros(51), ivp.Hidden(coulomb_pos=2.2, coulomb_neg=2.2, force=-0.5 * 2.2 * BENCH.r))
    assert np.max(np.abs(ours["x_motor"])) < 1e-12


def test_logged_command_leads_actual_by_the_delay():
    # a delay of exactly one position period: the current at tick k is the command of tick k - 1
    x = _nominal_move(duration=0.2)
    ours = ivp.simulate(BENCH, x, ivp.Hidden(delay=BENCH.tp))
    assert np.allclose(ours["torque_actual"][1:], ours["torque_command"][:-1], rtol=0, atol=1e-12)


# (config values of the catalogue effect, the same effect in the independent simulator, position tolerance m):
# linear effects agree as the nominal move does; dry friction to the time-stepping's stop instant (the kernel
# decides sticking once a velocity period); ripple to the kernel's holding of the effect forces over a period
# (force error about A r 2 pi v Tv / P, 5e-8 m measured on this move)
EFFECT_CASES = {
    "compliant_mode": ({"effects.compliant_mode.mass": 1.0, "effects.compliant_mode.frequency": 60.0,
                        "effects.compliant_mode.damping_ratio": 0.02}, ivp.Hidden(mode=(1.0, 60.0, 0.02)), POS_TOL),
    # the catalogue's constant force acts on the motor's mass by default
    "constant_force": ({"effects.constant_force.force": 200.0}, ivp.Hidden(force=200.0, force_mass=0), POS_TOL),
    # and, placed there, on the table (gravity on an inclined axis)
    "constant_force_table": ({"effects.constant_force.force": -150.0, "effects.constant_force.place": "table"},
                             ivp.Hidden(force=-150.0, force_mass=1), POS_TOL),
    "coulomb_friction": ({"effects.coulomb_friction.level": 2.2}, ivp.Hidden(coulomb_pos=2.2, coulomb_neg=2.2), 2e-8),
    "torque_ripple": ({"effects.torque_ripple.amplitude": 0.3, "effects.torque_ripple.period": 0.01 / 6,
                       "effects.torque_ripple.phase": 0.4}, ivp.Hidden(ripple=((0.3, 0.01 / 6, 0.4),)), 2e-7),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EFFECT_CASES))
def test_effects_agree_with_kernel(name):
    vals, hidden, tol = EFFECT_CASES[name]
    x = _nominal_move()
    ours = ivp.simulate(BENCH, x, hidden)
    ker = _kernel(CFG.with_values(vals), x)
    k = ours["t"].size
    for c in ("x_motor", "x_table", "x_tip"):
        assert np.max(np.abs(ker[c][:k] - ours[c])) < tol, c


def test_backlash_agrees_with_kernel():
    # the kernel takes the dead zone's force as the mean of its values at a step's two ends: held
    # from the step's start it lagged the contact, the table 0.7 um and the tip 1.6 um off this
    # integration (which converges to 1e-9 m, rtol 1e-9 against 1e-11), above a 0.5 um encoder's
    # floor; now 13 nm and 28 nm
    x = _nominal_move()
    ours = ivp.simulate(BENCH, x, ivp.Hidden(gap=20e-6))
    ker = _kernel(CFG.with_values({"effects.backlash.gap": 20e-6}), x)
    k = ours["t"].size
    for c in ("x_motor", "x_table", "x_tip"):
        assert np.max(np.abs(ker[c][:k] - ours[c])) < 1e-7, c


def test_the_simulator_imports_nothing_of_hil():
    # independent by construction: no import of the project in the simulator (the tests fill its Bench
    # from the config reader)
    import ast
    tree = ast.parse(Path(ivp.__file__).read_text(encoding="utf-8"))
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert names and not [m for m in names if m == "hil" or m.startswith("hil.")]
