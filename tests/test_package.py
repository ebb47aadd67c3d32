"""The package as a user gets it: a wheel built from the tree, installed into a fresh virtual
environment outside the clone, runs ``hil model`` on a shipped config and the README's CANopen
walkthrough (``hil drive-sim`` and ``hil move --backend canopen`` against it). And the command
line starts without importing the numerical stack (the times: benchmarks/bench_startup.py).
"""
import json
import os
import shutil
import signal
import site as site_module
import subprocess
import sys
import sysconfig
import time
import zipfile
from pathlib import Path

import pytest
from conftest import CONFIG, ROOT

HEAVY = {"numpy", "scipy", "numba", "matplotlib", "pint", "can", "canopen", "serial", "dask", "control",
         "sim_plant", "drivers.sim", "drivers.control"}   # drivers.canopen and .serial: their schemas are light


def clean_env(**extra) -> dict:
    """The environment without PYTHONPATH, so that no checkout comes before the installed wheel."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return dict(env, MPLBACKEND="Agg", **extra)


def test_help_and_version_import_no_heavy_module(capsys):
    code = ("import sys; from hil import cli, __version__; cli.build_parser(); "
            "print(sorted({'.'.join(m.split('.')[:n]) for m in sys.modules for n in (1, 2)} & set(sys.argv[1:])))")
    out = subprocess.run([sys.executable, "-c", code, *HEAVY], cwd=ROOT, capture_output=True, text=True,
                         env=clean_env(PYTHONPATH=str(ROOT)), check=True).stdout
    assert out.strip() == "[]"
    from hil import __version__
    from hil.cli import main
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out == f"hil {__version__}\n"


def test_missing_config_lists_the_shipped_examples(tmp_path, monkeypatch):
    from hil.config import ConfigError, example_names, examples_dir, load
    assert "paper_bench.toml" in example_names()
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"nope.toml: no such configuration file .*paper_bench_canopen.toml"):
        load("nope.toml")
    # a shipped name, bare or as the README writes it, where the working directory has no such file
    # (config/ of a source tree, hil/examples of the installed package the tests run against)
    assert (examples_dir() / "paper_bench.toml").read_bytes() == (CONFIG / "paper_bench.toml").read_bytes()
    for name in ("paper_bench.toml", "config/paper_bench.toml"):
        assert Path(load(name).source) == examples_dir() / "paper_bench.toml"
    shutil.copy(CONFIG / "paper_bench.toml", tmp_path)
    assert load("paper_bench.toml").source == "paper_bench.toml"    # a file of the user's comes first


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """A wheel built from a copy of the tree (the build leaves build/ and *.egg-info behind)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".git", "__pycache__", "build", "dist", "*.egg-info", "out", "runs", ".pytest_cache", ".venv"))
    subprocess.run([sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "--no-build-isolation", "-q",
                    "-w", str(tmp / "dist")], cwd=src, env=clean_env(), check=True)
    (whl,) = (tmp / "dist").glob("*.whl")
    return whl


def test_wheel_holds_every_module_eds_file_and_example_config(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for py in [f for pkg in ("hil", "drivers", "sim_plant") for f in (ROOT / pkg).rglob("*.py")]:
        if "__pycache__" not in py.parts:
            assert py.relative_to(ROOT).as_posix() in names, f"{py.relative_to(ROOT)} is not in the wheel " \
                "(a new package? add it to [tool.setuptools] packages in pyproject.toml)"
    assert {"drivers/canopen/eds/cia402_generic.eds", "drivers/canopen/eds/tip_encoder_cia406.eds"} <= names
    shipped = {f"hil/examples/{p.name}" for p in CONFIG.iterdir() if p.suffix in (".toml", ".md")}
    assert "hil/examples/paper_bench.toml" in shipped and shipped <= names
    templates = {f"hil/plots/templates/{p.name}" for p in (ROOT / "hil" / "plots" / "templates").glob("*.j2")}
    assert "hil/plots/templates/base.html.j2" in templates and templates <= names, "the report templates"
    assert not any(n.startswith(("tests/", "benchmarks/", "config/")) for n in names)


def test_wheel_installs_the_three_packages_of_the_design_and_nothing_else(wheel):
    """The design's top level: ``hil``, ``drivers`` and ``sim_plant`` at the top of site-packages, and
    nothing else (no tests, benchmarks or config folder of the clone)."""
    tops = {n.split("/")[0] for n in zipfile.ZipFile(wheel).namelist()}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"hil", "drivers", "sim_plant"}


