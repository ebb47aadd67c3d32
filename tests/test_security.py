"""Security (issue 18, item 9): outputs never through a planted link nor over an input, the latch
file deleted only when it is a latch, the simulated drive's socketcand server bounded and robust
to malformed frames, serial command templates without attribute access, bounded reply patterns."""
import json
import os
import socket
import stat
import time

import pytest
from conftest import CONFIG

from drivers.canopen.drive_sim import SocketcandServerBus
from drivers.serial.protocol import CommandSet, command_pattern
from hil.errors import ConfigError, UserError
from hil.io.recorder import Recorder
from hil.io.safe_write import open_new, write_atomic
from hil.supervisor import Supervisor, is_latch, remove_latch


def test_write_atomic_replaces_a_planted_link_not_its_target(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "out.json"
    out.symlink_to(victim)
    write_atomic(out, "new")
    assert victim.read_text() == "precious"
    assert not out.is_symlink() and out.read_text() == "new"
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_open_new_refuses_a_link_and_an_input(tmp_path):
    victim = tmp_path / "victim.csv"
    victim.write_text("precious")
    link = tmp_path / "rec.csv"
    link.symlink_to(victim)
    with pytest.raises(UserError, match="symbolic link"):
        open_new(link)
    with pytest.raises(UserError, match="is an input"):
        write_atomic(tmp_path / "." / "victim.csv", "x", inputs=[victim])
    assert victim.read_text() == "precious"


def test_recorder_never_writes_through_planted_links(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / "move.csv").symlink_to(victim)
    with pytest.raises(UserError):
        Recorder(tmp_path / "move.csv", ["t", "x_cmd"])
    (tmp_path / "move.csv").unlink()
    # the status file: a link planted at its name (or at the former fixed move.json.tmp) is not followed
    (tmp_path / "move.json").symlink_to(victim)
    (tmp_path / "move.json.tmp").symlink_to(victim)
    with Recorder(tmp_path / "move.csv", ["t", "x_cmd"]) as rec:
        rec.append(t=0.0, x_cmd=0.0)
    assert victim.read_text() == "precious"
    assert json.loads((tmp_path / "move.json").read_text())["status"] == "complete"


def test_latch_only_deleted_when_it_is_a_latch(bench, tmp_path):
    other = tmp_path / "axis.toml"
    other.write_text((CONFIG / "paper_bench.toml").read_text())
    assert not is_latch(other)
    sup = Supervisor(bench, latch_file=str(other))          # an unreadable latch keeps motion refused
    with pytest.raises(ConfigError, match="not a latch file"):
        sup.reset()
    assert other.exists()
    latch = tmp_path / "latch.json"
    sup = Supervisor(bench, latch_file=str(latch))
    sup.trip(0.1, "speed limit: test")
    assert is_latch(latch)
    link = tmp_path / "link.json"
    link.symlink_to(latch)
    with pytest.raises(ConfigError):
        remove_latch(link)                                  # a link is not a latch, even to one
    assert latch.exists() and link.is_symlink()
    Supervisor(bench, latch_file=str(latch)).reset()
    assert not latch.exists() and not remove_latch(latch)


class _Pump:
    """The drive's side of the server: a thread taking frames off the bus (``bus.recv``), which is
    also what serves the server's clients (it has no threads of its own), into ``frames``."""

    def __init__(self, bus):
        import threading
        self.bus, self.frames, self.stop = bus, [], threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop.is_set():
            msg = self.bus.recv(timeout=0.02)
            if msg is not None:
                self.frames.append(msg)

    def close(self):
        self.stop.set()
        self.thread.join(2)


def _client(port):
    s = socket.create_connection(("127.0.0.1", port), timeout=2)
    assert s.recv(64) == b"< hi >"
    s.sendall(b"< open can0 >")
    assert s.recv(64) == b"< ok >"
    s.sendall(b"< rawmode >")
    assert s.recv(64) == b"< ok >"
    return s


def test_socketcand_server_bounds_input_and_survives_malformed_frames():
    bus = SocketcandServerBus(port=0)
    pump = _Pump(bus)
    try:
        s = _client(bus.port)
        # 4 MB without a '>': dropped as it comes, never buffered whole
        chunk = b"x" * 65536
        for _ in range(64):
            s.sendall(chunk)
        for bad in (b"< send zz 2 00 00 >", b"< send 123 9 00 >", b"< send 123 1 1FF >", b"< send 7FFFFFFFF 0 >",
                    b"< send 123 >", b"<>", b">>>>", b"< send 123 2 00 >"):
            s.sendall(bad)
        s.sendall(b"< send 123 2 AB CD >")
        t0 = time.time()
        while time.time() - t0 < 5 and not pump.frames:
            time.sleep(0.02)
        time.sleep(0.2)
        assert [(m.arbitration_id, bytes(m.data)) for m in pump.frames] == [(0x123, b"\xab\xcd")], \
            "none of the malformed frames gets through, the good one does"
        assert len(bus._conns[next(iter(bus._conns))]) <= bus.MAX_COMMAND     # the buffer stayed bounded
        s.close()
    finally:
        pump.close()
        bus.shutdown()


@pytest.mark.parametrize("template", ["PT {position.__class__}", "PT {position[0]}", "PT {position!r}",
                                      "PT {position:{speed}}", "PT {x}", "PT {", "PT {position:>10s}",
                                      "PT " + "x" * 300])
def test_serial_templates_only_named_fields(template):
    with pytest.raises(ValueError):
        CommandSet({"set_position": template}, {"set_position": "OK"})


def test_serial_templates_with_a_decimal_spec_work_both_ways():
    cs = CommandSet({"set_position": "PT {position:+08d}"}, {"set_position": "PT (?P<echo>[+-][0-9]+)"})
    body = cs.body("set_position", position=-42)
    assert body == "PT -0000042"
    m = command_pattern("PT {position:+08d}").fullmatch(body)
    assert int(m.group("position")) == -42


@pytest.mark.parametrize("pattern", ["(", "x" * 600, "(?P<a>"])
def test_reply_patterns_bounded_and_compiled(pattern):
    with pytest.raises(ValueError, match="serial.replies.read"):
        CommandSet({"read": "RD"}, {"read": pattern})


def test_config_errors_name_the_key(tmp_path):
    from hil import config
    text = (CONFIG / "serial_ascii_example.toml").read_text().replace('set_position = "PT {position}"',
                                                                        'set_position = "PT {position.real}"')
    p = tmp_path / "s.toml"
    p.write_text(text)
    cfg = config.load(p)
    with pytest.raises(ConfigError, match="serial.commands.set_position"):
        CommandSet.from_config(cfg)


def test_move_outputs_never_follow_planted_links(tmp_path, capsys):
    """hil move --out DIR with links planted at the record's, its status file's and the plot's names:
    the links are replaced or refused, their targets never written."""
    from hil.cli import main
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "m"
    out.mkdir()
    for name in ("move.json", "move.json.tmp", "move.png"):
        (out / name).symlink_to(victim)
    rc = main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "10mm", "--feed", "7000mm/min",
               "--tacc", "200ms", "--out", str(out)])
    assert rc == 0 and victim.read_text() == "precious"
    assert not (out / "move.png").is_symlink() and (out / "move.png").stat().st_size > 1000
    (out / "move.csv").unlink()
    (out / "move.csv").symlink_to(victim)
    capsys.readouterr()
    rc = main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "10mm", "--feed", "7000mm/min",
               "--tacc", "200ms", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "symbolic link" in err and err.count("\n") == 1
    assert victim.read_text() == "precious"


