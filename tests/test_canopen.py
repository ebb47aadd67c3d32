"""The CANopen CiA 402 backend against the simulated drive on python-can's virtual bus, in lockstep
(the drive's clock is the SYNC count: no wall-clock timing in any assertion): the CiA 402 tables
against canopen's own BaseNode402 tables, the full start-up, a move in each mode, homing,
status, EMCY decoding, fault reset, shutdown; and the separate-process transport (socketcand
protocol on 127.0.0.1)."""
import math
import socket

import can
import pytest
from canopen.profiles.p402 import OperationMode, State402
from canopen_rig import channel, rig

from drivers.base import BackendFault, Fault
from drivers.canopen import cia402
from drivers.canopen.backend import CanopenBackend
from drivers.canopen.drive_sim import DriveSim
from hil import config
from hil.errors import ConfigError
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory
from hil.runtime import run_trajectory


def _rig(mode="csp", **ov):
    return rig(mode, prefix="co", **ov)


# -- the CiA 402 tables against canopen's ------------------------------------------------------------
def test_statusword_table_is_canopens():
    assert cia402.STATUSWORD == State402.SW_MASK
    for state in cia402.STATES:
        assert cia402.state_from_statusword(cia402.statusword_for(state)) == state


def test_transitions_agree_with_canopens_table():
    for (src, dst), cw in State402.TRANSITIONTABLE.items():
        if src in ("START", "NOT READY TO SWITCH ON", "FAULT REACTION ACTIVE"):
            continue                  # the drive leaves these by itself
        assert cia402.next_state(src, cw, 0) == dst, (src, dst, hex(cw))
    # what canopen's controlword codes mean here
    for cw, name in State402.CW_CODE_COMMANDS.items():
        assert cia402.COMMANDS[{"SWITCH ON DISABLED": "FAULT RESET", "READY TO SWITCH ON": "SHUTDOWN",
                                "SWITCHED ON": "SWITCH ON", "OPERATION ENABLED": "ENABLE OPERATION",
                                "QUICK STOP ACTIVE": "QUICK STOP"}.get(name, name)] == cw


def test_way_up_agrees_with_canopens():
    for state, cmd in cia402.NEXT_TO_ENABLE.items():
        if cmd is None:
            continue
        nxt = cia402.TRANSITIONS[(state, cmd)]
        assert nxt == State402.next_state_indirect(state), state


def test_fault_reset_only_on_rising_edge():
    assert cia402.next_state("FAULT", 0x80, 0x00) == "SWITCH ON DISABLED"
    assert cia402.next_state("FAULT", 0x80, 0x80) == "FAULT"


def test_mode_codes_are_canopens():
    names = {"csp": "CYCLIC SYNCHRONOUS POSITION", "csv": "CYCLIC SYNCHRONOUS VELOCITY",
             "cst": "CYCLIC SYNCHRONOUS TORQUE"}
    for m, code in cia402.MODES.items():
        assert OperationMode.NAME2CODE[names[m]] == code
    assert OperationMode.NAME2CODE["HOMING"] == cia402.HOMING_MODE


# -- start-up, modes, shutdown ----------------------------------------------------------------------
def test_full_start_up_configures_the_drive():
    cfg, sim, be = _rig()
    try:
        be.open()
        d = sim.node.sdo
        be.node.sdo[0x1001].raw            # an SDO answer: the drive has handled the NMT command before it
        assert sim.node.nmt.state == "OPERATIONAL"
        assert d[0x6060].raw == 8
        assert d[0x1016][1].raw == (127 << 16) | 350          # heartbeat consumer of the host
        assert d[0x6007].raw == 3 and d[0x1017].raw == 100 and d[0x1019].raw == 240
        assert d[0x6065].raw == round(0.030 * be.counts_per_m)  # 1.5 x the table window
        assert d[0x607D][1].raw < 0 < d[0x607D][2].raw
        assert d[0x1A02][0].raw == 3 and d[0x1A02][3].raw >> 16 == 0x2001     # the SYNC counter echo
        assert d[0x1600][2].raw >> 16 == 0x607A
        be.enable()
        assert sim.state == "OPERATION ENABLED"
        be.disable()
        assert sim.state == "READY TO SWITCH ON"
    finally:
        be.close()
        sim.close()
    assert sim.node.nmt.state == "PRE-OPERATIONAL"


