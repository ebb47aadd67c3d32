"""Every command of the documentation runs: no example goes stale.

The commands are taken from the fenced code blocks of README.md and docs/**/*.md:

- in a ```` ```bash ```` or ```` ```sh ```` block, every line that starts with ``hil `` (with its
  ``\\`` continuation lines; ``#`` starts a comment), and the ``hil`` part of a line joined by
  ``&&`` (``pip install . && hil move ...``);
- in a ```` ```console ```` block, the same for the lines that start with ``$ ``; the lines after
  one (after its continuation lines), up to the next ``$`` or the end of the block, are the output
  shown, and the test checks them against what the command printed (below).

The shown output of a ```` ```console ```` command is compared with its stdout (and its stderr too
when the block expects a non-zero exit: the error line); blank lines are ignored, and so is
whitespace within a line: the two are compared token by token (split at whitespace and punctuation), so that a
missing unit, a renamed or an added line fails, and floating-point noise does not:

- a token equal as text matches; otherwise its numbers (``-1.5``, ``1044.23``, ``2.644e+04``,
  also inside a token: ``c2=33,``) must agree within a relative 1e-3 or one unit of the last digit
  shown, whichever is larger (``8.94`` matches 8.93 to 8.95), and the text around them exactly;
- a line ``...`` alone stands for any number of lines (the output abbreviated); a ``...`` within a
  line for any number of tokens of that line (``,;()[]`` are tokens of their own, so
  ``(1.2 x floor), ..., torque`` and ``(with constant_force: ...)`` abbreviate a list);
- paths: the commands run in a temporary folder (below), so the absolute path of that folder (then
  ``out/move/move.csv`` reads as in the docs) and of the shared folder (read as ``../shared``) are
  taken out of the printed output before the comparison, and the folder of the shipped example
  configurations (``config/paper_bench.toml`` found in the package) reads ``config``;
- a command with no output shown, and a ``<!-- background -->`` command, is not checked.

Each command runs as ``hil ...`` through ``hil.cli.main`` of the package these tests import (the
installed one, or the checkout named by PYTHONPATH), without a shell, in a temporary folder of its own page: the commands of one page run
in the order written and see each other's files (the tutorial's record is the next command's
input). That folder has no ``config/``: ``config/paper_bench.toml`` is found among the shipped
examples, as it is for a user outside a clone. ``../shared`` is the project's shared folder
beside the checkout (the EMPS record; ``HIL_SHARED_DIR`` names another); a command that names
``DATA_EMPS.mat``, or a file under ``../shared/`` (a record of the shared folder), is skipped where it is absent. Each page has its own supervisor state folder (``HIL_STATE_DIR``), so a trip latched by
one command is seen by the next, as on a real machine.

An HTML comment right before a block says how its commands run:

- ``<!-- no-test: REASON -->``: not run (a second terminal, hardware); the reason is reported;
- ``<!-- slow -->``: marked slow (deselected by default, run by CI: ``pytest -m slow``);
- ``<!-- exit: N -->``: the commands must end with exit code N (a refused move: 2);
- ``<!-- output: varies -->``: the output shown is not compared (figures that truly vary from run
  to run or machine to machine: lateness, durations, ports, dates, load); the command still runs.
  Markers combine, one per line before the block;
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
MARKER = re.compile(r"^<!--\s*(no-test|slow|exit|background|output)\s*(?::\s*(.*?))?\s*-->$")
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
    shown: list[str] = field(default_factory=list)  # the output shown after it (console blocks)
    output_varies: bool = False

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"


def _logical_lines(body: list[tuple[int, str]], console: bool):
    """(line number, command text, output lines shown after it) of the block's commands,
    continuation lines joined; the shown output is that of a console block's ``$`` line."""
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
        shown = []
        while console and i < len(body) and not body[i][1].strip().startswith("$ "):
            shown.append(body[i][1])
            i += 1
        # "pip install . && hil move ...": the hil part
        for segment in " ".join(parts).split(" && "):
            if segment.strip().startswith("hil "):
                yield n, segment.strip(), shown


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
            for n, text, shown in _logical_lines(body, console=lang == "console"):
                argv = shlex.split(text, comments=True)
                out.append(DocCommand(rel, n, argv[1:], no_test=markers.get("no-test"), slow="slow" in markers,
                                      exit_code=int(markers.get("exit") or 0), background="background" in markers,
                                      shown=shown, output_varies=markers.get("output") == "varies"))
        markers = {}
    return out


