import os
import signal
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config"
SHARED = ROOT.parent / "shared"


def _keep_checkout_off_path() -> None:
    """Test the installed package, not the source tree: ``python -m pytest`` puts the working
    directory (the clone's root) first on sys.path, where the checkout's ``hil/`` would shadow
    the installed one and hide a file missing from the wheel. That entry goes; a PYTHONPATH given
    on purpose (a checkout being worked on, an editable install) stays."""
    given = {os.path.realpath(p) for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p}
    if str(ROOT) in given:
        return
    sys.path[:] = [p for p in sys.path if os.path.realpath(p or os.curdir) != str(ROOT)]


_keep_checkout_off_path()
# a suite started as a background job of a shell (nohup ... &) inherits SIGINT ignored, and so would every
# command it starts (an ignored signal stays ignored across exec): the tests that stop a drive simulator or
# a scope's hold with Ctrl-C need it heard (a handler is reset to the default in a child)
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
sys.path.insert(0, str(ROOT / "benchmarks"))
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def bench():
    from hil import config
    return config.load(CONFIG / "paper_bench.toml")


@pytest.fixture(scope="session")
def hsm_record(tmp_path_factory):
    """An open-loop record of the HSM150 motor (config/hsm150.toml: 1 m = 1 rad, no screw): torque
    pulses of 0.05 N m, 2 s."""
    from hil.cli import main
    out = tmp_path_factory.mktemp("hsm") / "steps.csv"
    assert main(["synth", "--config", str(CONFIG / "hsm150.toml"), "--open-loop", "--pulses", "0.05Nm",
                 "--duration", "2s", "--out", str(out)]) == 0
    return str(out)


@pytest.fixture(autouse=True)
def state_dir(tmp_path_factory, monkeypatch):
    """Every test its own state directory (the supervisor's latch): a test never touches the real
    home, and a trip in one test never refuses the motion of another. Subprocesses inherit it."""
    d = tmp_path_factory.mktemp("state")
    monkeypatch.setenv("HIL_STATE_DIR", str(d))
    return d


def pytest_configure(config):
    """Any run but the default set keeps each test module on one worker (xdist's loadscope): a docs
    page's slow commands build on what its earlier ones wrote, and a module's fixtures (a fleet's
    records) are computed once. The default set (addopts' ``-m 'not slow'``) spreads its tests
    one by one (load), which balances the workers best."""
    if getattr(config.option, "dist", "no") == "load" and config.option.markexpr != "not slow":
        config.option.dist = "loadscope"


def pytest_collection_modifyitems(config, items):
    """A "realtime" case runs a loop on the wall clock against a simulated drive: beside another
    worker it would measure that worker's load, not the runtime. Skipped there, with the command
    that runs it (CI does, after the rest)."""
    if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) <= 1:
        return
    alone = pytest.mark.skip(reason="realtime: needs the CPU alone: python -m pytest -m 'slow and realtime' -n 0")
    for item in items:
        if "realtime" in item.keywords:
            item.add_marker(alone)