def _move():
    tr = Trajectory(start=0.0)
    tr.move(MoveSpec(stroke=0.02, feed=0.1, a_max=2.0))
    tr.dwell(0.15)
    return tr


@pytest.mark.parametrize("mode,closes", [("csp", "both"), ("csv", "velocity"), ("cst", "none")])
def test_move_in_each_mode(mode, closes, tmp_path):
    cfg, sim, be = _rig(mode)
    assert be.closes == closes
    try:
        rec = run_trajectory(cfg, _move(), backend=be, out_file=tmp_path / "m.csv", settle=0.0)
    finally:
        sim.close()
    assert rec.status == "complete", rec.reason
    assert sim.node.sdo[0x6060].raw == cia402.MODES[mode]
    assert abs(rec["x_table"][-1] - 0.02) < 0.5e-3
    assert max(abs(rec["e_table"])) < 5e-3
    assert be.missed_total == 0 and be.late_total == 0
    assert sim.state == "READY TO SWITCH ON"


def test_cst_refuses_a_slow_velocity_loop():
    # a configuration mistake (issue 16: named as one, exit 2; it was a BackendFault)
    cfg = config.load("config/paper_bench_canopen.toml", {"control.velocity_period": "2 ms"})
    with pytest.raises(ConfigError, match="canopen.mode cst: .* 1 ms or faster"):
        CanopenBackend(cfg, mode="cst")


def test_emcy_fault_in_torque_mode_and_reset():
    cfg, sim, be = _rig("cst")
    try:
        be.open()
        be.enable()
        for _ in range(5):
            be.read_feedback()
            be.sync()
        sim.inject("emcy", 0x4310)
        be.sync()
        fb = be.read_feedback()
        assert fb.fault is Fault.DRIVE and fb.reason == "drive fault: EMCY 0x4310 drive overtemperature"
        assert be.emcy_log[-1]["code"] == "0x4310" and be.emcy_log[-1]["text"] == "drive overtemperature"
        be.disable()
        assert sim.state == "FAULT"
        assert be.status()["error_code"] == "0x4310"
        assert be.fault_reset() == "SWITCH ON DISABLED"
        be.enable()
        assert sim.state == "OPERATION ENABLED"
        be.disable()
    finally:
        be.close()
        sim.close()


def test_homing_sets_the_position():
    cfg, sim, be = _rig()
    try:
        be.open()
        sim.home_at(0.1234)
        out = be.home(offset=0.05)
        assert out["homed"] and abs(out["position_m"] - 0.05) < 1e-6
        assert sim.node.sdo[0x6060].raw == 8 and sim.state == "READY TO SWITCH ON"
        st = be.status()
        assert abs(st["position_m"] - 0.05) < 1e-6 and st["state"] == "READY TO SWITCH ON"
    finally:
        be.close()
        sim.close()


# -- the separate-process transport: socketcand protocol on 127.0.0.1 ---------------------------------
def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_socketcand_server_refuses_other_addresses():
    from drivers.canopen.drive_sim import SocketcandServerBus
    with pytest.raises(ValueError, match="127.0.0.1"):
        SocketcandServerBus(host="0.0.0.0", port=_free_port())


