"""hil frf: excitation signals, estimates against the exact sampled-loop model within the
coherence-based uncertainty, the paper bench's modes, a wrong c2 found, the backend path, the CLI."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from drivers.control import controller_from_config
from drivers.sim import SimulatedPlant
from hil import frf
from hil.cli import main
from hil.config import load
from hil.plant_config import plant_from_config

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "config" / "paper_bench.toml"


def _setup(overrides=None):
    cfg = load(BENCH, overrides or {})
    plant = plant_from_config(cfg)
    return cfg, plant, controller_from_config(cfg, plant)


@pytest.fixture(scope="module")
def bench():
    return _setup()


@pytest.fixture(scope="module")
def noisy_result(bench):
    _, plant, ctrl = bench
    st = frf.FrfSettings(noise_speed=3e-4, noise_position=1e-9, periods=6)
    return frf.measure(plant, plant, ctrl, st)


# --- signals -----------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["multisine", "chirp", "prbs"])
def test_excitation_is_periodic_band_limited_and_scaled(kind):
    ex = frf.make_excitation(kind, 62.5e-6, 1.0, (2.0, 150.0), 3.0)
    assert np.max(np.abs(ex.signal)) == pytest.approx(3.0)
    assert ex.lines.size > 50
    X = np.abs(np.fft.rfft(ex.signal))
    in_band = np.sum(X[ex.lines] ** 2)
    assert in_band / np.sum(X[1:] ** 2) > (0.5 if kind == "prbs" else 0.9)
    assert ex.freqs[0] >= 2.0 - 1e-9 and (kind == "prbs" or ex.freqs[-1] <= 150.0 + 1e-9)


def test_multisine_schroeder_crest_factor():
    ex = frf.make_excitation("multisine", 62.5e-6, 2.0, (1.0, 200.0), 1.0)
    crest = np.max(np.abs(ex.signal)) / np.sqrt(np.mean(ex.signal ** 2))
    assert crest < 2.0            # random phases give ~3.5, equal phases ~28


# --- estimates against the model ---------------------------------------------------------------

@pytest.mark.parametrize("name", ["TF1p", "TF2", "TF3", "tip", "Lv", "Tv", "Lp", "Tp"])
def test_estimates_match_model_within_uncertainty(noisy_result, name):
    r = noisy_result.responses[name]
    hm = noisy_result.model[name][:r.f.size]
    err = np.abs(r.h - hm)
    assert np.median(r.sigma / np.abs(r.h)) > 1e-7          # the noise is seen
    # sigma is the std of |H|: the complex error has about sqrt(2) sigma
    sc = np.sqrt(2) * r.sigma
    ok = err <= 3.0 * sc + 1e-6 * np.abs(hm)
    assert ok.mean() > 0.95, f"{name}: {ok.mean():.2%} of lines within 3 sigma"
    assert np.mean(err > 6.0 * sc + 1e-6 * np.abs(hm)) < 0.01


def test_paper_bench_modes_within_tolerance(noisy_result, bench):
    _, plant, _ = bench
    modes = {m["mode"]: m for m in noisy_result.modes}
    assert set(modes) == {2, 3}
    for i, (f_model, z_model) in zip((2, 3), frf.model_modes(plant)[0]):
        me = modes[i]["measured"]
        assert me["frequency_hz"] == pytest.approx(f_model, rel=0.02)
        assert me["damping_ratio"] == pytest.approx(z_model, rel=0.2)
    assert modes[2]["measured"]["frequency_hz"] == pytest.approx(14.94, abs=0.1)
    assert modes[3]["measured"]["frequency_hz"] == pytest.approx(86.63, abs=0.5)
    # with the motor's viscous friction the drive mode is damped at ~0.090, not the chain's 0.085
    assert modes[3]["measured"]["damping_ratio"] == pytest.approx(0.0896, rel=0.05)
    assert noisy_result.discrepancies == []


def test_wrong_c2_points_at_plant_c2(bench):
    _, model, ctrl = bench
    _, truth, _ = _setup({"plant.c2": 40.0})
    res = frf.measure(truth, model, ctrl, frf.FrfSettings(periods=3))
    assert len(res.discrepancies) == 1
    d = res.discrepancies[0]
    assert d["mode"] == 2 and "plant.c2" in d["sentence"]
    old, new = d["changes"]["plant.c2"]
    assert old == pytest.approx(11.8)
    assert 20.0 < new < 80.0
    assert new == pytest.approx(40.0, rel=0.1)


def test_velocity_input_measures_closed_velocity_loop_and_position_loop(bench):
    _, plant, ctrl = bench
    st = frf.FrfSettings(input="velocity", signal="chirp", amplitude=0.005 * ctrl.speed_scale, periods=2,
                         band=(2.0, 120.0), period=1.0, settle=1.0, auto_settle=False)
    res = frf.measure(plant, plant, ctrl, st)
    for name in ("Tv", "TF1p", "Lv"):
        r = res.responses[name]
        hm = res.model[name][:r.f.size]
        assert np.median(np.abs(r.h - hm) / np.abs(hm)) < 0.01, name
    # the multirate position loop: the hold approximation holds well below its Nyquist frequency
    lp = res.responses["Lp"]
    sel = lp.f < 30
    rel = np.abs(lp.h[sel] - res.model["Lp"][:lp.f.size][sel]) / np.abs(lp.h[sel])
    assert np.median(rel) < 0.05


def test_backend_path_equals_compiled_path(bench):
    cfg, plant, ctrl = bench
    st = frf.FrfSettings(period=0.25, band=(4.0, 100.0), periods=1, settle=0.25, lead_in=0.1, auto_settle=False)
    fast = frf.run_sim(plant, ctrl, st)
    b = SimulatedPlant(cfg, plant_from_config(cfg), closes="none")
    b.open()
    b.home_at(0.0)
    b.enable()
    slow = frf.run_backend(b, ctrl, st)
    assert slow.data.shape == fast.data.shape
    np.testing.assert_allclose(slow.data, fast.data, rtol=1e-9, atol=1e-12)


def test_margins_and_tuning(noisy_result, bench):
    _, _, ctrl = bench
    t = noisy_result.tuning
    v = t["velocity_loop"]
    assert 20 < v["bandwidth_hz"] < 80 and v["phase_margin_deg"] > 45
    assert v["kp_max"] > ctrl.kp
    assert 5 < t["position_loop"]["crossover_hz"] < 15
    assert "control.kp" in t["config_diff"] and "control.kv" in t["config_diff"]
    # margins of a known loop: L = K / (s (s + 1)) sampled
    f = np.linspace(0.01, 10, 5000)
    s = 2j * np.pi * f
    m = frf.margins(f, 2.0 / (s * (s + 1)))
    assert m["phase_margin_deg"] == pytest.approx(np.degrees(np.arctan(1 / np.sqrt((np.sqrt(17) - 1) / 2))), abs=0.5)


# --- the command -------------------------------------------------------------------------------

def test_cli_json(tmp_path, capsys):
    rc = main(["frf", "--config", str(BENCH), "--set", "plant.c2=11.8", "--sim-set", "plant.c2=40",
               "--periods", "2", "--out", str(tmp_path), "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    tf1 = out["responses"]["TF1p"]
    assert len(tf1["frequency_hz"]) == len(tf1["magnitude"]) == len(tf1["phase_deg"]) == len(tf1["coherence"])
    assert {m["mode"] for m in out["modes"]} == {2, 3}
    assert any("plant.c2" in s for s in out["discrepancies"])
    assert 20 < out["suggested_changes"]["plant.c2"][1] < 80
    for k in ("bode_plant", "bode_loops", "coherence"):
        assert Path(out["plots"][k]).stat().st_size > 10_000
    assert "plant.c2" in (tmp_path / "config_diff.txt").read_text()


def test_a_rigid_axis_has_no_mode_to_fit(tmp_path, capsys):
    """A one-mass model (config/emps.toml, with its P-only velocity loop) has no elastic mode: the
    mode fit crashed on the empty list of the model's modes ("zero-size array to reduction
    operation maximum"), and 'hil tune' with it. Now no mode is fitted and the loops are measured."""
    from hil.frf.modes import model_modes
    from hil.plant_config import plant_from_config
    emps = load(BENCH.parent / "emps.toml")
    assert plant_from_config(emps).n == 1 and model_modes(plant_from_config(emps))[0] == []
    rc = main(["frf", "--config", str(BENCH.parent / "emps.toml"), "--periods", "2", "--out", str(tmp_path), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["modes"] == []
    assert out["tuning"]["velocity_loop"]["phase_margin_deg"] > 45


def test_cli_user_errors(tmp_path, capsys):
    assert main(["frf", "--config", str(BENCH), "--band", "1Hz..9000Hz"]) == 2
    assert "Nyquist" in capsys.readouterr().err
    assert main(["frf", "--config", str(BENCH), "--amplitude", "40 N*m"]) == 2
    assert "output limit" in capsys.readouterr().err
    assert main(["frf", "--config", str(BENCH), "--speed", "0.2 m/s", "--out", str(tmp_path)]) == 2
    assert "travel" in capsys.readouterr().err


def test_canopen_torque_mode_backend():
    """Over the CANopen contract: the simulated CiA 402 drive in cyclic synchronous torque mode
    (lock-step), the host closing both loops at 1 ms."""
    can = pytest.importorskip("can")
    from drivers.canopen.backend import CanopenBackend
    from drivers.canopen.drive_sim import DriveSim
    cfg = load(ROOT / "config" / "paper_bench_canopen.toml",
               {"canopen.lockstep": True, "control.velocity_period": "1 ms"})
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel="frf-test"), lockstep=True)  # noqa: F841
    be = CanopenBackend(cfg, bus=can.Bus(interface="virtual", channel="frf-test"), mode="cst", lockstep=True)
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    st = frf.FrfSettings(period=1.0, band=(2.0, 100.0), periods=3, settle=1.0, lead_in=0.2, auto_settle=False)
    be.open()
    be.enable()
    try:
        rec = frf.run_backend(be, ctrl, st)
    finally:
        be.disable()
        be.close()
    assert rec.saturated == 0 and rec.backend == "canopen"
    resp = frf.estimate(rec, ctrl)
    model = frf.model_responses(plant, ctrl, rec.excitation.freqs, rec.tip_measured)
    for name in ("TF1p", "TF2", "Lv"):
        r = resp[name]
        hm = model[name][:r.f.size]
        assert np.median(np.abs(r.h - hm) / np.abs(hm)) < 0.01, name
