"""The small wrongs of issue 25 (item 5), each against what the code did before: a motor's angle
printed as metres, a fitted key dropped without a word, Kv in Hz in the text and 1/s in the JSON,
the actuator's help map on the target column, irregular sampling without a warning."""
import json
import re

import numpy as np
import pytest
from conftest import CONFIG

from hil.cli import main
from hil.io.measurement import read, write
from hil.units import fmt_si

BENCH = str(CONFIG / "paper_bench.toml")
HSM = str(CONFIG / "hsm150.toml")


def _run(capsys, *argv):
    rc = main(list(argv))
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_fmt_si_writes_an_angle_in_rad_mrad_urad():
    assert fmt_si(5865.8, "rad") == "5866 rad"
    assert fmt_si(2.083e-4, "rad", 3) == "208 urad"
    assert fmt_si(0.0123, "rad", 3) == "12.3 mrad"


@pytest.mark.slow
def test_a_motor_without_a_screw_prints_its_positions_in_rad(hsm_record, tmp_path, capsys):
    """The HSM150's positions are the motor's angle: 'x_motor RMS 5866 m' was printed."""
    rc, out, _ = _run(capsys, "compare", hsm_record, "--config", HSM, "--open-loop", "--set",
                      "friction.viscous=1e-4", "--out", str(tmp_path / "c"))
    assert rc == 0
    line = next(s for s in out.splitlines() if s.startswith("x_motor"))
    assert re.search(r"RMS\s+[\d.]+ (u|m)?rad\s+peak\s+[\d.]+ (u|m)?rad", line), line
    rc, out, _ = _run(capsys, "compare", hsm_record, "--config", HSM, "--open-loop", "--set",
                      "friction.viscous=1e-4", "--out", str(tmp_path / "c"), "--json")
    assert json.loads(out)["before"]["channels"]["x_motor"]["unit"] == "rad"


@pytest.mark.slow
def test_a_linear_axis_keeps_metres(tmp_path, capsys):
    rec = tmp_path / "r.csv"
    assert main(["synth", "--config", BENCH, "--duration", "2s", "--out", str(rec)]) == 0
    capsys.readouterr()
    rc, out, _ = _run(capsys, "compare", str(rec), "--config", BENCH, "--set", "plant.c2=40",
                      "--out", str(tmp_path / "c"), "--json")
    assert json.loads(out)["before"]["channels"]["x_tip"]["unit"] == "m"


def test_every_added_key_is_written_or_named_as_unchanged(tmp_path, capsys):
    """An open-loop record does not move Kv: '--add ... --add parameter:control.kv' wrote the
    friction and said nothing of Kv."""
    rec = tmp_path / "ol.csv"
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "level=2Nm", "--open-loop",
                 "--pulses", "5Nm", "--duration", "3s", "--seed", "2", "--out", str(rec)]) == 0
    capsys.readouterr()
    argv = ["fit", str(rec), "--open-loop", "--config", BENCH, "--add", "coulomb_friction",
            "--add", "parameter:control.kv", "--out", str(tmp_path / "f.toml")]
    rc, out, _ = _run(capsys, *argv)
    assert rc == 0
    assert "control.kv: the fit left it at the config's value 50 1/s" in out
    assert "unchanged: control.kv" in out
    rc, out, _ = _run(capsys, *argv, "--json")
    d = json.loads(out)
    assert "effects.coulomb_friction.level" in d["fitted"]
    assert d["unchanged"]["control.kv"]["value"] == 50.0 and d["unchanged"]["control.kv"]["unit"] == "1/s"


def test_kv_has_one_unit_in_text_and_json(tmp_path, capsys):
    """Kv printed as '74.246 Hz' in the text and '1/s' in the JSON: it is a gain in 1/s."""
    rec = tmp_path / "kv.csv"
    assert main(["synth", "--config", BENCH, "--set", "control.kv=60", "--duration", "3s", "--seed", "2",
                 "--out", str(rec)]) == 0
    capsys.readouterr()
    argv = ["fit", str(rec), "--config", BENCH, "--add", "parameter:control.kv", "--out", str(tmp_path / "f.toml")]
    rc, out, _ = _run(capsys, *argv)
    line = next(s for s in out.splitlines() if s.startswith("control.kv"))
    assert line.endswith("1/s  (standard error)") and "Hz" not in line
    value = float(line.split("=")[1].split("+-")[0])
    assert abs(value - 60.0) < 0.5                       # the synth's Kv, found again
    rc, out, _ = _run(capsys, *argv, "--json")
    assert json.loads(out)["fitted"]["control.kv"]["unit"] == "1/s"
    assert 'kv = "' in (tmp_path / "f.toml").read_text() and " 1/s\"" in (tmp_path / "f.toml").read_text()


