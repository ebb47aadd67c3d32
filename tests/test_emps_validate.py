"""``hil emps --validate``: the models fitted on DATA_EMPS.mat replayed on a validation record, its
pulses as the u_add input, beside the published validation figures (skipped without the record;
the path that needs u_add skipped where this version has no such channel)."""
import json
from pathlib import Path

import numpy as np
import pytest

from hil.io.measurement import CHANNELS

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "emps" / "DATA_EMPS.mat"
pytestmark = pytest.mark.skipif(not DATA.exists(), reason=f"EMPS record not present at {DATA}")


def _pulses_record(tmp_path):
    """The training record written as a validation record with no pulses (pulses_N all 0): its
    validation errors must be the training record's own errors of the same models."""
    import scipy.io
    d = scipy.io.loadmat(DATA)
    out = {k: d[k] for k in ("t", "qm", "qg", "vir", "gtau", "kp", "kv")}
    out["pulses_N"] = np.zeros_like(d["vir"])
    p = tmp_path / "DATA_EMPS_PULSES.mat"
    scipy.io.savemat(p, out)
    return p


@pytest.mark.slow
@pytest.mark.skipif("u_add" not in CHANNELS, reason="no u_add input channel in this version (issue 15 item 1)")
def test_emps_validate_json(tmp_path, capsys):
    from hil.cli import main
    from hil.ident.emps import PUBLISHED_VALIDATION
    val = _pulses_record(tmp_path)
    rc = main(["emps", "--data", str(DATA), "--validate", str(val), "--quick", "--no-diagnose", "--out",
               str(tmp_path / "emps"), "--json"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert d["published_validation"] == PUBLISHED_VALIDATION == {"position": 0.0080, "force": 8.94}
    rows = {r["step"]: r for r in d["rows"]}
    for v in d["validation"]:
        assert v["record"] == str(val)
        r = rows[v["model"]]          # no pulses: the same record, the same errors
        for k in ("position", "velocity", "force"):
            assert v[k] == pytest.approx(r[k], rel=1e-9)
    assert "published** validation" in (tmp_path / "emps" / "table.md").read_text()
    # the fitted models are edits of the start config: its comments kept, the fitted values in it
    from hil.config import load
    start = Path("config/emps.toml").read_text()
    for name, step in (("emps_fitted.toml", "output-error refit of M, Fv, Fc, offset"),
                       ("emps_asymmetric.toml", "+ asymmetric_friction")):
        text = (tmp_path / "emps" / name).read_text()
        assert start.splitlines()[0] in text and "published IDIM-LS mass M" in text and "hil emps on DATA_EMPS.mat" in text
        cfg, want = load(tmp_path / "emps" / name), rows[step]["params"]
        assert cfg["plant.m1"] == pytest.approx(want["M"], rel=1e-8)
        if "level_pos" in want:
            # the row names what the model has: the asymmetric levels, not the Fv and Fc they replaced
            assert "Fv" not in want and "Fc" not in want
            # asymmetric_friction sets the dry friction anew: the Coulomb level it replaced is left out
            # (the same plant), its own levels written
            assert "effects.coulomb_friction.level" not in cfg
            # and the motor's viscous friction, which it sets anew too (the start config's Fv): none left
            assert cfg["friction.viscous"] == 0.0
            for k in ("level_pos", "level_neg", "viscous_pos", "viscous_neg"):
                assert cfg[f"effects.asymmetric_friction.{k}"] == pytest.approx(want[k], rel=1e-8)
        else:
            assert cfg["friction.viscous"] == pytest.approx(want["Fv"], rel=1e-8)
            assert cfg["effects.coulomb_friction.level"] == pytest.approx(want["Fc"], rel=1e-8)


@pytest.mark.skipif("u_add" in CHANNELS, reason="this version has the u_add input channel")
def test_emps_validate_refused_without_u_add(tmp_path, capsys):
    from hil.config import load
    from hil.errors import HilError
    from hil.ident.emps import validate_emps
    with pytest.raises(HilError, match="u_add input channel"):
        validate_emps(_pulses_record(tmp_path), {"start": load("config/emps.toml")})
