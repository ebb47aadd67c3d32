"""Red team of the serial path (issue 30): each finding of the red-team report on the serial
backend, its simulated drive and the supervisor of the shipped configs, as a test that failed on
the code before the fix, and a bounded hypothesis fuzzer over serial replies and serial
configuration values.

The rules under test: a command template is one line of printable ASCII (no line ending, no
control character, before or after formatting), a command that carries a value is confirmed by
an ``echo`` group, the line settings are ones a UART has; the simulated drive quick-stops when the
host falls silent and never executes what was queued while it stood frozen; a real backend runs
only with the supervisor's windows, or where the configuration says ``supervisor.unsupervised``.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

from hil.cli import main
from hil.config import load, loads
from hil.drivers.serial.protocol import CommandSet, ReplyError, UnsafeCommand
from hil.errors import ConfigError

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pseudo-terminals: Linux")

ROOT = Path(__file__).resolve().parents[1]
SERIAL = "config/serial_ascii_example.toml"
SERIAL_TEXT = (ROOT / SERIAL).read_text()


def _with(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def _move_serial(capsys, tmp_path, config_text: str, *extra: str) -> tuple[int, str]:
    """``hil move --backend serial`` with the config ``config_text``, against a port that exists
    (/dev/null): a configuration mistake must be refused before it is opened."""
    p = tmp_path / "serial.toml"
    p.write_text(config_text)
    rc = main(["move", "--config", str(p), "--backend", "serial", "--set", "serial.port=/dev/null", *extra,
               "--stroke", "10mm", "--feed", "7000mm/min", "--tacc", "200ms", "--out", str(tmp_path / "out")])
    return rc, capsys.readouterr().err.strip()


# -- 1. templates and patterns validated as protocol --------------------------------------------------
def test_a_line_ending_inside_a_template_is_refused(capsys, tmp_path):
    """The report's unexpected motion: ``read = "RD\\rPT 50000000"`` sent a hidden absolute target
    every cycle (a 10 mm move ran to 81 mm); now the configuration is refused, one line naming the key."""
    text = _with(SERIAL_TEXT, 'read = "RD"', 'read = "RD\\rPT 50000000"')
    text = _with(text, 'checksum = "xor8"', 'checksum = "none"')
    rc, err = _move_serial(capsys, tmp_path, text)
    assert rc == 2 and "\n" not in err, err
    assert "serial.commands.read: the line ending '\\r' at position 2" in err, err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


@pytest.mark.parametrize("template,words", [
    ('RD\\nPT 5', "a control character '\\n' at position 2"),
    ('RD\\u0000', "a control character '\\x00'"),
    ('RD\\u001bPT 5', "a control character '\\x1b'"),
    ('RD\\u007f', "a control character '\\x7f'"),
    ('RD\\u00e9', "a non-ASCII character"),
    ('   ', "empty"),
])
def test_control_characters_in_a_template_are_refused(template, words):
    cfg = loads(_with(SERIAL_TEXT, 'read = "RD"', f'read = "{template}"'), source="s.toml")
    with pytest.raises(ConfigError, match="serial.commands.read: ") as e:
        CommandSet.from_config(cfg)
    assert words in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("old,new,key,words", [
    ("baudrate = 115200", "baudrate = 0", "serial.baudrate", "expected a whole number >= 1"),
    ("baudrate = 115200", "baudrate = 11520", "serial.baudrate", "expected a standard rate"),
    ('line_ending = "\\r"', 'line_ending = ""', "serial.line_ending", "empty"),
    ('line_ending = "\\r"', 'line_ending = "X"', "serial.line_ending", "control characters"),
    ('line_ending = "\\r"', 'line_ending = "\\r\\n\\r"', "serial.line_ending", "control characters"),
    ("set_position = 'PT (?P<echo>-?[0-9]+)'", "set_position = 'PT -?[0-9]+'", "serial.replies.set_position",
     "no (?P<echo>...) group"),
    ("watchdog = 'WD (?P<echo>[0-9]+)'", "watchdog = 'WD [0-9]+'", "serial.replies.watchdog",
     "no (?P<echo>...) group"),
    ('set_position = "PT {position}"', 'set_position = "PT {speed}"', "serial.commands.set_position",
     "expected the one field {position}"),
    ('set_position = "PT {position}"', 'set_position = "PT 5"', "serial.commands.set_position",
     "expected the one field {position}"),
    ('read = "RD"', 'read = "RD {position}"', "serial.commands.read", "carries no value"),
    ('set_position = "PT {position}"', 'set_position = "PT {position} {position}"',
     "serial.commands.set_position", "expected the one field {position}"),
    ('checksum_separator = "*"', 'checksum_separator = "A"', "serial.checksum_separator", "no letter or digit"),
    ('checksum_separator = "*"', 'checksum_separator = ""', "serial.checksum_separator", "no letter or digit"),
    ("max_reply = 96", "max_reply = 0", "serial.max_reply", "1..4096"),
    ('parity = "N"', 'parity = "N"\nstopbits = 0', "serial.stopbits", "expected 1 or 2"),
    ('identify = "ID"', 'identify = "ID"\nred = "RD"', "serial.commands.red", "unknown operation"),
])
def test_line_settings_and_patterns_out_of_protocol_are_refused(capsys, tmp_path, old, new, key, words):
    """Accepted before (the report: baud rate 0, an empty line ending, a reply pattern without its
    echo group); now one line naming the key, exit 2, before the port opens."""
    rc, err = _move_serial(capsys, tmp_path, _with(SERIAL_TEXT, old, new))
    assert rc == 2 and "\n" not in err, err
    assert f": {key}: " in err and words in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("written", ["\\r", "\\n", "\\r\\n", "CR", "lf", "CRLF"])
def test_the_documented_line_endings_are_accepted(written):
    cfg = loads(_with(SERIAL_TEXT, 'line_ending = "\\r"', f"line_ending = '{written}'"
                      if written.startswith("\\") else f'line_ending = "{written}"'), source="s.toml")
    cs = CommandSet.from_config(cfg)
    assert cs.line_ending in (b"\r", b"\n", b"\r\n")
    assert cs.encode("read").endswith(cs.line_ending)


def test_a_formatted_value_never_makes_a_second_line():
    """After formatting too: values are whole numbers (a NaN, an infinity, a string are refused),
    and a line with a control character is never framed."""
    cs = CommandSet.from_config(load(SERIAL))
    for bad in (math.nan, math.inf, -math.inf, "1\rPT 5", None):
        with pytest.raises(UnsafeCommand):
            cs.encode("set_position", position=bad)
    with pytest.raises(UnsafeCommand):
        cs.frame("RD\rPT 50000000")
    assert cs.encode("set_position", position=-12.0).startswith(b"PT -12*")


def test_a_non_finite_setpoint_is_a_backend_fault_not_a_traceback():
    from hil.drivers.base import BackendFault, Setpoint
    from hil.drivers.serial.backend import SerialBackend
    b = SerialBackend(load(SERIAL), port="/dev/null")
    with pytest.raises(BackendFault, match="setpoint refused: serial set_position: nan"):
        b.write_setpoint(Setpoint(position=math.nan))


def test_reply_errors_stay_reply_errors():
    cs = CommandSet.from_config(load(SERIAL))
    with pytest.raises(ReplyError):
        cs.parse("set_position", cs.frame("PT 5"), {"position": 6})


# -- 2. the simulated drive's watchdog: a frozen drive never executes what was queued ------------------
def _quick_stop_distance(cfg, v: float) -> float:
    """An upper bound of the quick stop's travel from speed ``v`` (m/s), from the model's data
    alone: the velocity loop's proportional gain brakes the reflected inertia J with time
    constant J/kp, the torque limit with at most tmax*2pi/pitch over the whole mass; the travel
    is at most the sum of the two stops' distances (the integral part only brakes harder)."""
    masses = sum(cfg[f"plant.m{i}"] for i in range(1, cfg.n_masses + 1))
    r = cfg["plant.pitch"] / (2 * math.pi)                     # m per rad
    tau = masses * r * r / cfg["control.kp"]                   # s
    a_max = cfg["limits.torque"] / r / masses                  # m/s^2
    return abs(v) * tau + v * v / (2 * a_max)


