"""Explicit state of the CANopen backend (issue 28, item 7): the CAN trace is an option of the
backend passed through ``open_backend`` (no process-wide request), the thread switch interval a
real-time open lowers is put back at ``shutdown()`` (twice is safe), and python-can's logging
filter is installed when a backend opens, not when its module is imported."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import can
import pytest
from canopen_rig import channel

import hil
from drivers.canopen import canlog
from hil import config
from hil.backends import open_backend
from hil.plant_config import plant_from_config

CANOPEN = "config/paper_bench_canopen.toml"


def test_the_can_trace_goes_through_open_backend_to_the_canopen_backend_only(tmp_path):
    from drivers.canopen.drive_sim import DriveSim
    trace = tmp_path / "bus.asc"
    ch = channel("trace")
    cfg = config.load(CANOPEN, {"canopen.lockstep": True})
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    try:
        be = open_backend(cfg, "canopen", can_log=str(trace), bus=can.Bus(interface="virtual", channel=ch))
        with be:
            be.enable()
            for _ in range(5):
                be.read_feedback()
                be.sync()
        assert be.link.can_log == str(trace)
    finally:
        sim.close()
    frames = list(can.ASCReader(str(trace)))
    assert sum(1 for m in frames if m.arbitration_id == 0x80) >= 5
    # the simulated plant takes no trace: the option is ignored there, never an error
    assert open_backend(config.load("config/paper_bench.toml"), "sim", can_log=str(trace)).name == "sim"
    assert not hasattr(canlog, "_requested")       # no process-wide request left to leak into the next run


def test_a_real_time_open_restores_the_switch_interval_at_shutdown():
    ch = channel("swi")
    cfg = config.load(CANOPEN, {"canopen.interface": "virtual", "canopen.channel": ch,
                                "canopen.sdo_timeout": "5ms", "canopen.switch_interval": "50us"})
    before = sys.getswitchinterval()
    be = open_backend(cfg, "canopen")            # no drive on the channel: open fails after it lowered it
    with pytest.raises(Exception, match="does not answer SDO"):
        be.open()
    assert sys.getswitchinterval() == pytest.approx(5e-5)
    be.shutdown()
    assert sys.getswitchinterval() == before
    be.shutdown()                                # safe twice: nothing changes
    assert sys.getswitchinterval() == before


def test_importing_the_backend_leaves_python_cans_logging_alone():
    code = ("import logging, can; import drivers.canopen.backend as b; "
            "f = logging.getLogger('can.broadcastmanager').filters; print(len(f)); "
            "from drivers.canopen.link import quiet_periodic_send_errors as q; q(); q(); "
            "print(len(logging.getLogger('can.broadcastmanager').filters))")
    root = str(Path(hil.__file__).parents[1])      # the hil under test ("-c" puts the working directory first)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=root,
                         env={**os.environ, "PYTHONPATH": root})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["0", "1"]


def test_the_backends_parts_are_short_and_say_whether_they_run_in_the_cycle():
    """No function of the CANopen and serial backends (and their simulated drives) over 80 lines;
    every method of the backends' contract says in its docstring whether it is real-time."""
    import ast
    import inspect

    import drivers as drivers_package
    from drivers.canopen.backend import CanopenBackend
    from drivers.serial.backend import SerialBackend
    drivers = Path(drivers_package.__file__).parent
    long = []
    for path in [*drivers.glob("canopen/*.py"), *drivers.glob("serial/*.py"), drivers / "rt.py"]:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and node.end_lineno - node.lineno + 1 > 80:
                long.append(f"{path.name}:{node.name}")
    assert long == []
    contract = ("open", "enable", "read_feedback", "write_setpoint", "quick_stop", "disable", "close")
    for cls in (CanopenBackend, SerialBackend):
        unmarked = [m for m in contract + ("sync",) if m in vars(cls)
                    and "real-time" not in (inspect.getdoc(getattr(cls, m)) or "")]
        assert unmarked == [], (cls.__name__, unmarked)


def test_the_state_is_read_again_after_an_answer_meant_for_another_sdo_client():
    """Two clients on the drive's one SDO server channel (hil status beside a move) each hear the
    other's answers; an upload that takes the other's download answer ("Unexpected response
    0x60") is read again, and a channel that keeps failing still says so."""
    from types import SimpleNamespace

    import canopen

    from drivers.canopen import cia402
    from drivers.canopen.statemachine import DriveStateMachine

    class Statusword:
        def __init__(self, failures):
            self.failures, self.reads = failures, 0

        @property
        def raw(self):
            self.reads += 1
            if self.reads <= self.failures:
                raise canopen.SdoCommunicationError("Unexpected response 0x60")
            return cia402.statusword_for("OPERATION ENABLED")

    def machine(failures):
        word = Statusword(failures)
        be = SimpleNamespace(link=SimpleNamespace(stop_cycling=lambda: None), node=SimpleNamespace(sdo={0x6041: word}))
        return DriveStateMachine(be), word
    m, word = machine(1)
    assert m.state() == "OPERATION ENABLED" and word.reads == 2
    m, word = machine(3)
    with pytest.raises(canopen.SdoCommunicationError):
        m.state()
    assert word.reads == 3
