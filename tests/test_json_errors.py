"""``--json`` always prints JSON (issue 51, item 5): a run that fails prints
``{"error", "exit_code", "kind"}`` on stdout beside its one line on stderr, so a script that reads
stdout gets an object either way (one that printed its object already prints no second one:
hil.cli's ``_Watched``)."""
import json

import pytest
from conftest import CONFIG

from hil.cli import main

BENCH = str(CONFIG / "paper_bench.toml")


@pytest.mark.parametrize("argv, code, kind, says", [
    (["move", "--config", "nope.toml", "--stroke", "10mm", "--feed", "1m/min", "--tacc", "100ms"], 2, "error",
     "no such configuration file"),
    (["move", "--config", BENCH, "--stroke", "10mm", "--feed", "7000", "mm/min", "--tacc", "100ms"], 2, "usage",
     "unrecognized arguments"),
    (["move", "--config", BENCH, "--stroke", "\u20ac10mm", "--feed", "1m/min", "--tacc", "100ms"], 2, "error", "U+20AC"),
])
def test_a_failed_json_run_prints_its_error_as_json(capsys, argv, code, kind, says):
    with pytest.raises(SystemExit) if kind == "usage" else _no_exit() as ctx:
        rc = main(argv + ["--json"])
    captured = capsys.readouterr()
    got = json.loads(captured.out)
    assert got["exit_code"] == code and got["kind"] == kind and says in got["error"]
    assert says in captured.err
    if kind == "usage":
        assert ctx.value.code == 2
    else:
        assert rc == code


class _no_exit:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


def test_a_unit_written_apart_is_said_with_its_fix_by_the_commands_own_usage(capsys):
    """``--feed 7000 mm/min`` gave the top-level usage and "unrecognized arguments: mm/min"."""
    with pytest.raises(SystemExit):
        main(["move", "--config", BENCH, "--stroke", "10mm", "--feed", "7000", "mm/min", "--tacc", "100ms", "--check"])
    err = capsys.readouterr().err
    assert err.startswith("usage: hil move") and "a quantity is one word: 7000mm/min" in err


def test_the_messages_name_the_fix(tmp_path, capsys):
    """The nearest key of the config's own chain (plant.kl on a chain of k1..k2 suggested plant.k9),
    --map for a record of other column names, the range form with its unit."""
    from hil.config import did_you_mean
    assert did_you_mean("plant.kl", ["plant.m1", "plant.m2", "plant.m3", "plant.k1", "plant.k2"]) == \
        "; did you mean 'plant.k1'?"
    rec = tmp_path / "drive.csv"
    rec.write_text("Time,Cmd,Act\n0,0,0\n0.004,0,0\n")
    assert main(["compare", str(rec), "--config", BENCH, "--out", str(tmp_path / "c")]) == 2
    assert "missing required column 't'" in (err := capsys.readouterr().err) and "--map" in err
    assert main(["sweep", "--config", BENCH, "--stroke", "50mm", "--feed", "6m/min", "--jmax", "1..2000",
                 "--no-plot"]) == 2
    assert "e.g. 1..2000m/s^3" in capsys.readouterr().err
