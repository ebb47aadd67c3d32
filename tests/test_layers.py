"""The architecture as a test: imports point one way, and there is no import circle.

Three top-level packages, one way down between them: ``sim_plant`` (the physics) imports neither
of the others; ``drivers`` (the backends, the drive's errors, the cascade law that a drive and the
simulator both run, the backends' config sections) imports ``sim_plant`` and never ``hil``;
``hil`` (the runtime and the tools) imports both.

Layers, lowest first (a module may import its own layer and the layers below it, never above):

0. the physics (``sim_plant``)
1. the drives (``drivers``)
2. the foundations every layer of ``hil`` uses (``hil.errors``, ``hil.units``)
3. the configuration, the reading of a configuration into a plant, and the opening of a backend
   (``hil.backends``)
4. the runtime core: simulator, cycle loop, runtime, supervisor, profiles and their shaping, measurement files
5. the applications: identification, jerk sweeps, frequency responses, tuning (``hil.tune``)
6. figures and reports, the live scope's server and page (``hil.scope.server``; its ring buffer,
   ``hil.scope.ring``, is of the runtime core: the cycle writes it)
7. the command line

Every import statement counts, at the top of a module or inside a function: an import inside a
function is still an arrow of the graph. The table is data; docs/architecture.md says the same
in words.
"""
from __future__ import annotations

import ast
import importlib.util
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGES = ("sim_plant", "drivers", "hil")    # the design's three, lowest first

# module prefix -> layer; the longest matching prefix decides
LAYERS = {
    "sim_plant": 0,
    "drivers": 1,
    "hil.errors": 2, "hil.units": 2,
    "hil": 3, "hil.config": 3, "hil.plant_config": 3, "hil.backends": 3,
    "hil.simulate": 4, "hil.loop": 4, "hil.runtime": 4, "hil.supervisor": 4, "hil.profiles": 4, "hil.shaping": 4,
    "hil.closed_loop": 4, "hil.analysis": 4, "hil.io": 4, "hil.scope": 4,
    "hil.ident": 5, "hil.sweep": 5, "hil.frf": 5, "hil.fleet": 5, "hil.tune": 5,
    "hil.plots": 6, "hil.scope.server": 6,
    "hil.commands": 7, "hil.cli": 7,
}