def test_drive_over_socketcand_on_loopback():
    """The python-can socketcand client (the host) against the drive's own socketcand server."""
    from drivers.canopen.drive_sim import SocketcandServerBus
    port = _free_port()
    cfg = config.load("config/paper_bench_canopen.toml", {"canopen.interface": "socketcand",
                                                            "canopen.channel": "can0", "canopen.port": port})
    server = SocketcandServerBus(host="127.0.0.1", port=port, channel="can0")
    sim = DriveSim(cfg, plant_from_config(cfg), bus=server, lockstep=False)
    be = CanopenBackend(cfg)
    try:
        be.open()
        be.enable()
        assert sim.state == "OPERATION ENABLED"
        for _ in range(20):
            be.read_feedback()
            be.sync()
            be.answers.event.wait(1.0)
        assert be.answer_latency and be.late_total == 0
        be.disable()
        assert be.status()["state"] == "READY TO SWITCH ON"
    finally:
        be.close()
        sim.close()
    assert math.isfinite(sim.plant.x[0])


# -- hil sweep / hil move --backend canopen, end to end (lockstep drive on a virtual channel) ---------
def _drive_on_channel(**ov):
    """A lockstep simulated drive on its own virtual channel, and the config whose canopen section
    points at it: every backend that config opens (one per run) reaches this drive."""
    ch = channel("co")
    over = {"canopen.lockstep": True, "canopen.interface": "virtual", "canopen.channel": ch}
    over.update(ov)
    cfg = config.load("config/paper_bench_canopen.toml", over)
    return cfg, ch, DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)


def test_sweep_on_the_canopen_backend_matches_the_simulated_plant():
    """run_sweep(backend="canopen"): one run_trajectory per jerk (move, dwell, return move, dwell),
    a new CanopenBackend each time (full start-up, enable, shutdown); the figures match the
    same sweep on the embedded plant (both sampled at the 4 ms position clock)."""
    from hil.sweep import SweepSettings, run_sweep
    cfg, _, sim = _drive_on_channel()
    s = SweepSettings(stroke=0.01, feed=0.1, values=[50.0, 200.0, 1000.0], dwell=0.2)
    try:
        rep = run_sweep(cfg, s, backend="canopen", progress=False, propose=False)
        assert sim.state == "READY TO SWITCH ON" and sim.node.nmt.state == "PRE-OPERATIONAL"
        assert abs(sim.plant.x[0]) < 0.2e-3              # the return moves brought the axis back
    finally:
        sim.close()
    ref = run_sweep(cfg, s, backend="sim", progress=False, propose=False)
    assert [r["j_max"] for r in rep["runs"]] == pytest.approx([50.0, 200.0, 1000.0])
    for got, want in zip(rep["runs"], ref["runs"]):
        assert got["overshoot_table_um"] == pytest.approx(want["overshoot_table_um"], rel=0.05, abs=2.0)
        assert got["peak_following_error_table_um"] == pytest.approx(want["peak_following_error_table_um"],
                                                                     rel=0.05, abs=5.0)
    # the tip rings more with the jerk (a real sweep on the axis needs the tip: recorded here)
    tips = [r["overshoot_tip_um"] for r in rep["runs"]]
    assert tips[0] < 100 < tips[1]


@pytest.mark.slow
@pytest.mark.realtime
def test_hil_move_and_sweep_commands_on_the_canopen_backend(tmp_path, capsys):
    """The CLI, as a user runs it, against the lockstep drive on the same virtual channel."""
    import json

    from hil.cli import main
    cfg, ch, sim = _drive_on_channel()
    sets = ["--set", "canopen.lockstep=true", "--set", "canopen.interface=virtual", "--set", f"canopen.channel={ch}"]
    try:
        rc = main(["move", "--config", "config/paper_bench_canopen.toml", *sets, "--backend", "canopen",
                   "--stroke", "10mm", "--feed", "6000mm/min", "--amax", "2m/s^2", "--dwell", "0.2s", "--back",
                   "--out", str(tmp_path / "move"), "--json"])
        out = capsys.readouterr().out
        assert rc == 0, out
        assert (tmp_path / "move" / "move.csv").exists()
        rc = main(["sweep", "--config", "config/paper_bench_canopen.toml", *sets, "--backend", "canopen",
                   "--stroke", "10mm", "--feed", "6000mm/min", "--jmax", "50,400m/s^3", "--dwell", "0.2s",
                   "--out", str(tmp_path / "sweep"), "--no-plot", "--no-progress", "--json"])
        out = capsys.readouterr().out
        assert rc == 0, out
        rep = json.loads(out)
        assert len(rep["runs"]) == 2 and all(r["overshoot_tip_um"] is not None for r in rep["runs"])
    finally:
        sim.close()
    assert sim.state == "READY TO SWITCH ON"


