"""The red team's smaller findings (issue 49, finding 6), each a test that failed before: a serial
fault whose count was -1 accepted, ``hil drive-sim --seconds 0s`` running forever, a candidate that
is a text setting silently dropped (an empty list, ``unexplained``, exit 0), and a ``--validate``
record that is the estimation record itself taken without a word."""
import pytest
from conftest import CONFIG

from drivers.serial.drive_sim import parse_fault
from hil.cli import main

BENCH = str(CONFIG / "paper_bench.toml")


@pytest.mark.parametrize("text", ["timeout@1x-1", "timeout@-1", "timeoutx0", "garbled x2", "timeout@1x2:", "", "@1"])
def test_a_serial_fault_outside_its_grammar_is_refused(text):
    with pytest.raises(ValueError):
        parse_fault(text)


def test_the_serial_fault_grammar_reads_every_part():
    assert parse_fault("timeout@100x3:set_position") == {"kind": "timeout", "after": 100, "count": 3,
                                                         "op": "set_position"}
    assert parse_fault("frozen_encoder") == {"kind": "frozen_encoder", "after": 0, "count": 1, "op": None}


def test_serial_sim_refuses_a_negative_count_in_one_line(capsys):
    assert main(["serial-sim", "--config", str(CONFIG / "serial_ascii_example.toml"), "--fault", "timeout@1x-1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--fault" in err and "COUNT 1 or more" in err


def test_drive_sim_seconds_zero_is_refused_not_forever(capsys):
    assert main(["drive-sim", "--config", str(CONFIG / "paper_bench_canopen.toml"), "--seconds", "0s"]) == 2
    assert "--seconds" in capsys.readouterr().err


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    rec = tmp_path_factory.mktemp("small") / "cf.csv"
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "level=2Nm", "--duration",
                 "3s", "--seed", "2", "--out", str(rec)]) == 0
    return rec


@pytest.mark.parametrize("key", ["measurement.torque", "meta.name", "backend.type"])
def test_a_text_setting_as_a_candidate_is_one_line_not_dropped(record, capsys, key):
    assert main(["diagnose", str(record), "--config", BENCH, "--candidates", f"parameter:{key}", "--no-chain"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"parameter:{key}: not a physical quantity" in err and len(err.splitlines()) == 1


def test_validating_on_the_estimation_record_itself_is_said(record, tmp_path, capsys):
    capsys.readouterr()
    assert main(["fit", str(record), "--config", BENCH, "--add", "coulomb_friction", "--validate", str(record),
                 "--out", str(tmp_path / "f.toml")]) == 0
    err = capsys.readouterr().err
    assert f"warning: --validate {record}: the estimation record itself" in err


def test_a_large_record_is_said_before_it_is_read(tmp_path, capsys, monkeypatch):
    """A 10^7-row record was read for 90 s in silence: a record above LARGE_RECORD_BYTES gets one
    line on stderr first (the bound lowered here, the record a small one)."""
    import hil.commands.record_inputs as ri
    monkeypatch.setattr(ri, "LARGE_RECORD_BYTES", 10)
    rec = tmp_path / "big.csv"
    rec.write_text("t [s],x_cmd [m]\n0,0\n")
    ri._say_if_large(rec)
    assert "a large record takes a while" in capsys.readouterr().err


def test_move_check_refuses_what_the_move_would_refuse(capsys):
    """``hil move --check`` passed a serial command with a line ending inside, which the move refused."""
    argv = ["move", "--config", str(CONFIG / "serial_ascii_example.toml"), "--stroke", "10mm", "--feed", "6000mm/min",
            "--tacc", "100ms", "--check"]
    assert main(argv) == 0
    assert main(argv + ["--set", 'serial.commands.read="RD\\rPT 50000000"']) == 2
    assert "serial.commands.read: the line ending" in capsys.readouterr().err


def test_a_canopen_quick_stop_that_is_not_sent_is_said():
    """The CANopen backend swallowed a quick stop it could not send, so a lost bus was reported as a
    stop done (controlled_stop.ok true, exit 4 not 6). It raises now, for the loop to report."""
    from canopen_rig import rig

    from drivers.base import BackendFault
    cfg, sim, be = rig(prefix="qsfail")
    try:
        be.open()
        be.enable()

        def gone(*_):
            raise OSError("the bus is down")
        be.link.send = gone
        with pytest.raises(BackendFault, match="quick stop was not sent"):
            be.quick_stop()
        assert not be.enabled
    finally:
        be.link.send = lambda *a, **k: None
        try:
            be.close()
        finally:
            sim.close()


def test_a_frame_during_the_socketcand_handshake_fails_no_connect():
    """``hil status`` now and then failed to connect: the simulated drive wrote a heartbeat right
    after the "< ok >" of the client's handshake, and python-can's client, which reads that "< ok >"
    with one recv and wants it alone, got both. A client joining gets frames after JOIN_GRACE, or
    from its own first frame on (the server's side, on a socket pair: the race itself depends on
    the scheduler)."""
    import socket

    import can

    from drivers.canopen.socketcand_server import JOIN_GRACE, SocketcandServerBus
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = SocketcandServerBus(port=port)
    near, far = socket.socketpair()
    far.setblocking(False)
    heartbeat = can.Message(arbitration_id=0x701, data=[5], is_extended_id=False)
    try:
        assert server._command(near, ["rawmode"], False)
        assert far.recv(256) == b"< ok >"
        server.send(heartbeat)                       # at once: not to the client still reading its "< ok >"
        with pytest.raises(BlockingIOError):
            far.recv(256)
        server._command(near, ["send", "601", "1", "40"], True)     # its first frame: it is on the bus
        server.send(heartbeat)
        assert far.recv(256).startswith(b"< frame 701 ")
        assert 0 < JOIN_GRACE <= 0.1
    finally:
        near.close()
        far.close()
        server.shutdown()
