"""The diagnosis chain (hil.ident.chain): pairs of hidden effects both named with their
parameters, a light second mode named, a clean record ``none``, an effect outside the catalogue
``unexplained``; the noise floor from the record (hil.ident.noise)."""
import json
import math

import numpy as np
import pytest

from hil.config import load
from hil.ident import Replay, synthesize
from hil.ident.chain import diagnose_chain
from hil.ident.noise import quantization_step, record_noise, standstill_noise
from hil.io.measurement import Measurement
from hil.plant_config import candidate, configure
from sim_plant import kernel
from sim_plant.effects import CATALOGUE, Effect, Param

CFG = load("config/paper_bench.toml")


def _truth(effects):
    """The paper bench with the hidden effects switched on (catalogue names or parameter:<key>)."""
    cfg = CFG
    for name, vals in effects:
        cfg = configure(candidate(name, cfg), cfg, vals)
    return cfg


def _record(effects, duration=6.0, seed=3):
    ch, truth = synthesize(_truth(effects), None, duration=duration, seed=seed)
    return Replay(Measurement(ch, source="synth"), CFG), ch


def _fitted(d, name):
    """The values of ``name`` after the whole chain (its last step's joint refit)."""
    for s in reversed(d["chain"]):
        if name in s["params"]:
            return s["params"][name]
    raise AssertionError(f"{name} not in the chain {[s['effects'] for s in d['chain']]}")


class LocalBump(Effect):
    """A tight spot of the guideway: a force bump F0 exp(-((x - xc) / w)^2) on the motor, less its
    mean over a 0.2 m period (so no constant force stands in for it), as 30 Fourier rows of the
    compiled loop's torque ripple. Not in the catalogue: the record's effect nothing models."""
    name = "local_bump_outside_catalogue"
    params = (Param("force", "torque", 0.0, 1e4, 1.0, "peak"), Param("centre", "length", 0, 1, 0.04, ""),
              Param("width", "length", 1e-4, 1, 4e-3, ""))

    def apply(self, plant, values):
        L, F0, xc, w = 0.2, values["force"] * plant.speed_scale, values["centre"], values["width"]
        rows = []
        for n in range(1, 31):
            a = 2 * F0 * w * math.sqrt(math.pi) / L * math.exp(-(math.pi * n * w / L) ** 2)
            rows.append((kernel.TORQUE_RIPPLE, (a, L / n, math.pi / 2 - 2 * math.pi * n * xc / L)))
        return plant.__class__(**{**plant.__dict__, "effects": plant.effects + tuple(rows)})


def _bump_record(force, seed=3):
    eff = LocalBump()
    CATALOGUE[eff.name] = eff
    try:
        cfg = configure(eff, CFG, {"force": force, "centre": 0.03, "width": 4e-3})
        ch, _ = synthesize(cfg, None, duration=6.0, seed=seed)
    finally:
        del CATALOGUE[eff.name]
    return Replay(Measurement(ch, source="synth: local bump"), CFG)


# --- the noise floor ------------------------------------------------------------------------------

def test_quantization_step_found_from_the_values():
    rng = np.random.default_rng(0)
    for q in (0.5e-6, 1e-6 / 3, 5e-8):
        y = q * np.round(np.cumsum(rng.normal(0, 3, 2000)))
        assert quantization_step(y) == pytest.approx(q, rel=1e-6)
        # a fast move skips 5 to 9 levels per sample; stored to 4 digits of the step
        y7 = 0.0123 + q * np.cumsum(rng.choice([5, 7, 9], 500))
        assert quantization_step(y7 + np.round(rng.normal(0, 1e-3, y7.size), 4) * q) == pytest.approx(q, rel=1e-3)
    assert quantization_step(rng.normal(0, 1e-6, 2000)) == 0.0


def test_standstill_noise_ignores_a_ringing_mode():
    # white noise of 0.02 at standstill, plus a 60 Hz ring (0.5, decaying by 2 % per cycle) after
    # each move: the AR predictor takes the ring away, the floor stays the noise's
    rng = np.random.default_rng(1)
    dt = 4e-3
    t = np.arange(3000) * dt
    x = np.where((t % 2.0) < 1.0, 0.0, 0.01)          # steps: 1 s standstills
    x = np.convolve(x, np.ones(25) / 25, mode="same")
    ring = np.zeros_like(t)
    for t0 in np.arange(0.0, t[-1], 1.0):
        k = t >= t0
        ring[k] += 0.5 * np.exp(-0.02 * 2 * math.pi * 60 * (t[k] - t0)) * np.sin(2 * math.pi * 60 * (t[k] - t0))
    r = rng.normal(0, 0.02, t.size) + ring
    s, n = standstill_noise(t, x, r)
    assert n > 500 and s == pytest.approx(0.02, rel=0.15)


