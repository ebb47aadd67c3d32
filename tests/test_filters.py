"""The filter sections of the velocity loop (issue 52, item 1): designed where the config asks them,
run in the one compiled control law, and in the lifted loop the stability check judges.

Checked against closed forms (the notch's depth at its frequency, the low-pass's gain 1/(2 zeta) at
its corner: exact, since the bilinear transform is pre-warped there) and against scipy.signal
(sosfilt on the same input, sosfreqz, iirnotch for a deep notch). The lifted loop against the
compiled kernel with filters: tests/test_stability_all_loops.py."""
import math

import numpy as np
import pytest
from conftest import CONFIG
from scipy import signal

from drivers.control import P, S, controller_from_config, filter_path, new_velocity_state
from drivers.filters import FilterSpec, design, frequency_response
from hil import config
from hil.cli import main
from hil.errors import ConfigError
from hil.plant_config import plant_from_config

TV = 62.5e-6
BENCH = CONFIG / "paper_bench.toml"
NOTCH = {"kind": "notch", "frequency": "86.6Hz", "width": "20Hz", "depth": "-20dB"}


@pytest.mark.parametrize("f0, width, depth_db", [(86.6, 20.0, -20.0), (300.0, 60.0, -40.0), (1500.0, 100.0, -6.0)])
def test_a_notch_has_its_depth_at_its_frequency(f0, width, depth_db):
    sec = design(FilterSpec("notch", frequency=f0, width=width, depth=10 ** (depth_db / 20)), TV)
    h = frequency_response([sec], [f0, 0.0, min(5 * f0, 0.49 / TV)], TV)
    assert 20 * np.log10(abs(h[0])) == pytest.approx(depth_db, abs=1e-9)
    assert abs(h[1]) == pytest.approx(1.0, abs=1e-12) and abs(h[2]) == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("fc, zeta", [(200.0, math.sqrt(0.5)), (800.0, 0.3), (3000.0, 1.0)])
def test_a_lowpass_has_gain_one_over_two_zeta_at_its_corner(fc, zeta):
    sec = design(FilterSpec("lowpass", frequency=fc, damping=zeta), TV)
    h = frequency_response([sec], [fc, 0.0], TV)
    assert abs(h[0]) == pytest.approx(1 / (2 * zeta), rel=1e-9)
    assert abs(h[1]) == pytest.approx(1.0, abs=1e-12)


def test_a_deep_notch_is_scipys_iirnotch():
    """At -120 dB the notch is the ideal one: scipy.signal.iirnotch with Q = frequency / width."""
    sec = design(FilterSpec("notch", frequency=300.0, width=30.0, depth=1e-6), TV)
    b, a = signal.iirnotch(300.0, 10.0, fs=1 / TV)
    assert np.allclose(sec[:3], b, atol=1e-4) and np.allclose(sec[3:], a[1:], atol=1e-4)


def test_the_compiled_sections_are_scipys_sosfilt():
    """Two sections on the torque path, run sample by sample by the compiled law's filter_path:
    the output is scipy.signal.sosfilt's on the same input; the response is sosfreqz's."""
    secs = [design(FilterSpec("notch", frequency=86.6, width=20.0, depth=0.1), TV),
            design(FilterSpec("lowpass", frequency=900.0, damping=0.5), TV)]
    p = np.zeros(int(P.SIZE))
    p[P.N_TQ] = 2
    for i, sec in enumerate(secs):
        p[P.TQ + 5 * i:P.TQ + 5 * i + 5] = sec
    s = new_velocity_state()
    x = np.random.default_rng(0).normal(size=4000)
    y = np.array([filter_path(p, s, P.N_TQ, P.TQ, S.TQ_Z, v) for v in x])
    sos = np.array([[b0, b1, b2, 1.0, a1, a2] for b0, b1, b2, a1, a2 in secs])
    assert np.max(np.abs(y - signal.sosfilt(sos, x))) < 1e-12
    f = np.linspace(1.0, 0.45 / TV, 300)
    _, h = signal.sosfreqz(sos, worN=f, fs=1 / TV)
    assert np.max(np.abs(frequency_response(secs, f, TV) - h)) < 1e-12


