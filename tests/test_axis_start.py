"""A real axis is never surprised (issue 16): a move starts where the axis stands, a trip stays
latched until ``hil reset``, and a move planned from elsewhere is refused, never run as a jump.

The simulated CiA 402 drive in lockstep on a private virtual bus; the host through the command
line (``hil move``, ``hil status``, ``hil reset``) as a user runs it, each command a new backend
(its own start-up and shutdown) against the same drive, whose shaft stays where it stopped."""
import json

import can
import pytest
from canopen_rig import channel

from drivers.canopen.drive_sim import DriveSim
from hil import config
from hil.cli import main
from hil.io.measurement import read as read_measurement
from hil.plant_config import plant_from_config

CANOPEN = "config/paper_bench_canopen.toml"


def _arm(sim: DriveSim, after: int, fault: str, value=None) -> None:
    """``fault`` injected ``after`` SYNCs from now (the next command's cycle ``after``)."""
    cycle, at_sync = sim._cycle, sim.syncs + after

    def hooked(from_sync):
        cycle(from_sync)
        if sim.syncs == at_sync:
            sim.inject(fault, value)
            sim._cycle = cycle
    sim._cycle = hooked


@pytest.fixture
def axis():
    ch = channel("start")
    sets = ["--set", "canopen.lockstep=true", "--set", "canopen.interface=virtual", "--set", f"canopen.channel={ch}"]
    cfg = config.load(CANOPEN, {"canopen.lockstep": True, "canopen.interface": "virtual", "canopen.channel": ch})
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    try:
        yield sim, ["--config", CANOPEN, *sets]
    finally:
        sim.close()


def _move(capsys, common, out, *args):
    rc = main(["move", *common, "--backend", "canopen", "--feed", "6000mm/min", "--amax", "2m/s^2", "--dwell", "0.2s",
               "--out", str(out), "--json", *args])
    cap = capsys.readouterr()
    return rc, (json.loads(cap.out[cap.out.index("{"):]) if "{" in cap.out else None), cap.err.strip()


def test_after_a_trip_and_reset_the_next_move_starts_where_the_axis_stands(axis, capsys, tmp_path):
    sim, common = axis
    # 1. to 4.8 mm, and a drive fault in the dwell after it: a trip with the axis at 4.8 mm
    _arm(sim, 70, "emcy", 0x2310)
    rc, s, _ = _move(capsys, common, tmp_path / "a", "--stroke", "4.8mm")
    assert (rc, s["status"], s["stop"]) == (1, "tripped", "drive_fault") and s["start_m"] == 0.0
    assert s["stopped_at_s"] > 0.2                      # the move was done, the dwell not
    assert "overshoot_table_um" not in s and "settling_time_table" not in s      # no figures of an incomplete move
    # 3. latched: every motion command refused, with the trip, its time and how to clear it
    rc, s, err = _move(capsys, common, tmp_path / "c", "--stroke", "20mm")
    assert rc == 2 and s["exit_code"] == 2 and s["error"] in err and err.count("\n") == 0
    assert "supervisor tripped at " in err and "EMCY 0x2310" in err and "hil reset" in err
    assert main(["status", *common, "--json"]) == 0
    st = json.loads(capsys.readouterr().out)
    assert st["supervisor"]["tripped"] and "EMCY 0x2310" in st["supervisor"]["reason"] and st["state"] == "FAULT"
    x_stood = st["position_m"]
    assert x_stood == pytest.approx(4.8e-3, abs=20e-6)
    # 4. reset: the drive's fault and the latch
    assert main(["reset", *common]) == 0
    assert "supervisor was: tripped at" in capsys.readouterr().out
    # 5. planned from 0 mm (--start): refused, one line naming both positions; nothing moved
    rc, s, err = _move(capsys, common, tmp_path / "d", "--stroke", "20mm", "--start", "0mm")
    assert rc == 2 and s["exit_code"] == 2 and s["error"] in err and err.count("\n") == 0
    assert f"stands at {x_stood * 1e3:.3f} mm" in err and "planned from 0.000 mm" in err
    # 6. the next move starts where the axis stands, never at 0
    rc, s, _ = _move(capsys, common, tmp_path / "e", "--stroke", "20mm")
    assert rc == 0 and s["status"] == "complete"
    m = read_measurement(tmp_path / "e" / "move.csv")
    assert m["x_cmd"][0] == pytest.approx(x_stood, abs=1e-6) and s["start_m"] == pytest.approx(x_stood, abs=1e-6)
    assert abs(m["e_table"][0]) < 1e-6                  # no snap back: the first command is where it stands
    assert abs(m["e_table"]).max() < 0.2e-3             # the move's own following error, no 4.8 mm step
    assert m["x_cmd"][-1] == pytest.approx(x_stood + 20e-3, abs=1e-9)
    assert abs(m["torque"][:10]).max() < 5.0                # nowhere near the 30 N m of a 4.8 mm jump


