"""The live scope's ring buffer (issue 27): wraparound, a consistent window under a writer thread,
no allocation in the cycle's write, and a loop whose numbers do not change with a scope attached."""
import threading
import time
import tracemalloc

import numpy as np
import pytest
from fault_backends import FaultyPlant

from drivers.sim import SimulatedPlant
from hil.io.measurement import read
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory
from hil.runtime import run_trajectory
from hil.scope.ring import SCOPE_CHANNELS, STATES, ScopeRing, feed


def _row(k):
    # every channel a function of the row index: a window is consistent when each row is one k's
    return (k * 1e-3, float(k), 2.0 * k, 3.0 * k, 4.0 * k, 5.0 * k, 6.0 * k, 7.0 * k, 8.0 * k)


def test_wraparound_keeps_the_newest_rows_in_order():
    ring = ScopeRing(capacity=7)
    for k in range(23):
        ring.write(*_row(k))
    first, rows = ring.window()
    # capacity - 1 rows: the oldest slot is the one the writer fills next (the seqlock drops it)
    assert first == 23 - 6 and rows.shape == (6, len(SCOPE_CHANNELS))
    assert rows[:, 1].tolist() == list(range(17, 23))
    first, rows = ring.window(since=20)
    assert first == 20 and rows[:, 1].tolist() == [20, 21, 22]
    first, rows = ring.window(most=2)
    assert first == 21 and rows[:, 1].tolist() == [21, 22]
    assert ring.window(since=23)[1].shape == (0, len(SCOPE_CHANNELS))


def test_a_window_is_consistent_while_a_thread_writes():
    """A writer thread laps a small ring many times while the reader copies windows: every row
    returned is whole (all its channels of one write) and the rows are contiguous."""
    ring = ScopeRing(capacity=64)
    done = threading.Event()

    def writer():
        k = 0
        while not done.is_set():
            ring.write(*_row(k))
            k += 1

    th = threading.Thread(target=writer)
    th.start()
    checked, windows = 0, 0
    # until the writer has lapped the ring many times, however the interpreter shares its lock between
    # the two threads (a fixed count of windows let a busy machine's writer lap it only 9 times)
    deadline = time.monotonic() + 60.0
    try:
        while (windows < 3000 or ring.count <= 64 * 10) and time.monotonic() < deadline:
            windows += 1
            first, rows = ring.window()
            if rows.shape[0] == 0:
                continue
            k = rows[:, 1]
            assert np.array_equal(k, np.arange(first, first + k.size)), "rows not contiguous"
            for c in range(2, 9):
                assert np.array_equal(rows[:, c], c * k), f"a half-written row in channel {SCOPE_CHANNELS[c]}"
            checked += k.size
    finally:
        done.set()
        th.join()
    assert ring.count > 64 * 10          # the writer lapped the ring many times meanwhile
    assert checked > 0


def test_the_write_allocates_nothing():
    """tracemalloc over 10000 writes: the memory held by what the ring's module allocated does not
    grow (the row goes into the preallocated array), and 20000 writes hold no more than 10000.
    Only the traces of ``hil/scope/ring.py`` count: a thread another test left running (the whole
    suite shares the process) allocates meanwhile, which a total would add in."""
    import hil.scope.ring as ring_module

    ring = ScopeRing(capacity=1000)
    values = [float(v) for v in _row(1)]
    ring.write(*values)
    ours = [tracemalloc.Filter(True, ring_module.__file__)]

    def held(n):
        tracemalloc.start()
        try:
            before = tracemalloc.take_snapshot().filter_traces(ours)
            for _ in range(n):
                ring.write(*values)
            after = tracemalloc.take_snapshot().filter_traces(ours)
        finally:
            tracemalloc.stop()
        return sum(d.size_diff for d in after.compare_to(before, "filename"))

    assert held(10000) < 256 and held(20000) < 256


def test_events_and_state():
    ring = ScopeRing(capacity=8, events=2)
    ring.write(*_row(0))
    ring.event(0.0, "start")
    ring.write(*_row(1))
    ring.event(1e-3, "trip", "following error 2.1 mm > 1 mm")
    ring.write(*_row(2))
    nxt, ev = ring.events()
    assert nxt == 2 and ev == [(0, 0.0, "start", ""), (1, 1e-3, "trip", "following error 2.1 mm > 1 mm")]
    assert ring.window()[1][:, -1].tolist() == [0.0, 0.0, STATES["tripped"]]
    ring.event(2e-3, "complete")                 # two kept: the oldest is gone
    assert [e[2] for e in ring.events()[1]] == ["trip", "complete"]


