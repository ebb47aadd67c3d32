"""Fitting catalogue effects and parameters to measured frequency responses (hil frf -> hil fit)."""
import json

import pytest
from conftest import CONFIG

from hil.cli import main
from hil.config import load
from hil.ident.frf_fit import FrfDataError, fit_frf, is_frf_file, load_frf


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """The bench measured with a compliant-mass damping of 40 N s/m (the config says 11.8), with
    speed noise on the simulated sensor."""
    out = tmp_path_factory.mktemp("frf")
    rc = main(["frf", "--config", str(CONFIG / "paper_bench.toml"), "--sim-set", "plant.c2=40",
               "--noise", "3e-4 rad/s", "--periods", "4", "--out", str(out), "--json"])
    assert rc == 0
    return out / "frf.json"


def test_fit_recovers_c2_from_the_frequency_responses(measured):
    cfg = load(CONFIG / "paper_bench.toml")
    data = load_frf(measured)
    assert is_frf_file(measured)
    fit = fit_frf(cfg, data, ["parameter:plant.c2"])
    assert fit.params["value"] == pytest.approx(40.0, rel=0.05)
    assert fit.error_after < 0.2 * fit.error_before
    assert fit.config["plant.c2"] == pytest.approx(fit.params["value"])


def test_hil_fit_takes_frf_data(measured, tmp_path, capsys):
    new = tmp_path / "fitted.toml"
    rc = main(["fit", str(measured), "--config", str(CONFIG / "paper_bench.toml"), "--add", "parameter:plant.c2",
               "--out", str(new), "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["domain"] == "frequency"
    assert load(new)["plant.c2"] == pytest.approx(40.0, rel=0.05)


def test_bad_frf_file_is_one_clear_error(tmp_path):
    p = tmp_path / "x.json"
    p.write_text('{"responses": {"TF2": {"frequency_hz": [1, 2]}}}')
    with pytest.raises(FrfDataError, match=r"x.json: responses.TF2: expected frequency_hz, magnitude, phase_deg"):
        load_frf(p)