# --- issue 29, item 4: outputs follow the umask (mkstemp made every one 0600) --------------------

@pytest.fixture(params=[0o022, 0o077, 0o002])
def umask(request):
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_written_files_follow_the_umask(tmp_path, umask):
    want = 0o666 & ~umask
    assert _mode(write_atomic(tmp_path / "a.txt", "x")) == want
    (tmp_path / "b.txt").write_text("old")                 # replaced: the new file's mode, not the old one's
    os.chmod(tmp_path / "b.txt", 0o600)
    assert _mode(write_atomic(tmp_path / "b.txt", b"new")) == want
    with open_new(tmp_path / "c.csv") as fh:
        fh.write("t\n")
    assert _mode(tmp_path / "c.csv") == want
    assert not list(tmp_path.glob(".*.tmp"))                # no temporary left behind


def test_command_outputs_follow_the_umask(tmp_path, capsys, umask):
    """A record, its plot and its status file from hil move; a fitted config from hil fit's writer."""
    from hil.cli import main
    from hil.config import load
    from hil.io.config_write import write_config
    out = tmp_path / "m"
    assert main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "10mm", "--feed", "7000mm/min",
                 "--tacc", "200ms", "--dwell", "0.2s", "--out", str(out)]) == 0
    files = [p for p in out.iterdir() if p.is_file()]
    assert {"move.csv", "move.png"} <= {p.name for p in files}
    assert {p.name: _mode(p) for p in files} == {p.name: 0o666 & ~umask for p in files}
    bench = str(CONFIG / "paper_bench.toml")
    write_config(tmp_path / "fitted.toml", bench, load(bench, {"plant.c2": "40 N*s/m"}))
    assert _mode(tmp_path / "fitted.toml") == 0o666 & ~umask
