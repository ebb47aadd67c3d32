"""Every command of the documentation runs: no example goes stale.

The commands are taken from the fenced code blocks of README.md and docs/**/*.md:

- in a ```` ```bash ```` or ```` ```sh ```` block, every line that starts with ``hil `` (with its
  ``\\`` continuation lines; ``#`` starts a comment), and the ``hil`` part of a line joined by
  ``&&`` (``pip install . && hil move ...``);
- in a ```` ```console ```` block, the same for the lines that start with ``$ `` (the lines after
  one, up to the next ``$``, are the output shown: not checked here, they are examples).

Each command runs as ``hil ...`` through ``hil.cli.main`` of the package these tests import (the
installed one, or the checkout named by PYTHONPATH), without a shell, in a temporary folder of its own page: the commands of one page run
in the order written and see each other's files (the tutorial's record is the next command's
input). That folder has no ``config/``: ``config/paper_bench.toml`` is found among the shipped
examples, as it is for a user outside a clone. ``../shared`` is the project's shared folder
beside the checkout (the EMPS record; ``HIL_SHARED_DIR`` names another); a command that names
``DATA_EMPS.mat`` is skipped where it is absent. Each page has its own supervisor state folder (``HIL_STATE_DIR``), so a trip latched by
one command is seen by the next, as on a real machine.

An HTML comment right before a block says how its commands run:

- ``<!-- no-test: REASON -->``: not run (a second terminal, hardware); the reason is reported;
- ``<!-- slow -->``: marked slow (deselected by default, run by CI: ``pytest -m slow``);
- ``<!-- exit: N -->``: the commands must end with exit code N (a refused move: 2);
- ``<!-- background -->``: the block's one command is started and left running until the page's
  last command has run (``hil drive-sim`` in "terminal 1"). For ``hil drive-sim`` the test asks
  for a free port (``--port 0``), reads it from the first line it prints, and adds
  ``--set canopen.port=PORT`` to the page's later commands that use the socketcand interface, so
  that two test runs on one machine never share a port.

A slow command runs after its page's earlier fast commands that the session left out (``pytest -m
slow`` alone still has the tutorial's record); a fast command never builds on a slow one.
"""
from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import ROOT, SHARED

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
MARKER = re.compile(r"^<!--\s*(no-test|slow|exit|background)\s*(?::\s*(.*?))?\s*-->$")
FENCE = re.compile(r"^(\s*)```+\s*([A-Za-z]*)")
COMMAND_TIMEOUT = 600
# the `hil` entry point of the package imported here (the installed one, or PYTHONPATH's)
HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]


@dataclass
class DocCommand:
    page: str           # relative to the repository root
    line: int           # 1-based line of the command in the page
    argv: list[str]     # after "hil"
    no_test: str | None = None
    slow: bool = False
    exit_code: int = 0
    background: bool = False

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"


def _logical_lines(body: list[tuple[int, str]], console: bool):
    """(line number, command text) of the block's commands, continuation lines joined."""
    i = 0
    while i < len(body):
        n, text = body[i]
        stripped = text.strip()
        i += 1
        if console:
            if not stripped.startswith("$ "):
                continue
            stripped = stripped[2:]
        parts = [stripped]
        while parts[-1].endswith("\\") and i < len(body):
            parts[-1] = parts[-1][:-1]
            parts.append(body[i][1].strip())
            i += 1
        # "pip install . && hil move ...": the hil part
        for segment in " ".join(parts).split(" && "):
            if segment.strip().startswith("hil "):
                yield n, segment.strip()


