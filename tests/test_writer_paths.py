"""Every writer of every command that writes files, fuzzed for planted links (issue 49: "a fuzzer
per surface ... and every writer's path"): each command runs once into a clean folder to learn the
files it writes; then again into a folder where a symbolic link to a file outside stands at every
one of those names (and at the names of the temporary files beside them). The file outside is
never written, whatever the command does: it replaces the link with a file of its own, or it
refuses in one line (exit 2) without a traceback.

The commands run through ``hil.cli.main`` on the simulated plant and a short synthetic record (the
fleet's: two nights of it; hil emps: the EMPS record it ships with)."""
from __future__ import annotations

from pathlib import Path

import pytest
from conftest import CONFIG

from hil.cli import main

BENCH = str(CONFIG / "paper_bench.toml")
MOVE = ["--stroke", "10mm", "--feed", "7000mm/min", "--tacc", "200ms"]


def _record(root: Path) -> Path:
    """The synthetic record, and beside it a fleet of it (one axis, two nights: rec/fleet) and that
    fleet's run (rec/fleet-run), which hil fleet report reads."""
    rec = root / "rec" / "friction.csv"
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--out", str(rec)]) == 0
    for night in ("2026-03-02", "2026-03-09"):
        (rec.parent / "fleet" / "A").mkdir(parents=True, exist_ok=True)
        (rec.parent / "fleet" / "A" / f"{night}.csv").write_bytes(rec.read_bytes())
    return rec


FLEET = ["--config", BENCH, "--max-steps", "0", "--baseline", "1", "--jobs", "1"]


# command -> argv given the output folder and the synthetic record
COMMANDS = {
    "move": lambda out, rec: ["move", "--config", BENCH, *MOVE, "--out", out],
    "sweep": lambda out, rec: ["sweep", "--config", BENCH, "--stroke", "20mm", "--feed", "7000mm/min",
                               "--jmax", "50,200m/s^3", "--no-progress", "--out", out],
    "compare": lambda out, rec: ["compare", rec, "--config", BENCH, "--out", out],
    "fit": lambda out, rec: ["fit", rec, "--config", BENCH, "--add", "coulomb_friction", "--out", Path(out) / "fit.toml"],
    "diagnose": lambda out, rec: ["diagnose", rec, "--config", BENCH, "--max-steps", "2", "--out",
                                  Path(out) / "fitted.toml", "--report", Path(out) / "diagnose.html"],
    "synth": lambda out, rec: ["synth", "--config", BENCH, "--effect", "backlash", "--out", Path(out) / "s.csv"],
    "frf": lambda out, rec: ["frf", "--config", BENCH, "--periods", "2", "--out", out],
    "tune": lambda out, rec: ["tune", "--config", BENCH, "--stroke", "100mm", "--feed", "7000mm/min", "--out", out],
    "model": lambda out, rec: ["model", "--config", BENCH, "--out", out],
    "emps": lambda out, rec: ["emps", "--quick", "--no-diagnose", "--out", out],
    "fleet_run": lambda out, rec: ["fleet", "run", rec.parent / "fleet", *FLEET, "--out", out],
    "fleet_report": lambda out, rec: ["fleet", "report", rec.parent / "fleet-run", "--out", out],
}


def _written(folder: Path) -> list[Path]:
    return sorted(p.relative_to(folder) for p in folder.rglob("*") if p.is_file())


@pytest.mark.slow
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_no_writer_follows_a_planted_link(command, tmp_path, capsys):
    rec = _record(tmp_path)
    if command == "fleet_report":
        assert main([str(a) for a in ["fleet", "run", rec.parent / "fleet", *FLEET, "--out", rec.parent / "fleet-run"]]) == 0
    capsys.readouterr()
    clean = tmp_path / "clean"
    assert main([str(a) for a in COMMANDS[command](clean, rec)]) == 0, capsys.readouterr().err
    names = _written(clean)
    assert names, f"{command} wrote nothing"
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "planted"
    for name in names:
        for link in (out / name, (out / name).with_name(name.name + ".tmp")):
            link.parent.mkdir(parents=True, exist_ok=True)
            link.symlink_to(victim)
    capsys.readouterr()
    rc = main([str(a) for a in COMMANDS[command](out, rec)])
    err = capsys.readouterr().err
    assert victim.read_text() == "precious", f"{command} wrote through a link"
    if rc != 0:
        assert rc == 2 and "Traceback" not in err and err.strip().count("\n") == 0, err
        assert "link" in err
