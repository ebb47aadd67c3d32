"""``--scope`` on every command that moves an axis (issue 27): jog, home, sweep --backend, frf
(move: tests/test_scope_server.py). Each run's scope gets the run's own numbers: the ring the
command's server reads is checked against what the command reports or records."""
import json

import can
import numpy as np
import pytest
from canopen_rig import channel
from conftest import CONFIG

from drivers.canopen.drive_sim import DriveSim
from hil import config
from hil.cli import main
from hil.commands import scope as scope_cmd
from hil.plant_config import plant_from_config
from hil.scope.ring import SCOPE_CHANNELS

BENCH = str(CONFIG / "paper_bench.toml")
CANOPEN = str(CONFIG / "paper_bench_canopen.toml")
IX = SCOPE_CHANNELS.index


@pytest.fixture
def started(monkeypatch):
    """The scope servers the commands start (stopped again by --scope-hold 0s)."""
    servers = []
    real = scope_cmd.start_scope

    def start(*a, **k):
        servers.append(real(*a, **k))
        return servers[-1]
    monkeypatch.setattr(scope_cmd, "start_scope", start)
    return servers


SCOPE = ["--scope", "--scope-hold", "0s"]


def test_jog_on_the_simulated_plant(started, capsys):
    assert main(["jog", "--config", BENCH, "--backend", "sim", "--distance", "2mm", "--json", *SCOPE]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert "hil jog: scope at http://127.0.0.1:" in cap.err
    (server,) = started
    _, rows = server.ring.window()
    assert rows.shape[0] > 50 and rows[-1, IX("x_table")] == pytest.approx(out["end_m"], abs=1e-12)
    assert rows[-1, IX("x_cmd")] == pytest.approx(0.002, abs=1e-12)
    assert server.ring.events()[1][-1][2] == "complete"
    assert not server.running                                    # held 0 s, then stopped


def test_home_shows_the_position_before_and_after(started, capsys):
    ch = channel("scopehome")
    over = {"canopen.lockstep": True, "canopen.interface": "virtual", "canopen.channel": ch}
    cfg = config.load(CANOPEN, over)
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    try:
        argv = ["--config", CANOPEN, *[x for k, v in over.items() for x in ("--set", f"{k}={str(v).lower()}")]]
        assert main(["home", *argv, "--offset", "3mm", "--json", *SCOPE]) == 0
    finally:
        sim.close()
    out = json.loads(capsys.readouterr().out)
    (server,) = started
    _, rows = server.ring.window()
    assert rows.shape[0] == 2 and rows[1, IX("x_motor")] == pytest.approx(out["position_m"]) == pytest.approx(0.003)
    assert server.ring.events()[1] == [(1, rows[1, 0], "complete", "homed (method 37)")]


def test_a_sweep_on_a_backend_shows_its_runs_on_one_time_axis(started, capsys, tmp_path):
    """Every run of the sweep (a move there and back): their rows one after the other, time going
    on, each run's end an event."""
    assert main(["sweep", "--config", BENCH, "--backend", "sim", "--jmax", "50,100m/s^3", "--feed", "7000mm/min",
                 "--stroke", "10mm", "--dwell", "0.2s", "--no-plot", "--no-progress", "--out", str(tmp_path),
                 "--json", *SCOPE]) == 0, capsys.readouterr().err
    runs = json.loads(capsys.readouterr().out)["stats"]["computed"]
    (server,) = started
    _, rows = server.ring.window()
    assert np.all(np.diff(rows[:, 0]) > 0)
    ends = [e for e in server.ring.events()[1] if e[2] == "complete"]
    assert runs >= 2 and len(ends) == runs and ends[-1][1] == pytest.approx(rows[-1, 0])
    # both runs start and end at the sweep's start: x_cmd is back at 0 at each run's end
    assert rows[ends[0][0], IX("x_cmd")] == pytest.approx(0.0, abs=1e-12)
    assert np.max(rows[:, IX("x_cmd")]) == pytest.approx(0.01)


def test_a_model_sweep_has_no_axis_to_show(started, capsys, tmp_path):
    assert main(["sweep", "--config", BENCH, "--jmax", "50,100m/s^3", "--feed", "7000mm/min", "--stroke", "10mm",
                 "--out", str(tmp_path), *SCOPE]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--scope: the model sweep moves no axis" in err and not started


@pytest.mark.slow
@pytest.mark.realtime
def test_frf_on_the_compiled_loop(started, capsys, tmp_path, monkeypatch):
    """The compiled run's record into the scope, one row per position tick: the record's own numbers."""
    import hil.frf
    records = []
    real = hil.frf.measure
    monkeypatch.setattr(hil.frf, "measure", lambda *a, **k: records.append(real(*a, **k)) or records[-1])
    assert main(["frf", "--config", BENCH, "--periods", "1", "--period", "0.5s", "--settle", "0.5s", "--out",
                 str(tmp_path), "--json", *SCOPE]) == 0, capsys.readouterr().err
    (server,) = started
    _, rows = server.ring.window()
    cfg = config.load(BENCH)
    tp, tv = cfg["control.position_period"], cfg["control.velocity_period"]
    rec = records[0].record
    every = round(tp / tv)
    np.testing.assert_allclose(np.diff(rows[:, 0]), tp, rtol=1e-9)
    np.testing.assert_array_equal(rows[:, IX("x_table")], rec.channel("x_table")[::every])
    np.testing.assert_array_equal(rows[:, IX("output")], rec.channel("u")[::every])
    assert np.isnan(rows[:, IX("x_cmd")]).all()          # the command is not in the compiled run's record


def test_bad_scope_options_are_one_line_before_motion(capsys):
    assert main(["jog", "--config", BENCH, "--backend", "sim", "--distance", "2mm", "--scope", "--scope-port",
                 "-1"]) == 2
    assert "--scope-port -1: expected a port" in capsys.readouterr().err
    assert main(["frf", "--config", BENCH, "--scope", "--scope-hold", "soon"]) == 2
    assert "--scope-hold" in capsys.readouterr().err
