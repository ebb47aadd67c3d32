"""The lifted closed-loop frequency response against the time-domain simulation of sinusoids."""
import numpy as np
import pytest

from hil.closed_loop import bandwidth, closed_loop_response
from hil.simulate import simulate_config


@pytest.mark.parametrize("f", [3.0, 12.0, 40.0])
def test_closed_loop_matches_simulated_sinusoid(bench, f):
    Tp = 0.004
    k = np.arange(int(6 / Tp))
    x = 1e-5 * np.sin(2 * np.pi * f * k * Tp)
    r = simulate_config(bench, x)
    sel = k * Tp > 3          # after the transient
    e = np.exp(-1j * 2 * np.pi * f * k[sel] * Tp)
    cl = closed_loop_response(bench, [f])
    for sim, model in ((r.x_table, cl.table[0]), (r.x_tip, cl.tip[0])):
        h = np.sum(sim[sel] * e) / np.sum(x[sel] * e)
        assert abs(h - model) < 5e-3 * abs(model) + 1e-3


def test_feed_forward_widens_the_band_and_tf3_narrows_it(bench):
    cl = closed_loop_response(bench)
    assert cl.stable
    b_ff, b_no = bandwidth(cl.f_hz, cl.table), bandwidth(cl.f_hz, cl.table_no_ff)
    assert b_ff > 2 * b_no
    # with Kv = 50 1/s alone the loop is about first order: -3 dB near Kv / 2 pi = 8 Hz, raised by the
    # velocity loop's dynamics; it must lie between 5 and 25 Hz
    assert 5 < b_no < 25
    # the compliant mass's resonance (~15 Hz) shows at the tip: a peak of about 1 / (2 zeta) = 30 dB
    assert 20 * np.log10(np.max(np.abs(cl.table_tf3))) > 25


def test_bandwidth_of_a_first_order_lag():
    f = np.logspace(-2, 3, 4000)
    h = 1 / (1 + 1j * f / 10.0)
    assert bandwidth(f, h) == pytest.approx(10.0, rel=1e-3)


def test_unstable_loop_configuration_is_refused_before_motion(bench, capsys):
    """The reference PI sampled at 4 ms is unstable (the CANopen issue's example); at 1 ms it is not.
    The lifted model's verdict agrees with a simulation of the same loop."""
    from hil.cli import main
    from hil.closed_loop import loop_stability
    slow = bench.with_values({"control.velocity_period": "4 ms"})
    fast = bench.with_values({"control.velocity_period": "1 ms"})
    assert loop_stability(slow)[0] is False and loop_stability(fast)[0] is True
    # the simulation of the 4 ms loop diverges from a 1 um step, the 1 ms loop settles
    x = np.full(500, 1e-6)
    x[0] = 0.0
    assert np.max(np.abs(simulate_config(slow, x).x_table[-50:])) > 1e-4     # grows to a torque-limited cycle
    assert abs(simulate_config(fast, x).x_table[-1] - 1e-6) < 1e-8
    rc = main(["move", "--config", bench.source, "--set", "control.velocity_period=4ms", "--stroke", "10mm",
               "--feed", "1m/min", "--amax", "1m/s^2"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "loop configuration refused: the model's closed loop is unstable" in err and err.count("\n") == 1
