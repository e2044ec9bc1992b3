"""behave among the tools researchers use: a quick CLI, an installable package, PettingZoo,
SuperSuit + Stable-Baselines3, Gymnasium and TensorBoard."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "pandas", "matplotlib", "libsumo", "sumolib", "traci")


@pytest.mark.parametrize("command", [[], ["train"], ["populate"], ["evaluate"], ["report"], ["plot"],
                                     ["export"], ["scenario"], ["scenario", "list"]])  # fmt: skip
def test_help_imports_no_heavy_library(command: list[str]) -> None:
    """`behave [CMD] --help` must answer at once: building the app and showing help loads none of
    torch, pandas, matplotlib or SUMO's libraries (a module check, not a timing)."""
    probe = (
        "import sys\n"
        "from behaviors.cli.main import main\n"
        f"sys.argv = ['behave', *{command!r}, '--help']\n"
        "try:\n    main()\n"
        "except SystemExit as exit:\n    assert exit.code in (0, None), exit.code\n"
        f"print('loaded:', *(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert "Usage: behave" in result.stdout
    assert result.stdout.splitlines()[-1] == "loaded:"


def test_cli_defaults_are_the_configs() -> None:
    """The CLI spells its defaults out (so --help needs no torch or pandas): they must stay the
    library's."""
    from behaviors import realism
    from behaviors.cli import populate, report, train
    from behaviors.populate import DEFAULT_POLICY, PopulateConfig
    from behaviors.train import TrainConfig

    for defaults, config in ((train.DEFAULTS, TrainConfig()), (populate.DEFAULTS, PopulateConfig())):
        assert vars(defaults) == {name: getattr(config, name) for name in vars(defaults)}
    assert populate.DEFAULT_POLICY == DEFAULT_POLICY
    assert (report.GROUP_BY, report.SKIP_S) == (realism.GROUP_BY, realism.SKIP_S)


def test_wheel_installs_the_cli_under_behaviors(tmp_path: Path) -> None:
    """The built wheel holds behaviors/cli/ and no top-level `cli`, and `behave` points into it."""
    source = tmp_path / "src"
    for part in ("behaviors", "cli", "sumo_scenarios"):
        shutil.copytree(ROOT / part, source / part, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    command = [sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation", "-q"]
    subprocess.run([*command, "-w", str(tmp_path)], capture_output=True, check=True, cwd=tmp_path)
    (wheel,) = tmp_path.glob("behave_traffic-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        entry_points = next(n for n in names if n.endswith("entry_points.txt"))
        scripts = archive.read(entry_points).decode()
    top_level = {name.split("/")[0] for name in names if "dist-info" not in name}
    assert top_level == {"behaviors", "sumo_scenarios"}
    assert "behaviors/cli/main.py" in names
    assert "behave = behaviors.cli.main:main" in scripts
