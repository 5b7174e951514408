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
    "provenance": BASE | {"tasks"},
    "sim": BASE | {"gl", "tasks", "provenance"},
    "control": BASE | {"tasks", "sim", "provenance"},
    "recording": BASE | {"provenance"},
    "teleop": BASE | {"tasks", "sim", "control", "recording"},
    "client": BASE | {"tasks", "sim", "control", "teleop"},
    "dataset": BASE | {"tasks", "sim", "control", "recording", "provenance"},
    "learn": BASE | {"tasks", "sim", "control", "recording", "dataset", "provenance"},
    "taskcheck": BASE | {"tasks", "sim", "control", "recording", "dataset", "provenance"},
    "web": set(),
    "linkemu": set(),
    "coord": BASE | {"tasks", "recording", "teleop", "web"},
    "crowd": BASE | {"tasks", "sim", "control", "teleop", "client", "coord", "linkemu"},
    "cli": BASE
    | {"tasks", "sim", "control", "recording", "teleop", "client", "dataset", "learn", "coord"}
    | {"crowd", "linkemu", "taskcheck"},
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


# --- inside the coordinator -------------------------------------------------------------------
# coord's own packages and which may import which: the routers call the service core, which
# reaches the teleop servers, the database and the guards; nothing but the app (and the `serve`
# command) imports the core, and nothing but the app the routers. An entry names a package
# (`service`) or one module of it (`db.tables`: the routers may name a session's row type, but
# reach the database only through the service).
COORD = "crowdteleop.coord"
COORD_MAY_IMPORT: dict[str, set[str]] = {
    "__init__": set(),
    "guard": set(),
    "db": {"guard"},
    "fleet": {"db", "guard"},
    "service": {"fleet", "db", "guard"},
    "api": {"service", "guard", "db.tables"},
    "app": {"api", "service", "fleet", "db", "guard"},
    "cli": {"app", "service", "db", "guard"},
    "node": {"fleet", "guard"},
}
# What coord takes from teleop: the config and the messages between processes (no simulator).
COORD_TELEOP = {f"crowdteleop.teleop.{name}" for name in ("config", "messages", "protocol")}
# What the rest of crowdteleop takes from coord: the `serve` command and the API's models.
COORD_ENTRY_POINTS = {"cli": {f"{COORD}.cli"}, "crowd": {f"{COORD}.api.schemas"}}


def _coord_part(module: str) -> str:
    rest = module.removeprefix(COORD).lstrip(".")
    return rest.split(".")[0] if rest else "__init__"


def _allowed_in_coord(module: str, target: str) -> bool:
    part, rest = _coord_part(module), target.removeprefix(COORD + ".")
    if _coord_part(target) == part:
        return True
    assert part in COORD_MAY_IMPORT, f"{module}: a new part of coord, add it to the table"
    return any(rest == entry or rest.startswith(entry + ".") for entry in COORD_MAY_IMPORT[part])


def _coord_violations(graph: dict[str, set[str]]) -> list[str]:
    """Imports against coord's own table, of teleop beyond its config and messages, and of
    coord from outside past its entry points."""
    found = []
    for module, targets in graph.items():
        inside = module == COORD or module.startswith(COORD + ".")
        for target in targets:
            into_coord = target == COORD or target.startswith(COORD + ".")
            if inside and into_coord:
                allowed = _allowed_in_coord(module, target)
            elif inside:
                allowed = _part(target) != "teleop" or target in COORD_TELEOP
            else:
                allowed = not into_coord or target in COORD_ENTRY_POINTS.get(_part(module), set())
            if not allowed:
                found.append(f"{module} -> {target}")
    return sorted(found)


def _sources() -> dict[str, ast.Module]:
    return {
        _module_name(path): ast.parse(path.read_text(), str(path)) for path in PACKAGE.rglob("*.py")
    }


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _private_imports(module: str, tree: ast.Module) -> list[str]:
    """`from other import _name`: another module's private name (ours; not the stdlib's)."""
    package = module.rpartition(".")[0]
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:
            base = package.split(".")[: len(package.split(".")) - node.level + 1]
            source = ".".join([*base, node.module] if node.module else base)
        else:
            source = node.module or ""
        if source.split(".")[0] == "crowdteleop" and source != module:
            found += [f"{module}: {source}.{a.name}" for a in node.names if _private(a.name)]
    return found


def _private_reaches(module: str, tree: ast.Module) -> list[str]:
    """`other._attribute`: another object's private state (its own `self._x` is its own)."""
    return [
        f"{module}:{node.lineno}: {ast.unparse(node)}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and _private(node.attr)
        and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
    ]


def test_coords_packages_import_only_what_their_table_allows():
    violations = _coord_violations(_graph())
    assert not violations, "imports against coord's table:\n" + "\n".join(violations)


def test_no_module_imports_another_modules_private_names():
    found = [hit for module, tree in _sources().items() for hit in _private_imports(module, tree)]
    assert not found, "private names imported from another module:\n" + "\n".join(found)


def test_no_coord_module_reaches_into_another_objects_private_state():
    """The Coordinator's collaborators are its own: sweeps and routers call its methods."""
    found = [
        hit
        for module, tree in _sources().items()
        if module.startswith(COORD)
        for hit in _private_reaches(module, tree)
    ]
    assert not found, "private attributes of other objects:\n" + "\n".join(found)


def test_the_coordinator_rules_catch_each_violation():
    """Each rule fails where it should: the real graph or source plus one bad line."""
    graph = _graph()
    bad_edges = {
        "crowdteleop.coord.service.coordinator": "crowdteleop.coord.api.views",  # up
        "crowdteleop.coord.api.sessions": "crowdteleop.coord.db.store",  # a router at the store
        "crowdteleop.coord.guard.limits": "crowdteleop.coord.db.tables",  # guard is the bottom
        "crowdteleop.coord.app": "crowdteleop.teleop.session",  # teleop beyond its messages
        "crowdteleop.crowd.api": "crowdteleop.coord.service.coordinator",  # past the entries
    }
    bad = {**graph}
    for module, target in bad_edges.items():
        bad[module] = bad[module] | {target}
    assert _coord_violations(graph) == []
    assert _coord_violations(bad) == sorted(f"{m} -> {t}" for m, t in bad_edges.items())

    module = "crowdteleop.coord.service.reaper"
    reaching = ast.parse(
        "from crowdteleop.coord.service.coordinator import _every, Coordinator\n"
        "from .liveness import __doc__\n"
        "def reap(coordinator):\n"
        "    self._cache.clear()\n"
        "    return coordinator._pool.slots\n"
    )
    assert _private_imports(module, reaching) == [
        "crowdteleop.coord.service.reaper: crowdteleop.coord.service.coordinator._every"
    ]
    assert _private_reaches(module, reaching) == [
        "crowdteleop.coord.service.reaper:5: coordinator._pool"
    ]
