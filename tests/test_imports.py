"""The source tree is the import tree: no import circles, sumo_scenarios below behaviors, one net reader.

Read statically (ast), so every import counts: module-level, inside functions (the lazy ones)
and under TYPE_CHECKING.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = {"behaviors": "behaviors", "sumo_scenarios": "sumo_scenarios", "cli": "behaviors.cli"}
"""Source folder -> the package it installs as (cli/ installs as behaviors.cli)."""

ALLOWED_CIRCLES: list[set[str]] = []

LAYERS = ("sumo", "road", "car", "report", "paper", "traffic", "fleet", "learn", "run")
"""behaviors' folders from the bottom up: a module imports from its own folder or one below it.
Below them all: `behaviors` itself (errors, files) and sumo_scenarios; above them all: the CLI."""

NET_READER = "sumo_scenarios.net"
SUMOLIB_NET_READERS_ALLOWED: set[str] = set()
"""Modules allowed to read nets with sumolib: none (realism_tracks.read_lanes reads through
sumo_scenarios.net)."""


def modules() -> dict[str, Path]:
    """Every source module by its import name."""
    found = {}
    for folder, package in PACKAGES.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            name = ".".join((package, *parts))
            found[name.removesuffix(".__init__")] = path
    return found


def imported_names(tree: ast.AST, module: str, is_package: bool) -> Iterator[str]:
    """Every name an import statement anywhere in the module imports (`from a import b`: a.b and a)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".")[: len(module.split(".")) - node.level + is_package]
                base = ".".join([*anchor, *([base] if base else [])])
            yield base
            yield from (f"{base}.{alias.name}" for alias in node.names)


def import_graph() -> dict[str, set[str]]:
    """Module -> the source modules it imports."""
    sources = modules()
    graph = {}
    for name, path in sources.items():
        tree = ast.parse(path.read_text(), str(path))
        targets = set(imported_names(tree, name, path.name == "__init__.py")) & set(sources)
        graph[name] = targets - {name}
    return graph


def circles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[set[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = {stack.pop()}
            while node not in component:
                component.add(stack.pop())
            if len(component) > 1:
                found.append(component)

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_walk_sees_every_kind_of_import() -> None:
    """Module-level, function-level and TYPE_CHECKING imports are all edges."""
    graph = import_graph()
    assert "behaviors.learn.distributed" in graph["behaviors.learn.train"]  # module level
    assert "behaviors.learn.train" in graph["behaviors.cli.train"]  # inside the command's function
    assert "behaviors.errors" in graph["behaviors.cli.train"]  # inside a helper function
    assert "sumo_scenarios.net" in graph["behaviors.road.geometry"]


def test_no_import_circles() -> None:
    found = circles(import_graph())
    unexpected = [sorted(c) for c in found if c not in ALLOWED_CIRCLES]
    assert not unexpected, f"import circles: {unexpected}"


def test_the_circle_finder_finds_circles() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert circles(graph) == [{"a", "b", "c"}]


def test_sumo_scenarios_imports_nothing_of_behaviors() -> None:
    graph = import_graph()
    upward = {
        name: sorted(t for t in targets if t.startswith("behaviors"))
        for name, targets in graph.items()
        if name.startswith("sumo_scenarios")
    }
    assert not any(upward.values()), upward


def reads_nets_with_sumolib(tree: ast.AST) -> bool:
    """Whether a module names sumolib's net reader (sumolib.net, readNet) anywhere."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr == "readNet":
            return True
        if isinstance(node, ast.Name) and node.id == "readNet":
            return True
        if isinstance(node, ast.Import) and any(a.name.startswith("sumolib.net") for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and node.module is not None:
            if node.module.startswith("sumolib.net"):
                return True
            if node.module == "sumolib" and any(a.name == "net" for a in node.names):
                return True
    return False


def test_one_net_reader() -> None:
    """Nets are read only by sumo_scenarios.net's streaming parse (sumolib's took minutes on region nets)."""
    readers = {
        name
        for name, path in modules().items()
        if name != NET_READER and reads_nets_with_sumolib(ast.parse(path.read_text(), str(path)))
    }
    assert readers <= SUMOLIB_NET_READERS_ALLOWED, f"sumolib net readers: {sorted(readers)}"


def test_the_net_reader_check_sees_sumolib() -> None:
    for source in (
        "import sumolib\nsumolib.net.readNet('n.net.xml')",
        "from sumolib.net import readNet",
        "from sumolib import net",
        "import sumolib.net",
    ):
        assert reads_nets_with_sumolib(ast.parse(source)), source
    assert not reads_nets_with_sumolib(ast.parse("from sumo_scenarios.net import read_net"))


def floor(module: str) -> int:
    """A module's height in the house: 0 for behaviors' own modules and sumo_scenarios, then its
    folder's place in LAYERS, the CLI on top."""
    parts = module.split(".")
    if parts[0] == "sumo_scenarios" or len(parts) <= 2 or parts[1] not in (*LAYERS, "cli"):
        return 0
    return len(LAYERS) + 1 if parts[1] == "cli" else LAYERS.index(parts[1]) + 1


def upward_imports(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    return sorted(
        (m, t) for m, targets in graph.items() for t in targets if floor(t) > floor(m) and t != "behaviors"
    )


def test_imports_flow_down_the_folders() -> None:
    graph = import_graph()
    assert set(LAYERS) == {p.name for p in (ROOT / "behaviors").iterdir() if (p / "__init__.py").exists()}
    assert not upward_imports(graph), upward_imports(graph)


def test_the_floor_check_sees_an_upward_import() -> None:
    graph = {"behaviors.road.routes": {"behaviors.fleet.handover", "behaviors.sumo.sim", "behaviors.errors"}}
    assert upward_imports(graph) == [("behaviors.road.routes", "behaviors.fleet.handover")]
    assert floor("behaviors.cli.main") > floor("behaviors.run.populate") > floor("behaviors.errors")
