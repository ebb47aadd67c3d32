"""The live scope's view rules (issue 27), on closed-form signals: a ramp crosses a level at a
known time and sample, a move starts at a known sample, the capture shows [t - pre, t + post],
cursors read a linear signal exactly, the CSV gives back the numbers, and one ring shows two
runs on one time axis."""
import io
import math

import numpy as np
import pytest

from hil.scope.ring import SCOPE_CHANNELS, ScopeRing
from hil.scope.view import Trigger, capture, cursor_values, find_level, move_starts, view_csv

DT = 1e-3
T = np.arange(1000) * DT


@pytest.mark.parametrize("level", [0.0123, 0.5, 0.7775])
def test_a_rising_ramp_crosses_the_level_where_it_must(level):
    """y = 2 t: the crossing is at t = level / 2, between samples floor and ceil of level / (2 DT)."""
    y = 2.0 * T
    t = find_level(T, y, level, "rising")
    assert t == pytest.approx(level / 2.0, abs=1e-12)
    # the level trigger fires on the first sample at or above: the sample ceil(level / (2 DT))
    k = math.ceil(level / (2.0 * DT) - 1e-9)
    assert find_level(T, y, level, "above") == pytest.approx(T[k])
    # the falling ramp -2 t through -level, and no falling edge on a rising ramp
    assert find_level(T, -y, -level, "falling") == pytest.approx(level / 2.0, abs=1e-12)
    assert find_level(T, -y, -level, "below") == pytest.approx(T[k])
    assert find_level(T, y, level, "falling") is None


def test_edge_and_level_differ_when_the_signal_is_already_there():
    y = np.full(T.size, 5.0)
    assert find_level(T, y, 1.0, "rising") is None           # never below: no edge
    assert find_level(T, y, 1.0, "above") == T[0]            # a level: fires at once
    assert find_level(T, y, 1.0, "above", t_from=0.3) == pytest.approx(0.3)
    y[:] = np.nan
    assert find_level(T, y, 1.0, "above") is None and find_level(T, y, 1.0, "rising") is None


def test_the_search_starts_at_t_from_with_the_sample_before_as_the_edge():
    """A sine crosses 0 upwards at every whole period: from t_from the next such crossing."""
    f = 10.0
    y = np.sin(2 * np.pi * f * T - 1e-6)                      # just below 0 at each whole period
    assert find_level(T, y, 0.0, "rising", t_from=0.05) == pytest.approx(0.1, abs=1e-6)
    assert find_level(T, y, 0.0, "rising", t_from=0.1) == pytest.approx(0.1, abs=1e-6)
    assert find_level(T, y, 0.0, "falling", t_from=0.1) == pytest.approx(0.15, abs=1e-6)


def test_the_start_of_a_move():
    x = np.where(T < 0.2, 0.0, (T - 0.2) ** 2)               # at rest, then a parabola from t = 0.2
    x[600:] = x[599]                                          # stops at sample 599
    x[800:] = x[599] - (T[800:] - T[799]) * 0.1               # and moves back from sample 800
    np.testing.assert_allclose(move_starts(T, x), [0.2, T[799]])
    trig = Trigger(source="move")
    cols = {"t": T, "x_cmd": x}
    assert trig.find(cols, [], -np.inf) == pytest.approx(0.2)
    assert trig.find(cols, [], 0.3) == pytest.approx(T[799])
    assert trig.find(cols, [], 0.9) is None


def test_trip_and_channel_sources():
    trig = Trigger(source="trip")
    assert trig.find({"t": T}, [0.7, 0.4], 0.5) == 0.7 and trig.find({"t": T}, [0.4], 0.5) is None
    trig = Trigger(source="channel", channel="e_table", slope="rising", level=30.0)
    assert trig.find({"t": T, "e_table": 100.0 * T}, [], 0.0) == pytest.approx(0.3, abs=1e-12)
    assert "e_table rising through 30 um" in trig.describe("um")


def test_the_capture_is_the_window_around_the_trigger():
    rows = np.column_stack([T] + [T * (i + 1) for i in range(len(SCOPE_CHANNELS) - 1)])
    got = capture(rows, 0.5, 0.1, 0.05, max_points=2000)
    assert got[0, 0] == pytest.approx(0.4) and got[-1, 0] == pytest.approx(0.55) and got.shape[0] == 151
    # decimated to at most 40 points, the trigger's sample among them
    got = capture(rows, 0.5003, 0.2, 0.2, max_points=40)
    assert got.shape[0] <= 40 and np.any(np.isclose(got[:, 0], 0.5)) and np.all(np.diff(got[:, 0]) > 0)
    assert got[0, 0] >= 0.3003 - 1e-12 and got[-1, 0] <= 0.7003 + 1e-12


def test_cursors_read_a_linear_signal_exactly():
    cols = {"t": T, "x_table": 3.0 * T + 1.0, "e_tip": np.sin(T)}
    (n, a, b, d), (_, sa, sb, _) = cursor_values(cols, ["x_table", "e_tip"], 0.1234, 0.5678)
    assert n == "x_table" and a == pytest.approx(1.3702) and b == pytest.approx(2.7034)
    assert d == pytest.approx(3.0 * (0.5678 - 0.1234))
    assert sa == pytest.approx(math.sin(0.1234), abs=1e-7) and sb == pytest.approx(math.sin(0.5678), abs=1e-7)
    assert math.isnan(cursor_values(cols, ["x_table"], 2.0, 0.1)[0][1])       # after the last sample


def test_the_csv_gives_back_the_rows_in_view():
    cols = {"t": T, "x_table": 3.0 * T + 1.0, "e_tip": np.sin(T) / 3.0}
    text = view_csv(cols, {"x_table": "mm", "e_tip": "um"}, 0.25, 0.5)
    assert text.splitlines()[0] == "t [s],x_table [mm],e_tip [um]"
    data = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1)
    keep = (T >= 0.25) & (T <= 0.5)
    np.testing.assert_array_equal(data[:, 0], T[keep])
    np.testing.assert_array_equal(data[:, 2], cols["e_tip"][keep])       # repr: every digit


def test_one_ring_shows_consecutive_runs_on_one_time_axis():
    """A sweep's runs each start their clock at 0: the second run goes on one period after the
    first, its events too."""
    ring = ScopeRing(capacity=64)
    for run in range(2):
        for k in range(10):
            ring.write(k * DT, 0, 0, 0, 0, 0, 0, 0, 0)
        ring.event(9 * DT, "complete")
    _, rows = ring.window()
    np.testing.assert_allclose(rows[:, 0], np.arange(20) * DT, atol=1e-15)
    assert [e[1] for e in ring.events()[1]] == pytest.approx([9 * DT, 19 * DT])
