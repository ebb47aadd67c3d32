"""Issue 15, items 4 and 6: a pair of effects that only helps together is found (joint candidates
screened by the inverse model, refined by simulation); an added mode starts from the residual's
own peaks, not from a strong line of the command."""
import math

import numpy as np
import pytest

from hil.config import load
from hil.ident import Replay, diagnose, synthesize
from hil.ident.synth import _ramp_move, move_sequence
from hil.ident.unexplained import HALF_GAP, gap_closed
from hil.io.measurement import Measurement
from hil.plant_config import candidate, configure, plant_from_config

CFG = load("config/paper_bench.toml")
TP = CFG["control.position_period"]
SP = 2 * math.pi / CFG["plant.pitch"]          # rad of the motor per m


def _servo_command(v0, seed=0, duration=6.0):
    """A servo bench's moves: back and forth at one speed v0, short ramps, dwells."""
    rng = np.random.default_rng(seed)
    x, parts = 0.01, [np.full(50, 0.01)]
    while sum(p.size for p in parts) * TP < duration:
        stroke = rng.uniform(0.02, 0.03) * (1 if x < 0.04 else -1)
        seg = _ramp_move(x, stroke, v0, 0.03, TP)
        parts += [seg, np.full(int(rng.uniform(0.1, 0.25) / TP), seg[-1])]
        x = float(seg[-1])
    return np.concatenate(parts)[:int(duration / TP)]


def _pair_record(level, v0, seed=1):
    # the model's viscous friction is too high; the axis has Coulomb friction and a lower slope, so
    # that at the bench's one speed they cancel: each alone barely changes the error
    dc = -level / (SP * v0)
    truth = configure(candidate("coulomb_friction", CFG), CFG, {"level": level})
    truth = configure(candidate("viscous_friction", truth), truth, {"coefficient": dc})
    ch, _ = synthesize(truth, None, x_cmd=_servo_command(v0, seed), seed=seed)
    return Replay(Measurement(ch, source="synth: servo bench"), CFG), dc


PAIRS = [(0.2, 0.05), (0.12, 0.04)]


@pytest.mark.parametrize("level,v0", PAIRS)
def test_inverse_model_screen_ranks_the_pair(level, v0):
    from hil.ident.joint import screen_pairs
    rp, dc = _pair_record(level, v0)
    s = screen_pairs(rp, rp.base_residuals, ["coulomb_friction", "viscous_friction", "constant_force", "mass_change"])
    top = s[0]
    assert set(top["effects"]) == {"coulomb_friction", "viscous_friction"} and top["synergy"] > 6
    assert top["start"]["coulomb_friction.level"] == pytest.approx(level, rel=0.15)
    assert top["start"]["viscous_friction.coefficient"] == pytest.approx(dc, rel=0.15)


@pytest.mark.parametrize("level,v0", PAIRS)
def test_pair_that_only_helps_together_is_found(level, v0):
    rp, dc = _pair_record(level, v0)
    d = diagnose(rp, ["coulomb_friction", "viscous_friction", "constant_force"], jobs=1)
    by = {c.effect: c for c in d["candidates"]}
    for name in ("coulomb_friction", "viscous_friction"):     # alone, each closes less than half the gap
        c = by[name]
        assert gap_closed(c.error_before, c.error_after, rp.noise[c.channel]) < HALF_GAP, (name, c.evidence)
    (j,) = [j for j in d["joint_candidates"] if set(j["effects"]) == {"coulomb_friction", "viscous_friction"}]
    assert j["preferred"] and j["gain"] > 0.8
    assert d["verdict"] in ("coulomb_friction", "viscous_friction")
    assert [m["effect"] for m in d["also_missing"]] == [n for n in ("coulomb_friction", "viscous_friction")
                                                        if n != d["verdict"]]
    assert j["params"]["coulomb_friction.level"] == pytest.approx(level, rel=0.1)
    assert j["params"]["viscous_friction.coefficient"] == pytest.approx(dc, rel=0.1)
    assert d["gap_closed"] > HALF_GAP


# --- modes from the residual, not the command's line --------------------------------------------

def _first_mode(cfg):
    """The lowest elastic mode (Hz) of a config's chain, sqrt(eig(M^-1 K)) / 2 pi."""
    ch = plant_from_config(cfg).chain
    ev = np.linalg.eigvals(np.linalg.solve(np.array(ch.M), np.array(ch.K))).real
    f = np.sort(np.sqrt(np.maximum(ev, 0.0)) / (2 * math.pi))
    return float(f[f > 0.1][0])


@pytest.mark.parametrize("mass,freq,line,amp", [(2.0, 25.0, 1.25, 20e-6), (1.0, 40.0, 1.2, 60e-6),
                                                (3.0, 20.0, 1.25, 60e-6)])
def test_mode_starts_from_residual_peaks_not_the_command_line(mass, freq, line, amp):
    # the extra mode pulls the chain's first mode down (14.9 Hz -> 10.6 .. 13.3 Hz): the residual
    # rings there; the command carries a sine just above it, whose forced response is the
    # residual's strongest peak
    from hil.ident.residual import spectrum_peaks
    from hil.ident.starts import mode_targets
    rich = configure(candidate("compliant_mode", CFG), CFG, {"mass": mass, "frequency": freq, "damping_ratio": 0.02})
    f_mode = _first_mode(rich)
    assert f_mode < 0.92 * _first_mode(CFG)
    f_line = line * f_mode
    x = move_sequence(6.0, TP, seed=4)
    t = np.arange(x.size) * TP
    x = x + amp * np.sin(2 * math.pi * f_line * t)        # a strong line of the command near the mode
    ch, _ = synthesize(rich, None, x_cmd=x, seed=4)
    rp = Replay(Measurement(ch, source="synth: line near the mode"), CFG)
    res = rp.base_residuals
    w = rp.objective.weights
    chan = max(res, key=lambda c: float(np.mean(res[c] ** 2)) * w[c] ** 2)
    top = spectrum_peaks(res[chan], rp.sample_period, n=1)[0][0]
    assert abs(top - f_line) <= 0.03 * f_line              # the residual's strongest peak is the command's line
    targets = mode_targets(rp, res)
    assert targets and abs(targets[0] - f_mode) <= 0.03 * f_mode, (targets, f_mode, f_line)
    assert all(abs(f - f_line) > 0.03 * f_line for f in targets)      # the line (its window: +-3 bins)
