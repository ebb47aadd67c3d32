"""One table of supervisor rules (issue 28, item 3): the per-cycle check (:class:`Supervisor`, in
the loop) and the vectorised one (:func:`check_record`, on a dry run's record) give the same
stop, the same reason and the same kind at the same cycle, on records of faults run through the
simulated backend; and the per-cycle check allocates nothing that outlives the cycle."""
import dataclasses
import tracemalloc

import numpy as np
import pytest

from drivers.base import Backend, Fault, Feedback
from drivers.control import controller_from_config
from drivers.sim import SimulatedPlant
from hil import config
from hil.errors import RunStatus, StopKind
from hil.loop import ControlLoop
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory
from hil.supervisor import RULES, Supervisor, check_record

BENCH = "config/paper_bench.toml"


class FaultyFeedback(Backend):
    """The embedded plant closing both loops (one exchange per position tick), whose readings go
    wrong from tick ``at`` on as ``fault`` says: ``stale`` (the answers stop coming in: the
    readings repeat), ``speed`` (the motor speed reads ``value`` m/s), ``jump`` (the table reading
    jumps by ``value`` m), ``torque`` (the output reads ``value``), ``tip`` (the tip reads ``value``
    m off the table). Every reading is kept in ``rows``."""
    name = "faulty-feedback"
    closes = "both"
    simulated = True

    def __init__(self, cfg, fault: str = "", at: int = 0, value: float = 0.0):
        self.sim = SimulatedPlant(cfg, plant_from_config(cfg), closes="both")
        self.cycle_time = self.sim.cycle_time
        self.fault, self.at, self.value = fault, at, value
        self.rows, self.last = [], None

    def open(self):
        pass

    def enable(self):
        self.sim.enable()

    def read_feedback(self):
        fb = self.sim.read_feedback()
        k = len(self.rows)
        if k >= self.at and self.fault:
            if self.fault == "stale":
                fb = Feedback(**{**vars(self.last), "stale": True})
            elif self.fault == "speed":
                fb.v_motor = self.value
            elif self.fault == "jump":
                fb.x_table += self.value
            elif self.fault == "torque":
                fb.output = self.value
            elif self.fault == "tip":
                fb.x_tip = fb.x_table + self.value
        if self.fault == "tip" and k < self.at:
            fb.x_tip = fb.x_table
        self.last = dataclasses.replace(fb)     # the backend's Feedback is updated in place
        self.rows.append((fb.x_motor, fb.x_table, fb.x_tip, fb.v_motor, fb.output))
        return fb

    def write_setpoint(self, sp):
        self.sim.write_setpoint(sp)

    def sync(self):
        self.sim.sync()

    def quick_stop(self):
        self.sim.disable()

    def disable(self):
        self.sim.disable()

    def close(self):
        pass


def _move(cfg, stroke=0.05, feed=0.1, back=False):
    tr = Trajectory(start=0.0)
    tr.move(MoveSpec(stroke=stroke, feed=feed, a_max=1.0))
    tr.dwell(0.1)
    return tr.sample(cfg["control.position_period"], 0.0)[1]


def _jump(cfg, at=40, size=0.004):
    x = np.zeros(120)
    x[at:] = size
    return x


def _kink(cfg, at=40):
    """a ramp that starts at full speed: an acceleration (and jerk) step, the speed within the limit"""
    T = cfg["control.position_period"]
    x = np.zeros(120)
    x[at:] = 0.1 * T * np.arange(1, 120 - at + 1)
    return x


# (name, config changes, command, fault of the feedback, tick, value, words of the reason, kind)
SCENARIOS = [
    ("following_error", {"limits.following_error_table": 20e-6}, _move, "", 0, 0.0, "following error at the table"),
    ("tip_window", {"limits.following_error_tip": 50e-6}, _move, "tip", 30, 80e-6, "following error at the tool tip"),
    ("speed_command", {}, _jump, "", 0, 0.0, "speed limit: commanded"),
    ("acceleration", {"limits.acceleration": 0.5}, _kink, "", 0, 0.0, "acceleration limit: commanded"),
    ("speed_measured", {}, _move, "speed", 25, 2.0, "speed limit: measured"),
    ("travel_table", {}, _move, "jump", 25, 5.0, "travel limit: table"),
    ("travel_command", {"limits.travel_max": 0.03}, _move, "", 0, 0.0, "travel limit: command"),
    ("torque", {}, _move, "torque", 25, 1e4, "torque limit"),
    ("stale", {"supervisor.frozen_cycles": 5}, _move, "stale", 30, 0.0, "position feedback frozen for 5 cycles"),
]


def _cfg(changes):
    return config.load(BENCH).with_values(changes)


def _run(cfg, x, fault, at, value, supervisor=None):
    be = FaultyFeedback(cfg, fault, at, value)
    be.sim.home_at(x[0])
    be.enable()
    ctrl = controller_from_config(cfg, be.sim.plant)
    res = ControlLoop(be, ctrl, supervisor=supervisor).run(x)
    return be, res


