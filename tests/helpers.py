"""What the test modules share: `from helpers import behave` (pyproject puts tests/ on the path).

Tiers (markers registered in pyproject.toml): `sumo` marks a test that starts SUMO (libsumo, a SUMO
binary such as netconvert) or runs a `behave` command that does (populate, train, evaluate, sweep;
also one meant to stop before SUMO starts: a subprocess costs seconds of imports), `train` one that
trains a network for more than a few steps. `make test-fast` runs the others:
`pytest -m "not sumo and not train"`, which must pass with SUMO out of reach.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

BEHAVE = [sys.executable, "-m", "behaviors.cli"]
"""`behave` as this interpreter runs it: the package under test, whatever is on PATH."""
INSTALLED_BEHAVE = str(Path(sys.executable).parent / "behave")
"""The console script `pip install` wrote, the command a user types."""


def behave(
    *args: str,
    cwd: Path | str | None = None,
    env: Mapping[str, str] | None = None,
    timeout: float | None = 300,
    installed: bool = False,
) -> subprocess.CompletedProcess[str]:
    """`behave ARGS` in a subprocess: its return code, stdout and stderr as text (never raises for a
    non-zero exit; raises subprocess.TimeoutExpired after `timeout` seconds). `env` replaces the whole
    environment, as subprocess.run's does; `installed` runs the console script instead of
    `python -m behaviors.cli`."""
    command = [INSTALLED_BEHAVE] if installed else BEHAVE
    return subprocess.run(
        [*command, *args], capture_output=True, text=True, timeout=timeout, cwd=cwd, env=env, check=False
    )