def extract(path: Path) -> list[DocCommand]:
    """The commands of one Markdown page, with the markers of their blocks."""
    lines = path.read_text(encoding="utf-8").split("\n")
    rel = str(path.relative_to(ROOT))
    out: list[DocCommand] = []
    markers: dict = {}
    i = 0
    while i < len(lines):
        line = lines[i]
        m = MARKER.match(line.strip())
        if m:
            markers[m.group(1)] = m.group(2) or ""
            i += 1
            continue
        f = FENCE.match(line)
        if not f:
            if line.strip():
                markers = {}            # a marker applies to the block right after it
            i += 1
            continue
        indent, lang = f.group(1), f.group(2).lower()
        body = []
        i += 1
        while i < len(lines) and not lines[i].strip().startswith("```"):
            body.append((i + 1, lines[i][len(indent):] if lines[i].startswith(indent) else lines[i]))
            i += 1
        i += 1
        if lang in ("bash", "sh", "shell", "console"):
            for n, text in _logical_lines(body, console=lang == "console"):
                argv = shlex.split(text, comments=True)
                out.append(DocCommand(rel, n, argv[1:], no_test=markers.get("no-test"), slow="slow" in markers,
                                      exit_code=int(markers.get("exit") or 0), background="background" in markers))
        markers = {}
    return out


ALL = [c for p in PAGES for c in extract(p)]


def _param(c: DocCommand):
    marks = [pytest.mark.slow] if c.slow else []
    return pytest.param(c, id=c.id, marks=marks)


@dataclass
class PageRun:
    """The folder, the supervisor state and the background processes of one page's commands."""
    work: Path
    env: dict
    background: list = field(default_factory=list)
    canopen_port: int | None = None
    done: set = field(default_factory=set)      # the ids of the commands run so far


_RUNS: dict[str, PageRun] = {}


def _shared() -> Path:
    """The project's shared folder: beside the checkout, or where HIL_SHARED_DIR says (a worktree
    elsewhere)."""
    return Path(os.environ.get("HIL_SHARED_DIR") or SHARED)


@pytest.fixture(scope="session")
def page_runs(tmp_path_factory):
    yield _RUNS
    for run in _RUNS.values():
        _stop_background(run)


def _stop_background(run: PageRun) -> None:
    for proc in run.background:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    run.background.clear()


def _page_run(page: str, tmp_path_factory) -> PageRun:
    if page not in _RUNS:
        base = tmp_path_factory.mktemp("doc_" + re.sub(r"\W", "_", page))
        work = base / "work"
        work.mkdir()
        if _shared().is_dir():
            (base / "shared").symlink_to(_shared())   # ../shared, as beside a clone
        env = dict(os.environ, MPLBACKEND="Agg", HIL_STATE_DIR=str(base / "state"))
        _RUNS[page] = PageRun(work, env)
    return _RUNS[page]


def test_the_docs_have_commands():
    """The extraction finds the README's and the tutorials' commands (a broken parser skips nothing
    silently)."""
    pages = {c.page for c in ALL}
    assert "docs/tutorials/dry-run-and-sweep.md" in pages and "docs/tutorials/commissioning.md" in pages
    assert any(c.argv[:1] == ["move"] for c in ALL if c.page == "README.md")
    for c in ALL:
        assert c.argv and not c.argv[0].startswith("-"), c.id


@pytest.mark.parametrize("cmd", [_param(c) for c in ALL])
def test_doc_command(cmd: DocCommand, page_runs, tmp_path_factory):
    why = _runnable(cmd)
    if why:
        pytest.skip(why)
    run = _page_run(cmd.page, tmp_path_factory)
    # a slow command's page may build on its earlier commands that this session deselected (the
    # tutorial's record): run those first (never a slow one: a fast command builds on fast ones only)
    for earlier in [c for c in ALL if c.page == cmd.page][:[c for c in ALL if c.page == cmd.page].index(cmd)]:
        if earlier.id not in run.done and not earlier.slow and _runnable(earlier) is None:
            _run_one(earlier, run)
    try:
        _run_one(cmd, run)
    finally:
        if cmd is _last_of_page(cmd.page):
            _stop_background(run)


