"""README.md's and the manual's (docs/manual/*.md) examples run as written, and the README stays short.

Every ```python block runs as a script of its own (a fresh interpreter: libsumo runs one simulation
per process) in an empty temporary folder; a manual block that repeats one of the README's word for
word runs once. Every line of a ```bash/```sh block that begins with `behave ` runs through bash in
one shared empty temporary folder: the README's in README order first, then the manual's, page by
page in file-name order, so later commands find what earlier ones wrote (`behave populate` then
`behave report` of its FCD; the manual's examples go on from the README's). A manual line that
repeats one already run is not run again. Both use this interpreter's environment: `behave` is the
one installed beside it.

Skipped: lines whose comment begins with `# long` (training runs of minutes to hours, written as they
would be used). Keep that list short: an example that can be made quick (a small `--duration`,
`--episodes`, `--max-steps`) should be written quick and run here. Lines of other tools (`make`,
`ray start`, `tensorboard`, `docker`) are not run. Both start SUMO (marked `sumo`: `make test-fast`
leaves them out); the checks below do not.

Besides: the README has at most MAX_README_LINES lines; every relative link in the README and the
manual points to a file that exists (and, with a `#anchor` into a Markdown file, to one of its
headings); the user-facing text names no issue numbers or working stops; and every function,
setting and test that the traffic driver's rules table (docs/manual/traffic-driver.md) names exists.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MANUAL = ROOT / "docs" / "manual"
RULES_PAGE = MANUAL / "traffic-driver.md"
MAX_README_LINES = 300
LONG = "# long"
PYTHON_TIMEOUT = 300.0
COMMAND_TIMEOUT = 300.0
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```", re.MULTILINE | re.DOTALL)
SHELL = {"bash", "sh", "shell", "console"}


def manual_pages() -> list[Path]:
    return sorted(MANUAL.glob("*.md"))


def pages() -> list[Path]:
    """The user-facing Markdown: the README first, then the manual."""
    return [README, *manual_pages()]


def name_of(page: Path) -> str:
    return str(page.relative_to(ROOT))


def fenced_blocks(page: Path, language: set[str]) -> list[tuple[int, str]]:
    """(line number, body) of every fenced block of `page` whose language is in `language`."""
    text = page.read_text(encoding="utf-8")
    return [
        (text.count("\n", 0, match.start()) + 1, match.group(2))
        for match in FENCE.finditer(text)
        if match.group(1) in language
    ]


def python_blocks() -> list[tuple[str, int, str]]:
    """(page, line number, body) of every python block, a manual block the README has run once."""
    out, seen = [], set()
    for page in pages():
        for line, body in fenced_blocks(page, {"python"}):
            if body not in seen:
                seen.add(body)
                out.append((name_of(page), line, body))
    return out


def behave_lines(page: Path) -> list[tuple[int, str]]:
    """(line number, command) of every `behave ...` shell line of `page`, long ones included."""
    out = []
    for start, body in fenced_blocks(page, SHELL):
        for k, line in enumerate(body.splitlines()):
            if line.strip().startswith("behave "):
                out.append((start + 1 + k, line.strip()))
    return out


def is_long(command: str) -> bool:
    """Marked `# long` (the comment may go on: `# long: PS-DDPG on the ring`)."""
    return LONG in command


def environment() -> dict[str, str]:
    """This interpreter's venv first on PATH, so `behave` and `python` are the ones under test."""
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env.pop("PYTHONPATH", None)
    return env


def failure(what: str, result: subprocess.CompletedProcess[str]) -> str:
    out, err = result.stdout[-3000:], result.stderr[-3000:]
    return f"{what} exited {result.returncode}\n--- stdout\n{out}\n--- stderr\n{err}"


def prose(page: Path) -> str:
    """`page` without its fenced blocks and inline code: the words a reader reads as text."""
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    return re.sub(r"`[^`\n]*`", "", text)


def test_the_readme_has_examples_and_few_long_ones() -> None:
    assert len(fenced_blocks(README, {"python"})) >= 2
    lines = behave_lines(README)
    long = [command for _, command in lines if is_long(command)]
    assert len(lines) - len(long) >= 8
    assert len(long) <= 6, f"too many README examples skipped as long: {long}"
    manual_long = [
        command for page in manual_pages() for _, command in behave_lines(page) if is_long(command)
    ]
    assert len(manual_long) <= 6, f"too many manual examples skipped as long: {manual_long}"


def test_the_readme_is_at_most_300_lines() -> None:
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_README_LINES, f"README.md has {lines} lines: move detail to docs/manual/"


LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    words = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return words.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    out: set[str] = set()
    for heading in re.findall(r"^#+\s+(.*)$", text, re.MULTILINE):
        name, k = slug(heading), 0
        while (f"{name}-{k}" if k else name) in out:  # a repeated heading gets -1, -2, ...
            k += 1
        out.add(f"{name}-{k}" if k else name)
    return out


@pytest.mark.parametrize("page", pages(), ids=name_of)
def test_relative_links_point_to_files_that_exist(page: Path) -> None:
    broken = []
    for target in LINK.findall(prose(page)):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto: ...
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists():
            broken.append(f"{target}: no {file}")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file):
            broken.append(f"{target}: no heading #{anchor} in {file.name}")
    assert not broken, f"{name_of(page)}: broken relative links:\n" + "\n".join(broken)


