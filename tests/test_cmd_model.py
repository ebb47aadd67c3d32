"""``hil model``: the required figures, JSON output, plots and error handling."""
import json
import math

import numpy as np
import pytest

from hil.cli import main


def run_json(capsys, *argv):
    assert main(["model", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_paper_bench_3dof(capsys, tmp_path):
    r = run_json(capsys, "--config", "config/paper_bench.toml", "--out", str(tmp_path))
    np.testing.assert_allclose(r["modes_hz"], [14.94, 86.63], atol=0.02)
    np.testing.assert_allclose(r["damping_ratios"], [0.015, 0.085], atol=0.0005)
    assert r["damping_ratios_with_friction"][1] == pytest.approx(0.090, abs=0.0005)
    assert r["viscous_friction_N_s_per_m"] == pytest.approx(0.0076 * (2 * math.pi / 0.01) ** 2)
    assert r["masses_kg"] == [335.57, 392.97, 4.228]
    assert (tmp_path / "bode_tf.png").stat().st_size > 10_000
    assert r["plot"] == str(tmp_path / "bode_tf.png")


def test_paper_bench_2dof(capsys, tmp_path):
    r = run_json(capsys, "--config", "config/paper_bench_2dof.toml", "--out", str(tmp_path))
    assert len(r["modes_hz"]) == 1
    assert r["modes_hz"][0] == pytest.approx(86.4, abs=0.02)


def test_set_override_changes_ratio(capsys, tmp_path):
    # c2 = 33 N s/m (the half-power value of Section 4.2.2) gives the 15 Hz mode about 0.042
    r = run_json(capsys, "--config", "config/paper_bench.toml", "--set", "plant.c2=33", "--out", str(tmp_path))
    assert r["damping_ratios"][0] == pytest.approx(0.042, abs=0.001)


def test_text_output_and_closed_loop_flag(capsys, tmp_path):
    assert main(["model", "--config", "config/paper_bench.toml", "--out", str(tmp_path), "--closed-loop"]) == 0
    out = capsys.readouterr().out
    assert "14.943 Hz" in out and "86.631 Hz" in out


@pytest.mark.parametrize("argv,message", [
    (["--config", "nope.toml"], "nope.toml: no such configuration file"),
    (["--config", "config/paper_bench.toml", "--set", "plant.m2=10 mm"], "plant.m2: '10 mm' is not a mass"),
    (["--config", "config/paper_bench.toml", "--set", "plant.k9=1"], "unknown key 'plant.k9'"),
    (["--config", "config/paper_bench.toml", "--set", "plant.c2"], "expected KEY=VALUE"),
])
def test_errors_are_one_line(capsys, tmp_path, argv, message):
    assert main(["model", *argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert err.count("\n") == 1