def _runnable(cmd: DocCommand) -> str | None:
    """Why the command cannot run here, or None."""
    if cmd.no_test is not None:
        return f"marked no-test in the docs: {cmd.no_test or 'no reason given'}"
    if any("DATA_EMPS.mat" in a for a in cmd.argv) and not (_shared() / "data" / "emps" / "DATA_EMPS.mat").is_file():
        return "needs the EMPS record, ../shared/data/emps/DATA_EMPS.mat (docs/how-to/emps-data.md)"
    return None


def _run_one(cmd: DocCommand, run: PageRun) -> None:
    run.done.add(cmd.id)
    argv = list(cmd.argv)
    if run.canopen_port is not None and any("canopen.interface=socketcand" in a for a in argv):
        argv += ["--set", f"canopen.port={run.canopen_port}"]
    if cmd.background:
        _start_background(cmd, argv, run)
        return
    r = subprocess.run([*HIL, *argv], cwd=run.work, env=run.env, capture_output=True,
                       text=True, timeout=COMMAND_TIMEOUT, stdin=subprocess.DEVNULL)
    assert r.returncode == cmd.exit_code, (
        f"{cmd.id}: hil {shlex.join(argv)}\nexit {r.returncode}, the docs expect {cmd.exit_code}\n"
        f"--- stdout\n{r.stdout[-3000:]}\n--- stderr\n{r.stderr[-3000:]}")
    if cmd.exit_code == 0:
        assert "Traceback" not in r.stderr, r.stderr[-3000:]


def _last_of_page(page: str) -> DocCommand:
    return [c for c in ALL if c.page == page][-1]


def _start_background(cmd: DocCommand, argv: list[str], run: PageRun) -> None:
    is_drive_sim = argv[:1] == ["drive-sim"]
    if is_drive_sim and "--port" not in argv:
        argv += ["--port", "0"]
    proc = subprocess.Popen([*HIL, *argv], cwd=run.work, env=run.env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
    run.background.append(proc)
    first = proc.stdout.readline()
    assert first, f"{cmd.id}: hil {shlex.join(argv)} printed nothing: {proc.stderr.read()[-2000:]}"
    if is_drive_sim:
        m = re.search(r"127\.0\.0\.1:(\d+)", first)
        assert m, f"{cmd.id}: no port in {first!r}"
        run.canopen_port = int(m.group(1))


# -- the generated reference and the site ----------------------------------------------------------------

def _gen():
    import importlib.util
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "docs" / "gen_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_reference_names_every_key_effect_and_option():
    """The generated pages hold every configuration key (the registered sections' too), every
    effect's parameters and every command's options: what the code accepts is what the docs list."""
    import argparse

    import drivers.canopen.backend as canopen_backend
    import drivers.serial.backend as serial_backend
    import hil.supervisor as supervisor
    from hil.cli import build_parser
    from hil.config import SCHEMA
    from sim_plant.effects import CATALOGUE

    gen = _gen()
    config, effects, commands = gen.config_reference(), gen.effects_reference(), gen.commands_reference()
    for key in [*SCHEMA, *supervisor.SECTION, *canopen_backend.SECTION, *serial_backend.SECTION]:
        assert f"`{key.replace('*', 'N')}`" in config, key
    for name, eff in CATALOGUE.items():
        assert f"## {name}" in effects, name
        for p in eff.params:
            assert f"`effects.{name}.{p.name}`" in config and f"| `{p.name}` |" in effects, (name, p.name)
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, p in sub.choices.items():
        section = commands.split(f"## hil {name}\n", 1)[1].split("\n## hil ", 1)[0]
        for a in p._actions:
            for opt in a.option_strings:
                if opt not in ("-h", "--help"):
                    assert f"`{opt}`" in section, (name, opt)


def test_the_site_builds_without_warnings(tmp_path):
    """mkdocs build --strict, as CI runs it (where mkdocs is installed: pip install ".[docs]")."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("material")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert (tmp_path / "site" / "reference" / "config" / "index.html").is_file()
