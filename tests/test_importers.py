"""One --map convention, SOURCE=CHANNEL[unit], for CSV columns and MATLAB variables."""
import numpy as np
import pytest
import scipy.io

from hil.io.importers import parse_mapping, read_any
from hil.io.measurement import MeasurementError


def _mat(tmp_path):
    t = np.arange(5) * 1e-3
    p = tmp_path / "rec.mat"
    scipy.io.savemat(p, {"time": t[:, None], "ref": (2.0 * t)[:, None], "pos": (1.5 * t)[:, None],
                         "u": np.ones((5, 1)), "g": np.array([[3.0]])})
    return p, t


def _csv(tmp_path):
    t = np.arange(5) * 1e-3
    p = tmp_path / "rec.csv"
    rows = "\n".join(f"{a},{b},{c}" for a, b, c in zip(t, 2.0 * t, 1.5 * t))
    p.write_text("t [s],ref [mm],pos\n" + rows + "\n")
    return p, t


def test_same_mapping_reads_mat_and_csv(tmp_path):
    pm, t = _mat(tmp_path)
    pc, _ = _csv(tmp_path)
    m = read_any(pm, parse_mapping("time=t, ref=x_cmd[mm], pos=x_table[mm], u*g=force"))
    c = read_any(pc, parse_mapping(["ref=x_cmd", "pos=x_table[mm]"]))
    # 1.5 t millimetres = 1.5e-3 t metres, whichever the format
    np.testing.assert_allclose(m["x_table"], 1.5e-3 * t)
    np.testing.assert_allclose(c["x_table"], 1.5e-3 * t)
    np.testing.assert_allclose(m["x_cmd"], 2e-3 * t)      # unit from the mapping
    np.testing.assert_allclose(c["x_cmd"], 2e-3 * t)      # unit from the CSV header
    np.testing.assert_allclose(m["force"], 3.0)            # product of variables, SI


def test_mapping_errors_name_the_problem(tmp_path):
    pm, _ = _mat(tmp_path)
    with pytest.raises(MeasurementError, match="SOURCE=CHANNEL"):
        parse_mapping("x_cmd")
    with pytest.raises(MeasurementError, match="no variable 'qq'"):
        read_any(pm, parse_mapping("time=t,qq=x_cmd"))
    with pytest.raises(MeasurementError, match="VARIABLE=x_cmd"):
        read_any(pm, parse_mapping("time=t,pos=x_table"))