def _move():
    traj = Trajectory()
    traj.move(MoveSpec(0.01, 0.1, a_max=3.0))
    traj.dwell(0.05)
    return traj


@pytest.mark.parametrize("closes", ["velocity", "none"])
def test_the_loop_records_the_same_with_a_scope(bench, tmp_path, closes):
    """Cycle by cycle on the simulated plant: the record is bit-identical with and without the
    ring attached, and the ring holds the record's rows."""
    paths = []
    for with_scope in (False, True):
        ring = ScopeRing() if with_scope else None
        sim = SimulatedPlant(bench, plant_from_config(bench), closes=closes)
        out = tmp_path / f"{with_scope}.csv"
        rec = run_trajectory(bench, _move(), backend=sim, out_file=out, settle=0.1, scope=ring)
        assert rec.status == "complete"
        paths.append(out)
    data = [p.read_text().splitlines() for p in paths]
    body = [[ln for ln in d if not ln.startswith("#")] for d in data]
    assert body[0] == body[1] and len(body[0]) > 50
    assert data[0] == data[1]                   # the header too: bit-identical files
    m = read(paths[1])
    first, rows = ring.window()
    assert first == 0 and rows.shape[0] == len(m)
    ix = SCOPE_CHANNELS.index
    np.testing.assert_allclose(rows[:, ix("x_table")], m["x_table"], rtol=1e-9, atol=1e-15)  # the file: 10 digits
    np.testing.assert_allclose(rows[:, ix("e_table")], m["e_table"], rtol=1e-9, atol=1e-15)  # the file: 10 digits
    np.testing.assert_allclose(rows[:, ix("output")], m["torque"], rtol=1e-9, atol=1e-12)
    assert ring.events()[1][-1][2] == "complete"


def test_a_trip_is_an_event_with_its_reason(bench):
    ring = ScopeRing()
    backend = FaultyPlant(bench, at=64 * 20 + 6, reason="drive fault 0x2310 (over-current)")
    rec = run_trajectory(bench, _move(), backend=backend, settle=0.1, scope=ring)
    assert rec.status == "tripped"
    _, events = ring.events()
    assert len(events) == 1
    row, t, kind, reason = events[0]
    assert kind == "trip" and "0x2310" in reason
    # the trip is at the last row written, the rows before it kept
    assert row == ring.count - 1 and t == pytest.approx(ring.window()[1][-1, 0])
    assert ring.count >= 20


def test_the_dry_run_feeds_the_record_unchanged(bench, tmp_path):
    """The dry run (compiled at once) writes the same record with a scope, and the ring gets its
    rows; with realtime the rows come at the run's pace."""
    import time
    ring = ScopeRing()
    a = run_trajectory(bench, _move(), out_file=tmp_path / "a.csv", settle=0.1)
    t0 = time.perf_counter()
    b = run_trajectory(bench, _move(), out_file=tmp_path / "b.csv", settle=0.1, scope=ring, realtime=True)
    took = time.perf_counter() - t0
    lines = [[ln for ln in (tmp_path / n).read_text().splitlines() if not ln.startswith("#")] for n in ("a.csv", "b.csv")]
    assert lines[0] == lines[1]
    duration = b["t"][-1] - b["t"][0]
    assert took >= duration * 0.95, (took, duration)
    _, rows = ring.window()
    np.testing.assert_array_equal(rows[:, SCOPE_CHANNELS.index("x_tip")], a["x_tip"])


def test_feed_paces_and_stops():
    ring = ScopeRing()
    t = np.arange(100) * 1e-3
    ch = {n: t * 0 + i for i, n in enumerate(["x_cmd", "x_motor", "x_table", "x_tip", "e_table", "e_tip", "torque"])}
    ch["t"] = t
    stop = threading.Event()
    stop.set()
    assert feed(ring, ch, stop=stop) == 0 and ring.count == 0
    assert feed(ring, ch, pace=None, status="tripped", reason="limit") == 100
    assert ring.events()[1] == [(99, pytest.approx(0.099), "trip", "limit")]
