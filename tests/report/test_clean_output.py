"""What behave prints and writes reads clean: rounded JSON, report text without
`infx`/`nanx`, the motorway's lanes as they are, a quiet `pip install`, sweeps without Ray's token
note."""

from __future__ import annotations

import logging
import math
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from helpers import behave

from behaviors.learn.distributed import TOKEN_LOGGER, TOKEN_NOTE, quiet_token_note
from behaviors.report.realism import like_for_like_note
from behaviors.run.records import PopulateSummary
from sumo_scenarios import get_scenario, scenario_info

ROOT = Path(__file__).resolve().parents[2]


def test_json_times_are_rounded() -> None:
    summary = PopulateSummary()
    for _ in range(100):
        summary.simulated_s += 0.2
        summary.longest_standstill_s += 0.2
    assert summary.simulated_s != 20.0  # the float sum: 19.99999999999996
    row = summary.as_dict()
    assert (row["simulated_s"], row["longest_standstill_s"]) == (20.0, 20.0)


def test_like_for_like_ratios_read_as_words_where_not_numbers() -> None:
    base = {"trips": 3.0, "km_share": 0.8}
    assert like_for_like_note({**base, "mean_speed": 1.1, "passes_per_km": 2.345}).endswith(
        "mean speed 1.10x, passes per km 2.35x"
    )
    note = like_for_like_note({**base, "mean_speed": 1.1, "passes_per_km": math.inf})
    assert note.endswith("passes per km only the overtakers had any passes")
    note = like_for_like_note({**base, "mean_speed": 1.1, "passes_per_km": math.nan})
    assert note.endswith("passes per km neither had any passes")
    none = like_for_like_note(
        {"trips": 0.0, "km_share": 0.0, "mean_speed": math.nan, "passes_per_km": math.nan}
    )
    assert none == "overtakers / keepers: no trip both made (first to last edge), so no like-for-like ratios"
    for text in (note, none):
        assert "infx" not in text and "nanx" not in text


def test_scenario_list_gives_the_motorways_lanes_as_they_are() -> None:
    """3 lanes, 4 along the weave: the list said 4 and its description 3."""
    info = scenario_info(get_scenario("motorway"))
    assert (info.lanes, info.route_lanes, info.lanes_text) == (4, (3, 4), "3-4")
    assert scenario_info(get_scenario("highway")).lanes_text == "3"
    assert "4th" in get_scenario("motorway").description
    done = behave("scenario", "list")
    assert done.returncode == 0, done.stderr
    [row] = [line for line in done.stdout.splitlines() if line.startswith("│ motorway")]
    assert "│ 3-4 " in row


def test_ray_token_note_is_dropped_and_nothing_else() -> None:
    seen: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.append(record.getMessage())

    logger = logging.getLogger(TOKEN_LOGGER)
    handler = Keep()
    logger.addHandler(handler)
    try:
        quiet_token_note()
        quiet_token_note()  # once is enough, twice does no harm
        logger.warning(f"{TOKEN_NOTE}. Set RAY_AUTH_MODE=disabled to opt out.")
        logger.warning("Token authentication is disabled for this Ray cluster.")
        setup = pytest.importorskip("ray._private.authentication.authentication_token_setup")
        assert setup.logger is logger
        setup._warn_token_auth_enabled()  # the very note a local ray.init() logs
    finally:
        logger.removeHandler(handler)
    assert seen == ["Token authentication is disabled for this Ray cluster."]


def test_building_the_package_prints_no_setuptools_warning(tmp_path: Path) -> None:
    """The wheel of this checkout's files, built by the installed setuptools: no warning (there was
    one of forty lines per data folder) and every data file inside."""
    pytest.importorskip("setuptools")
    src = tmp_path / "src"
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / name, src / name)
    for folder in ("behaviors", "cli", "sumo_scenarios"):
        shutil.copytree(ROOT / folder, src / folder, ignore=shutil.ignore_patterns("__pycache__"))
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-build-isolation", "--no-deps", "--no-index", "-q",
         "--disable-pip-version-check", str(src), "-w", str(tmp_path / "wheel")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "Warning" not in done.stdout + done.stderr, done.stderr[:2000]
    [wheel] = (tmp_path / "wheel").glob("*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    data = {str(p.relative_to(src)) for p in (src / "sumo_scenarios" / "data").glob("*/*.xml")}
    assert data and data <= names
    assert {"behaviors/pretrained/traffic.pt", "behaviors/cli/main.py", "behaviors/py.typed"} <= names
