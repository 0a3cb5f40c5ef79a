"""The package's shape: what an install adds to site-packages, and imports that run one way through its layers.

Layers, top to bottom (a module may import from its own layer or a lower one, never from a higher one):

| layer | modules | what they are |
| --- | --- | --- |
| cli | `mjdrive` (its `__init__`), `cli`, `drive`, `bench`, `bench_sensors`, `bench_operative` | commands, facade |
| agents | `agents` (the `agents/` folder) | learners, evaluation, ensembles |
| envs | `envs`, `policies` | gymnasium envs, scripted policies, replaying a log in an env |
| record | `record`, `video` | MCAP episode logs, summaries, videos of dm-control episodes |
| tasks | `tasks`, `suite` | dm-control tasks and their registry |
| parts | `traffic`, `sensors`, `vehicle`, `control`, `world` | what a task is built from |
| roads | `roads` | road geometry and maps |
| utilities | `config`, `progress`, `comfort`, `assets`, `version`, `run_folder` | leaves |

An import is any `import` or `from ... import` statement in a module, at module level or inside a function;
imports under `if TYPE_CHECKING:` never run and are left out. Importing a package means importing its
`__init__`; `from package import name` counts as importing the module `package.name` when there is one.
"""

from __future__ import annotations

import ast
from pathlib import Path

import setuptools
from setuptools.config.pyprojecttoml import read_configuration

ROOT = Path(__file__).resolve().parents[1]
SOURCES = {"mjdrive": ROOT / "mjdrive", "mjdrive.agents": ROOT / "agents"}  # package -> its folder

LAYERS = {  # top to bottom
    "cli": ("mjdrive", "mjdrive.cli", "mjdrive.drive", "mjdrive.bench", "mjdrive.bench_sensors",
            "mjdrive.bench_operative"),
    "agents": ("mjdrive.agents",),
    "envs": ("mjdrive.envs", "mjdrive.policies"),
    "record": ("mjdrive.record", "mjdrive.video"),
    "tasks": ("mjdrive.tasks", "mjdrive.suite"),
    "parts": ("mjdrive.traffic", "mjdrive.sensors", "mjdrive.vehicle", "mjdrive.control", "mjdrive.world"),
    "roads": ("mjdrive.roads",),
    "utilities": ("mjdrive.config", "mjdrive.progress", "mjdrive.comfort", "mjdrive.assets", "mjdrive.version",
                  "mjdrive.run_folder", "mjdrive.compiled"),
}
RANK = {name: rank for rank, name in enumerate(reversed(LAYERS))}  # higher rank: higher layer


def package_modules() -> dict[str, Path]:
    """Every module of the installed package (dotted name -> source file)."""
    modules = {}
    for package, folder in SOURCES.items():
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join([package, *parts])] = path
    return modules


MODULES = package_modules()


def layer(module: str) -> str:
    """The layer of `module`: its longest entry in LAYERS (a module, or a package holding it); the root
    package `mjdrive` names its `__init__` only."""
    best, length = None, -1
    for name, entries in LAYERS.items():
        for entry in entries:
            if (module == entry or (entry != "mjdrive" and module.startswith(entry + "."))) and len(entry) > length:
                best, length = name, len(entry)
    if best is None:
        raise AssertionError(f"{module} has no layer: add it to LAYERS in {Path(__file__).name}")
    return best


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _known(name: str) -> str | None:
    """The package module that importing `name` runs last (`name` or its nearest enclosing package module)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def imports(module: str) -> dict[str, int]:
    """The package modules that `module` imports -> the line of the first such import."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: dict[str, int] = {}

    def add(target: str | None, line: int) -> None:
        if target is not None and target != module:
            found.setdefault(target, line)

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(_known(alias.name), node.lineno)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            for alias in node.names:
                full = f"{source}.{alias.name}"
                add(full if full in MODULES else _known(source), node.lineno)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(), str(path)))
    return found


GRAPH = {module: imports(module) for module in MODULES}


def _cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []

    def connect(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph[node]:
            if target not in index:
                connect(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            connect(node)
    return components


def test_the_only_top_level_package_is_mjdrive():
    options = read_configuration(ROOT / "pyproject.toml")["tool"]["setuptools"]
    packages = options["packages"]
    assert {name.split(".")[0] for name in packages} == {"mjdrive"}
    assert options["package-dir"] == {"mjdrive.agents": "agents"}
    # the list names every package in the source tree: mjdrive/'s and the agents/ folder's (as mjdrive.agents)
    found = setuptools.find_packages(str(ROOT), include=["mjdrive", "mjdrive.*"])
    found += ["mjdrive.agents." + name for name in setuptools.find_packages(str(ROOT / "agents"))]
    assert sorted(packages) == sorted(found + ["mjdrive.agents"])


def test_agents_import_as_mjdrive_agents():
    import mjdrive.agents

    assert Path(mjdrive.agents.__file__).resolve().parent == ROOT / "agents"


def test_every_module_has_a_layer():
    for module in MODULES:
        layer(module)


def test_no_import_from_a_higher_layer():
    upward = [f"{MODULES[module].relative_to(ROOT)}:{line}: {module} ({layer(module)}) imports {target} "
              f"({layer(target)})"
              for module, targets in sorted(GRAPH.items()) for target, line in sorted(targets.items())
              if RANK[layer(target)] > RANK[layer(module)]]
    assert not upward, "imports against the layers:\n" + "\n".join(upward)


def test_no_import_cycle():
    cycles = _cycles(GRAPH)
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(cycle) for cycle in cycles)


def test_the_walk_sees_function_level_imports_and_cycles():
    assert "mjdrive.agents.ensemble" in GRAPH["mjdrive.cli"]  # imported inside cmd_ensemble
    assert "mjdrive.envs.gym_env" in GRAPH["mjdrive.envs.registration"]  # inside a function
    graph = {"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}
    assert _cycles(graph) == [["a", "b", "c"]]
