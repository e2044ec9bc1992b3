"""A newcomer's first hour: what `make run` installs, names where paths are taken, the small
things a user meets first (`--version`, `policy list`, LICENSE, py.typed), errors before work."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import behave

from behaviors.cli.policy import MODEL_CARD, model_card_lines
from behaviors.learn.env import KEEPER_TYPE, OVERTAKER_TYPE
from behaviors.report.fcd_read import read_fcd
from tests.sumo.test_own_scenario import netconvert

ROOT = Path(__file__).resolve().parents[1]


def one_line_error(result: subprocess.CompletedProcess[str]) -> str:
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("behave: error: "), result.stderr
    return lines[0]


@pytest.mark.skipif(shutil.which("make") is None, reason="no make")
def test_make_run_installs_no_extras_and_make_test_installs_what_tests_use(tmp_path: Path) -> None:
    venv = str(tmp_path / "fresh")  # no venv there: make prints the whole set-up it would run
    run = subprocess.run(["make", "-n", "run", f"VENV={venv}"], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout  # fmt: skip
    installs = [line for line in run.splitlines() if " install " in line]
    assert any("torch==" in line for line in installs)
    assert any(line.rstrip().endswith("-e .") for line in installs)
    assert not any("[" in line for line in installs), installs  # no extras: no Ray, SB3, TorchRL, TensorBoard
    test = subprocess.run(["make", "-n", "test", f"VENV={venv}"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout  # fmt: skip
    assert "-e '.[dev,integrations,distributed,video]'" in test


def test_version_and_policy_list(tmp_path: Path) -> None:
    version = re.search(r'^version = "([^"]+)"', (ROOT / "pyproject.toml").read_text(), re.MULTILINE)[1]
    result = behave("--version", cwd=tmp_path, installed=True)
    assert result.returncode == 0 and result.stdout.strip() == f"behave {version}"
    listed = behave("policy", "list", cwd=tmp_path, installed=True)
    assert listed.returncode == 0, listed.stderr
    for name in ("traffic", "lanekeeping", "overtaking", "multi"):
        assert f"│ {name} " in listed.stdout
    cards = model_card_lines(MODEL_CARD.read_text(encoding="utf-8"))
    assert cards["traffic"][0].startswith("Traffic driver")
    assert cards["lanekeeping"][1].startswith("evaluation (")
    assert all(cards[name][1] for name in ("traffic", "lanekeeping", "overtaking", "multi"))
    section = "## Mine (mine.pt)\n- command: x\n- screens of episode 9: ok\n- evaluation (1 episode): good\n"
    assert model_card_lines(section) == {"mine": ("Mine", "evaluation (1 episode): good")}


def test_project_files() -> None:
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    assert "Parameter Sharing Reinforcement Learning" in (ROOT / "CITATION.cff").read_text()
    assert (ROOT / "behaviors" / "py.typed").is_file()
    assert re.search(r'^behaviors = \[.*"py.typed"', (ROOT / "pyproject.toml").read_text(), re.MULTILINE)


@pytest.mark.sumo
def test_net_takes_a_scenario_name(tmp_path: Path) -> None:
    result = behave("populate", "--net", "tiny", "--duration", "4", "--keepers", "1", "--overtakers", "0",
                    "--background", "2", "--fcd", "out/fcd.xml", cwd=tmp_path, installed=True)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "<timestep" in (tmp_path / "out" / "fcd.xml").read_text()  # the missing folder was created
    assert "tiny.net.xml" in result.stdout


@pytest.mark.sumo
def test_net_errors_are_one_line(tmp_path: Path) -> None:
    sumocfg = one_line_error(behave("populate", "--net", "mine.sumocfg", cwd=tmp_path, installed=True))
    assert "--sumocfg mine.sumocfg" in sumocfg
    unknown = one_line_error(behave("report", "x.xml", "--net", "motorwy", cwd=tmp_path, installed=True))
    assert "motorway" in unknown and "no bundled scenario" in unknown


def test_report_out_unwritable_fails_before_reading_the_fcd(tmp_path: Path) -> None:
    fcd = tmp_path / "fcd.xml"
    fcd.write_text("not an FCD at all")  # reading it would fail: the error must be about --out
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    start = time.perf_counter()
    error = one_line_error(
        behave("report", str(fcd), "--out", str(blocker / "report"), cwd=tmp_path, installed=True)
    )
    assert "a-file/report" in error and "cannot create output directory" in error
    assert time.perf_counter() - start < 60


def long_vehicles_scenario(tmp: Path) -> Path:
    """A 3-lane road fed by cars and by 12 m vehicles whose vType sets no vClass (so SUMO takes them
    for passenger cars, as in the eclipse-sumo wheel's tools/game ramp scenario)."""
    folder = tmp / "scenario"
    folder.mkdir()
    netconvert(folder, "road", '<node id="a" x="0" y="0"/><node id="b" x="600" y="0"/>',
               '<edge id="r" from="a" to="b" numLanes="3" speed="30"/>')  # fmt: skip
    (folder / "demand.rou.xml").write_text(
        '<routes><vType id="car" vClass="passenger"/><vType id="long" length="12" maxSpeed="25"/>'
        '<flow id="car" type="car" begin="0" end="30" vehsPerHour="1800" departLane="random" '
        'departSpeed="max"><route edges="r"/></flow>'
        '<flow id="long" type="long" begin="0" end="30" vehsPerHour="1800" departLane="random" '
        'departSpeed="max"><route edges="r"/></flow></routes>'
    )
    cfg = folder / "road.sumocfg"
    cfg.write_text(
        '<configuration><input><net-file value="road.net.xml"/><route-files value="demand.rou.xml"/></input>'
        '<time><begin value="0"/><end value="30"/></time></configuration>'
    )
    return cfg


@pytest.mark.sumo
def test_share_leaves_vehicles_of_another_size_to_sumo_and_json_has_sumos_figures(tmp_path: Path) -> None:
    cfg = long_vehicles_scenario(tmp_path)
    fcd = tmp_path / "out" / "fcd.xml"
    result = behave("populate", "--sumocfg", str(cfg), "--share", "0.5", "--fcd", str(fcd), "--json",
                    "--plot", str(tmp_path / "out" / "traces.png"), cwd=tmp_path, installed=True)  # fmt: skip
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["scenario_passenger_cars"] >= 20  # cars and 12 m vehicles alike have vClass passenger
    assert summary["left_to_sumo_not_car_sized"] >= 3
    assert summary["of_them_agents"] >= 3
    assert summary["sumo_mean_speed"] > 0 and "sumo_standing_30s" in summary
    assert summary["fcd"] == str(fcd)
    trace = read_fcd(fcd)
    long_ids = set(trace.loc[trace["id"].str.startswith("long"), "id"])
    agent_ids = set(trace.loc[trace["type"].isin({KEEPER_TYPE, OVERTAKER_TYPE}), "id"])
    assert long_ids and agent_ids and not long_ids & agent_ids  # no 12 m vehicle became a 5 m agent
    assert set(trace.loc[trace["id"].isin(long_ids), "type"]) == {"long"}


@pytest.mark.sumo
def test_plot_titles_say_what_the_run_was(tmp_path: Path) -> None:
    from behaviors.cli.populate import plot_title
    from behaviors.run.populate_config import config_from

    cfg = long_vehicles_scenario(tmp_path)
    assert plot_title(config_from(cfg, share=0.25, seed=3)).startswith(
        "road.sumocfg: 0.25 of its passenger cars"
    )
    assert plot_title(config_from(None, keepers=2, overtakers=1)).endswith(": 2 keepers, 1 overtakers")


def test_report_of_a_missing_fcd_answers_before_loading_pandas(tmp_path: Path) -> None:
    code = (
        "import sys\nfrom behaviors.cli.main import app\n"
        "try:\n    app(['report', 'missing.xml'], standalone_mode=False)\n"
        "except Exception as exc:\n    print(type(exc).__name__, exc)\n"
        "print('pandas loaded:', 'pandas' in sys.modules)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                            timeout=120, check=True)  # fmt: skip
    assert "BehaveError FCD file not found: missing.xml" in result.stdout
    assert "pandas loaded: False" in result.stdout
    assert not (tmp_path / "realism.csv").exists()
