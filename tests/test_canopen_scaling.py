"""The CANopen backend's units in one place (drivers.canopen.codec.Scaling, issue 48): each
conversion against its CiA 402 definition written out, the targets round trip to within a count,
and the torque target clamps to the 16 bits of 0x6071."""
import math

import numpy as np
import pytest

from drivers.canopen.codec import NM, PER_MILLE, Scaling

SC = Scaling(counts_per_m=1048576 * 2 / 0.01, rated=8.0, speed_scale=2 * math.pi / 0.01)


@pytest.mark.parametrize("counts", [0, 1, -1, 123456789, -2 ** 31])
def test_the_feedback_is_the_objects_in_si(counts):
    assert SC.position(counts) == counts / SC.counts_per_m
    assert SC.table(counts) == counts * 1e-9 and NM == 1e-9
    assert SC.torque(counts % 32768) == (counts % 32768) * 1e-3 * 8.0 and PER_MILLE == 1e-3


def test_the_targets_round_trip_within_a_count():
    rng = np.random.default_rng(7)
    for x in rng.uniform(-1.0, 1.0, 200):
        assert abs(SC.position(SC.position_target(x)) - x) <= 0.5 / SC.counts_per_m
    v = 0.1 * SC.speed_scale                          # 0.1 m/s in controller speed units
    assert SC.speed_target(v) == round(0.1 * SC.counts_per_m)
    assert SC.torque(SC.torque_target(3.3)) == pytest.approx(3.3, abs=0.5e-3 * 8.0)


def test_the_torque_target_holds_in_16_bits():
    assert SC.torque_target(1e9) == 32767 and SC.torque_target(-1e9) == -32768
