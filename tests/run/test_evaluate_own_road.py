"""`behave evaluate --net/--sumocfg`, evaluate tables that count the agents that started, and the Gym
env that never starts its car where its episode cannot run."""

from __future__ import annotations

from pathlib import Path

import gymnasium
import numpy as np
import pandas as pd
import pytest
from helpers import behave

from behaviors.errors import BehaveError
from behaviors.learn.gym_env import ENV_ID, longest_drive, room_ahead
from behaviors.learn.metrics import EpisodeStats, agent_runs, mean_rows, summary
from behaviors.road.routes import RouteGraph
from behaviors.run.evaluate import (
    EvaluationOptions,
    markdown_table,
    placed_text,
    plan_evaluation,
    short_placements,
)
from sumo_scenarios.osm_like import OsmLikeNet

PLAN = {"agents": [], "episodes": 1, "behaviour": None, "overtakers": 1, "keepers": 1, "placements": None,
        "scenario": None, "seed": 0, "max_steps": 10, "baseline": None}  # fmt: skip


# the agents that started ------------------------------------------------------------------------


def test_per_agent_figures_count_the_agents_that_started() -> None:
    """8 slots, 1 car placed: its reward is the reward per agent, not an eighth of it; the agents
    table has its row alone."""
    stats = EpisodeStats(8, np.array([1.0] * 4 + [0.0] * 4), step_length=0.2, start_s=10.0)
    stats.place(np.array([5]))
    stats.reward[5], stats.progress[5], stats.speed_sum[5], stats.speed_steps[5] = 12.0, 30.0, 40.0, 2
    row = summary(stats, speed_limit=20.0)
    assert row["agents_placed"] == 1
    assert (row["overtakers_placed"], row["keepers_placed"]) == (0, 1)
    assert row["reward_per_agent"] == pytest.approx(12.0)
    assert row["progress_per_agent"] == pytest.approx(30.0)
    assert row["keeper_reward_per_agent"] == pytest.approx(12.0)
    assert "overtaker_reward_per_agent" not in row  # no overtaker drove
    assert [run.id for run in agent_runs(stats, [f"agent_{k}" for k in range(8)], "p")] == ["agent_5"]
    other = summary(EpisodeStats(8, np.array([1.0] * 4 + [0.0] * 4), 0.2, 0.0), speed_limit=20.0)
    mean = mean_rows([row, other])  # a figure only some episodes have is averaged over those
    assert mean["agents_placed"] == pytest.approx(4.5) and "overtaker_speed_frac" in mean


def test_the_tables_say_how_many_started() -> None:
    results = pd.DataFrame([
        {"policy": "traffic", "setting": "4 overtakers + 4 keepers", "agents": 8, "agents_placed": 1.0},
        {"policy": "traffic", "setting": "2 agents", "agents": 2, "agents_placed": 2.0},
    ])  # fmt: skip
    assert [placed_text(row) for _, row in results.iterrows()] == ["1 of 8", "2 of 2"]
    [line] = short_placements(results)
    assert line.startswith("traffic, 4 overtakers + 4 keepers: 1 of 8 agents started")
    assert markdown_table(results.assign(**{m: 0.0 for m in ("reward_per_agent", "progress_per_agent",
        "colliding_steps_per_agent", "colliding_steps_pct", "reward_sum", "off_tracks", "mean_speed_frac",
        "lane_deviation")})).splitlines()[0].endswith("| agents | agents_placed |")  # fmt: skip


@pytest.mark.sumo
def test_evaluate_counts_the_agents_placed(tmp_path: Path) -> None:
    """Seed 0's first episode on the training roads has room for 1 of the 8 agents."""
    done = behave("evaluate", "traffic", "--episodes", "1", "--max-steps", "20", "--out", str(tmp_path))
    assert done.returncode == 0, done.stderr
    table = pd.read_csv(tmp_path / "results.csv")
    assert table["agents"].tolist() == [8] and table["agents_placed"].tolist() == [1]
    assert "1 of 8" in done.stdout
    assert "1 of 8 agents started per episode on average" in " ".join(done.stdout.split())
    assert "agents_placed" in (tmp_path / "results.md").read_text()