@pytest.mark.parametrize("name,changes,command,fault,at,value,words", SCENARIOS, ids=[s[0] for s in SCENARIOS])
def test_per_cycle_and_record_rules_agree_on_recorded_faults(tmp_path, name, changes, command, fault, at, value,
                                                               words):
    """The fault run without the supervisor makes the whole record; the loop with the supervisor
    (per cycle) and check_record on that record (vectorised) stop at the same tick, with the same
    reason and kind; the supervisor stepped through the record by hand agrees with both."""
    cfg = _cfg(changes)
    x = command(cfg)
    be, res = _run(cfg, x, fault, at, value)
    assert res.status == RunStatus.COMPLETE and res.stop is StopKind.COMPLETE
    xm, xt, tip, v, out = (np.array(c) for c in zip(*be.rows))
    ch = {"x_cmd": x, "x_table": xt, "x_motor": xm, "x_tip": tip, "torque": out}
    trip = check_record(cfg, ch, v_motor=v)
    assert trip is not None and words in trip.reason, (name, trip)
    assert trip.kind is StopKind.TRIP
    # the same readings through the per-cycle check, tick by tick
    T = cfg["control.position_period"]
    sup = Supervisor(cfg, latch_file=str(tmp_path / "step.json"))
    nxt = np.append(x, x[-1])
    for k in range(x.size):
        fb = Feedback(x_motor=xm[k], x_table=xt[k], x_tip=tip[k], v_motor=v[k], output=out[k])
        r = sup.check(k * T, fb, x[k]) or sup.check_setpoint(k * T, nxt[k + 1])
        if r:
            break
    assert (k, r, sup.trip_kind) == tuple(trip), name
    # and in the loop: the run with the supervisor stops at that tick, for that reason
    sup = Supervisor(cfg, latch_file=str(tmp_path / "loop.json"))
    _, res = _run(cfg, x, fault, at, value, supervisor=sup)
    assert (res.status, res.ticks, res.reason, res.stop) == (RunStatus.TRIPPED, trip.cycle, trip.reason, trip.kind)
    assert res.stop.exit_code == 3


def test_every_rule_that_a_record_can_show_is_exercised():
    """The scenarios cover the rules on the readings and the command (the setpoint's copies of the
    command rules, the backend's fault and the real-time watchdog aside)."""
    named = {w.split(":")[0].split(" ")[0] for *_, w in SCENARIOS}
    assert {"following", "speed", "acceleration", "travel", "torque", "position"} <= named
    assert [r.name for r in RULES][:2] == ["fault", "overrun"]
    assert [r.kind for r in RULES][:2] == [None, StopKind.OVERRUN]


def test_a_reported_fault_carries_its_kind_to_the_exit_code(tmp_path):
    """A drive fault the backend reports (Feedback.fault) trips with its kind: the kind is carried,
    not read back from the reason by the command."""
    from fault_backends import FaultyPlant
    cfg = config.load(BENCH)
    x = _move(cfg)
    for reason, kind in (("drive fault: overcurrent", StopKind.DRIVE_FAULT), ("lost communication: port", StopKind.LINK)):
        be = FaultyPlant(cfg, at=20, reason=reason, kind=kind)
        ctrl = controller_from_config(cfg, be.sim.plant)
        sup = Supervisor(cfg, latch_file=str(tmp_path / f"{kind}.json"))
        res = ControlLoop(be, ctrl, supervisor=sup).run(x)
        assert (res.status, res.stop, sup.trip_kind) == (RunStatus.TRIPPED, kind, kind)
    # the kind the backend says, whatever the words
    fb = Feedback(0.0, 0.0, 0.0, fault=Fault.LINK, reason="drive fault: bus off")
    sup = Supervisor(cfg, latch_file=str(tmp_path / "said.json"))
    assert sup.check(0.0, fb, 0.0) == "drive fault: bus off" and sup.trip_kind is StopKind.LINK


def test_the_per_cycle_check_allocates_nothing_that_lives_on(tmp_path):
    """Per cycle the check and the setpoint check leave nothing behind (the history is a ring
    written in place) and build no containers: the peak of one cycle's allocations stays within a
    few numbers' worth (64 bytes measured: two floats alive at once; the check of before, with a
    dictionary of history and a list of commands per cycle, peaked at 272 bytes)."""
    cfg = _cfg({"limits.following_error_table": 1.0, "limits.following_error_tip": 1.0, "limits.torque": 1e6})
    T = cfg["control.position_period"]
    sup = Supervisor(cfg, latch_file=str(tmp_path / "latch.json"))
    fbs = [Feedback(x_motor=1e-6 * k, x_table=1e-6 * k, v_motor=0.0, output=1.0, x_tip=1e-6 * k) for k in range(3000)]
    xs = [1e-6 * k for k in range(3001)]
    tracemalloc.start()
    try:
        for k in range(400):       # past the history's length (and the cached small ints): the ring is full
            sup.check(k * T, fbs[k], xs[k])
            sup.check_setpoint(k * T, xs[k + 1])
        before = tracemalloc.take_snapshot()
        # each cycle's peak; tracemalloc sees every thread, so a thread left running by an earlier test
        # can put a spike into any one cycle: the typical cycle (the median) is what the check costs
        peaks = np.zeros(2600)
        for k in range(400, 3000):
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
            sup.check(k * T, fbs[k], xs[k])
            sup.check_setpoint(k * T, xs[k + 1])
            peaks[k - 400] = tracemalloc.get_traced_memory()[1] - base
        after = tracemalloc.take_snapshot()
        worst = float(np.median(peaks))
    finally:
        tracemalloc.stop()
    assert not sup.tripped, sup.reason
    grown = sum(s.size_diff for s in after.compare_to(before, "filename")
                if s.traceback[0].filename.endswith("supervisor.py"))
    assert grown < 512, grown            # nothing per cycle (2 600 cycles)
    assert worst < 160, worst


def test_a_stopped_run_raises_with_the_exit_code_of_its_kind():
    """RunStopped (a sweep's run, an frf) takes its exit code from the kind it is given, whatever
    its reason says (before: read back from the reason's first words)."""
    from hil.errors import RunStopped
    for kind in StopKind:
        e = RunStopped("stopped", RunStatus.TRIPPED, "drive fault: words that no longer decide", kind)
        assert e.exit_code == kind.exit_code and e.stop is kind
    assert [k.exit_code for k in StopKind] == [0, 1, 3, 4, 5, 130]