def layer_of(module: str) -> tuple[str, int]:
    """(matching prefix, layer) of a module of the project."""
    parts = module.split(".")
    for i in range(len(parts), 0, -1):
        prefix = ".".join(parts[:i])
        if prefix in LAYERS:
            return prefix, LAYERS[prefix]
    raise KeyError(module)


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        spec = importlib.util.find_spec(pkg)
        assert spec is not None and spec.submodule_search_locations, pkg
        root = Path(list(spec.submodule_search_locations)[0])
        for path in root.rglob("*.py"):
            rel = path.relative_to(root.parent).with_suffix("")
            name = ".".join(rel.parts)
            if name.endswith(".__init__"):
                name = name[: -len(".__init__")]
            out[name] = path
    return out


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The project modules ``name`` imports (relative imports resolved; ``from pkg import mod``
    counted as an import of ``pkg.mod``)."""
    is_pkg = path.name == "__init__.py"
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in known else mod for a in node.names]
        else:
            continue
        for t in targets:
            if t.split(".")[0] in PACKAGES:
                # the deepest known module the import names
                while t not in known and "." in t:
                    t = t.rsplit(".", 1)[0]
                if t in known and t != name:
                    found.add(t)
    return found


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    return {name: _imports(name, path, known) for name, path in mods.items()}


def test_every_module_has_a_layer(graph):
    missing = []
    for name in graph:
        try:
            layer_of(name)
        except KeyError:
            missing.append(name)
    assert not missing, f"modules with no layer in LAYERS (add them to the table): {missing}"


def test_no_upward_import(graph):
    upward = []
    for name, targets in sorted(graph.items()):
        _, low = layer_of(name)
        for t in sorted(targets):
            prefix, high = layer_of(t)
            if high > low:
                upward.append(f"{name} (layer {low}) imports {t} (layer {high})")
    assert not upward, "imports pointing up:\n  " + "\n  ".join(upward)


def test_physics_imports_nothing_of_the_application(graph):
    bad = [f"{n} -> {t}" for n, ts in graph.items() if n.startswith("sim_plant")
           for t in ts if not t.startswith("sim_plant")]
    assert not bad, bad


def test_one_way_down_between_the_three_packages(graph):
    """sim_plant imports neither of the others; drivers imports sim_plant and never hil (also
    inside a function: every import statement is an arrow of the graph)."""
    allowed = {"sim_plant": {"sim_plant"}, "drivers": {"sim_plant", "drivers"}, "hil": set(PACKAGES)}
    bad = [f"{n} -> {t}" for n, ts in sorted(graph.items()) for t in sorted(ts)
           if t.split(".")[0] not in allowed[n.split(".")[0]]]
    assert not bad, "imports between the top-level packages pointing up:\n  " + "\n  ".join(bad)


def test_the_three_packages_are_at_the_root():
    """The design's layout: hil/, drivers/ and sim_plant/ at the repository root, each a package."""
    root = Path(__file__).resolve().parents[1]
    for pkg in PACKAGES:
        assert (root / pkg / "__init__.py").is_file(), pkg
    assert not (root / "hil" / "drivers").exists() and not (root / "hil" / "sim_plant").exists()


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of the graph, or None (depth-first search, three colours)."""
    state: dict[str, int] = defaultdict(int)       # 0 new, 1 on the stack, 2 done
    stack: list[str] = []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state[m] == 1:
                return stack[stack.index(m):] + [m]
            if state[m] == 0:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if state[n] == 0:
            found = visit(n)
            if found:
                return found
    return None


def test_no_import_circle_between_modules(graph):
    cycle = _cycle(graph)
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_no_import_circle_between_parts(graph):
    """The parts of one layer (e.g. identification and frequency responses) import each other
    in one direction only."""
    parts: dict[str, set[str]] = defaultdict(set)
    for name, targets in graph.items():
        a = layer_of(name)[0]
        for t in targets:
            b = layer_of(t)[0]
            if a != b:
                parts[a].add(b)
    cycle = _cycle(parts)
    assert cycle is None, "import circle between parts: " + " -> ".join(cycle)


def test_the_checker_sees_an_upward_import(tmp_path):
    """The test itself: an upward import in a module is found (a checker that sees nothing
    would pass everything)."""
    mod = tmp_path / "probe.py"
    mod.write_text("def f():\n    from hil.commands.move import run\n    from .chain import Chain\n")
    found = _imports("sim_plant.probe", mod, {"hil.commands.move", "sim_plant.chain"})
    assert found == {"hil.commands.move", "sim_plant.chain"}
    assert layer_of("hil.commands.move")[1] > layer_of("sim_plant.probe")[1]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


# --- configuration access below the configuration's layer (issue 28, item 4) ---------------------

# What a backend may read of the configuration besides its own section (drivers.<name> reads
# <name>.*; drivers itself, the registry, backend.*): what a drive is set up with before it
# moves: the cycle, the controller's output limit, the axis limits the drive also guards on its
# side, the screw's pitch, the controlled stop, and whether the supervisor may be left out.
DRIVER_SHARED_KEYS = {"control.position_period", "control.velocity_period", "control.output_limit",
                      "limits.travel_min", "limits.travel_max", "limits.speed", "limits.torque",
                      "limits.following_error_table", "plant.pitch", "supervisor.stop", "supervisor.unsupervised"}


def _config_accesses(path: Path, sections: set[str]) -> list[tuple[int, str, str]]:
    """(line, how, key) of every duck-typed configuration access in a module: a subscript or a
    ``.get``/``.section`` by a dotted key whose first part is a configuration section (a literal,
    or an f-string whose literal start names the section: ``cfg[f"effects.{name}.{k}"]``), and
    every ``.with_values`` call (which makes configurations)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    out = []

    def key_of(node) -> str | None:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            text = node.value
        elif isinstance(node, ast.JoinedStr) and node.values and isinstance(node.values[0], ast.Constant):
            text = node.values[0].value + "{}"
        else:
            return None
        head = text.split(".", 1)[0]
        return text if "." in text and head in sections else None

    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript):
            key = key_of(node.slice)
            if key:
                out.append((node.lineno, "[]", key))
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            if node.func.attr == "with_values":
                out.append((node.lineno, ".with_values", ""))
            elif node.func.attr in ("get", "section") and node.args:
                key = key_of(node.args[0])
                if key:
                    out.append((node.lineno, f".{node.func.attr}", key))
    return out