# evaluate --net / --sumocfg ---------------------------------------------------------------------


@pytest.mark.sumo
def test_evaluate_on_a_users_net_and_sumocfg(tmp_path: Path, motorway: OsmLikeNet) -> None:
    for option, road in (("--net", motorway.net), ("--sumocfg", motorway.sumocfg)):
        out = tmp_path / option.strip("-")
        done = behave("evaluate", "traffic", option, str(road), "--overtakers", "1", "--keepers", "1",
                      "--episodes", "1", "--max-steps", "10", "--out", str(out))  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert f"behave evaluate on {road.name}" in done.stdout
        table = pd.read_csv(out / "results.csv")
        assert table["agents"].tolist() == [2] and table["steps"].tolist() == [10]


@pytest.mark.sumo  # a `behave evaluate` that stops before SUMO: seconds of imports (helpers.py)
def test_evaluate_road_options_are_checked_before_anything_runs(tmp_path: Path) -> None:
    net, cfg = tmp_path / "n.net.xml", tmp_path / "s.sumocfg"
    with pytest.raises(BehaveError, match="--net and --sumocfg both name a network"):
        plan_evaluation(EvaluationOptions([Path("traffic")], **PLAN, net=net, sumocfg=cfg))
    with pytest.raises(BehaveError, match="--scenario and --net both name a road"):
        plan_evaluation(EvaluationOptions([Path("traffic")], **{**PLAN, "scenario": "roads"}, net=net))
    with pytest.raises(BehaveError, match="--sumocfg drives the policies among SUMO's traffic"):
        plan_evaluation(EvaluationOptions([Path("lanekeeping")], **{**PLAN, "overtakers": 0, "keepers": 0,
                                                                    "agents": [2]}, sumocfg=cfg))  # fmt: skip
    done = behave("evaluate", "traffic", "--net", str(net))
    assert done.returncode == 2 and "network file not found" in done.stderr


# the Gym env's start ------------------------------------------------------------------------------


def test_the_longest_drive_follows_the_edges_up_to_the_cap() -> None:
    chain = RouteGraph(edges=["a", "b", "c"], length=np.array([100.0, 200.0, 50.0]), lanes=np.full(3, 2),
                       successors=[[1], [2], []], start_cdf=np.array([200.0, 600.0, 700.0]))  # fmt: skip
    assert longest_drive(chain, 1e9) == pytest.approx(350.0)
    assert longest_drive(chain, 120.0) == pytest.approx(120.0)
    ring = RouteGraph(edges=["a", "b"], length=np.array([100.0, 100.0]), lanes=np.array([2, 2]),
                      successors=[[1], [0]], start_cdf=np.array([200.0, 400.0]))  # fmt: skip
    assert longest_drive(ring, 1000.0) == pytest.approx(1000.0)


@pytest.mark.sumo
def test_the_gym_car_starts_with_room_for_its_episode(motorway: OsmLikeNet) -> None:
    """On this road seed 1 put the car 78 m before the end of the road (17 steps of 1000); every
    start now leaves 20 s at the limit ahead (667 m here), the same for the same seed."""
    env = gymnasium.make(ENV_ID, net=motorway.net, max_steps=1000)
    traffic = env.unwrapped.traffic
    try:
        rooms = []
        for seed in range(8):
            env.reset(seed=seed)
            rooms.append(room_ahead(traffic.sim, traffic.geometry, traffic.agents[0]))
        assert min(rooms) >= 20.0 * 33.33 - 1.0, rooms
        first, _ = env.reset(seed=1)
        again, _ = env.reset(seed=1)
        np.testing.assert_array_equal(first, again)  # still repeatable
    finally:
        env.close()
