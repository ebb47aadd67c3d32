"""The kind of a backend's fault is set where the backend decides it (issue 28 follow-up): the CANopen
and serial backends put it in ``Feedback.fault_kind`` and ``BackendFault.kind``, and nothing reads it
back from the reason's words (a fault without a kind takes the default of where it stops the run).

Against the simulated drives: the lockstep CANopen rig on a private python-can virtual channel, the
simulated serial drive on a pseudo-terminal."""
from __future__ import annotations

import sys

import pytest
from canopen_rig import rig

from drivers.base import BackendFault, Fault, Setpoint, fault_kind
from drivers.control import controller_from_config
from hil import config
from hil.errors import RunStatus, StopKind
from hil.loop import ControlLoop
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory
from hil.supervisor import Supervisor

BENCH = "config/paper_bench.toml"
SERIAL = "config/serial_ascii_example.toml"
linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pseudo-terminals: Linux")


def test_a_fault_without_a_kind_takes_the_default_whatever_its_words(tmp_path):
    """The words "drive fault" / "lost communication" of a reason say nothing about the kind: a
    backend that reports a fault without one gets the default of where the run stops (a trip for a
    Feedback.fault, the link for a setpoint not delivered)."""
    from fault_backends import FaultyPlant
    assert fault_kind(None, StopKind.TRIP) is StopKind.TRIP
    assert fault_kind(StopKind.DRIVE_FAULT, StopKind.LINK) is StopKind.DRIVE_FAULT
    cfg = config.load(BENCH)
    tr = Trajectory(start=0.0)
    tr.move(MoveSpec(stroke=0.002, feed=0.1, a_max=1.0))
    x = tr.sample(cfg["control.position_period"], 0.0)[1]
    for reason, raises, ends in (("drive fault: overcurrent", False, (RunStatus.TRIPPED, StopKind.TRIP)),
                                 ("lost communication: port", True, (RunStatus.FAULT, StopKind.LINK)),
                                 ("drive fault: overcurrent", True, (RunStatus.FAULT, StopKind.LINK))):
        be = FaultyPlant(cfg, at=20, reason=reason, raises=raises, kind=None)
        sup = Supervisor(cfg, latch_file=str(tmp_path / f"{reason}{raises}.json"))
        res = ControlLoop(be, controller_from_config(cfg, be.sim.plant), supervisor=sup).run(x)
        assert (res.status, res.stop, sup.trip_kind) == (*ends, ends[1]), reason


def _canopen_fault(fault, value, **ov):
    """The lockstep rig: enabled, a few clean cycles, then ``fault`` injected; the first feedback
    that reports a fault."""
    cfg, sim, be = rig("csp", prefix="fk", **ov)
    try:
        be.open()
        be.enable()
        for k in range(40):
            if k == 5:
                sim.inject(fault, value)
            fb = be.read_feedback()
            if fb.fault:
                return fb
            be.write_setpoint(Setpoint(position=fb.x_motor))
            be.sync()
        raise AssertionError(f"{fault}: no fault reported")
    finally:
        be.close()
        sim.close()


@pytest.mark.parametrize("fault,value,words,kind", [
    ("emcy", 0x2310, "drive fault: EMCY 0x2310", StopKind.DRIVE_FAULT),
    ("missing_pdo", 5, "lost communication: no TPDO from the drive", StopKind.LINK),
])
def test_the_canopen_backend_says_the_kind_of_its_feedback_fault(fault, value, words, kind):
    fb = _canopen_fault(fault, value)
    assert fb.reason.startswith(words) and fb.fault_kind is kind


def test_the_canopen_backend_reports_no_kind_while_well():
    cfg, sim, be = rig("csp", prefix="fk")
    try:
        be.open()
        be.enable()
        for _ in range(5):
            fb = be.read_feedback()
            be.write_setpoint(Setpoint(position=fb.x_motor))
            be.sync()
        assert (fb.fault, fb.reason, fb.fault_kind) == (Fault.NONE, "", None)
    finally:
        be.close()
        sim.close()


def test_a_frame_the_bus_refuses_is_a_link_fault():
    """The setpoint that cannot be sent (the bus gone) raises BackendFault of the link's kind."""
    import can
    cfg, sim, be = rig("csp", prefix="fk")
    try:
        be.open()
        be.enable()
        fb = be.read_feedback()
        be.write_setpoint(Setpoint(position=fb.x_motor))

        def refuse(*a, **k):
            raise can.CanOperationError("bus off")
        be.link.network.send_message = refuse
        with pytest.raises(BackendFault) as err:
            be.sync()
        assert err.value.kind is StopKind.LINK and err.value.reason.startswith("lost communication")
    finally:
        be.close()
        sim.close()


@linux
@pytest.mark.parametrize("fault,words,kind", [
    ("drive_fault", "drive fault 2", StopKind.DRIVE_FAULT),
    ("timeout", "lost communication: serial read: timeout", StopKind.LINK),
])
def test_the_serial_backend_says_the_kind_of_its_feedback_fault(fault, words, kind):
    from drivers.serial.backend import SerialBackend
    from drivers.serial.drive_sim import SimulatedSerialDrive
    cfg = config.load(SERIAL)
    with SimulatedSerialDrive(cfg, plant_from_config(cfg)) as drive:
        drive.inject(fault, count=10, after=6, op="read")
        with SerialBackend(cfg, port=drive.port, timeout=0.03, budget=0.1, retries=2, free_run=True) as b:
            b.enable()
            for _ in range(40):
                fb = b.read_feedback()
                if fb.fault:
                    break
                b.write_setpoint(Setpoint(position=fb.x_motor))
            assert fb.reason.startswith(words) and fb.fault_kind is kind, fb.reason


@linux
def test_the_serial_drive_refusing_a_setpoint_is_a_drive_fault():
    from drivers.serial.backend import SerialBackend
    from drivers.serial.drive_sim import SimulatedSerialDrive
    cfg = config.load(SERIAL)
    with SimulatedSerialDrive(cfg, plant_from_config(cfg)) as drive:
        drive.inject("refuse", count=10, after=0, op="set_position")
        with SerialBackend(cfg, port=drive.port, timeout=0.03, budget=0.1, retries=2, free_run=True) as b:
            b.enable()
            fb = b.read_feedback()
            with pytest.raises(BackendFault) as err:
                b.write_setpoint(Setpoint(position=fb.x_motor))
            assert err.value.kind is StopKind.DRIVE_FAULT and err.value.reason.startswith("drive fault"), \
                err.value.reason


def test_supervisor_trip_takes_the_kind_the_feedback_carries(tmp_path):
    from drivers.base import Feedback
    sup = Supervisor(config.load(BENCH), latch_file=str(tmp_path / "latch.json"))
    fb = Feedback(0.0, 0.0, 0.0, fault=Fault.OTHER, reason="drive fault: overcurrent")       # no kind: the default, a trip
    assert sup.check(0.0, fb, 0.0) and sup.trip_kind is StopKind.TRIP
