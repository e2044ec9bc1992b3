"""The house's bars: no module under behaviors/ over MAX_LINES lines, no function outside the CLI
over MAX_PARAMETERS parameters (positional and keyword-only, self and cls not counted).

Read statically (ast). The exceptions are named one by one and must match exactly: a new violation
anywhere fails, and so does an exception that no longer is one (take it off the list).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MAX_LINES = 600
MAX_PARAMETERS = 10
FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef)
CHECKED = ("behaviors", "sumo_scenarios", "benchmarks", "tests")
"""Folders whose functions the parameter bar covers (cli/ is exempt: a command takes its options)."""

LONG_MODULES_ALLOWED: set[str] = set()
"""Modules allowed over MAX_LINES, by path from the repository root."""

WIDE_FUNCTIONS_ALLOWED: set[str] = set()
"""Functions allowed over MAX_PARAMETERS, as `path:name`."""


def sources(folder: str) -> Iterator[Path]:
    """The Python files under a folder of the repository."""
    yield from sorted((ROOT / folder).rglob("*.py"))


def parameter_count(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Positional and keyword-only parameters, self and cls not counted."""
    args = node.args
    names = [arg.arg for arg in (*args.posonlyargs, *args.args, *args.kwonlyargs)]
    return len([name for name in names if name not in ("self", "cls")])


def wide_functions(path: Path) -> Iterator[str]:
    """`path:name` of every function in the file over MAX_PARAMETERS parameters."""
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        if isinstance(node, FUNCTIONS) and parameter_count(node) > MAX_PARAMETERS:
            yield f"{path.relative_to(ROOT).as_posix()}:{node.name}"


def long_modules() -> set[str]:
    """Modules under behaviors/ over MAX_LINES lines."""
    return {
        path.relative_to(ROOT).as_posix()
        for path in sources("behaviors")
        if len(path.read_text().splitlines()) > MAX_LINES
    }


def test_no_module_over_max_lines() -> None:
    assert long_modules() == LONG_MODULES_ALLOWED


def test_no_function_over_max_parameters() -> None:
    wide = {name for folder in CHECKED for path in sources(folder) for name in wide_functions(path)}
    assert wide == WIDE_FUNCTIONS_ALLOWED


def test_parameter_count_leaves_out_self() -> None:
    tree = ast.parse("def f(self, a, /, b, *args, c, **kw): pass")
    function = tree.body[0]
    assert isinstance(function, ast.FunctionDef)
    assert parameter_count(function) == 3
