"""The chain's backward step (hil.ident.chain, ``chain[].dropped``): an effect of an earlier step
that no longer pays for its parameters once a later step's effects are in the model is dropped.

The record with Coulomb friction and an actuator delay comes from the independent simulator
(plant_ivp): the first step takes the friction with a mass change, the inverse model's pair, which
stands in for the delay's share of the torque; once the delay is found the mass is refitted to
almost nothing and dropped. With the record's moves held out (hil diagnose's default) the mass does
not earn its own place in the first step and never enters (chain[].held_out.members)."""
import io
import json
import sys
from contextlib import redirect_stdout
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plant_ivp as ivp  # noqa: E402

from hil.config import load  # noqa: E402
from hil.ident import Replay, synthesize  # noqa: E402
from hil.ident.chain import _unpaid  # noqa: E402
from hil.io.measurement import Measurement, write  # noqa: E402
from hil.plant_config import candidate, configure  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CFG_PATH = ROOT / "config" / "paper_bench.toml"
CFG = load(CFG_PATH)
BENCH = ivp.bench_from_config(CFG)


@pytest.mark.parametrize("level,kept", [(1e-5, False), (1.5, True)])
def test_an_earlier_effect_is_dropped_only_where_it_no_longer_pays(level, kept):
    # the record has Coulomb friction 1.5 N m: in a model that holds it the friction pays by far;
    # 10 uN m of it changes nothing the record can see (its BIC score below MIN_SCORE): dropped
    ch, _ = synthesize(configure(candidate("coulomb_friction", CFG), CFG, {"level": 1.5}), None,
                       duration=2.0, seed=1)
    rp = Replay(Measurement(ch, source="synth"), CFG)
    cfg1 = configure(candidate("coulomb_friction", CFG), CFG, {"level": level})
    cfg1 = configure(candidate("viscous_friction", CFG), cfg1, {"coefficient": 0.0})
    res1 = rp.residuals(cfg1)
    cfg2, res2, dropped = _unpaid(rp, ["coulomb_friction", "viscous_friction"], ["viscous_friction"], cfg1, res1)
    if kept:
        assert dropped == [] and cfg2 is cfg1 and res2 is res1
    else:
        assert [d["effect"] for d in dropped] == ["coulomb_friction"]
        assert dropped[0]["params"] == {"level": pytest.approx(level)} and dropped[0]["score"] <= 6.0
        assert "effects.coulomb_friction.level" not in cfg2 and cfg2["effects.viscous_friction.coefficient"] == 0.0


def _delay_record():
    x = ivp.command_sequence(4.0, BENCH.tp, 3, v_max=0.15)
    return ivp.measure(ivp.simulate(BENCH, x, ivp.Hidden(coulomb_pos=2.0, coulomb_neg=2.0, delay=1e-3)), 3)


@pytest.mark.slow
def test_a_mass_that_stood_in_for_a_delay_is_dropped():
    # judged on the record alone (no held-out half, as a record of one move): the first step's
    # pair takes the mass, the second step's delay makes it pay no more
    from hil.commands.diagnose import chain_text
    from hil.ident.chain import diagnose_chain
    rp = Replay(Measurement(_delay_record(), source="plant_ivp"), CFG)
    d = diagnose_chain(rp, jobs=1, max_steps=2, holdout=None)
    first, second = d["chain"]
    assert first.effects == ["coulomb_friction", "mass_change"]
    assert second.effects == ["actuator_delay"]
    (drop,) = second.dropped
    assert drop["effect"] == "mass_change" and abs(drop["params"]["mass"]) < 1.0 and drop["score"] <= 6.0
    assert set(second.params) == {"coulomb_friction", "actuator_delay"}
    assert second.params["actuator_delay"]["delay"] == pytest.approx(1e-3, rel=0.01)
    assert second.params["coulomb_friction"]["level"] == pytest.approx(2.0, rel=0.01)
    text = "\n".join(chain_text(d, rp))
    assert "- mass_change [mass " in text and "dropped from the model" in text


@pytest.mark.slow
def test_with_held_out_moves_the_mass_never_enters(tmp_path):
    # the record's moves held out (hil diagnose's default): the pair's mass does not earn its own
    # place on them beyond the friction refitted there, and is taken out of the first step
    from hil.cli import main
    path = write(tmp_path / "rec.csv", _delay_record(), {"sample_period": f"{BENCH.tp} s"})
    args = ["diagnose", str(path), "--config", str(CFG_PATH), "--jobs", "1", "--max-steps", "2",
            "--out", str(tmp_path / "found.toml")]
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(args + ["--json"]) == 0
    d = json.loads(out.getvalue())
    assert d["verdict"] == "coulomb_friction" and d["also_missing"] == []
    first, second = d["chain"]
    assert first["effects"] == ["coulomb_friction"]
    mass = first["held_out"]["members"]["mass_change"]
    assert not mass["earned"] and mass["fall"] <= mass["uncertainty"] + mass["model_refit_fall"]
    assert first["held_out"]["members"]["coulomb_friction"]["earned"]
    assert second["effects"] == ["actuator_delay"] and "dropped" not in second
    assert second["params"]["actuator_delay"]["delay"] == pytest.approx(1e-3, rel=0.01)
    assert second["params"]["coulomb_friction"]["level"] == pytest.approx(2.0, rel=0.01)
    found = load(tmp_path / "found.toml")
    assert "effects.mass_change.mass" not in found and found["effects.actuator_delay.delay"] == pytest.approx(1e-3, rel=0.01)
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(args) == 0
    assert "mass_change on its own: " in out.getvalue() and "not earned, taken out of the step" in out.getvalue()
