"""One ``hil move`` reads its config once and samples its trajectory once (issue 48): the CAN
options are applied to the config loaded, not by loading the file again, and the samples checked
against the limits are the ones run."""
import argparse
from pathlib import Path

from hil import profiles
from hil.cli import main
from hil.commands.move import add_arguments, load_config

ROOT = Path(__file__).resolve().parents[1]
CANOPEN = str(ROOT / "config" / "paper_bench_canopen.toml")


def _args(*argv):
    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(["--stroke", "10mm", "--feed", "7000mm/min", "--tacc", "200ms", *argv])


def test_can_options_apply_to_the_config_read_once(monkeypatch):
    """``-i``/``-c``/``-b`` on a CANopen config: the file is read once; the options are in the
    config; ``--set`` wins over an option naming the same key; the file's own keys are known."""
    from hil.config import loader
    reads = []
    real = loader.loads
    monkeypatch.setattr(loader, "loads", lambda *a, **k: reads.append(a[1]) or real(*a, **k))
    cfg = load_config(_args("--config", CANOPEN, "-i", "virtual", "-c", "c7", "-b", "500000",
                            "--set", "canopen.channel=from_set"))
    assert len(reads) == 1
    assert cfg["canopen.interface"] == "virtual" and cfg["canopen.bitrate"] == 500000
    assert cfg["canopen.channel"] == "from_set"
    assert cfg.overrides["canopen.interface"] == "virtual" and cfg.overrides["canopen.channel"] == "from_set"
    import tomllib
    table = tomllib.loads(Path(CANOPEN).read_text())
    assert cfg.file_keys == {f"{sec}.{k}" for sec, t in table.items() for k in t}     # no nested tables here


def test_a_move_samples_its_trajectory_once(monkeypatch, tmp_path, capsys):
    """A dry-run ``hil move``: ``Trajectory.sample`` is called once, and the record holds that many
    rows."""
    calls = []
    real = profiles.Trajectory.sample

    def counted(self, period, settle=0.0):
        out = real(self, period, settle)
        calls.append(out[1].size)
        return out
    monkeypatch.setattr(profiles.Trajectory, "sample", counted)
    rc = main(["move", "--config", str(ROOT / "config" / "paper_bench.toml"), "--stroke", "10mm",
               "--feed", "7000mm/min", "--tacc", "200ms", "--out", str(tmp_path)])
    assert rc == 0, capsys.readouterr()
    assert len(calls) == 1
    rows = [ln for ln in (tmp_path / "move.csv").read_text().splitlines() if ln and not ln.startswith("#")]
    assert len(rows) - 1 == calls[0]
