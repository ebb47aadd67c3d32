"""Every command's ``--json`` output against its documented keys (``JSON_KEYS`` of the command's
module, :class:`hil.io.jsonout.JsonKey`), from which docs/reference/json.md is generated: a key a
command prints is documented, and a documented key without a ``when`` is printed.

Each command runs once through ``hil.cli.main`` on small inputs: the simulated plant
(config/paper_bench.toml), a short record written by ``hil synth``, the simulated CiA 402 drive
in lockstep on a private virtual CAN channel for ``home``, ``jog``, ``status`` and ``reset`` (as
tests/test_axis_start.py), ``hil drive-sim`` as a process of its own, and the EMPS record where
it is present (``--quick --no-diagnose``; marked slow: about 20 s). Nested keys are checked where
they are documented: ``candidates[].effect`` against every entry of ``candidates``, ``final.end``
against ``final``.
"""
import argparse
import importlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import can
import pytest
from canopen_rig import channel
from conftest import CONFIG, ROOT, SHARED

from drivers.canopen.drive_sim import DriveSim
from hil import config
from hil.cli import COMMANDS, build_parser, main
from hil.io.jsonout import JsonKey
from hil.plant_config import plant_from_config

BENCH = str(CONFIG / "paper_bench.toml")
CANOPEN = str(CONFIG / "paper_bench_canopen.toml")
# the project's shared folder: beside the checkout, or where HIL_SHARED_DIR says (a worktree elsewhere)
EMPS = Path(os.environ.get("HIL_SHARED_DIR") or SHARED) / "data" / "emps" / "DATA_EMPS.mat"


def json_keys(command: str) -> dict:
    return importlib.import_module(COMMANDS[command]).JSON_KEYS


def _at(obj, path: str) -> list[dict]:
    """The objects at ``path`` of ``obj``: ``a.b`` the object ``b`` of ``a``, ``a[]`` every entry
    of the list ``a``."""
    nodes = [obj]
    for seg in path.split("."):
        many = seg.endswith("[]")
        name = seg[:-2] if many else seg
        found = []
        for n in nodes:
            v = n.get(name) if isinstance(n, dict) else None
            if v is not None:
                found += list(v) if many else [v]
        nodes = found
    return [n for n in nodes if isinstance(n, dict)]


def problems(obj: dict, keys: dict, complete: bool = True) -> list[str]:
    """What ``obj`` (a command's JSON) and its documentation ``keys`` disagree on: keys printed but
    not documented, and (``complete``: an ordinary run) documented keys without ``when`` missing."""
    groups: dict[str, dict[str, JsonKey]] = {}
    for key, doc in keys.items():
        parent, _, leaf = key.rpartition(".")
        groups.setdefault(parent, {})[leaf] = doc
    out = []
    for parent, docs in groups.items():
        for entry in [obj] if not parent else _at(obj, parent):
            where = f"{parent}." if parent else ""
            out += [f"printed, not documented: {where}{k}" for k in entry if k not in docs]
            if complete:
                out += [f"documented, not printed: {where}{k}" for k, d in docs.items()
                        if d.when is None and k not in entry]
    return sorted(set(out))


def run_json(capsys, command: str, *argv, rc: int = 0) -> dict:
    assert main([command, *map(str, argv), "--json"]) == rc, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)


def check(command: str, obj: dict, complete: bool = True) -> None:
    assert problems(obj, json_keys(command), complete) == []


# -- the checker and the generated page ------------------------------------------------------------

def test_the_check_finds_a_key_printed_but_not_documented_and_one_documented_but_missing():
    keys = {"a": JsonKey("m", "a length"), "b": JsonKey("", "a flag", when="with --b"),
            "rows": JsonKey("", "rows"), "rows[].x": JsonKey("s", "a time")}
    assert problems({"a": 1.0, "rows": [{"x": 1.0}, {"x": 2.0}]}, keys) == []
    assert problems({"a": 1.0, "b": True, "rows": []}, keys) == []
    assert problems({"a": 1.0, "c": 2, "rows": [{"x": 1.0, "y": 2}, {}]}, keys) == [
        "documented, not printed: rows[].x", "printed, not documented: c", "printed, not documented: rows[].y"]
    assert problems({"rows": []}, keys) == ["documented, not printed: a"]
    assert problems({"rows": []}, keys, complete=False) == []


def test_every_command_with_json_documents_its_keys():
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    with_json = {name for name, p in sub.choices.items() if any("--json" in a.option_strings for a in p._actions)}
    assert with_json >= {"compare", "diagnose", "fit", "emps", "frf", "model", "move", "sweep", "synth", "home", "jog",
                         "status", "reset", "drive-sim"}
    for name in with_json:
        keys = json_keys(name)
        assert keys and all(isinstance(k, JsonKey) for k in keys.values()), name
        for key, k in keys.items():
            assert k.text.strip() and "\n" not in k.text, (name, key)
            # Markdown: <word> would be read as an HTML tag, {...} as attributes, outside `code`
            assert not re.search(r"[<{]", re.sub(r"`[^`]*`", "", k.text + (k.when or ""))), (name, key)
            assert key.split(".")[0].removesuffix("[]") in keys, (name, key)      # a nested key's parent too