@pytest.mark.slow
@pytest.mark.realtime
def test_can_log_traces_every_run_of_a_sweep_on_the_canopen_backend(tmp_path, capsys):
    """``hil --can-log FILE sweep --backend canopen``: every run of the sweep traced, one file per
    run numbered in run order (issue 28: after the split the option no longer reached the sweep's
    backends and nothing was recorded). Each trace holds its own run: the start-up (SDO), the cyclic
    phase (a SYNC per position cycle of the move, its dwell, the return move and its dwell) and the
    TPDO answers, no more than one run's cycles."""
    import json

    from hil.cli import main
    cfg, ch, sim = _drive_on_channel()
    sets = ["--set", "canopen.lockstep=true", "--set", "canopen.interface=virtual", "--set", f"canopen.channel={ch}"]
    trace = tmp_path / "bus.asc"
    try:
        rc = main(["--can-log", str(trace), "sweep", "--config", "config/paper_bench_canopen.toml", *sets,
                   "--backend", "canopen", "--stroke", "10mm", "--feed", "6000mm/min", "--jmax", "50,400m/s^3",
                   "--dwell", "0.2s", "--out", str(tmp_path / "sweep"), "--no-plot", "--no-progress", "--json"])
        assert rc == 0, capsys.readouterr()
    finally:
        sim.close()
    # the runs on the axis, in the order they were made (the grid, then the sweep's refinements)
    runs = [json.loads(line)["spec"] for line in (tmp_path / "sweep" / "runs.jsonl").read_text().splitlines()]
    assert len(runs) >= 2
    assert sorted(p.name for p in tmp_path.glob("bus*.asc")) == [f"bus-{k:03d}.asc" for k in range(1, len(runs) + 1)]
    node = cfg.get("canopen.node_id", 1)
    from hil.sweep.run import RunSpec, backend_trajectory
    T = cfg["control.position_period"]
    for k, spec in enumerate(runs, 1):
        frames = list(can.ASCReader(str(tmp_path / f"bus-{k:03d}.asc")))
        sent = {m.arbitration_id for m in frames if not m.is_rx}
        got = {m.arbitration_id for m in frames if m.is_rx}
        assert {0x80, 0x200 + node, 0x600 + node} <= sent and {0x180 + node, 0x580 + node} <= got
        # a SYNC per position cycle of this run's trajectory (move, dwell, return, dwell), counted
        # from the trajectory, not the trace: each file holds its own run, whole
        cycles = backend_trajectory(RunSpec(**spec))[0].duration / T
        syncs = sum(1 for m in frames if m.arbitration_id == 0x80)
        assert cycles <= syncs <= cycles + 5, (k, syncs, cycles)


# -- a tool-tip sensor on its own node (CiA 406-like encoder, config/tip_encoder_cia406.eds) ---------
def _tip_rig(mode="csp", **ov):
    return _rig(mode, **{"canopen.tip_node_id": 2, **ov})


