"""`behave train` on a user's road (--net, --sumocfg) with --reward-weight, through the command line:
real SUMO on a netconvert-built motorway, runs of one or two 30-step episodes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
from helpers import behave

from behaviors.learn.ddpg.checkpoint import load_checkpoint
from sumo_scenarios.osm_like import Demand, OsmLikeNet, build_osm_like

pytestmark = pytest.mark.sumo

SMALL = ["train", "lanekeeping", "--driver", "traffic", "--agents", "2", "--max-steps", "30", "--hidden",
         "16,16", "--batch-size", "16", "--episodes", "1", "-q"]  # fmt: skip
"""Two agents, one 30-step episode; the default warmup (1000 transitions) means no update, so a
run's driving depends on its seed alone, whatever its reward."""
WEIGHTS = ["--reward-weight", "speed=3", "--reward-weight", "centre=0"]


def trained(out: Path, *args: str) -> Path:
    done = behave(*SMALL, *args, "--out", str(out))
    assert done.returncode == 0, done.stderr
    return out


def env_of(run: Path) -> dict:
    return json.loads((run / "config.json").read_text())["env"]


@pytest.fixture(scope="module")
def road(tmp_path_factory: pytest.TempPathFactory) -> OsmLikeNet:
    """A 3-lane motorway with an exit and an on-ramp, built by netconvert, and its sumocfg."""
    return build_osm_like("motorway3", tmp_path_factory.mktemp("motorway3"), Demand(end=600.0, scale=2.0))


@pytest.fixture(scope="module")
def weighted(road: OsmLikeNet, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return trained(tmp_path_factory.mktemp("runs") / "weighted", "--net", str(road.net), *WEIGHTS)


@pytest.fixture(scope="module")
def unweighted(road: OsmLikeNet, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return trained(tmp_path_factory.mktemp("runs") / "unweighted", "--net", str(road.net))


def test_config_json_records_the_net_and_the_weights(weighted: Path, road: OsmLikeNet) -> None:
    env = env_of(weighted)
    assert env["net"] == str(road.net.resolve()) and env["sumocfg"] is None
    assert env["reward_weights"] == {"speed": 3.0, "centre": 0.0}
    ckpt = load_checkpoint(weighted / "checkpoints" / "final.pt")
    assert ckpt.meta["driver"] == "traffic" and ckpt.meta["episodes"] == 1
    assert len(pd.read_csv(weighted / "metrics.csv")) == 1


def test_reward_weights_change_the_reward_and_not_the_driving(weighted: Path, unweighted: Path) -> None:
    assert env_of(unweighted)["reward_weights"] is None
    ours, default = (pd.read_csv(run / "metrics.csv").iloc[0] for run in (weighted, unweighted))
    for same in ("agent_steps", "mean_speed_frac", "colliding_steps_pct"):
        assert ours[same] == default[same], same
    assert ours["reward_sum"] != pytest.approx(default["reward_sum"])


def test_resume_trains_on_the_stored_road_with_the_stored_weights(weighted: Path, tmp_path: Path) -> None:
    run = shutil.copytree(weighted, tmp_path / "run")
    done = behave("train", "lanekeeping", "--resume", str(run), "--episodes", "2", "-q")
    assert done.returncode == 0, done.stderr
    metrics = pd.read_csv(run / "metrics.csv")
    assert list(metrics["episode"]) == [0, 1]
    assert metrics.iloc[0].equals(pd.read_csv(weighted / "metrics.csv").iloc[0])
    assert env_of(run) == env_of(weighted)
    assert load_checkpoint(run / "checkpoints" / "final.pt").meta["episodes"] == 2


def test_a_sumocfg_run_records_it(road: OsmLikeNet, tmp_path: Path) -> None:
    run = trained(tmp_path / "run", "--sumocfg", str(road.sumocfg))
    env = env_of(run)
    assert env["sumocfg"] == str(road.sumocfg.resolve()) and env["net"] is None
    assert (run / "checkpoints" / "final.pt").is_file()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--reward-weight", "sped=2"], "no reward term 'sped' in the traffic driver's reward"),
        (["--reward-weight", "speed=fast"], "--reward-weight speed=fast: the weight must be a number"),
        (["--reward-weight", "speed=nan"], "reward weight of 'speed' must be a finite number, got nan"),
        (["--reward-weight", "speed=-inf"], "reward weight of 'speed' must be a finite number, got -inf"),
        (["--reward-weight", "speed"], "--reward-weight takes TERM=WEIGHT"),
        (["--reward-weight", "speed=1", "--reward-weight", "speed=2"], "gives 'speed' twice"),
        (["--driver", "paper", "--net", "motorway"], "--net trains among SUMO's traffic"),
        (["--net", "NET", "--sumocfg", "SUMOCFG"], "--net and --sumocfg both name a network"),
        (["--net", "SUMOCFG"], "is a SUMO configuration, not a network: pass it as --sumocfg"),
    ],
)
def test_bad_input_is_one_line_before_any_output(
    road: OsmLikeNet, tmp_path: Path, args: list[str], message: str
) -> None:
    files = {"NET": str(road.net), "SUMOCFG": str(road.sumocfg)}
    done = behave(*SMALL, *(files.get(a, a) for a in args), "--out", str(tmp_path / "run"))
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith("behave: error: ") and message in lines[0]
    assert not (tmp_path / "run").exists()
