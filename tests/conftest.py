import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config"
SHARED = ROOT.parent / "shared"
sys.path.insert(0, str(ROOT / "benchmarks"))
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def bench():
    from hil import config
    return config.load(CONFIG / "paper_bench.toml")


@pytest.fixture(autouse=True)
def state_dir(tmp_path_factory, monkeypatch):
    """Every test its own state directory (the supervisor's latch): a test never touches the real
    home, and a trip in one test never refuses the motion of another. Subprocesses inherit it."""
    d = tmp_path_factory.mktemp("state")
    monkeypatch.setenv("HIL_STATE_DIR", str(d))
    return d
