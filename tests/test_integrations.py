"""behave among the tools researchers use: a quick CLI, an installable package, PettingZoo,
SuperSuit + Stable-Baselines3, Gymnasium and TensorBoard."""

from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY = ("torch", "pandas", "matplotlib", "libsumo", "sumolib", "traci")


@pytest.mark.parametrize("command", [[], ["train"], ["populate"], ["evaluate"], ["report"], ["plot"],
                                     ["export"], ["scenario"], ["scenario", "list"]])  # fmt: skip
def test_help_imports_no_heavy_library(command: list[str]) -> None:
    """`behave [CMD] --help` must answer at once: building the app and showing help loads none of
    torch, pandas, matplotlib or SUMO's libraries (a module check, not a timing)."""
    probe = (
        "import sys\n"
        "from cli.main import main\n"
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
    from behaviors.populate import DEFAULT_POLICY, PopulateConfig
    from behaviors.train import TrainConfig
    from cli import populate, report, train

    for defaults, config in ((train.DEFAULTS, TrainConfig()), (populate.DEFAULTS, PopulateConfig())):
        assert vars(defaults) == {name: getattr(config, name) for name in vars(defaults)}
    assert populate.DEFAULT_POLICY == DEFAULT_POLICY
    assert (report.GROUP_BY, report.SKIP_S) == (realism.GROUP_BY, realism.SKIP_S)
