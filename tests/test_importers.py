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


# --- every layout through one map (issue 15) ---------------------------------------------------

def _signals(n=400):
    t = np.arange(n) * 4e-3
    x = 0.01 * np.sin(2 * np.pi * 0.5 * t)
    return t, x, x - 1e-5 * np.cos(2 * np.pi * 0.5 * t), 0.3 * np.cos(2 * np.pi * 0.5 * t)


def _same_channels(a, b):
    assert set(a.channels) == set(b.channels)
    for c in a.channels:
        np.testing.assert_allclose(a[c], b[c], rtol=1e-9, atol=1e-15, err_msg=c)


@pytest.fixture
def layouts(tmp_path):
    """One record (t [s], x_cmd [mm], x_table [mm], current [A]) in every layout."""
    t, x, xt, cur = _signals()
    mm = np.column_stack([t, x * 1e3, xt * 1e3, cur])
    csv = tmp_path / "r.csv"
    csv.write_text("t [s],x_cmd [mm],x_table [mm],current [A]\n" +
                   "\n".join(",".join(f"{v:.10g}" for v in row) for row in mm) + "\n")
    mat = tmp_path / "r.mat"
    scipy.io.savemat(mat, {"data": mm, "kt": np.array([[4.29e-5]])})
    txt = tmp_path / "r.txt"
    txt.write_text("time  ref_mm  pos_mm  current\n" + "\n".join("  ".join(f"{v:.10g}" for v in row) for row in mm))
    semi = tmp_path / "r_semi.csv"
    semi.write_text("Time (s);Position Target (mm);Position Actual (mm);Current (A)\n" +
                    "\n".join(";".join(f"{v:.10g}".replace(".", ",") for v in row) for row in mm))
    return {"csv": csv, "mat": mat, "txt": txt, "semi": semi, "rows": mm}


def test_matrix_text_and_excel_import_like_the_csv(tmp_path, layouts):
    openpyxl = pytest.importorskip("openpyxl")
    ref = read_any(layouts["csv"], parse_mapping("current*4.29e-5=torque"))
    np.testing.assert_allclose(ref["torque"], layouts["rows"][:, 3] * 4.29e-5)
    # a column of a matrix variable, 0-based as numpy, and MATLAB's 1-based (:,k)
    mat = read_any(layouts["mat"], parse_mapping("data[:,0]=t,data[:,1]=x_cmd[mm],data(:,3)=x_table[mm],"
                                                 "data[:,3]*kt=torque"))
    _same_channels(mat, ref)
    txt = read_any(layouts["txt"], parse_mapping("time=t,ref_mm=x_cmd[mm],pos_mm=x_table[mm],current*4.29e-5=torque"))
    _same_channels(txt, ref)
    semi = read_any(layouts["semi"], parse_mapping("Time=t,Position_Target=x_cmd,Position_Actual=x_table,"
                                                   "Current*4.29e-5=torque"))
    _same_channels(semi, ref)       # the units of the header's parentheses, a decimal comma
    wb = openpyxl.Workbook()
    wb.active.title = "other"
    ws = wb.create_sheet("run 1")
    ws.append(["t [s]", "ref [mm]", "pos", "current [A]"])
    for row in layouts["rows"]:
        ws.append([float(v) for v in row])
    xl = tmp_path / "r.xlsx"
    wb.save(xl)
    sheet = read_any(xl, parse_mapping("ref=x_cmd,pos=x_table[mm],current*4.29e-5=torque"), sheet="run 1")
    _same_channels(sheet, ref)
    with pytest.raises(MeasurementError, match="no sheet 'run 2'.*other, run 1"):
        read_any(xl, parse_mapping("ref=x_cmd"), sheet="run 2")


def test_headerless_text_is_the_matrix_data(tmp_path, layouts):
    p = tmp_path / "log.txt"
    p.write_text("\n".join("\t".join(f"{v:.10g}" for v in row) for row in layouts["rows"]))
    m = read_any(p, parse_mapping("data[:,0]=t,data[:,1]=x_cmd[mm],data[:,2]=x_table[mm]"))
    np.testing.assert_allclose(m["x_table"], layouts["rows"][:, 2] * 1e-3)
    with pytest.raises(MeasurementError, match=r"no header: map the columns of 'data'"):
        read_any(p)


