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

NET_READER = "sumo_scenarios.net"
SUMOLIB_NET_READERS_ALLOWED: set[str] = set()
"""Modules allowed to read nets with sumolib: none (realism.read_lanes reads through sumo_scenarios.net)."""


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
    assert "behaviors.distributed" in graph["behaviors.train"]  # module level
    assert "behaviors.train" in graph["behaviors.cli.train"]  # inside the command's function
    assert "behaviors.errors" in graph["behaviors.cli.train"]  # inside a helper function
    assert "sumo_scenarios.net" in graph["behaviors.geometry"]


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
