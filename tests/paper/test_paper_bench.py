"""`make paper`'s evaluation path (benchmarks/paper.py): a plan of a bundled policy and SUMO's own
drivers runs through the one loader and gives the paper's metrics and the realism rows. It broke
once unnoticed ('PosixPath' object has no attribute 'act') because nothing but `make paper` ran it."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from paper import plan_df

from behaviors.learn.env import EnvConfig
from behaviors.learn.policy import PRETRAINED

pytestmark = pytest.mark.sumo


def test_a_plan_of_a_bundled_policy_and_sumos_drivers_runs(tmp_path: Path) -> None:
    settings = [("2 agents", EnvConfig(scenario="tiny", agents=2, max_steps=30))]
    plans = [("PS-DDPG", PRETRAINED / "lanekeeping.pt"), ("SUMO", None)]
    out = plan_df(plans, settings, episodes=1, seed=0, out=tmp_path)
    assert [row["policy"] for row in out["results"]] == ["PS-DDPG", "SUMO"]
    assert all(row["agents"] == 2 for row in out["results"])
    assert {row["policy"] for row in out["realism"]} <= {"PS-DDPG", "SUMO"}