def _config_sections() -> set[str]:
    from hil.config import SCHEMA, SECTION_NAMES
    return {k.split(".", 1)[0] for k in SCHEMA} | set(SECTION_NAMES)


def _driver_may_read(module: str, key: str) -> bool:
    parts = module.split(".")
    # drivers.<own>... reads <own>.* (drivers.control: the control law's control.*); drivers: backend.*
    own = parts[1] if len(parts) > 1 else "backend"
    return key.split(".", 1)[0] == own or key in DRIVER_SHARED_KEYS


def test_physics_and_backends_know_no_configuration_syntax():
    """``sim_plant`` takes parameters: no configuration key (``cfg["plant.m1"]``,
    ``values.get("actuator.type")``, ``cfg[f"effects.{name}.{k}"]``) and no ``.with_values`` in it;
    hil.plant_config reads the configuration into it and switches effects on. ``drivers``: a
    backend is built from the configuration and may read its own section and
    :data:`DRIVER_SHARED_KEYS`, and makes no configurations (no ``.with_values``). The imports
    cannot show this (the configuration is passed in, duck-typed); the syntax tree does."""
    sections = _config_sections()
    bad = []
    for name, path in sorted(_modules().items()):
        if name.startswith("sim_plant"):
            bad += [f"{name}:{line} {how} {key}" for line, how, key in _config_accesses(path, sections)]
        elif name.startswith("drivers"):
            bad += [f"{name}:{line} {how} {key}" for line, how, key in _config_accesses(path, sections)
                    if how == ".with_values" or not _driver_may_read(name, key)]
    assert not bad, "configuration syntax below the configuration's layer:\n  " + "\n  ".join(bad)


def test_the_checker_sees_duck_typed_config_access(tmp_path):
    """The checker itself, on the forms it must see (what sim_plant.effects did before: an
    f-string key into ``with_values``, ``values.get("actuator.type")``), and not on a parameter
    dictionary's own dotted names (a combination's ``values[f"{n}.{p.name}"]``)."""
    mod = tmp_path / "probe.py"
    mod.write_text("def f(cfg, values, n, p):\n"
                   "    cfg.with_values({f'effects.{n}.{p}': 1.0})\n"
                   "    values.get('actuator.type', 'rotary')\n"
                   "    cfg['plant.m1']\n"
                   "    cfg[f'effects.{n}.level']\n"
                   "    values[f'{n}.{p}']\n"
                   "    values['stiffness.k_em']\n")
    found = [(line, how) for line, how, _ in _config_accesses(mod, {"effects", "actuator", "plant"})]
    assert found == [(2, ".with_values"), (3, ".get"), (4, "[]"), (5, "[]")]
    assert _driver_may_read("drivers.canopen.backend", "canopen.node_id")
    assert not _driver_may_read("drivers.canopen.backend", "serial.port")
    assert not _driver_may_read("drivers.sim", "effects.backlash.gap")


def test_the_stores_code_versions_hash_files_that_exist():
    """The sweep's and the fleet's stores are keyed by a hash of the sources that compute their
    figures; a path left behind by a move would hash its name instead, and a changed kernel would
    be taken from the store."""
    from hil.fleet.run import code_files as fleet_files
    from hil.sweep.run import code_files as sweep_files
    for path in [*fleet_files(), *sweep_files()]:
        assert path.is_file(), path
    assert any(p.parent.name == "effects" for p in fleet_files())
