"""Input shaping of the command (hil.shaping): the shapers' impulses against their closed forms,
their residual vibration against a simulated damped mode (scipy.signal), the shaped trajectory
within the unshaped one's limits, and `hil move --shaper` bringing the paper bench's tool tip to
rest where the unshaped move leaves it ringing."""
import json
import math

import numpy as np
import pytest
from conftest import CONFIG
from scipy import signal

from hil.cli import main
from hil.profiles import MoveSpec, Trajectory
from hil.shaping import ALL_KINDS, KINDS, SI_BAND, V_TOL, ShapedTrajectory, Shaper, parse_shaper, residual_vibration

BENCH = str(CONFIG / "paper_bench.toml")


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("zeta", [0.0, 0.015, 0.1])
def test_the_impulses_are_the_closed_forms(kind, zeta):
    f = 14.94
    s = Shaper.design(kind, f, zeta)
    k = math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2))
    td = 1 / (f * math.sqrt(1 - zeta ** 2))
    raw = {"zv": [1, k], "zvd": [1, 2 * k, k * k], "ei": [0.25 * (1 + V_TOL), 0.5 * (1 - V_TOL) * k,
                                                         0.25 * (1 + V_TOL) * k * k]}[kind]
    assert s.amplitudes == pytest.approx(np.array(raw) / sum(raw), rel=1e-12)
    assert sum(s.amplitudes) == pytest.approx(1.0, rel=1e-15) and min(s.amplitudes) > 0
    assert s.times == pytest.approx([0.0, 0.5 * td, td][:len(raw)], rel=1e-12)
    # at the design mode: nothing left (ZV, ZVD), the tolerance left (EI; below it with damping, as
    # Klipper's damped EI is an approximation of the exact one)
    left = float(residual_vibration(s, f))
    if kind != "ei":
        assert left == pytest.approx(0.0, abs=1e-12)
    elif zeta == 0:
        assert left == pytest.approx(V_TOL, rel=1e-12)
    else:
        assert 0.5 * V_TOL < left <= V_TOL


@pytest.mark.parametrize("zeta", [0.0, 0.015, 0.1])
def test_the_specified_insensitivity_shaper_keeps_its_band(zeta):
    """The SI shaper: positive impulses summing to 1 every half damped period, its residual within
    V_TOL over the whole +-30 % band (where EI leaves more than three times as much), and longer
    than EI by the price of that band."""
    f = 14.94
    si, ei = Shaper.design("si", f, zeta), Shaper.design("ei", f, zeta)
    td = 1 / (f * math.sqrt(1 - zeta ** 2))
    assert sum(si.amplitudes) == pytest.approx(1.0, rel=1e-12) and min(si.amplitudes) > 0
    steps = np.asarray(si.times) / (0.5 * td)
    assert np.allclose(steps, np.round(steps), atol=1e-9) and si.times[0] == 0.0
    band = np.linspace(f * (1 - SI_BAND), f * (1 + SI_BAND), 241)
    assert np.max(residual_vibration(si, band)) <= V_TOL
    assert np.max(residual_vibration(ei, band)) > 3 * np.max(residual_vibration(si, band))
    assert si.duration > ei.duration
    assert parse_shaper(f"si@{f}Hz:{zeta}") == si


def test_zvd_is_flat_at_its_mode_and_wider_than_zv():
    zv, zvd = Shaper.design("zv", 10.0, 0.02), Shaper.design("zvd", 10.0, 0.02)
    h = 1e-4
    slope = (residual_vibration(zvd, 10.0 + h) - residual_vibration(zvd, 10.0 - h)) / (2 * h)
    assert abs(slope) < 1e-6
    band = np.linspace(8.5, 11.5, 61)          # +-15 %
    assert np.max(residual_vibration(zvd, band)) < np.max(residual_vibration(zv, band))
    assert np.max(residual_vibration(zvd, band)) < 0.12


@pytest.mark.parametrize("kind", ALL_KINDS)
@pytest.mark.parametrize("f_true", [10.0, 11.0])
def test_the_residual_vibration_is_what_a_damped_mode_keeps(kind, f_true):
    """A second-order mode (f_true, zeta) driven by the shaped unit step and by the plain one given
    at the shaper's last impulse (scipy.signal.lsim): the ratio of their vibration amplitudes after
    it is residual_vibration at f_true (Singer and Seering's definition: the shaped command against
    the unshaped one ending when it ends)."""
    zeta = 0.02
    s = Shaper.design(kind, 10.0, zeta)
    w = 2 * math.pi * f_true
    sys2 = signal.lti([w * w], [1, 2 * zeta * w, w * w])
    t = np.arange(0.0, 2.0, 1e-5)
    plain = (t >= s.times[-1]).astype(float)
    shaped = sum(a * (t >= ti) for a, ti in zip(s.amplitudes, s.times))
    after = t >= s.times[-1]

    def amplitude(u):
        _, y, _ = signal.lsim(sys2, u, t)
        e = (y - 1.0)[after] * np.exp(zeta * w * t[after])        # undo the decay: a constant envelope
        return 0.5 * (e.max() - e.min())
    assert amplitude(shaped) / amplitude(plain) == pytest.approx(float(residual_vibration(s, f_true)), rel=2e-3,
                                                                 abs=2e-4)


