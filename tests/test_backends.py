"""What every backend shares (drivers.base): the lifecycle's end (``shutdown``, safe twice, never
raising; the context manager), the one fault rule of the cycle (a serial in-cycle fault and a
CANopen one end a ``hil move`` the same way), and configuration mistakes named as such (one line,
exit 2), never as drive faults."""
from __future__ import annotations

import json
import logging
import sys

import can
import pytest
from canopen_rig import channel, rig
from fault_backends import FaultyPlant

from drivers.base import Backend, Feedback
from drivers.canopen.backend import CanopenBackend
from drivers.canopen.drive_sim import DriveSim
from drivers.sim import SimulatedPlant
from hil import config
from hil.cli import main
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory
from hil.runtime import run_trajectory
from hil.supervisor import Supervisor

CANOPEN = "config/paper_bench_canopen.toml"
SERIAL = "config/serial_ascii_example.toml"
linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pseudo-terminals: Linux")


# -- shutdown ---------------------------------------------------------------------------------------
class _Recording(Backend):
    """A backend that records its calls; its disable fails as a lost link's would."""
    name = "recording"

    def __init__(self, fail_open: bool = False):
        self.calls: list[str] = []
        self.fail_open = fail_open

    def open(self):
        self.calls.append("open")
        if self.fail_open:
            raise OSError("no such device")

    def enable(self):
        self.calls.append("enable")

    def read_feedback(self):
        return Feedback(0.0, 0.0, 0.0)

    def write_setpoint(self, setpoint):
        pass

    def disable(self):
        self.calls.append("disable")
        raise OSError("link gone")

    def close(self):
        self.calls.append("close")


def test_shutdown_never_raises_logs_and_closes(caplog):
    b = _Recording()
    with caplog.at_level(logging.WARNING, logger="drivers.base"):
        b.shutdown()
        b.shutdown()                      # twice: still no exception
    assert b.calls == ["disable", "close", "disable", "close"]
    assert "disable at shutdown failed: link gone" in caplog.text


def test_context_manager_shuts_down_however_the_block_ends():
    b = _Recording()
    with pytest.raises(RuntimeError):
        with b:
            b.enable()
            raise RuntimeError("boom")
    assert b.calls == ["open", "enable", "disable", "close"]
    b = _Recording(fail_open=True)        # a start-up that fails half-way releases what it took
    with pytest.raises(OSError):
        with b:
            pass
    assert b.calls == ["open", "disable", "close"]


def test_shutdown_twice_on_the_simulated_plant(bench):
    b = SimulatedPlant(bench, plant_from_config(bench))
    with b:
        b.enable()
    assert not b.enabled
    b.shutdown()


def test_shutdown_twice_on_the_canopen_backend():
    cfg, sim, be = rig(prefix="be")
    try:
        with be:
            be.enable()
            assert sim.state == "OPERATION ENABLED"
        assert sim.state == "READY TO SWITCH ON" and sim.node.nmt.state == "PRE-OPERATIONAL"
        be.shutdown()                     # closed already: nothing goes out, nothing raises
        assert be.network is None
    finally:
        sim.close()