def test_tip_sensor_node_start_up_and_recorded_beside_the_drive(tmp_path):
    cfg, sim, be = _tip_rig()
    assert sim.tip_sensor is not None and be.tip_id == 2 and not be.tip
    try:
        rec = run_trajectory(cfg, _move(), backend=be, out_file=tmp_path / "m.csv", settle=0.0)
        d = sim.tip_sensor.node.sdo
        assert d[0x1A00][0].raw == 1 and d[0x1A00][1].raw == 0x60040020 and d[0x1800][2].raw == 1
        # the drive's TPDO3 no longer carries 0x60E4.2: the tip comes from node 2
        assert all(sim.node.sdo[0x1A02][k].raw >> 16 != 0x60E4 for k in range(1, sim.node.sdo[0x1A02][0].raw + 1))
    finally:
        sim.close()
    assert rec.status == "complete", rec.reason
    assert be.missed_total == 0 and sim.tip_sensor.sent >= len(rec["t"])
    step = sim.tip_sensor.node.sdo[0x6005][1].raw * 1e-9
    # the same tip mass as the drive's own second encoder input shows, in the same cycle
    assert abs(sim.tip_sensor.node.sdo[0x6004].raw * step - sim.node.sdo[0x60E4][2].raw * 1e-9) < step + 1e-9
    # a real tip: it lags and rings beside the table during the move, and arrives
    assert max(abs(rec["x_tip"] - rec["x_table"])) > 20e-6
    assert abs(rec["x_tip"][-1] - 0.02) < 0.5e-3
    assert sim.tip_sensor.node.nmt.state == "PRE-OPERATIONAL"      # put back with the drive at close


def test_tip_sensor_missing_pdo_trips_as_lost_communication(tmp_path):
    from hil.supervisor import Supervisor

    class Injector(Supervisor):
        def check(self, t, fb, x_cmd):
            if self.k == 20:
                sim.inject("tip_missing_pdo", 5)
            return super().check(t, fb, x_cmd)

    cfg, sim, be = _tip_rig()
    sup = Injector(cfg)
    try:
        rec = run_trajectory(cfg, _move(), backend=be, out_file=tmp_path / "m.csv", settle=0.0, supervisor=sup)
    finally:
        sim.close()
    assert rec.status == "tripped"
    assert "no TPDO from the tip sensor node 2 for 2 cycles" in rec.reason
    assert 1 <= sup.trip_cycle - 20 <= 2 and be.quick_stop_sync == sup.trip_cycle
    assert sim.state == "SWITCH ON DISABLED"


def test_tip_sensor_preset_at_homing_and_wrong_node():
    cfg, sim, be = _tip_rig()
    try:
        be.open()
        sim.home_at(0.1234)
        out = be.home(offset=0.05)
        assert abs(out["tip_m"] - 0.05) < 1e-6
        assert abs(be.status()["tip_m"] - 0.05) < 1e-6
    finally:
        be.close()
        sim.close()
    # node 3 answers nothing: the start-up says which node is missing
    cfg = config.load("config/paper_bench_canopen.toml", {"canopen.lockstep": True, "canopen.tip_node_id": 3,
                                                            "canopen.sdo_timeout": 0.05})
    ch = channel("co")
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True, tip_node_id=0)
    be = CanopenBackend(cfg, bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    try:
        with pytest.raises(BackendFault, match="tip sensor node 3 does not answer"):
            be.open()
    finally:
        be.close()
        sim.close()


def test_the_cycles_statusword_tests_agree_with_the_state_names():
    """The real-time cycle tests the statusword's bits against (mask, value) pairs bound once; over
    every statusword they classify as the state names do (the names no longer made per cycle)."""
    from drivers.canopen.backend import _ENABLED_WORD, _FAULT_WORDS
    for sw in range(1 << 16):
        st = cia402.state_from_statusword(sw)
        assert any(sw & m == v for m, v in _FAULT_WORDS) == (st in ("FAULT", "FAULT REACTION ACTIVE")), hex(sw)
        assert (sw & _ENABLED_WORD[0] == _ENABLED_WORD[1]) == (st == "OPERATION ENABLED"), hex(sw)