def test_the_actuator_help_maps_the_demand_the_loop_follows(capsys):
    """The maxon log's columns (PROVENANCE.md): 0 time, 1 target, 2 demand, 3 actual. The help's
    example mapped the target (a step) to x_cmd; the loop follows the profile generator's demand."""
    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    text = capsys.readouterr().out
    line = next(s for s in text.splitlines() if "lina.toml" in s)
    assert "data[:,2]=x_cmd" in line and "data[:,1]=x_cmd" not in line


def _jittered(tmp_path, steps):
    t = np.concatenate([[0.0], np.cumsum(steps)])
    x = 1e-3 * np.sin(t)
    p = tmp_path / "j.csv"
    write(p, {"t": t, "x_cmd": x, "x_motor": x})
    return p


def test_irregular_sampling_is_said_with_its_samples(tmp_path):
    """A logger stepping 12-20 ms around 14 ms: no gap over 1.5 periods, and no word before."""
    rng = np.random.default_rng(1)
    steps = rng.choice([0.013, 0.014, 0.015, 0.017, 0.019], size=400)
    m = read(_jittered(tmp_path, steps))
    msg = next(w for w in m.warnings if "irregular sampling" in w)
    off = np.flatnonzero(np.abs(steps - np.median(steps)) > 0.1 * np.median(steps))
    assert f"{off.size} of 400 steps" in msg
    # the line of the later sample of the first irregular step (line 1: the header, sample k on line k + 1)
    assert f"lines {off[0] + 3}," in msg


def test_regular_sampling_with_float_jitter_is_quiet(tmp_path):
    steps = 0.004 + 1e-9 * np.random.default_rng(2).standard_normal(400)
    assert read(_jittered(tmp_path, steps)).warnings == []


# -- the run-to-run spread (issue 25, item 3) -------------------------------------------------------------
def _repetition(src, dst, sigma, seed):
    """A repetition of the record ``src``: the same command, the positions with their own scatter."""
    m = read(src)
    rng = np.random.default_rng(seed)
    ch = dict(m.channels)
    for c in ("x_motor", "x_table", "x_tip"):
        ch[c] = ch[c] + sigma * rng.standard_normal(ch[c].size)
    write(dst, ch)
    return read(dst)


def test_the_spread_of_repetitions_is_their_scatter_about_the_mean(tmp_path):
    from hil.ident.noise import run_to_run_spread
    src = tmp_path / "base.csv"
    assert main(["synth", "--config", BENCH, "--duration", "2s", "--out", str(src)]) == 0
    a = _repetition(src, tmp_path / "a.csv", 2e-6, 1)
    b = _repetition(src, tmp_path / "b.csv", 2e-6, 2)
    s = run_to_run_spread([a, b], ["x_motor", "x_tip"], "x_cmd")
    # two records: the sample standard deviation at each sample is |a - b| / sqrt(2)
    d = a["x_motor"] - b["x_motor"]
    assert s["x_motor"]["rms"] == pytest.approx(np.sqrt(np.mean(d * d) / 2), rel=1e-12)
    assert s["x_motor"]["repetitions"] == 2 and s["x_motor"]["tests"] == 1
    # another command is another test: nothing to pool
    other = read(src)
    other.channels["x_cmd"] = other.channels["x_cmd"] * 1.1
    assert run_to_run_spread([a, other], ["x_motor"], "x_cmd") == {}


def test_diagnose_says_within_the_run_to_run_spread(tmp_path, capsys):
    """HSM150's chain ended 'no effect pays' at 461 633 x the encoder's floor while its repetitions
    differ by 10-217 rad: repetitions of one command now raise the floor by their scatter."""
    src = tmp_path / "base.csv"
    assert main(["synth", "--config", BENCH, "--duration", "2s", "--out", str(src)]) == 0
    a, b = (tmp_path / "a.csv"), (tmp_path / "b.csv")
    _repetition(src, a, 5e-6, 1)
    _repetition(src, b, 5e-6, 2)
    capsys.readouterr()
    rc, out, _ = _run(capsys, "diagnose", str(a), str(b), "--config", BENCH, "--candidates", "coulomb_friction",
                      "--no-chain", "--jobs", "1", "--json")
    assert rc == 0
    r = json.loads(out)["run_to_run"]
    ma, mb = read(a), read(b)
    d = ma["x_tip"] - mb["x_tip"]
    assert r["spread"]["x_tip"] == pytest.approx(np.sqrt(np.mean(d * d) / 2), rel=1e-9)
    assert r["within"] is True
    rc, out, _ = _run(capsys, "diagnose", str(a), str(b), "--config", BENCH, "--candidates", "coulomb_friction",
                      "--no-chain", "--jobs", "1")
    assert "run-to-run: within the run-to-run spread" in out


