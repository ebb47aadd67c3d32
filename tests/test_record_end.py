"""Records without end artefacts (issue 18, item 6): a record that ends mid-motion replays
without a torque error at its last sample, and ``hil synth`` writes none into its records."""
import numpy as np
import pytest

from hil.ident.replay import Replay
from hil.ident.synth import extend_command, synthesize
from hil.io.measurement import Measurement
from hil.profiles import MoveSpec, Trajectory
from hil.simulate import simulate_config


def _long_command(bench):
    tr = Trajectory()
    tr.move(MoveSpec(0.1, 7 / 60, t_acc=0.2, g0=0.5))
    tr.dwell(0.2)
    _, x = tr.sample(bench["control.position_period"])
    return x


@pytest.mark.parametrize("cut", [100, 150, 200, 222])
def test_record_cut_mid_motion_replays_without_a_torque_spike(bench, cut):
    """The machine's record of a longer run, stopped mid-motion (the drive went on): replaying
    its first ``cut`` rows gives the same torque at every row, the last included (before: the
    held command's missing feed-forward gave a spike at the last sample)."""
    x = _long_command(bench)
    full = simulate_config(bench, x).channels()
    ch = {c: full[c][:cut].copy() for c in ("t", "x_cmd", "x_motor", "x_table", "x_tip", "torque")}
    assert abs(np.diff(ch["x_cmd"][-2:])[0]) > 1e-5          # really mid-motion
    rp = Replay(Measurement(ch, source="cut"), bench, ["torque"])
    r = rp.base_residuals["torque"]
    peak = np.max(np.abs(ch["torque"]))
    # the command extrapolated at constant acceleration: the last tick's feed-forward is the
    # machine's but for the jerk over one tick (largest at the end of the braking, cut 222)
    assert abs(r[-1]) < 2e-2 * peak
    assert np.max(np.abs(r[:-1])) < 1e-9 * peak


def test_synth_record_has_no_end_spike(bench):
    """``synthesize`` with a command ending mid-motion: its last torque sample is the one a longer
    run has there (but for the jerk over one tick), not a spike."""
    x = _long_command(bench)
    cut = 200
    quiet = dict(resolution=0.0, position_noise=0.0, force_noise=1e-30, x_cmd=x[:cut])
    ch, _ = synthesize(bench, None, **quiet)
    full = simulate_config(bench, x).channels()
    assert ch["torque"].size == cut
    assert abs(ch["torque"][-1] - full["torque"][cut - 1]) < 2e-2 * np.max(np.abs(full["torque"]))
    assert np.max(np.abs(ch["torque"][:-1] - full["torque"][:cut - 1])) < 1e-9


def test_extend_command_is_a_no_op_at_rest():
    x = np.array([0.0, 1.0, 2.0, 2.0, 2.0])
    assert extend_command(x)[-1] == 2.0
    assert extend_command(np.array([0.0, 1.0, 4.0]))[-1] == 9.0       # constant acceleration
    assert extend_command(np.array([0.0, 1.0]))[-1] == 2.0
    assert extend_command(np.array([3.0]))[-1] == 3.0