def test_noise_floor_of_a_clean_record_and_a_given_figure():
    rp, ch = _record([], duration=4.0)
    src = rp.noise_sources
    assert src["x_tip"]["quantization"] == pytest.approx(0.5e-6)
    for c in ("x_motor", "x_table", "x_tip"):      # 0.1 um noise dithering a 0.5 um grid: 0.144 .. 0.175 um
        assert 0.14e-6 <= rp.noise[c] <= 0.18e-6
    rms = float(np.sqrt(np.mean(ch["torque"] ** 2)))  # synth's torque noise: 1 % of its RMS
    assert rp.noise["torque"] == pytest.approx(0.01 * rms, rel=0.3)
    meas = Measurement(ch, meta={"noise.x_tip": "0.3 um", "noise_torque": "0.05 N*m"}, source="synth")
    given = record_noise(meas, CFG, rp.base_residuals)
    assert given["x_tip"]["rms"] == pytest.approx(math.hypot(0.3e-6, 0.5e-6 / math.sqrt(12)))
    assert given["torque"]["rms"] == pytest.approx(0.05) and given["torque"]["source"] == "given"
    from hil.errors import HilError
    with pytest.raises(HilError, match=r"synth: noise.x_tip: cannot read 'banana' as a length"):
        record_noise(Measurement(ch, meta={"noise.x_tip": "banana"}, source="synth"), CFG, rp.base_residuals)


# --- the chain on the command line: its JSON ----------------------------------------------------

def test_cli_chain_json_and_out(tmp_path, capsys):
    from hil.cli import main
    from hil.io.measurement import write
    ch, _ = synthesize(_truth([("coulomb_friction", {"level": 2.2}), ("constant_force", {"force": 400.0})]), None,
                       duration=4.0, seed=2)
    data = tmp_path / "cc.csv"
    write(data, ch, {"sample_period": "0.004 s"})
    out = tmp_path / "fitted.toml"
    rc = main(["diagnose", str(data), "--config", "config/paper_bench.toml", "--candidates",
               "coulomb_friction,constant_force,parameter:plant.c2", "--jobs", "1", "--json", "--out", str(out)])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert {"candidates", "verdict", "also_missing", "combinations", "noise_floor", "error_before", "chain",
            "final", "noise_floor_source"} <= set(d)
    assert d["verdict"] == d["chain"][0]["effect"]
    named = [e for s in d["chain"] for e in s["effects"]]
    assert set(named) == {"coulomb_friction", "constant_force"}
    for s in d["chain"]:
        assert {"step", "effect", "effects", "params", "error_before", "error_after", "gap_closed", "score",
                "refitted_together"} <= set(s)
        assert set(s["error_before"]) == set(d["noise_floor"])
        assert all(s["error_after"][c] <= s["error_before"][c] * 1.01 for c in ("x_motor", "torque"))
    p = d["chain"][-1]["params"]
    assert p["coulomb_friction"]["level"] == pytest.approx(2.2, rel=0.1)
    assert p["constant_force"]["force"] == pytest.approx(400.0, rel=0.1)
    f = d["final"]
    assert f["end"] in ("noise floor reached", "no effect pays for its parameters")
    assert f["at_noise_floor"] == all(f["error"][c] <= 1.5 * f["noise_floor"][c] for c in f["error"])
    for c in ("x_motor", "torque"):             # the error falls step by step, by 5 times at least
        assert f["error"][c] < 0.2 * d["error_before"][c]
        assert f["error"][c] == pytest.approx(d["chain"][-1]["error_after"][c])
    if not f["at_noise_floor"]:
        assert f["residual"]["channels"][0]["above_floor"] > 1.5
    cfg = load(out)
    assert cfg["effects.coulomb_friction.level"] == pytest.approx(p["coulomb_friction"]["level"])
    assert cfg["effects.constant_force.force"] == pytest.approx(p["constant_force"]["force"])
    # --no-chain: the single diagnosis, today's keys, nothing added
    rc = main(["diagnose", str(data), "--config", "config/paper_bench.toml", "--candidates",
               "coulomb_friction,constant_force", "--jobs", "1", "--json", "--no-chain"])
    one = json.loads(capsys.readouterr().out)
    assert rc == 0 and "chain" not in one and one["verdict"] == d["verdict"]
    assert one["noise_floor"] == pytest.approx(d["noise_floor"])


# --- the physics, over strengths ----------------------------------------------------------------

PAIRS = {
    "coulomb+mode": [[("coulomb_friction", {"level": 2.2}),
                      ("compliant_mode", {"mass": 2.0, "frequency": 25.0, "damping_ratio": 0.02})],
                     [("coulomb_friction", {"level": 0.8}),
                      ("compliant_mode", {"mass": 1.0, "frequency": 40.0, "damping_ratio": 0.03})]],
    "ripple+mass": [[("torque_ripple", {"amplitude": 0.6, "period": 0.005, "phase": 0.3}), ("mass_change", {"mass": 80.0})],
                    [("torque_ripple", {"amplitude": 0.3, "period": 0.0025, "phase": -1.0}),
                     ("mass_change", {"mass": 150.0})]],
    "pitch+c2": [[("pitch_error", {"amplitude": 4e-6, "period": 0.01, "phase": 0.5}), ("parameter:plant.c2", {"value": 40.0})],
                 [("pitch_error", {"amplitude": 8e-6, "period": 0.005, "phase": 2.0}),
                  ("parameter:plant.c2", {"value": 25.0})]],
}