ALL = [c for p in PAGES for c in extract(p)]


def _param(c: DocCommand):
    # on several workers (pytest-xdist) this module runs on one, in order (--dist loadscope, as CI
    # runs the slow set): a command builds on the files its page's earlier commands wrote (a fit's
    # config, then the compare that reads it)
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


def test_a_command_naming_an_absent_shared_file_is_skipped(monkeypatch, tmp_path):
    """A docs command that names a file under ../shared skips, with its path, where the shared
    folder lacks it, and runs where it is there."""
    monkeypatch.setenv("HIL_SHARED_DIR", str(tmp_path))
    path = "../shared/data/hsm150-servo-motor/idf_pos_0.06_1.mat"
    cmd = DocCommand("docs/x.md", 1, ["compare", path, "--open-loop"])
    assert path in _runnable(cmd)
    record = tmp_path / "data" / "hsm150-servo-motor" / "idf_pos_0.06_1.mat"
    record.parent.mkdir(parents=True)
    record.write_bytes(b"")
    assert _runnable(cmd) is None


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
    for a in cmd.argv:
        # a record with its own map after a colon (--validate RECORD:MAP) needs the record alone
        path = a.split(":", 1)[0] if a.startswith("../shared/") and ".mat:" in a else a
        if path.startswith("../shared/") and not (_shared() / path.removeprefix("../shared/")).exists():
            return f"needs {path}, a record of the project's shared folder, absent here"
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
    if cmd.shown and not cmd.output_varies:
        printed = r.stdout if cmd.exit_code == 0 else r.stdout + "\n" + r.stderr
        problem = output_mismatch(cmd.shown, _normalise_paths(printed, run))
        assert problem is None, (
            f"{cmd.id}: hil {shlex.join(argv)}\nthe output shown in the docs is not what the command prints: "
            f"{problem}\n--- shown\n" + "\n".join(cmd.shown) + f"\n--- printed\n{printed}")


# -- the shown output against the printed one ------------------------------------------------------------

NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
ELLIPSIS = "..."


def _normalise_paths(text: str, run: PageRun) -> str:
    """The printed output with the page's temporary folder taken out (paths read relative to it, as
    in the docs), the shared folder written ``../shared`` and the shipped examples ``config``."""
    from hil.config import examples_dir

    shared = run.work.parent / "shared"
    for folder, name in [(shared, "../shared"), (_shared(), "../shared"), (examples_dir(), "config"), (run.work, ".")]:
        for form in {str(folder), str(folder.resolve()) if folder.exists() else str(folder)}:
            text = text.replace(form + os.sep, "" if name == "." else name + "/").replace(form, name)
    return text


def _numbers_match(shown: str, printed: str) -> bool:
    """Two numbers written as text agree within rel 1e-3 or one unit of the shown last digit."""
    a, b = float(shown), float(printed)
    mantissa = re.split(r"[eE]", shown)[0]
    exponent = int(re.split(r"[eE]", shown)[1]) if re.search(r"[eE]", shown) else 0
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    last_digit = 10.0 ** (exponent - decimals)
    return abs(a - b) <= max(1e-3 * max(abs(a), abs(b)), last_digit * (1 + 1e-9))


def _tokens_match(shown: str, printed: str) -> bool:
    if shown == printed:
        return True
    s_nums, p_nums = NUMBER.findall(shown), NUMBER.findall(printed)
    if len(s_nums) != len(p_nums) or not s_nums:
        return False
    if NUMBER.split(shown) != NUMBER.split(printed):     # the text around the numbers, exactly
        return False
    return all(_numbers_match(s, p) for s, p in zip(s_nums, p_nums))


def _seq_match(shown: list, printed: list, same) -> bool:
    """Whether the shown items match the printed ones in order, ``...`` standing for any run of
    printed items (dynamic programming over the two positions)."""
    reach = {0}                 # printed positions reachable after the shown items so far
    for item in shown:
        if item == ELLIPSIS:
            reach = set(range(min(reach), len(printed) + 1)) if reach else set()
        else:
            reach = {j + 1 for j in reach if j < len(printed) and same(item, printed[j])}
        if not reach:
            return False
    return len(printed) in reach


