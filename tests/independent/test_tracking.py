"""The tracked effects on the night's plant (hil.ident.tracking): a backlash and a Coulomb friction of
random strength, fitted on records of the independent simulator (plant_ivp) whose every mass,
stiffness and damping is scattered as a healthy axis's are from night to night, read within a few
per cent of the drawn truth; the springs that set the lightly damped modes against the chain's
closed form."""
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plant_ivp as ivp  # noqa: E402

from hil.config import load  # noqa: E402
from hil.ident import Replay  # noqa: E402
from hil.ident.tracking import LIGHT_ZETA, _profile_points, fit_tracked, light_mode_keys  # noqa: E402
from hil.io.measurement import Measurement  # noqa: E402
from hil.plant_config import plant_from_config  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CFG = load(ROOT / "config" / "paper_bench.toml")
BENCH = ivp.bench_from_config(CFG)


def _zeta_tip(cfg) -> float:
    """The tip's damping ratio as a mass on a spring over a table that does not move:
    c2 / (2 sqrt(k2 m3)) (the table is 90 times heavier)."""
    return cfg["plant.c2"] / (2.0 * math.sqrt(cfg["plant.k2"] * cfg["plant.m3"]))


def test_the_springs_of_the_lightly_damped_modes():
    # the paper bench: the tool tip rings at 1.5 % (k2), the transmission's mode is damped at 8.5 % (k1)
    assert _zeta_tip(CFG) == pytest.approx(0.0149, abs=2e-4)
    assert light_mode_keys(CFG) == ["plant.k2"]
    # the tip damped beyond the limit: no light mode; the transmission's damping cut tenfold: both
    damped = CFG.with_values({"plant.c2": 2.0 * LIGHT_ZETA * 2.0 * math.sqrt(CFG["plant.k2"] * CFG["plant.m3"])})
    assert _zeta_tip(damped) == pytest.approx(2.0 * LIGHT_ZETA)
    assert light_mode_keys(damped) == []
    light = CFG.with_values({"plant.c1": CFG["plant.c1"] / 10.0})
    assert sorted(light_mode_keys(light)) == ["plant.k1", "plant.k2"]
    # the config's own chain, not the plant an effect makes of it (a flexible transmission adds a mass
    # and would shift the links' numbers to a k3 the config does not have)
    flexible = CFG.with_values({"effects.flexible_transmission.load_share": 0.5,
                                "effects.flexible_transmission.frequency": 60.0,
                                "effects.flexible_transmission.damping_ratio": 0.02})
    assert plant_from_config(flexible).chain.n == 4 and light_mode_keys(flexible) == ["plant.k2"]


def test_the_profile_refines_between_the_best_point_and_its_neighbours():
    grid = [{"gap": float(g)} for g in (3, 0, 9, 6)]
    points, fine = _profile_points(grid)
    assert [p["gap"] for p in points] == [0.0, 3.0, 6.0, 9.0]
    assert [p["gap"] for p in fine({"gap": 3.0})] == pytest.approx([2.4, 1.8, 1.2, 0.6, 3.6, 4.2, 4.8, 5.4])
    assert [p["gap"] for p in fine({"gap": 9.0})] == pytest.approx([8.4, 7.8, 7.2, 6.6])
    # a grid of two parameters: every point, none finer
    two = [{"a": 1.0, "b": 2.0}, {"a": 2.0, "b": 1.0}]
    assert _profile_points(two)[0] == two and _profile_points(two)[1](two[0]) == []


def _scattered_night(seed: int):
    """A 2 s record of the independent simulator: a backlash gap and a Coulomb level drawn over a
    ball screw's range, every mass, stiffness and damping scattered by 1.5 % (all from ``seed``):
    (the night's bench, the replay, gap, level)."""
    rng = np.random.default_rng(seed)
    gap, level = rng.uniform(3e-6, 15e-6), rng.uniform(1.0, 2.5)
    bench = BENCH.changed(**{k: tuple(v * (1.0 + 0.015 * rng.standard_normal()) for v in getattr(BENCH, k))
                             for k in "mkc"})
    x = ivp.command_sequence(2.0, BENCH.tp, seed=0)
    rec = ivp.measure(ivp.simulate(bench, x, ivp.Hidden(coulomb_pos=level, coulomb_neg=level, gap=gap)), seed)
    return bench, Replay(Measurement(rec, source="ivp"), CFG), gap, level


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 4, 5])
def test_backlash_and_friction_on_a_scattered_night(seed):
    """Strengths drawn over a ball screw's range, every plant parameter scattered by 1.5 % (the tip's
    mode by 0.75 % in frequency: a 2 s record's ringing out of phase by a tenth of a cycle)."""
    _, replay, gap, level = _scattered_night(seed)
    values, stderr = fit_tracked(replay, ["backlash", "coulomb_friction"])
    assert values["backlash.gap"] == pytest.approx(gap, rel=0.06)
    assert values["coulomb_friction.level"] == pytest.approx(level, rel=0.025)
    assert set(stderr) == set(values) and all(s >= 0 for s in stderr.values() if math.isfinite(s))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [6, 7])
def test_a_mass_on_the_table_tracked_beside_the_tables_own_mass_claims_no_certainty_it_lacks(seed):
    """Issue 49: a mass_change tracked on a night whose table mass only scattered (1.5 %) is the same
    physical change as the table's own mass, which the night's plant refits beside it within the
    config's tolerance: the record cannot split the two, so its standard error must cover both 0 (no
    mass was added) and the table's whole scatter. It had claimed -5.37 +- 0.004 kg against +1.9 kg:
    the two columns of one change were taken with steps of 0.39 kg and 3.4 g through a backlash."""
    bench, replay, _, _ = _scattered_night(seed)
    values, stderr = fit_tracked(replay, ["backlash", "coulomb_friction", "mass_change"])
    got, se = values["mass_change.mass"], stderr["mass_change.mass"]
    for truth in (0.0, bench.m[1] - BENCH.m[1]):
        assert abs(got - truth) <= 3.0 * se, (got, se, truth)