def test_matlab_73_hdf5(tmp_path, layouts):
    h5py = pytest.importorskip("h5py")
    p = tmp_path / "r73.mat"
    with h5py.File(p, "w", userblock_size=512) as f:
        f["data"] = layouts["rows"].T          # MATLAB stores a matrix transposed in HDF5
        f["kt"] = np.array([[4.29e-5]])
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 .".ljust(124) + b"\x00\x02IM"
    with open(p, "r+b") as fh:
        fh.write(header)
    m = read_any(p, parse_mapping("data[:,0]=t,data[:,1]=x_cmd[mm],data[:,2]=x_table[mm],data[:,3]*kt=torque"))
    ref = read_any(layouts["csv"], parse_mapping("current*4.29e-5=torque"))
    _same_channels(m, ref)


@pytest.mark.parametrize("entry,word", [
    ("data=t", "--map data=t: 'data' is a 400 x 4 matrix"),
    ("data[:,7]=t", "--map data\\[:,7\\]=t: 'data' has 4 columns"),
    ("data[:,0]=t,dta[:,1]=x_cmd", "--map dta\\[:,1\\]=x_cmd: no variable 'dta'"),
    ("data[:,0]=t,data[:,1]=x_cdm", "--map data\\[:,1\\]=x_cdm: 'x_cdm' is not a channel"),
    ("data[:,0]=t,open('x')=x_cmd", "is not allowed"),
    ("data(:,0)=t", "counts from 1"),
])
def test_bad_map_entry_is_named(layouts, entry, word):
    with pytest.raises(MeasurementError, match=word):
        read_any(layouts["mat"], parse_mapping(entry))


def test_misspelt_csv_column_is_named(layouts):
    with pytest.raises(MeasurementError, match="--map curent\\*4.29e-5=torque: no variable 'curent'"):
        read_any(layouts["csv"], parse_mapping("curent*4.29e-5=torque"))


def test_warnings_name_the_samples(tmp_path):
    from hil.io.importers import data_warnings
    from hil.io.measurement import Measurement
    t, x, xt, cur = _signals(2000)
    cur = cur.copy()
    cur[1234] = 16711.0                 # one corrupt current sample
    t = t.copy()
    t[1500:] += 0.02                    # a gap of 6 sample periods
    p = tmp_path / "w.csv"
    rows = np.column_stack([t, x * 1e3, xt * 1e3, cur])
    p.write_text("t [s],x_cmd [mm],x_table [mm],current [A]\n" +
                 "\n".join(",".join(f"{v:.10g}" for v in row) for row in rows) + "\n")
    m = read_any(p, parse_mapping("current=torque[N*m]"))
    w = data_warnings(m, position_period=4e-4)
    assert any("'torque'" in s and "sample(s) 1235" in s and "16711" in s for s in w), w
    assert any("gap" in s and "1501" in s for s in w), w
    assert any("10 times the position loop" in s for s in w), w
    clean = Measurement({"t": t[:1000], "x_cmd": x[:1000], "torque": cur[:1000]})
    assert data_warnings(clean, position_period=4e-3) == []


def test_compare_prints_each_warning_with_its_file_once(tmp_path, capsys):
    """The warnings name their file themselves: the command prints them as they are."""
    from hil.cli import main
    from hil.config import examples_dir
    cfg = str(examples_dir() / "paper_bench.toml")
    rec = tmp_path / "r.csv"
    assert main(["synth", "--config", cfg, "--duration", "2s", "--out", str(rec)]) == 0
    lines = rec.read_text().split("\n")
    head = next(i for i, s in enumerate(lines) if s.startswith("t "))
    row = lines[head + 251].split(",")
    row[-1] = str(float(row[-1]) + 500.0)          # one corrupt torque sample
    lines[head + 251] = ",".join(row)
    bad = tmp_path / "spike.csv"
    bad.write_text("\n".join(lines))
    capsys.readouterr()
    assert main(["compare", str(bad), "--config", cfg, "--out", str(tmp_path / "o")]) == 0
    warned = [s for s in capsys.readouterr().err.splitlines() if s.startswith("warning:")]
    assert warned and all(s.count("spike.csv") == 1 for s in warned), warned
    assert any("channel 'torque'" in s and "sample(s) 251" in s for s in warned), warned