@linux
def test_a_frozen_drive_stops_and_never_executes_what_was_queued():
    """The report's second unexpected motion, on the serial line: a drive frozen mid-move (SIGSTOP
    of its process) while the host goes on sending targets ahead and then trips; on SIGCONT the
    old drive executed the queued targets and coasted on. Now its watchdog (armed by the host at
    open, 50 ms) trips first, it quick-stops from where it stood and drops the queue unread."""
    import os
    import signal
    import time

    from hil.drivers.base import BackendFault, Setpoint
    from hil.drivers.serial.backend import SerialBackend
    from hil.drivers.serial.drive_sim import SimulatedSerialDrive
    cfg = load(SERIAL)
    T, v, acc = cfg["control.position_period"], 0.1, 2.0
    with SimulatedSerialDrive(cfg, advance="wall") as drive:
        b = SerialBackend(cfg, port=drive.port, timeout=0.03, budget=0.03, retries=0, setup_timeout=0.5)
        b.open()                       # arms the drive's watchdog: serial.watchdog = 50 ms
        b.enable()

        def target(k):                 # a ramp at 2 m/s^2 to 0.1 m/s, then 0.1 m/s
            t = k * T
            ta = v / acc
            return 0.5 * acc * t * t if t < ta else 0.5 * acc * ta * ta + v * (t - ta)

        t0 = time.perf_counter()
        for k in range(1, 31):          # 0.3 s of the move, in real time
            fb = b.read_feedback()
            assert not fb.fault, fb.fault
            b.write_setpoint(Setpoint(position=target(k)))
            time.sleep(max(0.0, t0 + k * T - time.perf_counter()))
        before = drive.state()
        os.kill(drive.proc.pid, signal.SIGSTOP)
        try:
            faults = 0
            for k in range(31, 41):      # the host goes on: targets up to 10 mm ahead, all queued
                faults += bool(b.read_feedback().fault)
                try:
                    b.write_setpoint(Setpoint(position=target(k)))
                except BackendFault:
                    faults += 1
            with pytest.raises(BackendFault):
                b.quick_stop()           # the host's stop does not get through either
            assert faults == 20
            b.close()                    # the host is gone; what it sent waits on the line
        finally:
            os.kill(drive.proc.pid, signal.SIGCONT)
        time.sleep(1.0)                  # the drive resumes and stops
        after = drive.state()
    trip = after["watchdog_trip"]
    assert trip is not None and after["fault"] == 1 and not after["enabled"] and not after["stopping"]
    assert after["setpoints"] == before["setpoints"] == trip["setpoints"]     # nothing queued executed
    assert after["discarded"] > 20 * 8                                       # the queue, dropped unread
    # where it stood: within one cycle of the last state read before the freeze
    assert before["x_table"] - 1e-6 <= trip["x"] <= before["x_table"] + v * T + 1e-6
    bound = _quick_stop_distance(cfg, max(abs(trip["v"]), v))
    assert after["x_table"] <= trip["x"] + bound, (after["x_table"] - trip["x"], bound)
    assert after["x_table"] >= trip["x"] - 20e-6            # and never back past where it stood