def test_the_config_designs_them_at_the_velocity_period():
    cfg = config.load(BENCH).with_values({"control.filters": [NOTCH, {"kind": "lowpass", "frequency": "1kHz",
                                                                      "at": "speed"}]})
    ctrl = controller_from_config(cfg, plant_from_config(cfg))
    assert len(ctrl.torque_filters) == 1 and len(ctrl.speed_filters) == 1
    assert abs(frequency_response(ctrl.torque_filters, [86.6], cfg["control.velocity_period"])[0]) == \
        pytest.approx(0.1, rel=1e-9)
    p = ctrl.as_array()
    assert p[P.N_TQ] == 1 and p[P.N_SP] == 1
    # no filter: no section, the law as before
    plain = controller_from_config(config.load(BENCH), plant_from_config(config.load(BENCH))).as_array()
    assert plain[P.N_TQ] == 0 and plain[P.N_SP] == 0


@pytest.mark.parametrize("entry, words", [
    ({"kind": "notc", "frequency": "86.6Hz"}, "control.filters[1].kind: expected one of notch, lowpass, biquad"),
    ({"kind": ["notch"]}, "control.filters[1].kind: expected one of notch, lowpass, biquad"),
    ({"kind": "lowpass", "frequency": "nan Hz"}, "control.filters[1].frequency"),
    ({"kind": "notch", "frequency": "86.6Hz", "depth": "-20dB"}, "control.filters[1].width: missing"),
    ({"kind": "notch", "frequency": "86.6Hz", "width": "200Hz", "depth": "-20dB"}, "control.filters[1].width: expected"),
    ({"kind": "notch", "frequency": "86.6 m", "width": "20Hz", "depth": "-20dB"}, "control.filters[1].frequency"),
    ({"kind": "notch", "frequency": "9kHz", "width": "20Hz", "depth": "-20dB"}, "Nyquist frequency 8000 Hz"),
    ({"kind": "notch", "frequency": "86.6Hz", "width": "20Hz", "depth": "20dB"}, "from -120 dB to 0 dB"),
    ({"kind": "lowpass", "frequency": "1kHz", "at": "current"}, "control.filters[1].at: expected torque or speed"),
    ({"kind": "lowpass", "frequency": "1kHz", "width": "3Hz"}, "width: not a key of a lowpass"),
    ({"kind": "biquad", "b": [1, 0], "a": [1, 0, 0]}, "control.filters[1].b: expected three numbers"),
])
def test_a_bad_filter_is_one_line_naming_its_key(entry, words):
    with pytest.raises(ConfigError) as e:
        config.load(BENCH).with_values({"control.filters": [entry]})
    assert words in str(e.value) and "\n" not in str(e.value)


def test_more_than_four_on_a_path_is_refused():
    with pytest.raises(ConfigError, match="at most 4 filters on the torque path"):
        config.load(BENCH).with_values({"control.filters": [NOTCH] * 5})


def test_a_move_runs_with_a_notch_and_a_loop_it_destabilises_is_refused(tmp_path, capsys):
    """``hil move`` with a notch on the torque setpoint runs; a 30 Hz low-pass on the torque
    setpoint (its phase lag inside the velocity loop's crossover) makes the loop unstable, and the
    move is refused before anything runs, the filter named."""
    text = BENCH.read_text() + '\n[[control.filters]]\nkind = "notch"\nfrequency = "86.6Hz"\nwidth = "20Hz"\n' \
                               'depth = "-20dB"\n'
    (tmp_path / "notch.toml").write_text(text)
    assert main(["move", "--config", str(tmp_path / "notch.toml"), "--stroke", "10mm", "--feed", "7000mm/min",
                 "--tacc", "200ms", "--out", str(tmp_path / "m")]) == 0
    capsys.readouterr()
    bad = BENCH.read_text() + '\n[[control.filters]]\nkind = "lowpass"\nfrequency = "30Hz"\ndamping = 0.2\n'
    (tmp_path / "bad.toml").write_text(bad)
    assert main(["move", "--config", str(tmp_path / "bad.toml"), "--stroke", "10mm", "--feed", "7000mm/min",
                 "--tacc", "200ms", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "unstable" in err and "control.filters lowpass at 30 Hz on the torque path" in err
