"""Issue 24, item 3: a ball screw's preload friction and its friction growing with the axial load
(``load_dependent_friction``), against its closed form at two strengths, named by ``hil diagnose``
on what ``hil synth`` hides at two strengths, and refused in one line where a config gives it a
value out of its physical range.

Closed form (sim_plant/effects/load_friction.py): the torque the effect adds on the motor is
T_pre + mu |F_link| p / (2 pi); on the paper bench the load side has no damping of its own, so at
constant speed F_link = 0 (T_pre alone) and during a constant acceleration or deceleration a,
F_link = (m2 + m3) a, against the motion in both (mu = 1/eta - 1).
"""
import json
import math

import numpy as np
import pytest
from conftest import CONFIG

from hil.cli import main
from hil.config import load
from hil.plant_config import candidate, configure, plant_from_config
from hil.simulate import simulate_config

BENCH = CONFIG / "paper_bench.toml"
CFG = load(BENCH)
TP = CFG["control.position_period"]
PITCH = CFG["plant.pitch"]
NAME = "load_dependent_friction"


def _with(values, cfg=CFG):
    return configure(candidate(NAME), cfg, values)


def _accelerate_cruise_brake(a=2.0, v=0.5, cruise=0.4, dwell=0.2):
    """Positions at the position ticks: rest, a constant acceleration a up to v, a cruise at v, a
    constant deceleration, rest; and the times each phase starts (s)."""
    t_acc = v / a
    t = np.arange(0.0, dwell + 2 * t_acc + cruise + dwell, TP)
    s = np.clip(t - dwell, 0.0, None)
    x = np.where(s < t_acc, 0.5 * a * s ** 2,
                 np.where(s < t_acc + cruise, 0.5 * a * t_acc ** 2 + v * (s - t_acc),
                          0.5 * a * t_acc ** 2 + v * cruise + v * np.clip(s - t_acc - cruise, 0.0, t_acc)
                          - 0.5 * a * np.clip(s - t_acc - cruise, 0.0, t_acc) ** 2))
    return x, (dwell, dwell + t_acc, dwell + t_acc + cruise, dwell + 2 * t_acc + cruise)


@pytest.mark.parametrize("preload,mu", [(0.6, 0.08), (1.8, 0.3)])
def test_torque_added_at_constant_speed_and_constant_acceleration(preload, mu):
    # the 2-dof bench (the tool tip rigid on the table): the 3-dof bench's tip rings at 15 Hz with a
    # damping ratio of 0.015 after every change of the acceleration and keeps loading the link
    cfg = load(CONFIG / "paper_bench_2dof.toml")
    m_load = cfg["plant.m2"]                      # m2 + m3
    a = 2.0
    x, (t0, t1, t2, t3) = _accelerate_cruise_brake(a=a)
    base = simulate_config(cfg, x).channels()
    eff = simulate_config(_with({"preload": preload, "coefficient": mu}, cfg), x).channels()
    t, d = base["t"], eff["torque"] - base["torque"]

    def mean(lo, hi):
        return float(np.mean(d[(t > lo) & (t < hi)]))
    # each window from 0.1 s into its phase: the velocity PI (Ti 16 ms) and the position loop
    # (1 / kv = 20 ms) have taken up the step of the friction by then (to 0.6 %: e^-5)
    extra = mu * m_load * a * PITCH / (2 * math.pi)
    assert mean(t1 + 0.1, t2) == pytest.approx(preload, rel=5e-4)                 # cruising: the preload alone
    assert mean(t0 + 0.1, t1) - preload == pytest.approx(extra, rel=0.01)         # accelerating
    assert mean(t2 + 0.1, t3) - preload == pytest.approx(extra, rel=0.01)         # braking: against the motion too


def test_without_the_load_part_it_is_coulomb_friction():
    """Its coefficient at 0 is coulomb_friction at the preload's level (it nests it), exactly."""
    x, _ = _accelerate_cruise_brake()
    coulomb = simulate_config(configure(candidate("coulomb_friction"), CFG, {"level": 1.3}), x).channels()
    nested = simulate_config(_with({"preload": 1.3, "coefficient": 0.0}), x).channels()
    for c in ("x_motor", "x_table", "x_tip", "torque"):
        assert np.array_equal(coulomb[c], nested[c]), c


def test_the_load_part_alone_switches_the_dry_friction_on():
    """No preload, a load part only: the plant step decides dry friction (its level the link's
    force times mu), which acts while the link carries the load's inertia, and not at constant speed."""
    from drivers.control import T, controller_from_config, loop_terms
    from sim_plant.kernel import LOAD_FRICTION, dry_friction
    cfg2 = load(CONFIG / "paper_bench_2dof.toml")
    mu, a = 0.2, 2.0
    cfg = _with({"preload": 0.0, "coefficient": mu}, cfg2)
    plant = plant_from_config(cfg)
    assert not plant.friction.active and dry_friction(plant)
    assert [c for c, _ in plant.effects] == [LOAD_FRICTION]
    assert loop_terms(plant, controller_from_config(cfg, plant)).array[T.DRY] == 1.0
    x, (t0, t1, t2, t3) = _accelerate_cruise_brake(a=a)
    d = simulate_config(cfg, x).channels()["torque"] - simulate_config(cfg2, x).channels()["torque"]
    t = np.arange(d.size) * TP
    # cruising: no force through the link, no friction (the step down at the cruise's start decays by then)
    assert np.max(np.abs(d[(t > t1 + 0.3) & (t < t2)])) < 1e-5
    accelerating = float(np.mean(d[(t > t0 + 0.1) & (t < t1)]))
    assert accelerating == pytest.approx(mu * cfg2["plant.m2"] * a * PITCH / (2 * math.pi), rel=0.01)


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    """``hil synth`` then ``hil diagnose --json`` at a strength: (the synth's JSON, the diagnosis')."""
    made = {}

    def run(params):
        key = tuple(params)
        if key not in made:
            d = tmp_path_factory.mktemp("ldf")
            out = d / "ldf.csv"
            argv = ["synth", "--config", str(BENCH), "--effect", NAME, "--duration", "6s", "--seed", "7",
                    "--out", str(out), "--json"]
            for p in params:
                argv += ["--param", p]
            made[key] = [_json(argv), _json(["diagnose", str(out), "--config", str(BENCH), "--jobs", "1",
                                             "--no-chain", "--candidates", ",".join(CANDIDATES), "--json"])]
        return made[key]
    return run


