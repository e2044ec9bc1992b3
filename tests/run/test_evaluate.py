"""Evaluation: metrics against a hand-made episode log, the report on real SUMO, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from behaviors.cli.main import app
from behaviors.errors import BehaveError
from behaviors.learn.ddpg.checkpoint import save_checkpoint
from behaviors.learn.ddpg.networks import Actor
from behaviors.learn.env import OVERTAKER_TYPE, StepBatch
from behaviors.learn.metrics import EpisodeStats, agent_runs, summary
from behaviors.run.evaluate import PAPER_METRICS, EvaluationOptions, plan_evaluation
from behaviors.traffic.rewards import RewardTerms


def step(slots, collided, speed=20.0, reward=10.0, off_track=None, lane_deviation=0.0) -> StepBatch:
    n = len(slots)
    zeros = np.zeros(n)
    terms = RewardTerms(np.full(n, reward), zeros, zeros, zeros, zeros, zeros)
    off = np.zeros(n, bool) if off_track is None else np.asarray(off_track)
    collided = np.asarray(collided)
    no = np.zeros(n, bool)
    obs = np.zeros((n, 65))
    return StepBatch(np.asarray(slots), obs, terms.total, terms, collided | off, no, collided, off, no,
                     np.full(n, speed), np.full(n, lane_deviation))  # fmt: skip


def test_metrics_follow_the_paper_on_a_hand_made_episode():
    stats = EpisodeStats(3, np.array([1.0, 0.0, 0.0]), step_length=0.5, start_s=100.0)
    stats.record(np.array([0, 1, 2]), step([0, 1, 2], [False, False, False]))
    stats.record(np.array([0, 1, 2]), step([0, 1, 2], [True, True, False]))  # two agents, ONE colliding step
    stats.record(np.array([2]), step([2], [False], speed=10.0, lane_deviation=0.5))
    stats.record(np.array([2]), step([2], [False], off_track=[True], lane_deviation=0.3))
    row = summary(stats, speed_limit=20.0)
    assert row["colliding_steps_pct"] == pytest.approx(25.0)  # 1 of 4 steps
    assert row["colliding_steps_per_agent"] == pytest.approx(2 / 3)
    assert row["collisions"] == 2 and row["off_tracks"] == 1
    assert row["reward_sum"] == pytest.approx(80.0)  # 8 agent-steps of 10
    assert row["reward_per_agent"] == pytest.approx(80.0 / 3)
    assert row["mean_speed_frac"] == pytest.approx((7 * 20 + 10) / 8 / 20)
    assert row["overtaker_speed_frac"] == pytest.approx(1.0)
    assert row["lane_deviation"] == pytest.approx(0.8 / 8)  # per agent-step
    first, _, last = agent_runs(stats, ["a", "b", "c"], "lk")
    assert (first.behaviour, first.vtype, first.policy) == ("overtaker", OVERTAKER_TYPE, "lk")
    assert first.end_reason == "collision"
    assert (first.depart_s, first.end_s, first.distance_m) == (100.0, 101.0, 20.0)  # left after step 2
    assert (last.end_reason, last.end_s, last.distance_m, last.mean_speed_mps) == (
        "off_track",
        102.0,
        35.0,
        17.5,
    )


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("ckpt") / "lk.pt"
    meta = {"algorithm": "ps-ddpg", "behaviour": "lanekeeping", "behaviours": ["lanekeeping"],
            "obs_dim": 65, "observation_layout": "t", "normalisation": "t", "hidden": [16, 16],
            "training_steps": 0}  # fmt: skip
    save_checkpoint(path, actor_state=Actor(65, (16, 16)).state_dict(), meta=meta)
    return path


@pytest.mark.sumo
def test_evaluate_writes_table_csv_markdown_and_png(tmp_path, checkpoint):
    out = tmp_path / "report"
    result = CliRunner().invoke(app, [
        "evaluate", str(checkpoint), "--agents", "1,2", "--episodes", "2", "--scenario", "tiny",
        "--max-steps", "15", "--baseline", "sumo", "--out", str(out),
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "reward" in result.output and "lk" in result.output  # the terminal table
    table = pd.read_csv(out / "results.csv")
    assert list(table["setting"]) == ["1 agents", "2 agents"] * 2
    assert set(table["policy"]) == {"lk", "sumo (Krauss + SL2015)"}
    assert {m for m, _ in PAPER_METRICS} <= set(table.columns)
    assert (table["steps"] <= 15).all()
    markdown = (out / "results.md").read_text()
    assert markdown.startswith("| policy | setting | reward_per_agent") and markdown.count("\n") == 6
    assert (out / "metrics.png").stat().st_size > 5000


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"checkpoints": [Path("/nope.pt")]}, "checkpoint not found"),
        ({"agents": []}, "agent list is empty"),
        ({"placements": ["A"]}, "--placement applies to multi-behaviour"),
        ({"behaviour": "multi"}, "takes 65 observations but multi gives 66"),
        ({"baseline": "idm"}, "unknown baseline"),
        ({"agents": [0]}, "at least one agent"),
        ({"opponents": -1}, "opponents must be >= 0"),
    ],
)
def test_bad_input_is_refused_before_anything_runs(checkpoint, kwargs, message):
    options = {"checkpoints": [checkpoint], "agents": [2], "episodes": 1, "behaviour": None, "overtakers": 0,
               "keepers": 0, "placements": None, "scenario": "tiny", "seed": 0, "max_steps": 10,
               "baseline": None, **kwargs}  # fmt: skip
    with pytest.raises(BehaveError, match=message):
        plan_evaluation(EvaluationOptions(**options))


def test_opponents_and_the_shield_reach_every_setting(checkpoint):
    options = EvaluationOptions([checkpoint], agents=[1, 2], episodes=1, behaviour="overtaking", overtakers=0,
                                keepers=0, placements=None, scenario="ring", seed=0, max_steps=10,
                                baseline=None, opponents=3, shield=True)  # fmt: skip
    plan = plan_evaluation(options)
    assert [(c.n_opponents, c.shield) for _, c in plan.settings] == [(3, True), (3, True)]


def test_a_traffic_policy_gets_its_driver_its_roads_and_four_plus_four_agents():
    options = {"agents": [], "episodes": 1, "behaviour": None, "overtakers": 0, "keepers": 0,
               "placements": None, "scenario": None, "seed": 0, "max_steps": 10,
               "baseline": None}  # fmt: skip
    plan = plan_evaluation(EvaluationOptions([Path("traffic")], **options))
    [(label, config)] = plan.settings
    assert (config.driver, config.scenario, config.behaviour) == ("traffic", "roads", "multi")
    assert (config.overtakers, config.keepers, label) == (4, 4, "4 overtakers + 4 keepers")
    with pytest.raises(BehaveError, match="--baseline set the paper's formations"):
        plan_evaluation(EvaluationOptions([Path("traffic")], **{**options, "baseline": "sumo"}))
    with pytest.raises(BehaveError, match="different driver models"):
        plan_evaluation(EvaluationOptions([Path("traffic"), Path("multi")], **options))


@pytest.mark.sumo
def test_the_traffic_driver_is_evaluated_with_realism_on_and_says_why_it_has_no_report(tmp_path):
    out = tmp_path / "report"
    result = CliRunner().invoke(app, ["evaluate", "traffic", "--overtakers", "1", "--keepers", "1",
                                      "--episodes", "1", "--max-steps", "60", "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "none: no FCD of the traffic driver" in (out / "results.md").read_text()