def _check_named(d, truth):
    named = [e for s in d["chain"] for e in s["effects"]]
    for name, vals in truth:
        assert name in named, (name, named, d["verdict"])
        got = _fitted(d, name)
        for k, v in vals.items():
            if k == "phase":
                continue
            if k == "damping_ratio":
                assert got[k] == pytest.approx(v, rel=0.25), (name, k, got)
                continue
            assert got[k] == pytest.approx(v, rel=0.1), (name, k, got)


@pytest.mark.slow
@pytest.mark.parametrize("pair", sorted(PAIRS))
@pytest.mark.parametrize("strength", [0, 1])
def test_pair_both_named_in_the_chain(pair, strength):
    truth = PAIRS[pair][strength]
    rp, _ = _record(truth)
    d = diagnose_chain(rp, jobs=2)
    _check_named(d, truth)
    assert d["verdict"] in [n for n, _ in truth]
    assert d["final"]["at_noise_floor"], d["final"]


@pytest.mark.slow
@pytest.mark.parametrize("level,delay,seed", [(2.2, 2e-3, 3), (1.0, 1e-3, 3), (0.6, 3e-3, 7)])
def test_feedback_delay_and_coulomb_both_named(level, delay, seed):
    # the inverse model's screen pairs Coulomb friction with a mass change (+178 kg at 2.2 N m and
    # 2 ms) that takes the delay's share of the torque; the pair's leader fitted with the strongest
    # single candidates (hil.ident.diagnosis._rival_pairs) names the delay instead, and the record
    # ends at its floor in one step, where the chain named control.ffv, an actuator delay and a
    # stiffness along the travel beside the mass
    p = CATALOGUE["feedback_delay"].params[0].name
    truth = [("coulomb_friction", {"level": level}), ("feedback_delay", {p: delay})]
    rp, _ = _record(truth, seed=seed)
    d = diagnose_chain(rp, jobs=2)
    named = [e for s in d["chain"] for e in s["effects"]]
    assert set(named) == {"coulomb_friction", "feedback_delay"}, named
    assert _fitted(d, "coulomb_friction")["level"] == pytest.approx(level, rel=0.02)
    assert abs(_fitted(d, "feedback_delay")[p] - delay) <= 0.02 * delay
    assert d["final"]["at_noise_floor"]
    screened = [j for j in d["joint_candidates"] if "rival_of" not in j and j["preferred"]]
    if screened:        # the screen's pair stood in for the delay: a rival pair of its leader says so
        best = max(screened, key=lambda j: j["score"])
        rivals = [j for j in d["joint_candidates"] if j.get("rival_of") == "+".join(best["effects"])]
        assert rivals, d["joint_candidates"]
        top = max(rivals, key=lambda j: j["score"])
        assert set(top["effects"]) == {"coulomb_friction", "feedback_delay"} and top["score"] > best["score"]
        json.loads(json.dumps(d["joint_candidates"], allow_nan=False))


@pytest.mark.slow
@pytest.mark.parametrize("mass,freq", [(0.5, 60.0), (0.3, 45.0)])
def test_light_second_mode_named(mass, freq):
    # a light mode above the first on the tool side: its residual is not noise (the floor comes
    # from standstills and the encoder grid, not from the residual that holds the mode)
    truth = [("compliant_mode", {"mass": mass, "frequency": freq, "damping_ratio": 0.02})]
    rp, _ = _record(truth)
    assert rp.noise["x_tip"] < 0.2e-6
    d = diagnose_chain(rp, jobs=2)
    assert d["verdict"] == "compliant_mode"
    got = _fitted(d, "compliant_mode")
    assert got["frequency"] == pytest.approx(freq, rel=0.1)
    assert got["mass"] == pytest.approx(mass, rel=0.1)
    assert d["final"]["at_noise_floor"]


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 5])
def test_clean_record_none(seed):
    rp, _ = _record([], seed=seed)
    d = diagnose_chain(rp, jobs=2)
    assert d["verdict"] == "none" and d["chain"] == [] and d["final"]["at_noise_floor"]


@pytest.mark.slow
@pytest.mark.parametrize("force", [1.0, 2.5])
def test_effect_outside_the_catalogue_unexplained(force):
    rp = _bump_record(force)
    d = diagnose_chain(rp, jobs=2)
    assert d["verdict"] == "unexplained"
    ev = d["residual"]
    assert ev["best_gap_closed"] < 0.5
    top = ev["channels"][0]
    assert top["above_floor"] > 3
    # where it lives: the force residual largest in the band of the travel that holds the bump (30 mm)
    tq = next(c for c in ev["channels"] if c["channel"] == "torque")
    lo, hi = tq["along_travel"]["band"]
    assert lo - 0.004 <= 0.03 <= hi + 0.004 and tq["along_travel"]["against_median"] > 3
    assert not d["final"]["at_noise_floor"] and d["final"]["end"] == "unexplained"