TOKEN = re.compile(r"\.\.\.|[,;()\[\]]|[^\s,;()\[\]]+")


def _tokens(line: str) -> list[str]:
    """The tokens of a line: split at whitespace, with ``...`` and the punctuation ``,;()[]`` tokens
    of their own (``floor), ..., torque`` abbreviates a list)."""
    return TOKEN.findall(line)


def _line_match(shown: str, printed: str) -> bool:
    return _seq_match(_tokens(shown), _tokens(printed), _tokens_match)


def output_mismatch(shown: list[str], printed: str) -> str | None:
    """None where the shown lines match the printed output, else what differs first (for the
    failure message)."""
    want = [line.strip() for line in shown if line.strip()]
    got = [line.strip() for line in printed.split("\n") if line.strip()]
    if _seq_match(want, got, _line_match):
        return None
    # the first shown line (other than "...") that no printed line matches, for the message
    for line in want:
        if line != ELLIPSIS and not any(_line_match(line, g) for g in got):
            return f"no printed line matches {line!r}"
    return "the lines are all printed, but not in this order or with more lines between them (use ...)"


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


def test_the_reference_names_the_module_that_reads_each_backend_section():
    """The [canopen] and [serial] sections of the generated reference name the module that reads
    their keys: a file that exists, and for [canopen] the one that reads most of its keys by name
    (counted in the sources here; after the CANopen split that is drivers/canopen/section.py,
    the page named drivers/canopen/backend.py, which reads three)."""
    import re

    from hil.config import CANOPEN_SECTION
    page = _gen().config_reference()

    def named(section):
        block = page.split(f"## `[{section}]`", 1)[1].split("\n## ", 1)[0]
        return re.search(r"Read by `([^`]+)`", block).group(1)
    for section in ("canopen", "serial"):
        assert (ROOT / named(section)).is_file(), named(section)
    reads = {}
    for path in [*(ROOT / "hil").rglob("*.py"), *(ROOT / "drivers").rglob("*.py")]:
        text = path.read_text()
        reads[path.relative_to(ROOT).as_posix()] = sum(f'"{key}"' in text for key in CANOPEN_SECTION)
    del reads["drivers/canopen/schema.py"]            # where the keys are defined, not read
    assert named("canopen") == max(reads, key=reads.get), sorted(reads.items(), key=lambda kv: -kv[1])[:3]


def test_the_site_builds_without_warnings(tmp_path):
    """mkdocs build --strict, as CI runs it (where mkdocs is installed: pip install ".[docs]")."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("material")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert (tmp_path / "site" / "reference" / "config" / "index.html").is_file()


def test_the_shown_output_is_compared_token_by_token():
    """The comparison of shown and printed output: numbers within tolerance, text exact, ``...``."""
    printed = "move 100 mm\n  residual tip vibration 1044.2312 um, peak torque 8.9413 N m\n  record out/move/move.csv\n"
    assert output_mismatch(["move 100 mm", "residual   tip vibration 1044.23 um, peak torque 8.94 N m", "..."],
                           printed) is None
    # a missing unit, a renamed line, a wrong figure fail
    assert output_mismatch(["...", "residual tip vibration 1044.23 um, peak torque 8.94", "..."], printed)
    assert output_mismatch(["...", "residual tip motion 1044.23 um, peak torque 8.94 N m", "..."], printed)
    assert output_mismatch(["...", "residual tip vibration 1052.0 um, peak torque 8.94 N m", "..."], printed)
    # an extra printed line needs "..."; a token "..." stands for the rest of a line
    assert output_mismatch(["move 100 mm", "record out/move/move.csv"], printed)
    assert output_mismatch(["move 100 mm", "residual tip vibration ...", "record out/move/move.csv"], printed) is None
    assert output_mismatch(["j 2.644e+04 m/s^3"], "j 2.6445e+04 m/s^3") is None
    assert output_mismatch(["j 2.644e+04 m/s^3"], "j 2.66e+04 m/s^3")
    assert output_mismatch(["a (1 x floor), ..., t 2 N m (0.9 x floor)"],
                           "a (1 x floor), b 3 um (2 x floor), t 2 N m (0.9 x floor)") is None
    assert output_mismatch(["verdict: c (with k: ...)"], "verdict: c (with k: score 4.2, 100 %)") is None