def test_the_shaped_command_keeps_the_limits_and_the_target():
    traj = Trajectory()
    traj.move(MoveSpec(0.1, 7.0 / 60, t_acc=0.2, g0=30.0 / 60))
    traj.dwell(0.5)
    st = ShapedTrajectory(traj, Shaper.design("zvd", 14.94, 0.015))
    assert st.duration == pytest.approx(traj.duration + st.shaper.duration)
    t = np.arange(0.0, st.duration, 1e-4)
    for what in ("velocity", "acceleration", "jerk"):
        assert np.max(np.abs(getattr(st, what)(t))) <= np.max(np.abs(getattr(traj, what)(t))) * (1 + 1e-12)
    assert st.position(st.duration) == pytest.approx(0.1, abs=1e-15)
    # the convex combination of delayed copies, at any time
    for tk in (0.05, 0.4, 0.93):
        want = sum(a * traj.position(tk - ti) for a, ti in zip(st.shaper.amplitudes, st.shaper.times))
        assert st.position(tk) == pytest.approx(want, rel=1e-15)
    assert st.shifted(0.01).position(st.duration) == pytest.approx(0.11)


@pytest.mark.parametrize("text,error", [
    ("bogus", "expected KIND@FREQUENCY"), ("zvd@-3Hz", "positive"), ("zv@14.94Hz:1.5", "[0, 1)"),
    ("zv@14.94Hz:abc", "damping ratio"), ("zv@14.94m", "frequency"),
])
def test_a_bad_shaper_is_one_line_naming_it(text, error):
    with pytest.raises(ValueError) as e:
        parse_shaper(text, "--shaper", [(14.94, 0.015)])
    assert error in str(e.value) and "--shaper" in str(e.value)


def test_the_damping_comes_from_the_nearest_mode_and_auto_from_the_lowest():
    modes = [(14.94, 0.015), (86.6, 0.09)]
    assert parse_shaper("zv@80Hz", modes=modes).damping == 0.09
    assert parse_shaper("zv@15Hz:0.05", modes=modes).damping == 0.05
    auto = parse_shaper("auto", modes=modes)
    assert (auto.kind, auto.frequency, auto.damping) == ("zvd", 14.94, 0.015)
    assert parse_shaper("none") is None


def _move(capsys, tmp_path, *extra):
    capsys.readouterr()
    rc = main(["move", "--config", BENCH, "--stroke", "100mm", "--feed", "7000mm/min", "--tacc", "200ms",
               "--band", "5um", "--out", str(tmp_path), "--json", *extra])
    return rc, json.loads(capsys.readouterr().out)


def test_hil_move_with_a_zvd_shaper_brings_the_tip_to_rest(capsys, tmp_path):
    from hil.io.measurement import read
    rc, plain = _move(capsys, tmp_path / "plain")
    assert rc == 0 and plain["shaper"] is None and plain["settling_time_tip"] is None     # rings past 5 um
    rc, shaped = _move(capsys, tmp_path / "zvd", "--shaper", "zvd@14.94Hz")
    assert rc == 0 and shaped["shaper"]["kind"] == "zvd" and shaped["shaper"]["damping_ratio"] > 0
    assert shaped["settling_time_tip"] is not None and shaped["overshoot_tip_um"] < 0.01 * plain["overshoot_tip_um"]
    # the record's x_cmd is the shaped command the axis received
    m = read(tmp_path / "zvd" / "move.csv")
    traj = Trajectory()
    traj.move(MoveSpec(0.1, 7.0 / 60, t_acc=0.2, g0=0.5))          # nc.g0 = 30 m/min
    s = shaped["shaper"]
    want = sum(a * traj.position(m.t - ti) for a, ti in zip(s["amplitudes"], s["times_s"]))
    assert np.max(np.abs(m["x_cmd"] - want)) < 1e-9


def test_a_sweep_compares_the_shaped_command_with_the_plain_one(capsys, tmp_path):
    """nc.shaper in the compared config: the same jerks through a ZVD shaper at the tip mode leave
    the tip within a hundredth of the plain command's overshoot; a bad nc.shaper is refused before
    any run, naming the file and the key."""
    text = (CONFIG / "paper_bench.toml").read_text(encoding="utf-8")
    shaped_cfg = tmp_path / "zvd.toml"
    shaped_cfg.write_text(text.replace('g0 = "30 m/min"', 'g0 = "30 m/min"\nshaper = "zvd@14.94Hz"'), encoding="utf-8")
    capsys.readouterr()
    assert main(["sweep", "--config", BENCH, "--compare", str(shaped_cfg), "--stroke", "100mm", "--feed", "7000mm/min",
                 "--jmax", "100..300m/s^3", "--points", "2", "--no-progress", "--no-plot", "--jobs", "1",
                 "--out", str(tmp_path / "sw"), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    plain = [x["overshoot_tip_um"] for x in r["runs"]]
    shaped = [x["overshoot_tip_um"] for x in r["compare_runs"]]
    assert min(plain) > 100 and max(shaped) < 0.01 * min(plain)
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('g0 = "30 m/min"', 'g0 = "30 m/min"\nshaper = "zvd@fast"'), encoding="utf-8")
    assert main(["sweep", "--config", str(bad), "--stroke", "100mm", "--feed", "7000mm/min", "--jmax", "100..300m/s^3",
                 "--points", "2", "--no-progress", "--no-plot", "--out", str(tmp_path / "sw2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.toml: nc.shaper" in err[0]
