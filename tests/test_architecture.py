"""The layout is the architecture (docs/architecture.md): packages import only downward, no
module imports itself round a circle, and the coordinator runs without the simulator."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "crowdteleop"

BASE = {"errors", "vocab"}
# Which top-level part of crowdteleop may import which: the table in docs/architecture.md.
MAY_IMPORT: dict[str, set[str]] = {
    "errors": set(),
    "vocab": set(),
    "tasks": {"errors"},
    "gl": {"errors"},
    "sim": BASE | {"gl", "tasks"},
    "control": BASE | {"tasks", "sim"},
    "recording": BASE,
    "teleop": BASE | {"tasks", "sim", "control", "recording"},
    "client": BASE | {"tasks", "sim", "control", "teleop"},
    "dataset": BASE | {"tasks", "sim", "control", "recording", "teleop"},
    "learn": BASE | {"tasks", "sim", "control", "recording", "dataset"},
    "web": set(),
    "linkemu": set(),
    "coord": BASE | {"tasks", "recording", "teleop", "web"},
    "crowd": BASE | {"tasks", "sim", "control", "teleop", "client", "coord", "linkemu"},
    "cli": BASE
    | {"tasks", "sim", "control", "recording", "teleop", "client", "dataset", "learn", "coord"}
    | {"crowd", "linkemu"},
    "__main__": {"cli"},
    "__init__": {"gl"},
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, modules: set[str]) -> set[str]:
    """Every crowdteleop module `path` imports, at the top or inside a function."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join([*base, node.module] if node.module else base)
            else:
                source = node.module or ""
            for alias in node.names:  # `from package import submodule` names the submodule
                submodule = f"{source}.{alias.name}"
                found.add(submodule if submodule in modules else source)
    return {name for name in found if name.split(".")[0] == "crowdteleop"}


def _graph() -> dict[str, set[str]]:
    modules = {_module_name(path): path for path in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        targets = set()
        for imported in _imports(path, set(modules)):
            # `from crowdteleop.x import y` may name a module y or an object in x
            while imported not in modules and "." in imported:
                imported = imported.rpartition(".")[0]
            if imported != name:
                targets.add(imported)
        graph[name] = targets
    return graph


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _upward(graph: dict[str, set[str]]) -> list[str]:
    """Imports of a part that the table does not allow it."""
    found = []
    for module, targets in graph.items():
        part = _part(module)
        assert part in MAY_IMPORT, f"{module}: a new top-level part, add it to the table"
        for target in targets:
            other = _part(target)
            if other != part and other not in MAY_IMPORT[part]:
                found.append(f"{module} -> {target}")
    return sorted(found)


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Groups of modules that import each other round a circle (Tarjan's components)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return circles


def test_packages_import_only_the_layers_below_them():
    upward = _upward(_graph())
    assert not upward, "imports against the layering:\n" + "\n".join(upward)


def test_no_module_imports_itself_round_a_circle():
    circles = _circles(_graph())
    assert not circles, f"import circles: {circles}"


def test_the_rules_catch_an_arrow_up_and_a_circle():
    """Each check fails where it should: the real graph plus one bad edge."""
    graph = _graph()
    bad = {
        **graph,
        "crowdteleop.sim.config": graph["crowdteleop.sim.config"] | {"crowdteleop.teleop.config"},
    }
    assert _upward(bad) == ["crowdteleop.sim.config -> crowdteleop.teleop.config"]
    assert any("crowdteleop.sim.config" in circle for circle in _circles(bad))


@pytest.mark.parametrize("module", ["crowdteleop.coord.app", "crowdteleop.cli"])
def test_the_coordinator_loads_no_simulator(module):
    """A coordinator on a small machine in front of a cluster needs neither MuJoCo nor h5py."""
    probe = (
        f"import sys, {module}; "
        "print(','.join(m for m in ('mujoco', 'robosuite', 'h5py') if m in sys.modules))"
    )
    loaded = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert loaded == ""