def _short_record():
    x = ivp.command_sequence(0.6, BENCH.tp, seed=1)
    return Measurement(ivp.measure(ivp.simulate(BENCH, x, ivp.Hidden(coulomb_pos=1.5, coulomb_neg=1.5, gap=5e-6)), 1),
                       source="ivp")


@pytest.mark.slow
@pytest.mark.parametrize("track", [["backlash+coulomb_friction"], ["parameter:plant.k2", "backlash"],
                                   ["coulomb_friction"]])
def test_combinations_plant_keys_and_effects_without_a_grid_are_tracked(track):
    """A combination is fitted by stage 1 alone; a tracked plant key is one of the tolerance test's
    own (its standard error from there); an effect without a grid skips the profile. Every value
    finite, every standard error a number or NaN."""
    values, stderr = fit_tracked(Replay(_short_record(), CFG), track)
    assert values and set(stderr) == set(values)
    assert all(math.isfinite(v) for v in values.values())
    assert all(isinstance(s, float) for s in stderr.values())


def test_without_a_tolerance_the_plant_stays_the_configs():
    rp = Replay(_short_record(), CFG.with_values({"plant.tolerance": 0.0}))
    values, _ = fit_tracked(rp, ["backlash"])
    assert 0.0 <= values["backlash.gap"] < 2e-3


@pytest.mark.slow
@pytest.mark.parametrize("seed", [6, 7, 8, 9])
def test_the_chain_refits_a_backlash_on_the_nights_plant(seed):
    """hil diagnose's chain (hil.ident.chain._on_nights_plant): a backlash of random width on a
    night whose every mass, stiffness and damping is scattered by 1.5 %, the truth from the
    independent simulator. Fitted on the config's plant the gap follows the tip mode's mismatch; the
    step refits it on the night's plant, the plant's changes within its tolerance, and the error
    falls on every position channel. (A first diagnosis that the config's plant leaves
    ``unexplained``, a 31 um gap fitted as 7 um there, takes the backlash so as its first step.)"""
    from hil.ident.chain import diagnose_chain
    rng = np.random.default_rng(seed)
    gap = rng.uniform(15e-6, 45e-6)
    bench = BENCH.changed(**{k: tuple(v * (1.0 + 0.015 * rng.standard_normal()) for v in getattr(BENCH, k))
                             for k in "mkc"})
    x = ivp.command_sequence(3.0, BENCH.tp, seed=seed)
    rec = ivp.measure(ivp.simulate(bench, x, ivp.Hidden(gap=gap)), seed)
    rp = Replay(Measurement(rec, source="ivp"), CFG)
    d = diagnose_chain(rp, ["backlash", "coulomb_friction", "pitch_error", "torque_ripple"], max_steps=1,
                       holdout="moves", jobs=1)
    first = d["chain"][0]
    assert first.effects == ["backlash"] and first.nights_plant is not None
    n = first.nights_plant
    assert all(abs(p["change"]) <= CFG.get("plant.tolerance", 0.05) for p in n["params"].values())
    assert first.params["backlash"]["gap"] == pytest.approx(gap, rel=0.03)
    assert all(first.error_after[c] < n["error_on_config_plant"][c] for c in ("x_motor", "x_table", "x_tip"))
    assert (n.get("held_out") or first.held_out)["earned"]
    # what hil diagnose prints and its JSON
    from hil.commands.diagnose import chain_text
    from hil.ident.chain import chain_json
    from hil.io.jsonout import dumps
    text = "\n".join(chain_text(d, rp))
    assert "on the night's plant (within plant.tolerance 5 %, no finding): m1 " in text
    out = json.loads(dumps({"chain": chain_json(d["chain"])}))["chain"][0]["nights_plant"]
    assert out["effects"] == ["backlash"] and set(out["params"]) >= {"plant.m1", "plant.k2"}


@pytest.mark.slow
def test_every_catalogue_effect_tracked_on_a_clean_night_gives_a_value_the_config_holds():
    """Issue 53: ``--track feedback_delay`` ended every record of a fleet in an error (a delay fitted
    at 0.75 us that the config cannot hold). Each catalogue effect that can act on the paper bench,
    tracked alone on a clean night of the independent simulator (every mass, stiffness and damping
    scattered by 1 %, no hidden effect), gives finite values that the config holds."""
    from hil.ident.tracking import with_effects
    from sim_plant.effects import CATALOGUE
    rng = np.random.default_rng(530)
    bench = BENCH.changed(**{k: tuple(v * (1.0 + 0.01 * rng.standard_normal()) for v in getattr(BENCH, k))
                             for k in "mkc"})
    x = ivp.command_sequence(2.0, BENCH.tp, seed=0)
    rp = Replay(Measurement(ivp.measure(ivp.simulate(bench, x, ivp.Hidden()), 530), source="ivp"), CFG)
    plant = plant_from_config(CFG)
    names = [n for n, e in sorted(CATALOGUE.items()) if not e.unsuited(plant)]
    assert len(names) >= 20
    for name in names:
        values, _ = fit_tracked(rp, [name])
        assert values and all(math.isfinite(v) for v in values.values()), name
        with_effects(CFG, values)           # raises where the config cannot hold a value