def test_the_generated_page_lists_every_key_of_every_command():
    import importlib.util
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "docs" / "gen_reference.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    page = gen.json_reference()
    assert "reference/json.md" in gen.PAGES
    for name in gen.json_keys():
        section = page.split(f"\n## hil {name}\n", 1)[1].split("\n## hil ", 1)[0]
        for key, k in json_keys(name).items():
            row = next((ln for ln in section.splitlines() if ln.startswith(f"| `{key}` |")), None)
            assert row is not None, (name, key)
            assert (k.when or "") in row and (k.unit or "-") in row, (name, key, row)
        assert f"[`hil {name} --json`](#hil-{name})" in page


# -- the model side --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def record(tmp_path_factory):
    """A short record with a hidden Coulomb friction (2 s, 4 ms sampling)."""
    out = tmp_path_factory.mktemp("record") / "coulomb.csv"
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "level=2Nm",
                 "--duration", "2s", "--out", str(out)]) == 0
    return out


def test_model(capsys, tmp_path):
    check("model", run_json(capsys, "model", "--config", BENCH, "--out", tmp_path))


def test_synth(capsys, tmp_path):
    check("synth", run_json(capsys, "synth", "--config", BENCH, "--effect", "coulomb_friction", "--duration", "1s",
                            "--pulses", "0.2Nm", "--out", tmp_path / "s.csv"))


def test_move_and_its_check(capsys, tmp_path):
    move = ("move", "--config", BENCH, "--stroke", "5mm", "--feed", "3000mm/min", "--amax", "2m/s^2", "--dwell",
            "0.2s", "--out", tmp_path)
    out = run_json(capsys, *move)
    assert out["status"] == "complete"
    check("move", out)
    check("move", run_json(capsys, *move, "--check"), complete=False)
    check("move", run_json(capsys, "move", "--config", BENCH, "--stroke", "0mm", "--feed", "3000mm/min", "--amax",
                           "2m/s^2", "--out", tmp_path), complete=False)


def test_sweep(capsys, tmp_path):
    check("sweep", run_json(capsys, "sweep", "--config", BENCH, "--stroke", "5mm", "--feed", "3m/min", "--jmax",
                            "50,500m/s^3", "--dwell", "0.2s", "--jobs", "1", "--out", tmp_path, "--no-plot",
                            "--no-progress"))


def test_frf_and_a_fit_to_its_responses(capsys, tmp_path):
    check("frf", run_json(capsys, "frf", "--config", BENCH, "--periods", "2", "--out", tmp_path))
    out = run_json(capsys, "fit", tmp_path / "frf.json", "--config", BENCH, "--add", "parameter:plant.c2", "--out",
                   tmp_path / "c2.toml")
    assert out["domain"] == "frequency"
    check("fit", out)


def test_compare(capsys, tmp_path, record):
    check("compare", run_json(capsys, "compare", record, "--config", BENCH, "--out", tmp_path))


def test_diagnose_with_its_chain(capsys, tmp_path, record):
    out = run_json(capsys, "diagnose", record, "--config", BENCH, "--candidates", "coulomb_friction", "--jobs", "1",
                   "--max-steps", "2", "--report", tmp_path / "d.html")
    assert out["verdict"] == "coulomb_friction" and out["chain"]
    check("diagnose", out)


def test_fit(capsys, tmp_path, record):
    out = run_json(capsys, "fit", record, "--config", BENCH, "--add", "coulomb_friction", "--out", tmp_path / "f.toml")
    assert out["written"]
    check("fit", out)


@pytest.mark.slow                  # about 20 s even --quick: the whole chain on 25 000 samples
@pytest.mark.skipif(not EMPS.exists(), reason=f"EMPS record not present at {EMPS}")
def test_emps(capsys, tmp_path):
    check("emps", run_json(capsys, "emps", "--data", EMPS, "--config", CONFIG / "emps.toml", "--quick",
                           "--no-diagnose", "--out", tmp_path))


# -- the CANopen commands ----------------------------------------------------------------------------------

@pytest.fixture
def drive():
    """The simulated CiA 402 drive with a tip sensor node, in lockstep on a virtual channel of its own;
    the command line's options that reach it."""
    ch = channel("json")
    over = {"canopen.lockstep": True, "canopen.interface": "virtual", "canopen.channel": ch, "canopen.tip_node_id": 2}
    cfg = config.load(CANOPEN, over)
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    try:
        yield ["--config", CANOPEN, *[x for k, v in over.items() for x in ("--set", f"{k}={str(v).lower()}")]]
    finally:
        sim.close()


def test_status_home_jog_reset(capsys, drive):
    check("status", run_json(capsys, "status", *drive))
    check("home", run_json(capsys, "home", *drive, "--offset", "1mm"))
    check("jog", run_json(capsys, "jog", *drive, "--distance", "1mm"))
    check("jog", run_json(capsys, "jog", *drive, "--distance", "0mm"), complete=False)
    check("reset", run_json(capsys, "reset", *drive))


def test_drive_sim_both_lines():
    """The connection settings when the drive is up, its answer times when it stops."""
    cmd = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))", "drive-sim",
           "--config", CANOPEN, "--set", "canopen.tip_node_id=2", "--port", "0", "--seconds", "0.5s", "--json"]
    r = subprocess.run(cmd, cwd=ROOT, env=dict(os.environ), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    first, *_, last = [json.loads(line) for line in r.stdout.splitlines() if line.strip()]
    assert first["tip_node_id"] == 2 and "syncs" in last
    check("drive-sim", first)
    check("drive-sim", last, complete=False)