# working words that belong in docs/history.md, not in what a user reads
NOTEBOOK = re.compile(
    r"\bissues? \d+|(?<![\w&/])#\d+\b|\bsessions?\b"
    r"|\b(?:\w+th|first|second|third|this|that|last|next) stop\b",
    re.IGNORECASE,
)


@pytest.mark.parametrize("page", pages(), ids=name_of)
def test_user_facing_text_names_no_issue_numbers_or_working_stops(page: Path) -> None:
    found = [match.group(0) for match in NOTEBOOK.finditer(prose(page))]
    assert not found, f"{name_of(page)}: {found} (dated history belongs in docs/history.md)"


MOTIVES = {"strategic", "cooperative", "speed gain", "keep right", "safety limit", "law"}
"""Why a rule exists: the words of the table's motive column."""


def rules_table() -> list[list[str]]:
    """The cells of every row of the traffic driver's rules table."""
    lines = RULES_PAGE.read_text(encoding="utf-8").splitlines()
    start = next(
        k for k, line in enumerate(lines) if line.startswith("| rule | motive | setting | function |")
    )
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in re.split(r"(?<!\\)\|", line)[1:-1]])
    return rows


def named(cell: str) -> list[str]:
    return re.findall(r"`([^`]+)`", cell)


def cli_options() -> set[str]:
    """Every option of every `behave` command."""
    import typer

    from behaviors.cli.main import app

    out: set[str] = set()
    commands = [typer.main.get_command(app)]
    while commands:
        command = commands.pop()
        for param in command.params:
            out |= set(param.opts) | set(param.secondary_opts)
        commands += getattr(command, "commands", {}).values()
    return out


def is_setting(name: str) -> bool:
    """`Class.field[.field]`: a field of a settings dataclass of behaviors.traffic.settings (`LaneDriving`,
    `CarFollowing`, ...; every one has defaults), through nested settings (`LaneDriving.following.accel`)."""
    from behaviors.traffic import settings

    owner, *path = name.split(".")
    found = getattr(settings, owner, None)
    if not (isinstance(found, type) and dataclasses.is_dataclass(found) and path):
        return False
    found = found()
    for part in path:
        if not (dataclasses.is_dataclass(found) and part in {f.name for f in dataclasses.fields(found)}):
            return False
        found = getattr(found, part)
    return True


def module_named(short: str) -> str:
    """The import name of behaviors' module `short` (the table names modules without their folder)."""
    (path,) = (ROOT / "behaviors").rglob(f"{short}.py")
    return ".".join(path.relative_to(ROOT).with_suffix("").parts)


def test_the_rules_table_names_settings_functions_and_tests_that_exist() -> None:
    options = cli_options()
    rows = rules_table()
    assert len(rows) >= 30
    for rule, motive, setting, function, test in rows:
        where = f"rules table, {rule[:60]!r}"
        assert motive in MOTIVES, where
        modules = []
        for name in named(function):
            module, *attributes = name.split(".")
            found = importlib.import_module(module_named(module))
            modules.append(found)
            for attribute in attributes:
                assert hasattr(found, attribute), f"{where}: no {name}"
                found = getattr(found, attribute)
        assert modules, f"{where}: no function named"
        assert setting.startswith("none (always on") or named(setting), where
        for name in named(setting):
            if name.startswith("--"):
                assert set(name.split("/")) <= options, f"{where}: no option {name}"
            elif "." in name:
                assert is_setting(name), f"{where}: no setting {name}"
            else:
                assert any(hasattr(module, name) for module in modules), f"{where}: no constant {name}"
        assert test == "none" or named(test), where
        for name in named(test):
            file, _, test_name = name.rpartition("::")
            (path,) = (ROOT / "tests").glob(f"*/{file or 'test_traffic.py'}")
            source = path.read_text(encoding="utf-8")
            assert f"def {test_name}(" in source, f"{where}: no test {name}"


@pytest.mark.sumo
@pytest.mark.parametrize(
    ("page", "line", "code"),
    [pytest.param(page, line, code, id=f"{page}:line{line}") for page, line, code in python_blocks()],
)
def test_python_block_runs(page: str, line: int, code: str, tmp_path: Path) -> None:
    script = tmp_path / "example.py"
    script.write_text(code, encoding="utf-8")
    result = subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,
        env=environment(),
        capture_output=True,
        text=True,
        timeout=PYTHON_TIMEOUT,
        check=False,
    )
    assert result.returncode == 0, failure(f"{page}'s python block at line {line}", result)


@pytest.fixture(scope="module")
def shell_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One folder for all shell lines: they build on each other as a reader's would."""
    return tmp_path_factory.mktemp("readme_shell")


@pytest.mark.sumo
def test_behave_lines_run_in_order(shell_folder: Path) -> None:
    ran: list[str] = []
    for page in pages():
        for line, command in behave_lines(page):
            if is_long(command) or command in ran:
                continue
            result = subprocess.run(
                ["bash", "-c", command],
                cwd=shell_folder,
                env=environment(),
                capture_output=True,
                text=True,
                timeout=COMMAND_TIMEOUT,
                check=False,
            )
            assert result.returncode == 0, failure(f"{name_of(page)} line {line}: {command}", result)
            ran.append(command)
    assert len(ran) >= 8