# -- a validation record is a record of its own (issue 25, item 1) ----------------------------------------
def _pulsed_record(tmp_path, name, column):
    """A record with Coulomb friction and u_add pulses, the pulses in a column named ``column``."""
    src = tmp_path / f"{name}_src.csv"
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "level=2Nm", "--pulses",
                 "3Nm", "--duration", "3s", "--seed", "5", "--out", str(src)]) == 0
    m = read(src)
    ch = {(column if k == "u_add" else k): v for k, v in m.channels.items()}
    out = tmp_path / f"{name}.csv"
    header = ",".join(f"{k} [{'N*m' if k in ('torque', column) else 's' if k == 't' else 'm'}]" for k in ch)
    np.savetxt(out, np.column_stack(list(ch.values())), delimiter=",", header=header, comments="", fmt="%.12g")
    return out


def test_a_validation_record_takes_its_own_map(tmp_path, capsys):
    """The estimation record has no pulses; the validation record has them in its own column: one
    --map for both could not say it (it gave 36.9 % on EMPS with no word of the unused pulses)."""
    est = tmp_path / "est.csv"
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "level=2Nm",
                 "--duration", "3s", "--seed", "4", "--out", str(est)]) == 0
    val = _pulsed_record(tmp_path, "val", "pulses_Nm")
    capsys.readouterr()
    own = "t=t,x_cmd=x_cmd,x_motor=x_motor,x_table=x_table,x_tip=x_tip,torque=torque,pulses_Nm=u_add[N*m]"
    base = ["fit", str(est), "--config", BENCH, "--add", "coulomb_friction", "--out", str(tmp_path / "f.toml"),
            "--json"]
    rc, out, err = _run(capsys, *base, "--validate", f"{val}:{own}")
    assert rc == 0
    with_pulses = json.loads(out)["validation"][0]
    rc, out, err = _run(capsys, *base, "--validate", str(val))
    without = json.loads(out)["validation"][0]
    assert "'pulses_Nm' looks like an input of the run" in err        # said, not silently dropped
    # with its pulses the fitted model replays the validation record to its floor; without, it does not
    e_with, e_without = with_pulses["after"]["error"]["x_tip"], without["after"]["error"]["x_tip"]
    assert e_with < 0.2 * e_without, (e_with, e_without)


def test_split_record_map_finds_the_file_before_a_map_with_colons(tmp_path):
    from hil.commands.record_inputs import split_record_map
    f = tmp_path / "rec.txt"
    f.write_text("0 0\n")
    assert split_record_map(str(f)) == (str(f), None)
    assert split_record_map(f"{f}:data[:,0]=t,data[:,1]=x_cmd") == (str(f), "data[:,0]=t,data[:,1]=x_cmd")
    assert split_record_map(f"{tmp_path}/missing.csv:t=t") == (f"{tmp_path}/missing.csv:t=t", None)


def test_a_mapped_channel_the_replay_does_not_use_is_said(tmp_path, capsys):
    """A torque mapped on a linear axis (which compares its force) was dropped without a word."""
    rec = tmp_path / "lin.csv"
    t = np.arange(0, 2, 0.004)
    x = 1e-3 * (1 - np.cos(t))
    np.savetxt(rec, np.column_stack([t, x, x, 10 * np.sin(t), 10 * np.sin(t)]), delimiter=",",
               header="t [s],x_cmd [m],x_motor [m],force [N],torque [N*m]", comments="")
    rc, out, err = _run(capsys, "compare", str(rec), "--config", str(CONFIG / "emps.toml"), "--out", str(tmp_path / "c"))
    assert "channel 'torque' is mapped but the replay does not use it" in err


def test_the_evidence_of_an_angle_axis_speaks_rad(hsm_record, capsys):
    """On HSM150 the ripple's period printed '5.01 mm' and the offset '+0.000103  more' (no unit)."""
    rc, out, _ = _run(capsys, "diagnose", hsm_record, "--config", HSM, "--open-loop", "--set", "friction.viscous=1e-4",
                      "--candidates", "torque_ripple,force_offset", "--no-chain", "--jobs", "1", "--json")
    ev = {c["effect"]: c["evidence"] for c in json.loads(out)["candidates"]}
    assert re.search(r"period [\d.]+ (m|u)?rad;", ev["torque_ripple"]), ev["torque_ripple"]
    assert re.search(r"reads [+-][\d.e-]+ N m more than the actuator", ev["force_offset"]), ev["force_offset"]