# the friction effects it could be taken for, and the mass change that does its work one way
CANDIDATES = (NAME, "coulomb_friction", "stribeck_friction", "viscous_friction", "asymmetric_friction",
              "mass_change")


def _json(argv):
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(argv)
    assert rc == 0, (argv, buf.getvalue()[-400:])
    text = buf.getvalue()
    return json.loads(text[text.index("{"):])


@pytest.mark.parametrize("params,preload,mu", [((), 1.0, 0.15), (("preload=0.4N*m", "coefficient=0.3"), 0.4, 0.3)])
def test_synth_then_diagnose_names_it(diagnosed, params, preload, mu):
    synth, diag = diagnosed(params)
    assert synth["params"] == {"preload": pytest.approx(preload), "coefficient": pytest.approx(mu)}
    assert diag["verdict"] == NAME
    lead = diag["candidates"][0]
    assert lead["effect"] == NAME
    # the fit recovers what the record hides, both within 1 % (0.1 % on these records)
    assert lead["params"]["preload"] == pytest.approx(preload, rel=0.01)
    assert lead["params"]["coefficient"] == pytest.approx(mu, rel=0.01)
    # Coulomb friction alone (the preload's level) is not the answer, nor Coulomb friction and a mass change
    coulomb = next(c for c in diag["candidates"] if c["effect"] == "coulomb_friction")
    assert lead["score"] > coulomb["score"] + 6.0
    assert not any(c["preferred"] for c in diag["combinations"])
    assert "follows |link force| sign(v)" in lead["evidence"]
    assert "like coulomb_friction plus a mass change while accelerating" in lead["evidence"]


def test_regression_start_recovers_the_hidden_values():
    """The least squares of the torque residual while moving on [sign(v), |F_link| sign(v) / k],
    the link's force from the measured motion (the inverse model of the load). The preload comes
    out within 10 %; the coefficient only within 50 %: in the closed loop the torque residual is
    the friction plus the loop's answer to it, which overshoots where the load part steps with the
    acceleration (on this record the regression gives 0.20 even on the link's true force, for a
    hidden 0.15); the fit by simulation takes it from there (test_synth_then_diagnose_names_it)."""
    from hil.ident import Replay, synthesize
    from hil.ident.starts import record_scales, starting_values
    from hil.io.measurement import Measurement
    ch, truth = synthesize(CFG, NAME, duration=6.0, seed=3)
    rp = Replay(Measurement(ch, source="synth"), CFG)
    res0 = rp.residuals(CFG)
    start = starting_values(candidate(NAME), rp, res0, record_scales(rp, res0), CFG)[0]
    assert start["preload"] == pytest.approx(truth["params"]["preload"], rel=0.1)
    assert start["coefficient"] == pytest.approx(truth["params"]["coefficient"], rel=0.5)


@pytest.mark.parametrize("line,word", [
    ('coefficient = 0.7', "effects.load_dependent_friction.coefficient: expected 0 .. 0.5, got 0.7"),
    ('coefficient = -0.1', "effects.load_dependent_friction.coefficient: expected 0 .. 0.5, got -0.1"),
    ('preload = "-1 N*m"', "effects.load_dependent_friction.preload: expected 0 .. 10000, got -1"),
    ('coefficient = "0.1 N"', "effects.load_dependent_friction.coefficient"),
])
def test_a_bad_value_is_refused_in_one_line_naming_the_key(capsys, tmp_path, line, word):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(BENCH.read_text() + f"\n[effects.load_dependent_friction]\n{line}\n")
    rc = main(["move", "--config", str(cfg), "--stroke", "10mm", "--feed", "7000mm/min", "--tacc", "200ms",
               "--out", str(tmp_path / "m")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert word in err, err
    assert not (tmp_path / "m").exists()


def test_a_rigid_axis_has_no_link_to_load():
    """On one mass (no transmission link) it is no candidate, and a config that asks for it is
    refused naming the section."""
    from hil.errors import ConfigError
    emps = load(CONFIG / "emps.toml")
    assert not candidate(NAME).applicable(plant_from_config(emps))
    with pytest.raises(ConfigError, match=r"effects\.load_dependent_friction: cannot act on this axis: no transmission link"):
        plant_from_config(_with({"preload": 1.0, "coefficient": 0.1}, emps))