def test_connect_only_leaves_the_drive_alone():
    """hil status and hil reset only connect: their shutdown sends no NMT command and no disable
    (the drive may be another process's, in the middle of a move)."""
    ch = channel("be")
    cfg = config.load(CANOPEN, {"canopen.lockstep": True})
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    be = CanopenBackend(cfg, bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    observer = CanopenBackend(cfg, bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    try:
        with be:
            be.enable()
            observer.connect()
            assert observer.state() == "OPERATION ENABLED"
            observer.shutdown()
            assert sim.state == "OPERATION ENABLED" and sim.node.nmt.state == "OPERATIONAL"
        assert sim.state == "READY TO SWITCH ON"
    finally:
        sim.close()


@linux
def test_shutdown_twice_on_the_serial_backend():
    from drivers.serial.backend import SerialBackend
    from drivers.serial.drive_sim import SimulatedSerialDrive
    cfg = config.load(SERIAL)
    with SimulatedSerialDrive(cfg, plant_from_config(cfg)) as drive:
        b = SerialBackend(cfg, port=drive.port, timeout=0.03, budget=0.1, free_run=True)
        with b:
            b.enable()
            assert drive.state()["enabled"]
        commands = drive.state()["commands"]
        assert not drive.state()["enabled"]
        b.shutdown()                      # the port is not reopened to disable again
        assert drive.state()["commands"] == commands


# -- one fault rule -----------------------------------------------------------------------------------
def _inject_at_sync(sim: DriveSim, sync: int, fault: str, value) -> None:
    """The lockstep drive injects ``fault`` in its cycle ``sync`` (deterministic, any caller)."""
    cycle = sim._cycle

    def at(from_sync):
        cycle(from_sync)
        if sim.syncs == sync:
            sim.inject(fault, value)
    sim._cycle = at


def _move(args, tmp_path, capsys):
    rc = main(["move", *args, "--stroke", "5mm", "--feed", "6000mm/min", "--amax", "2m/s^2", "--dwell", "0.2s",
               "--out", str(tmp_path), "--json"])
    out = capsys.readouterr().out
    summary = json.loads(out[out.index("{"):])
    record = json.loads((tmp_path / "move.json").read_text())
    return rc, summary, record


def _canopen_move(tmp_path, capsys, fault, value):
    ch = channel("be")
    cfg = config.load(CANOPEN, {"canopen.lockstep": True, "canopen.interface": "virtual", "canopen.channel": ch})
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    _inject_at_sync(sim, 30, fault, value)
    try:
        return _move(["--config", CANOPEN, "--backend", "canopen", "--set", "canopen.lockstep=true",
                      "--set", "canopen.interface=virtual", "--set", f"canopen.channel={ch}"], tmp_path, capsys)
    finally:
        sim.close()


def _serial_move(tmp_path, capsys, kind, count):
    from drivers.serial.drive_sim import SimulatedSerialDrive
    cfg = config.load(SERIAL)
    with SimulatedSerialDrive(cfg, plant_from_config(cfg)) as drive:
        drive.inject(kind, count=count, after=30, op="read")
        return _move(["--config", SERIAL, "--backend", "serial", "--set", f'serial.port="{drive.port}"',
                      "--set", "serial.timeout=30ms", "--set", "serial.budget=100ms",
                      # the fault under test, not the host's scheduling: a loaded test machine holds the
                      # serial loop up now and then (as test_faults does)
                      "--set", "supervisor.overrun_cycles=25"], tmp_path, capsys)


@linux
@pytest.mark.parametrize("canopen_fault,serial_fault,words", [
    (("emcy", 0x2310), ("drive_fault", 1), ("drive fault", "drive fault")),
    (("missing_pdo", 5), ("timeout", 10), ("lost communication: no TPDO", "serial read: timeout")),
])
def test_in_cycle_faults_end_the_same_way_on_canopen_and_serial(tmp_path, capsys, canopen_fault, serial_fault,
                                                                 words):
    """A fault the drive reports, or a link that stops answering, in the middle of a move: on either
    backend it reaches the loop as Feedback.fault, the supervisor trips on it, the axis is stopped,
    the record is closed ``tripped`` with the fault as its reason, the trip is latched, and hil move
    exits with the code of the kind of stop: 1 for a drive fault, 4 for lost communication (issue 16:
    the exit codes tell them apart; before, both exited 1)."""
    ends = []
    for name, run, fault, word in (("canopen", _canopen_move, canopen_fault, words[0]),
                                   ("serial", _serial_move, serial_fault, words[1])):
        rc, summary, record = run(tmp_path / name, capsys, *fault)
        assert word in summary["reason"], (name, summary["reason"])
        assert record["reason"] == summary["reason"] and record["rows"] > 20
        ends.append((rc, summary["status"], record["status"]))
        # latched: the next motion command is refused until hil reset
        assert main(["status", "--config", CANOPEN, "--backend", "sim"]) == 0
        assert "TRIPPED" in capsys.readouterr().out
        assert main(["reset", "--config", CANOPEN, "--supervisor-only"]) == 0
        capsys.readouterr()
    code = 1 if canopen_fault[0] == "emcy" else 4
    assert ends[0] == ends[1] == (code, "tripped", "tripped")


def test_a_fault_between_position_ticks_trips_the_same_way(bench, tmp_path):
    traj = Trajectory()
    traj.move(MoveSpec(0.01, 0.1, a_max=3.0))
    sup = Supervisor(bench)
    be = FaultyPlant(bench, at=64 * 20 + 5)                 # a velocity cycle inside tick 20
    rec = run_trajectory(bench, traj, backend=be, out_file=tmp_path / "run.csv", settle=0.1, supervisor=sup)
    assert (rec.status, rec.reason) == ("tripped", "drive fault: overcurrent") and be.stopped
    assert sup.tripped and sup.reason == rec.reason
    assert json.loads((tmp_path / "run.json").read_text())["status"] == "tripped"


# -- configuration mistakes: one line, exit 2 ---------------------------------------------------------
def _one_line_error(capsys, argv):
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    return rc, err


@pytest.mark.parametrize("command", ["move", "status"])
def test_missing_eds_is_a_configuration_error(capsys, tmp_path, command):
    extra = ["--stroke", "1mm", "--feed", "1000mm/min", "--amax", "1m/s^2", "--out", str(tmp_path)] \
        if command == "move" else []
    rc, err = _one_line_error(capsys, [command, "--config", CANOPEN, "--set", "canopen.eds=/nonexistent.eds",
                                       *(["--backend", "canopen"] if command == "move" else []), *extra])
    assert rc == 2 and "\n" not in err
    assert err.startswith(f"hil {command}: error: {CANOPEN}: canopen.eds: ") and "/nonexistent.eds" in err
    assert "drive fault" not in err and "no CiA 402 drive" not in err


@pytest.mark.parametrize("setting,words", [
    ("serial.commands.read=R{bogus}", "serial.commands.read: unknown field {bogus}"),
    ("serial.replies.read=OK", "serial.replies.read: no (?P<x_motor>...) group"),
    ('serial.port="foo://bar"', "serial.port 'foo://bar': invalid URL"),
])
def test_bad_serial_configuration_is_a_configuration_error(capsys, tmp_path, setting, words):
    set_port = [] if setting.startswith("serial.port") else ["--set", "serial.port=/dev/null"]
    rc, err = _one_line_error(capsys, ["move", "--config", SERIAL, "--backend", "serial", *set_port,
                                       "--set", setting, "--stroke", "1mm", "--feed", "1000mm/min",
                                       "--amax", "1m/s^2", "--out", str(tmp_path)])
    assert rc == 2 and "\n" not in err
    assert err.startswith(f"hil move: error: {SERIAL}: {words}")
