"""Issue 24, item 5: an effect is a plug-in in fact, not in name. An effect defined and registered
here, in a test module, is synthesized, screened, fitted and named by the diagnosis with its own
evidence, and no module of the identification names a catalogue effect as a string."""
import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from hil.config import load
from sim_plant.effects import CATALOGUE, Effect, Param, register

CFG = load("config/paper_bench.toml")
DRAG = 5000.0            # N s/m on the table, hidden by synth (its synth_strength)


class TableDrag(Effect):
    """Viscous drag on the table (a way cover, a wiper): F = c v on the table mass. Through the
    inverse model of a rigid axis the force residual (motor torque) it asks for is c v / k,
    k = force_to_load (2 pi / pitch): linear in c with the regressor v / k."""
    name = "table_drag_test"
    description = "viscous drag on the table (a way cover, a wiper), c v on the table mass"
    params = (Param("coefficient", "damping", 0.0, 1e6, 100.0, "viscous coefficient on the table"),)
    synth_strength = {"coefficient": DRAG}
    linear_param = "coefficient"

    def apply(self, plant, values):
        ch = plant.chain
        cg = list(ch.c_ground)
        cg[plant.table] += values["coefficient"]
        return dataclasses.replace(plant, chain=dataclasses.replace(ch, c_ground=tuple(cg)))

    def guess(self, plant, scale):
        return {"coefficient": scale.get("force", 1.0) / max(scale.get("speed", 1.0), 1e-9)}

    def _slope(self, ctx):
        """The force residual's slope in v while moving, as a force on the load (N per m/s)."""
        vm, r = ctx.v_cmd[ctx.moving], ctx.force_residual[ctx.moving]
        return float(vm @ r / (vm @ vm)) * ctx.force_to_load

    def evidence(self, ctx, values):
        if ctx.force_residual is None:
            return ""
        return f"the table drags: the {ctx.force_channel} residual rises {self._slope(ctx):.4g} N per m/s; "

    def regression_start(self, ctx):
        if ctx.force_residual is None or ctx.moving.sum() < 16:
            return None
        return {"coefficient": ctx.configured(self.name, "coefficient") + self._slope(ctx)}

    def linear_column(self, ctx):
        return ctx.v / ctx.force_to_load, ctx.configured(self.name, "coefficient")


@pytest.fixture(scope="module")
def drag():
    register(TableDrag)
    try:
        yield CATALOGUE[TableDrag.name]
    finally:
        del CATALOGUE[TableDrag.name]


@pytest.fixture(scope="module")
def drag_record(drag):
    from hil.ident import Replay, synthesize
    from hil.io.measurement import Measurement
    ch, truth = synthesize(CFG, TableDrag.name, duration=4.0, seed=3)
    return Replay(Measurement(ch, source="synth:table_drag_test"), CFG), truth


def test_synth_hides_the_effects_own_strength(drag_record):
    _, truth = drag_record
    assert truth["params"] == {"coefficient": DRAG}
    assert truth["config"]["effects.table_drag_test.coefficient"] == DRAG


def test_a_registered_effect_is_diagnosed_with_its_own_evidence(drag_record):
    from hil.ident import diagnose
    rp, _ = drag_record
    d = diagnose(rp, [TableDrag.name, "coulomb_friction", "constant_force"], jobs=1)
    assert d["verdict"] == TableDrag.name
    (c,) = [c for c in d["candidates"] if c.effect == TableDrag.name]
    # the hidden drag, fitted (closed form: the loop holds the command, the table sees c v)
    assert c.params["coefficient"] == pytest.approx(DRAG, rel=0.05)
    assert c.error_after <= 0.3 * c.error_before
    m = re.match(r"the table drags: the torque residual rises ([0-9.e+]+) N per m/s; RMS \w+ error", c.evidence)
    assert m, c.evidence
    # the evidence's slope is the regression of the residual before the fit: the same drag, independently
    assert float(m.group(1)) == pytest.approx(DRAG, rel=0.1)


def test_a_registered_linear_effect_joins_the_inverse_models_screen(drag, drag_record):
    from hil.ident.joint import linear_effects, regressors
    rp, _ = drag_record
    assert linear_effects()[TableDrag.name] == "coefficient"
    cols, moving = regressors(rp)
    col, have = cols[TableDrag.name]
    assert have == 0.0
    # v / k against viscous friction's s v: the same shape, scaled by 1 / (s k)
    s, k = rp.plant.speed_scale, rp.force_to_load
    vis = cols["viscous_friction"][0]
    assert np.allclose(col * s * k, vis)


def test_the_starts_come_from_the_effects_own_regression(drag, drag_record):
    from hil.ident.starts import record_scales, starting_values
    rp, _ = drag_record
    res0 = rp.residuals(CFG)
    starts = starting_values(drag, rp, res0, record_scales(rp, res0), CFG)
    assert len(starts) == 2 and starts[0]["coefficient"] == pytest.approx(DRAG, rel=0.1)


IDENT = Path(__file__).resolve().parents[1] / "hil" / "ident"


@pytest.mark.parametrize("module", ["evidence.py", "starts.py", "synth.py", "joint.py", "diagnosis.py"])
def test_the_identification_names_no_effect(module):
    """Adding an effect edits no module of the identification: none names a catalogue effect
    as a string (the effects say their own through their hooks)."""
    text = (IDENT / module).read_text()
    named = sorted(n for n in CATALOGUE if re.search(rf"[\"']{re.escape(n)}[\"']", text))
    assert not named, f"hil/ident/{module} names {named}"
