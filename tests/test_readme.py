"""README.md's examples run as written.

Every ```python block runs as a script of its own (a fresh interpreter: libsumo runs one
simulation per process) in an empty temporary folder. Every line of a ```bash/```sh block that
begins with `behave ` runs through bash, in README order, in one shared empty temporary folder,
so later commands find what earlier ones wrote (`behave populate` then `behave report` of its
FCD). Both use this interpreter's environment: `behave` is the one installed beside it.

Skipped: lines whose comment begins with `# long` (training runs of minutes to hours, written in the README
as they would be used). Keep that list short: an example that can be made quick (a small
`--duration`, `--episodes`, `--max-steps`) should be written quick and run here. Lines of
other tools (`make`, `ray start`, `tensorboard`) are not run.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
LONG = "# long"
PYTHON_TIMEOUT = 180.0
COMMAND_TIMEOUT = 180.0
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```", re.MULTILINE | re.DOTALL)


def fenced_blocks(language: set[str]) -> list[tuple[int, str]]:
    """(line number, body) of every fenced block whose language is in `language`."""
    text = README.read_text(encoding="utf-8")
    return [
        (text.count("\n", 0, match.start()) + 1, match.group(2))
        for match in FENCE.finditer(text)
        if match.group(1) in language
    ]


def python_blocks() -> list[tuple[int, str]]:
    return fenced_blocks({"python"})


def behave_lines() -> list[tuple[int, str]]:
    """(README line number, command) of every `behave ...` shell line, long ones included."""
    out = []
    for start, body in fenced_blocks({"bash", "sh", "shell", "console"}):
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


def test_the_readme_has_examples_and_few_long_ones() -> None:
    assert len(python_blocks()) >= 2
    lines = behave_lines()
    long = [command for _, command in lines if is_long(command)]
    assert len(lines) - len(long) >= 8
    assert len(long) <= 6, f"too many examples skipped as long: {long}"


@pytest.mark.parametrize(
    ("line", "code"), [pytest.param(line, code, id=f"line{line}") for line, code in python_blocks()]
)
def test_python_block_runs(line: int, code: str, tmp_path: Path) -> None:
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
    assert result.returncode == 0, failure(f"README.md's python block at line {line}", result)


@pytest.fixture(scope="module")
def shell_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One folder for all shell lines: they build on each other as a reader's session would."""
    return tmp_path_factory.mktemp("readme_shell")


def test_behave_lines_run_in_order(shell_folder: Path) -> None:
    ran = 0
    for line, command in behave_lines():
        if is_long(command):
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
        assert result.returncode == 0, failure(f"README.md line {line}: {command}", result)
        ran += 1
    assert ran >= 8
