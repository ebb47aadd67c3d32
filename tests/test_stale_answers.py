"""A real axis's cycle without its answer (issue 30, item 4): the backend's feedback repeats the
last answer while the command moves on, so the record marks the row (``stale``) and the move's
following errors leave it out; the summary says how many there were. Checked on the simulated
CiA 402 drive in lockstep: a run with answers missed mid-move gives the following errors of the
same run without a miss (the drive went on executing its setpoints; only the answers were lost)."""
import json

import numpy as np
from canopen_rig import rig
from test_supervisor import Injector

from hil.analysis import move_figures
from hil.io.measurement import read as read_measurement
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory
from hil.runtime import run_trajectory

AT, MISSED = 40, 3           # answers missing from cycle AT + 1 on, in the constant-speed phase


def _traj():
    tr = Trajectory(start=0.0)
    tr.move(MoveSpec(stroke=0.05, feed=0.1, a_max=2.0))
    tr.dwell(0.1)
    return tr


def _run(tmp_path, name, fault):
    cfg, sim, be = rig("csp", prefix=f"stale{name}", **{"canopen.pdo_miss_limit": 10})
    sup = Injector(cfg, sim, AT, "missing_pdo", MISSED) if fault else None
    try:
        rec = run_trajectory(cfg, _traj(), backend=be, out_file=tmp_path / f"{name}.csv", settle=0.0,
                             supervisor=sup)
    finally:
        sim.close()
    assert rec.status == "complete", rec.reason
    return rec


def _figures(rec, stale):
    ch = rec.channels
    move = _traj().moves[0]
    return move_figures(ch["t"], ch["x_cmd"], ch["x_table"], ch["x_tip"], ch["torque"], move, stale=stale)


def test_missed_answers_are_marked_and_left_out_of_the_following_error(tmp_path):
    clean = _run(tmp_path, "clean", fault=False)
    missed = _run(tmp_path, "missed", fault=True)
    m = read_measurement(tmp_path / "missed.csv").channels
    stale = m["stale"]
    # the rows marked are the cycles whose answer was missing, and only those
    rows = np.flatnonzero(stale)
    assert rows.size == MISSED and np.all(np.diff(rows) == 1) and AT < rows[0] <= AT + 2, rows
    assert not read_measurement(tmp_path / "clean.csv").channels["stale"].any()
    # the marked rows repeat the last answer while the command moved on
    assert np.all(m["x_table"][rows] == m["x_table"][rows[0] - 1])
    speed = 0.1
    naive = _figures(missed, None)
    honest = _figures(missed, stale)
    reference = _figures(clean, None)
    # left out, the following error is that of the run without a miss (the drive kept executing);
    # counted, it grows by the command's travel in the missed cycles (speed x cycles x period)
    assert honest.stale_samples == MISSED
    assert abs(honest.peak_following_error_table_um - reference.peak_following_error_table_um) < 1.0
    travel_um = speed * MISSED * 0.004 * 1e6
    assert naive.peak_following_error_table_um > reference.peak_following_error_table_um + 0.8 * travel_um


def _cli_move(tmp_path, name, fault):
    """``hil move --backend canopen`` as a user runs it, against the lockstep drive on a private
    virtual bus with ``fault`` scheduled as ``hil drive-sim --fault`` does: (JSON summary, text)."""
    import contextlib
    import io

    import can
    from canopen_rig import channel
    from conftest import CONFIG
    from test_faults import FaultSchedule, parse_fault

    from drivers.canopen.drive_sim import DriveSim
    from hil import config
    from hil.cli import main
    ch = channel(f"cli{name}")
    sets = {"canopen.lockstep": "true", "canopen.interface": "virtual", "canopen.channel": ch,
            "canopen.pdo_miss_limit": "10"}
    cfg = config.load(CONFIG / "paper_bench_canopen.toml", {**sets, "canopen.lockstep": True,
                                                             "canopen.pdo_miss_limit": 10})
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    schedule = []                    # each run its own schedule: a fault fires once per schedule
    cycle = sim._cycle

    def hooked(from_sync):
        cycle(from_sync)
        schedule[-1].poll(sim)
    sim._cycle = hooked
    argv = ["move", "--config", str(CONFIG / "paper_bench_canopen.toml"), "--backend", "canopen", "--stroke", "20mm",
            "--feed", "6000mm/min", "--amax", "2m/s^2", "--dwell", "0.3s"]
    for k, v in sets.items():
        argv += ["--set", f"{k}={v}"]
    out = {}
    try:
        for form in ("json", "text"):
            schedule.append(FaultSchedule([parse_fault(fault)] if fault else []))
            buf = io.StringIO()
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
                rc = main(argv + ["--out", str(tmp_path / f"{name}-{form}")] + (["--json"] if form == "json" else []))
            assert rc == 0, buf.getvalue()
            out[form] = buf.getvalue()
            if form == "json":       # the second run starts where the first left the axis
                argv[argv.index("--stroke") + 1] = "-20mm"
    finally:
        sim.close()
    return json.loads(out["json"]), out["text"]


def test_the_move_summary_says_how_many_answers_were_missed(tmp_path):
    """The issue's case: a real-axis summary counted stale feedback as following error (381 um where
    the model gives 61.4 um). With answers missed mid-move, hil move's peak following error is
    the clean run's, and its text and JSON say how many cycles had no answer."""
    clean, clean_text = _cli_move(tmp_path, "clean", None)
    missed, missed_text = _cli_move(tmp_path, "missed", f"missing_pdo={MISSED}@0.2")
    assert clean["stale_samples"] == 0 and "cycles without an answer" not in clean_text
    assert missed["stale_samples"] == MISSED
    assert abs(missed["peak_following_error_table_um"] - clean["peak_following_error_table_um"]) < 1.0
    assert f"cycles without an answer {MISSED} (left out of the following errors)" in missed_text
    assert "overruns" in missed and missed["overruns"] >= 0
