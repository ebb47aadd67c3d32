"""Each injected fault against the simulated CiA 402 drive on python-can's virtual bus (lockstep,
simulated time): the supervisor's reaction time in cycles, the stop, the recorded reason, the
intact recording."""
import json
import math

import pytest
from canopen_rig import rig

from drivers.base import Setpoint
from hil.io.measurement import read as read_measurement
from hil.profiles import MoveSpec, Trajectory
from hil.runtime import run_trajectory
from hil.supervisor import Supervisor, SupervisorTripped


def _rig(mode="csp", **ov):
    return rig(mode, prefix="sup", **ov)


class Injector(Supervisor):
    def __init__(self, cfg, sim, at, fault, value=None, **kw):
        super().__init__(cfg, **kw)
        self.sim, self.at, self.fault, self.value = sim, at, fault, value

    def check(self, t, fb, x_cmd):
        if self.k == self.at:
            self.sim.inject(self.fault, self.value)
        return super().check(t, fb, x_cmd)


def _traj():
    tr = Trajectory(start=0.0)
    tr.move(MoveSpec(stroke=0.05, feed=0.1, a_max=2.0))
    tr.dwell(0.1)
    return tr


AT = 20


T = 0.004
# (fault, value, words in the reason, worst-case reaction in position cycles after the injection).
# The injection happens in cycle AT after its feedback was read: the drive's answer to that cycle's
# SYNC is read in cycle AT + 1.
REACTION = {
    "emcy": 1,                                   # the next TPDO shows FAULT, the EMCY came before it
    "missing_pdo": 2,                            # canopen.pdo_miss_limit consecutive cycles without answer
    "late_pdo": 2,                               # late answers (SYNC counter echo) count as missing
    "following_error": 1,                        # the next reading is outside the window
    "frozen_encoder": 10 + 1,                    # supervisor.frozen_cycles unchanged readings after a change
    "heartbeat_loss": math.ceil(0.35 / T) + 1,   # canopen.heartbeat_timeout after the last heartbeat
}


@pytest.mark.parametrize("fault,value,word", [
    ("emcy", 0x2310, "EMCY 0x2310"),
    ("missing_pdo", 5, "lost communication: no TPDO"),
    ("late_pdo", 1.5 * T, "lost communication: no TPDO"),
    ("following_error", 0.03, "following error at the table"),
    ("frozen_encoder", None, "frozen"),
    ("heartbeat_loss", None, "heartbeat lost"),
])
def test_fault_trips_and_stops(tmp_path, fault, value, word):
    cfg, sim, be = _rig()
    sup = Injector(cfg, sim, AT, fault, value)
    out = tmp_path / "run.csv"
    try:
        rec = run_trajectory(cfg, _traj(), backend=be, out_file=out, settle=0.0, supervisor=sup)
    finally:
        sim.close()
    assert rec.status == "tripped", (rec.status, rec.reason)
    assert word in rec.reason and rec.reason == sup.reason
    reaction = sup.trip_cycle - AT
    assert 1 <= reaction <= REACTION[fault], reaction
    if fault == "late_pdo":
        assert be.late_total >= 1 and any("late TPDO" in e for e in be.events)
    # the controlled stop went out in the cycle of the detection, and the drive took it
    assert be.quick_stop_sync == sup.trip_cycle
    if fault == "emcy":
        assert sim.state == "FAULT" and sim.fault_at == AT
    else:
        assert sim.quick_stop_at is not None and sim.quick_stop_at - 1 <= sup.trip_cycle + 1
        assert sim.state == "SWITCH ON DISABLED"
    assert abs(sim.plant.x[sim.plant.plant.n]) < 1e-3           # the axis is at rest
    assert sup.record["last_cycles"] and sup.record["reason"] == sup.reason
    assert sup.record["last_cycles"][-1]["k"] == sup.trip_cycle
    # the recording is intact up to the trip and says why it ended
    m = read_measurement(out)
    assert len(m.channels["t"]) == sup.trip_cycle + 1
    assert all(math.isfinite(v) for v in m.channels["x_table"])
    status = json.loads(out.with_suffix(".json").read_text())
    assert status["status"] == "tripped" and status["reason"] == sup.reason
    assert status["rows"] == sup.trip_cycle + 1
    with pytest.raises(SupervisorTripped):
        sup.arm()
    sup.reset()
    sup.arm()


def test_drive_side_guard_stops_axis_when_host_dies():
    """The link dies mid-move: the drive's heartbeat consumer (0x1016) quick-stops it (0x6007 = 3)."""
    cfg, sim, be = _rig()
    try:
        be.open()
        be.enable()
        for _ in range(10):
            be.read_feedback()
            be.write_setpoint(Setpoint(position=0.0))
            be.sync()
        sim.plant.x[sim.plant.plant.n:] = 0.05         # moving at 50 mm/s
        sim.advance(200)                               # no SYNC, no host heartbeat for 0.8 s
        assert sim.quick_stop_at is not None
        assert (sim.quick_stop_at - 10) * T <= 0.35 + T + 0.1    # within the consumer time (+ one period)
        assert sim.state == "SWITCH ON DISABLED"
        assert abs(sim.plant.x[sim.plant.plant.n]) < 1e-3
        assert any("0x8130" in f"0x{c:04X}" for _, c in [(0, 0x8130)]) and "abort connection option 3" in \
            " ".join(e for _, e in sim.log)
    finally:
        be.close()
        sim.close()


def test_limits_refused_and_latch(tmp_path):
    cfg, sim, be = _rig()
    sim.close()
    sup = Supervisor(cfg, latch_file=str(tmp_path / "latch.json"))
    from drivers.base import Feedback
    assert sup.check(0.0, Feedback(0, 0, 0), 0.0) is None
    r = sup.check(0.004, Feedback(0, 0, 0), 1.5)
    assert r and "travel limit" in r
    assert Supervisor(cfg, latch_file=str(tmp_path / "latch.json")).tripped     # survives the process
    s2 = Supervisor(cfg, latch_file=str(tmp_path / "latch.json"))
    s2.reset()
    Supervisor(cfg, latch_file=str(tmp_path / "latch.json")).arm()