# -- 3. every shipped config supervised; a real backend refused without the windows -------------------
def _axis_configs():
    return sorted(p for p in (ROOT / "config").glob("*.toml") if "[limits]" in p.read_text())


@pytest.mark.parametrize("path", _axis_configs(), ids=lambda p: p.name)
def test_every_shipped_config_has_the_supervisor_windows(path):
    """The report: the serial example had no following-error window, so a hidden target ran the
    axis 71 mm off its command, status complete. Each window is 2 x speed / kv (the lag of the
    position loop without feed-forward at the top speed, twice)."""
    from hil.drivers import SUPERVISOR_WINDOWS
    cfg = load(path)
    assert all(cfg.get(k) is not None for k in SUPERVISOR_WINDOWS), path.name
    want = 2 * cfg["limits.speed"] / cfg["control.kv"]
    assert cfg["limits.following_error_table"] == pytest.approx(want, rel=1e-3)
    assert not cfg.get("supervisor.unsupervised", False)


def _without_windows(tmp_path, name: str) -> Path:
    text = "\n".join(line for line in (ROOT / "config" / name).read_text().splitlines()
                     if not line.startswith(("following_error_table", "following_error_tip")))
    p = tmp_path / name
    p.write_text(text + "\n")
    return p


MOVE = ["--stroke", "1mm", "--feed", "1000mm/min", "--amax", "1m/s^2"]


@pytest.mark.parametrize("name,backend,extra", [
    ("serial_ascii_example.toml", "serial", ["--set", "serial.port=/dev/null"]),
    ("paper_bench_canopen.toml", "canopen", []),
    ("paper_bench.toml", "serial", ["--set", "serial.port=/dev/null"]),
])
def test_a_real_backend_without_the_windows_is_refused_before_it_connects(capsys, tmp_path, name, backend, extra):
    import time
    p = _without_windows(tmp_path, name)
    t0 = time.perf_counter()
    rc = main(["move", "--config", str(p), "--backend", backend, *extra, *MOVE, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err, err
    assert err.startswith(f"hil move: error: {p}: limits.following_error_table: missing; the {backend} backend"), err
    assert "supervisor.unsupervised = true" in err
    assert time.perf_counter() - t0 < 5.0          # nothing waited for a drive


def test_hil_home_without_the_windows_is_refused(capsys, tmp_path):
    p = _without_windows(tmp_path, "paper_bench_canopen.toml")
    rc = main(["home", "--config", str(p)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "limits.following_error_table: missing; the canopen backend" in err, err


def test_unsupervised_is_said_explicitly(capsys, tmp_path):
    """With ``supervisor.unsupervised = true`` the same configuration goes on (here to the port,
    /dev/null, where no drive answers: a drive fault, not the refusal)."""
    p = _without_windows(tmp_path, "serial_ascii_example.toml")
    rc = main(["move", "--config", str(p), "--backend", "serial", "--set", "serial.port=/dev/null",
               "--set", "serial.setup_timeout=20ms", "--set", "supervisor.unsupervised=true", *MOVE,
               "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and "following_error_table" not in err, err
    with pytest.raises(ConfigError, match="supervisor.unsupervised: expected true or false"):
        load(p, {"supervisor.unsupervised": "yes"})


def test_the_simulated_plant_runs_without_windows(capsys, tmp_path):
    p = _without_windows(tmp_path, "paper_bench.toml")
    rc = main(["move", "--config", str(p), *MOVE, "--dwell", "0.1s", "--out", str(tmp_path / "o")])
    assert rc == 0, capsys.readouterr().err