@pytest.mark.slow
@pytest.mark.realtime
def test_wheel_installed_outside_the_clone_runs_the_canopen_walkthrough(wheel, tmp_path):
    venv = tmp_path / "venv"
    # the dependencies come from the environment running the tests (no network), whether that is
    # the system interpreter or a virtualenv: --system-site-packages would reach only the base
    # interpreter's packages from inside a venv, so the venv gets this one's site-packages as a .pth
    # instead. The wheel goes into the venv first on its path, even where the project is installed
    # in the outer environment too (e.g. editable)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py, hil = venv / "bin" / "python", venv / "bin" / "hil"
    inner = subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                           capture_output=True, text=True, check=True).stdout.strip()
    outer = dict.fromkeys([*site_module.getsitepackages(), sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]])
    Path(inner, "outer_environment.pth").write_text("".join(f"{p}\n" for p in outer if Path(p).is_dir()))
    subprocess.run([py, "-m", "pip", "install", "-q", "--no-deps", "--ignore-installed", "--no-index", wheel],
                   env=clean_env(), check=True)
    work = tmp_path / "work"              # the user's folder: no clone, no config/ in it
    work.mkdir()

    def run(*argv, cmd=(hil,), **kw):
        return subprocess.run([*cmd, *argv], cwd=work, env=clean_env(), capture_output=True, text=True,
                              timeout=300, **kw)

    where = run("-c", "import hil, drivers, sim_plant; print(hil.__file__, drivers.__file__, sim_plant.__file__)",
                cmd=(py,))
    site = str(venv / "lib")
    assert all(p.startswith(site) for p in where.stdout.split()), where.stdout + where.stderr
    assert run("--version").stdout.strip().startswith("hil ")

    r = run("model", "--config", "paper_bench.toml", "--json", "--out", "out/model")
    assert r.returncode == 0, r.stderr
    model = json.loads(r.stdout)
    assert model["config"].startswith(site) and model["masses_kg"] == [335.57, 392.97, 4.228]
    assert (work / "out" / "model" / "bode_tf.png").is_file()
    r = run("model", "--config", "nope.toml")
    assert r.returncode == 2 and "paper_bench.toml" in r.stderr

    # README, CANopen, "Try it": the drive in one process, the host in another (a free port here)
    sets = ["--config", "config/paper_bench_canopen.toml", "--set", "canopen.tip_node_id=2"]
    drive = subprocess.Popen([hil, "drive-sim", *sets, "--port", "0", "--json", "--seconds", "240s"], cwd=work,
                             env=clean_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = drive.stdout.readline()
        assert line, drive.stderr.read() if drive.poll() is not None else "hil drive-sim printed nothing"
        info = json.loads(line)
        assert info["tip_node_id"] == 2
        r = run("move", *sets, "--set", "canopen.interface=socketcand", "--set", f"canopen.channel={info['channel']}",
                "--set", f"canopen.port={info['port']}", "--backend", "canopen", "--stroke", "20mm",
                "--feed", "6000mm/min", "--amax", "2m/s^2", "--dwell", "0.3s", "--back", "--json",
                "--out", "out/move")
        assert r.returncode == 0, r.stdout + r.stderr
        move = json.loads(r.stdout)
        assert move["status"] == "complete" and move["backend"] == "canopen"
        assert (work / "out" / "move" / "move.csv").is_file()
    finally:
        drive.send_signal(signal.SIGINT)
        try:
            drive.wait(timeout=20)
        except subprocess.TimeoutExpired:   # hung: its signal masks and threads' stacks (dumped on SIGUSR1)
            try:
                masks = [ln for ln in Path(f"/proc/{drive.pid}/status").read_text().splitlines() if ln.startswith("Sig")]
            except OSError:
                masks = []
            drive.send_signal(signal.SIGUSR1)
            time.sleep(2.0)
            drive.kill()
            drive.wait()
            pytest.fail(f"hil drive-sim did not end on SIGINT ({'; '.join(masks)}): {drive.stderr.read()}")
    assert drive.returncode == 0, drive.stderr.read()
