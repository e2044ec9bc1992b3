"""`behave populate --driver rules`: the traffic driver's law and lane-change rules with no network,
through populate's one step (one batched call of a constant "policy"), and no checkpoint read."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import behaviors.run.populate_config as populate_config
from behaviors.errors import BehaveError
from behaviors.report.agents_table import agents_path
from behaviors.report.fcd_read import read_fcd
from behaviors.report.realism import measure, read_agents
from behaviors.report.realism_tracks import KEEPERS, OVERTAKERS, read_lanes
from behaviors.run.populate import populate
from behaviors.run.populate_config import PopulateConfig, config_from
from sumo_scenarios import get_scenario


def behave(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "populate", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.sumo
def test_the_rules_driver_drives_the_bundled_highway_and_changes_lanes(tmp_path):
    fcd = tmp_path / "rules.parquet"
    done = behave("--driver", "rules", "--duration", "150", "--overtakers", "8", "--keepers", "8",
                  "--keep-count", "--fcd", str(fcd), "--json", "-q")  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["collisions"] == 0 and summary["off_tracks"] == 0
    assert summary["keeper_mean_speed"] > 20 and summary["overtaker_mean_speed"] > 20
    report = measure(
        read_fcd(fcd), read_lanes(get_scenario("highway").net), agents=read_agents(agents_path(fcd))
    )
    assert report.table.loc["lane_changes_per_km", OVERTAKERS] > 0
    assert report.table.loc["mean_speed", OVERTAKERS] > report.table.loc["mean_speed", KEEPERS]
    assert set(read_agents(agents_path(fcd))["policy"]) == {"rules"}


@pytest.mark.sumo
def test_the_rules_driver_reads_no_policy_file(tmp_path, monkeypatch):
    def no_loading(*args, **kwargs):
        raise AssertionError("the rules driver loaded a policy")

    monkeypatch.setattr(populate_config, "load_policy", no_loading)
    config = PopulateConfig(
        driver="rules", policy=tmp_path / "absent.pt", duration=5.0, fcd=tmp_path / "f.xml"
    )
    summary = populate(config)
    assert summary.agent_steps > 0
    assert "driver=rules" in (tmp_path / "f.xml").read_text()[:400]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--driver", "rules", "--policy", "traffic"], "rules drives with no network: drop --policy"),
        (["--driver", "paper"], "drives the traffic driver, not the paper one"),
        (["--driver", "autopilot"], "unknown driver 'autopilot' (choose from paper, traffic, "),
    ],
)  # fmt: skip
def test_a_driver_that_does_not_fit_is_one_line_on_stderr(tmp_path, args, message):
    fcd = tmp_path / "f.xml"
    done = behave(*args, "--duration", "5", "--fcd", str(fcd))
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and lines[0].startswith("behave: error: ")
    assert not fcd.exists()


def test_the_config_refuses_a_policy_beside_the_rules():
    with pytest.raises(BehaveError, match="drop --policy"):
        config_from(None, driver="rules", policy="traffic")
    assert config_from(None, driver="rules", policy=None).driver == "rules"


@pytest.mark.sumo
def test_evaluate_takes_the_rules_beside_a_policy(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "evaluate", "rules", "traffic", "--episodes", "1",
         "--max-steps", "50", "--no-realism", "--out", str(tmp_path), "-q"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    results = (tmp_path / "results.csv").read_text()
    assert "\nrules," in results and "\ntraffic," in results