def test_start_within_the_window_runs_from_the_measured_position(axis, capsys, tmp_path):
    sim, common = axis
    sim.home_at(0.05e-3)                         # 0.05 mm off: inside limits.start_window (0.1 mm)
    sim.advance(1)                               # one drive cycle: its position objects show it
    rc, s, _ = _move(capsys, common, tmp_path / "a", "--stroke", "2mm", "--start", "0mm")
    assert rc == 0
    m = read_measurement(tmp_path / "a" / "move.csv")
    assert m["x_cmd"][0] == pytest.approx(0.05e-3, abs=1e-6)
    rc, s, err = _move(capsys, common, tmp_path / "b", "--stroke", "2mm", "--start", "0mm",
                       "--set", "limits.start_window=1um")
    assert rc == 2 and "limits.start_window 0.001 mm" in err


def test_negative_quantities_on_the_command_line(axis, capsys, tmp_path):
    sim, common = axis
    rc, s, _ = _move(capsys, common, tmp_path / "a", "--stroke", "-0.002m")
    assert rc == 0 and s["status"] == "complete"
    assert read_measurement(tmp_path / "a" / "move.csv")["x_cmd"][-1] == pytest.approx(-2e-3, abs=1e-9)
    rc = main(["jog", *common, "--distance", "-1mm", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["start_m"] == pytest.approx(-2e-3, abs=20e-6)
    assert out["end_m"] == pytest.approx(-3e-3, abs=50e-6)


def test_a_sweep_starts_where_the_axis_stands_and_finds_it_back_before_each_run(axis):
    """The first run starts where the axis stands (3 mm here); each run's return move brings it back
    there, and the next run is refused unless it is found back there (limits.start_window)."""
    from hil.errors import UserError
    from hil.sweep.executors import BackendExecutor
    from hil.sweep.run import RunSpec
    sim, common = axis
    cfg = sim.cfg                                      # the drive's channel: every backend opened reaches it
    sim.home_at(3e-3)
    sim.advance(1)
    ex = BackendExecutor("canopen", None)
    specs = [RunSpec("mechatronic", 0.005, 0.1, None, None, j, 0.2, 1) for j in (100.0, 300.0, 1000.0)]
    _, fig = ex.one(cfg, "a", specs[0])
    assert ex.start == pytest.approx(3e-3, abs=1e-6) and fig["start_m"] == ex.start
    _, fig = ex.one(cfg, "b", specs[1])                 # back at the start: runs from there
    assert fig["start_m"] == pytest.approx(3e-3, abs=20e-6)
    sim.home_at(4e-3)                                  # someone moved the axis between the runs
    sim.advance(1)
    with pytest.raises(UserError, match=r"stands at 4\.000 mm, the run was planned from 3\.000 mm"):
        ex.one(cfg, "c", specs[2])


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="pseudo-terminals: Linux")
def test_a_serial_move_starts_where_the_last_one_left_the_axis(capsys, tmp_path):
    """The serial backend reads the position (one ``read``) before it enables the drive: a second
    10 mm move starts at 10 mm, and a move planned from 0 mm is refused."""
    from drivers.serial.drive_sim import SimulatedSerialDrive
    serial_cfg = "config/serial_ascii_example.toml"
    cfg = config.load(serial_cfg)
    with SimulatedSerialDrive(cfg, plant_from_config(cfg)) as drive:
        common = ["--config", serial_cfg, "--set", f'serial.port="{drive.port}"', "--set",
                  "supervisor.overrun_cycles=25", "--set", "serial.timeout=30ms", "--set", "serial.budget=100ms",
                      "--backend", "serial", "--feed", "7000mm/min", "--tacc", "200ms",
                  "--dwell", "0.3s", "--json"]
        ends = []
        for k in range(2):
            assert main(["move", *common, "--stroke", "10mm", "--out", str(tmp_path / str(k))]) == 0
            s = json.loads(capsys.readouterr().out)
            m = read_measurement(tmp_path / str(k) / "move.csv")
            ends.append((s["start_m"], m["x_cmd"][0], m["x_motor"][-1]))
        assert ends[0][:2] == (0.0, 0.0)
        # where the first move left the motor (the drive closes its loops on it), to the count
        assert ends[1][0] == pytest.approx(ends[0][2], abs=5e-6) and ends[1][1] == pytest.approx(ends[1][0], abs=1e-9)
        assert ends[1][2] == pytest.approx(20e-3, abs=0.1e-3)
        assert main(["move", *common, "--stroke", "10mm", "--start", "0mm", "--out", str(tmp_path / "x")]) == 2
        assert "planned from 0.000 mm" in capsys.readouterr().err
