"""No warning on the project's own clean records (issue 51, item 3): the tutorial's `hil synth`
records were warned about for "outliers" of the torque that were its real steps at the start and
the end of each move, which the command explains. A spike away from a move's edges is still one."""
import numpy as np
import pytest
from conftest import CONFIG

from hil.cli import main
from hil.io.importers import data_warnings, read_any

BENCH = str(CONFIG / "paper_bench.toml")


@pytest.mark.parametrize("effect, param", [("coulomb_friction", "level=2.2Nm"), ("backlash", "gap=20um")])
def test_a_clean_synthetic_record_gets_no_warning_and_a_spike_still_does(tmp_path, effect, param):
    rec = tmp_path / "r.csv"
    assert main(["synth", "--config", BENCH, "--effect", effect, "--param", param, "--out", str(rec)]) == 0
    meas = read_any(rec)
    assert data_warnings(meas, 0.004) == []
    from hil.io.importers import _accelerating
    u = meas.channels["torque"].copy()
    calm = np.flatnonzero(~_accelerating(meas))
    k = int(calm[len(calm) // 2])                         # a sample away from the start and end of a move
    u[k] += 20 * (np.ptp(u) + 1.0)
    meas.channels["torque"] = u
    (warning,) = data_warnings(meas, 0.004)
    assert "channel 'torque': 1 outlier(s)" in warning and f"sample(s) {k + 1} " in warning
