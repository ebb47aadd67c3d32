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
