"""A record survives its host killed outright (issue 30): the rows recorded reach the file within
a drain interval of the recorder's thread (issue 48: no file I/O in the cycle; the page cache
keeps them through ``kill -9``), the status beside it is rewritten as the run goes, and the
readers take a record whose last line was cut in its write."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from hil.io.measurement import read
from hil.io.recorder import STATUS_EVERY, Recorder, status_of
from hil.plant_config import plant_from_config
from hil.runtime import record_channels

ROOT = Path(__file__).resolve().parents[1]
CLI = "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"
linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="kill -9 and pseudo-terminals: Linux")


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    return env


def _rows(path: Path) -> list[str]:
    """The complete data lines of a record (those that end in a line break)."""
    text = path.read_text()
    body = text[:text.rfind("\n") + 1].splitlines()
    return [ln for ln in body if ln and not ln.startswith("#")][1:]


@linux
def test_rows_older_than_a_drain_interval_survive_kill_9(tmp_path):
    """A child appends 138 rows at 2 ms (no close, no flush), says so, and keeps appending a row
    every 0.5 s; killed with SIGKILL 0.3 s after it said so (30 drain intervals of 10 ms), the
    file has all 138 rows and they parse, with nothing the cycle wrote itself; the status has the
    run still ``running`` and says it did not end cleanly."""
    rec = tmp_path / "r.csv"
    child = textwrap.dedent(f"""
        import sys, time
        from hil.io.recorder import Recorder
        from hil.runtime import record_channels
        names = record_channels(True)
        r = Recorder({str(rec)!r}, names, {{"sample_period": "0.01 s"}}, status_every=0.05, drain_every=0.01)
        for k in range(138):
            r.append(**{{n: (k * 0.01 if n == "t" else k * 1e-4) for n in names}})
            time.sleep(0.002)
        print("138", flush=True)
        time.sleep(1000)
    """)
    p = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True, env=_env())
    try:
        assert p.stdout.readline().strip() == "138"
        time.sleep(0.3)
        os.kill(p.pid, signal.SIGKILL)
    finally:
        p.kill()
        p.wait()
    rows = _rows(rec)
    assert len(rows) == 138
    m = read(rec)
    assert np.allclose(m["t"], np.arange(138) * 0.01, rtol=0, atol=1e-12)
    assert any("did not end cleanly" in w for w in m.warnings)
    st = status_of(rec)
    assert st["status"] == "running" and st["ended_cleanly"] is False
    assert 0 < st["rows"] <= len(rows)


def test_the_file_holds_what_memory_holds(tmp_path):
    """The rows drained by the thread are the rows in memory, written as %.10g in the written
    units (read back: equal within that rounding), and the channels from memory are exactly the
    values stored."""
    names = record_channels(True)
    rng = np.random.default_rng(3)
    values = rng.normal(size=(777, len(names))) * 1e-3
    values[:, names.index("t")] = np.arange(777) * 1e-3 + rng.uniform(0, 1e-4)
    rec = Recorder(tmp_path / "r.csv", names, rows=100, drain_every=0.001)     # grows past 100
    for row in values:
        rec.write_row(tuple(row))
    rec.close("complete")
    mem = rec.channels()
    back = read(tmp_path / "r.csv").channels
    for i, n in enumerate(names):
        assert np.array_equal(mem[n], values[:, i])
        assert np.allclose(back[n], values[:, i], rtol=1e-9, atol=1e-15)


def test_status_is_updated_as_the_run_goes(tmp_path):
    """With rows coming in, the status's row count follows within an update interval; closing
    writes the final status (the thread stopped first: the last word is the close's)."""
    names = record_channels(True)
    rec = Recorder(tmp_path / "r.csv", names, status_every=0.02)
    for k in range(50):
        rec.append(**{n: k * 1e-3 for n in names})
    deadline = time.monotonic() + 5.0
    while json.loads((tmp_path / "r.json").read_text())["rows"] != 50 and time.monotonic() < deadline:
        time.sleep(0.01)
    st = json.loads((tmp_path / "r.json").read_text())
    assert st["status"] == "running" and st["rows"] == 50 and st["t_s"] == pytest.approx(49e-3)
    assert status_of(tmp_path / "r.csv")["ended_cleanly"] is None          # this process: still running
    rec.close("complete")
    time.sleep(0.05)
    st = status_of(tmp_path / "r.csv")
    assert st["status"] == "complete" and st["rows"] == 50 and st["ended_cleanly"] is True
    assert len(read(tmp_path / "r.csv")) == 50
    assert STATUS_EVERY <= 0.5


def _cut_record(tmp_path: Path, keep_bytes_of_last: int) -> tuple[Path, int]:
    """A record of a run killed in the write of its last row: ``keep_bytes_of_last`` bytes of it
    written, the status still ``running`` for a process that is gone."""
    from hil import config
    from hil.profiles import MoveSpec, Trajectory
    from hil.simulate import simulate_config
    cfg = config.load(ROOT / "config" / "paper_bench.toml")
    tr = Trajectory()
    tr.move(MoveSpec(0.02, 7 / 60, t_acc=0.2, g0=0.5))
    _, x = tr.sample(cfg["control.position_period"])
    ch = simulate_config(cfg, x).channels()
    names = record_channels(True)
    path = tmp_path / "move.csv"
    with Recorder(path, names, {"sample_period": f"{cfg['control.position_period']:g} s"}) as rec:
        rec.extend({n: ch[n] for n in names})
    text = path.read_text()
    last = text.rstrip("\n").rfind("\n") + 1
    path.write_text(text[:last + keep_bytes_of_last])
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    st = json.loads((tmp_path / "move.json").read_text())
    st.update(status="running", pid=dead.pid, rows=len(x) - 30)
    (tmp_path / "move.json").write_text(json.dumps(st))
    return path, len(x)


@pytest.mark.parametrize("keep", [3, 12, 30])
def test_readers_take_a_record_cut_in_its_last_write(tmp_path, keep):
    """A last row cut in its write (with the right number of commas, or not) is dropped with a
    warning naming the line, by the plain reader and by the reader with a map; the rows before
    it are all there."""
    from hil.io.importers import read_any
    path, n = _cut_record(tmp_path, keep)
    for m in (read(path), read_any(path, {"t": "t [s]", "x_cmd": "x_cmd [mm]", "x_table": "x_table [mm]"})):
        assert len(m) == n - 1
        assert any(f"line {n + 2}: cut short" in w for w in m.warnings), m.warnings


def test_compare_reads_a_cut_record(tmp_path, capsys):
    """``hil compare`` on a record cut by a kill: compares what is there, warns on stderr."""
    from hil.cli import main
    path, n = _cut_record(tmp_path, 12)
    rc = main(["compare", str(path), "--config", str(ROOT / "config" / "paper_bench.toml"),
               "--out", str(tmp_path / "cmp"), "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "cut short" in cap.err and "did not end cleanly" in cap.err
    json.loads(cap.out[cap.out.index("{"):])


@linux
def test_hil_move_killed_mid_move_keeps_its_rows(tmp_path):
    """``hil move`` on the serial backend (real-time pacing against the simulated serial drive),
    killed with SIGKILL mid-move: the record holds a row for every cycle the drive saw (two
    commands a cycle, read and set_position, plus a few at start-up) but the last one or two,
    all parse, and move.json says ``running`` (did not end cleanly) with a row count within an
    update interval of the file's."""
    from drivers.serial.drive_sim import SimulatedSerialDrive
    from hil import config
    cfg_path = ROOT / "config" / "serial_ascii_example.toml"
    cfg = config.load(cfg_path)
    period = cfg["control.position_period"]
    out = tmp_path / "move"
    with SimulatedSerialDrive(cfg, plant_from_config(cfg)) as drive:
        p = subprocess.Popen([sys.executable, "-c", CLI, "move", "--config", str(cfg_path), "--backend", "serial",
                              "--set", f'serial.port="{drive.port}"', "--set", "serial.timeout=30ms",
                              "--set", "serial.budget=100ms", "--stroke", "200mm", "--feed", "7000mm/min",
                              "--tacc", "200ms", "--out", str(out)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=_env())
        try:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and p.poll() is None:
                if (out / "move.csv").exists() and len(_rows(out / "move.csv")) > 80:
                    break
                time.sleep(0.02)
            assert p.poll() is None, p.stderr.read().decode()
            time.sleep(0.137)                     # mid-cycle, mid-move (about 1 s of a 2.9 s run)
            os.kill(p.pid, signal.SIGKILL)
            p.wait()
            time.sleep(0.2)                       # the drive's last answers
            commands = drive.state()["commands"]
        finally:
            p.kill()
            p.wait()
            p.stderr.close()
    rows = _rows(out / "move.csv")
    cycles = (commands - 10) / 2                  # at most 10 commands at start-up
    assert len(rows) >= cycles - 2, (len(rows), commands)
    m = read(out / "move.csv")
    assert len(m) >= len(rows) - 1
    assert np.allclose(np.diff(m["t"]), period)
    assert 0.0 < m["x_cmd"][-1] < 0.2            # mid-move
    st = status_of(out / "move.csv")
    assert st["status"] == "running" and st["ended_cleanly"] is False
    assert 0 < st["rows"] <= len(rows) and (len(rows) - st["rows"]) * period < STATUS_EVERY + 0.5
