"""`behave train --workers N`: rollout workers on Ray (each its own SUMO), one learner."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import torch
from helpers import behave

from behaviors.learn.train import prepare_run
from behaviors.learn.train_config import TrainConfig

pytest.importorskip("ray", reason="ray is not installed (the distributed extra)")

TINY = ["--scenario", "tiny", "--agents", "2", "--max-steps", "40", "--hidden", "32,32",
        "--batch-size", "16", "--checkpoint-every", "1"]  # fmt: skip


SMALL = {"scenario": "tiny", "agents": 2, "max_steps": 40, "warmup": 32, "batch_size": 16,
         "hidden": (32, 32), "buffer_size": 5000, "checkpoint_every": 1}  # fmt: skip


@pytest.mark.sumo
@pytest.mark.train
def test_two_workers_train_checkpoint_and_resume_on_tiny(tmp_path: Path) -> None:
    """Two workers (two SUMOs: one process could not hold both) feed one learner: its buffer holds
    every agent step of both workers' episodes, it updates, and --resume continues the run."""
    run = tmp_path / "run"
    config = TrainConfig.from_options(**SMALL, episodes=3, workers=2)
    prepare_run(config, run, resume=False).run()
    prepare_run(config, run, resume=True, episodes=4).run()
    metrics = pd.read_csv(run / "metrics.csv")
    assert metrics["episode"].tolist() == [0, 1, 2, 3]
    assert (metrics["agent_steps"] > 0).all() and metrics["updates"].sum() > 0
    state = torch.load(run / "state.pt", weights_only=True)
    assert state["learner"]["transitions"] == metrics["agent_steps"].sum()
    assert state["learner"]["updates"] == metrics["updates"].sum()
    assert '"workers": 2' in (run / "config.json").read_text()
    for name in ("final", "episode_00003", "episode_00004"):
        assert (run / "checkpoints" / f"{name}.pt").is_file()


@pytest.mark.sumo
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--workers", "2", "--algo", "multi-ddpg"], "--workers trains ps-ddpg or ddpg"),
        (["--workers", "2", "--ray-address", "127.0.0.1:9"], "no Ray cluster answers at 127.0.0.1:9"),
    ],
)
def test_bad_distributed_options_are_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    result = behave("train", "lanekeeping", *TINY, "--episodes", "1", "--out", str(tmp_path / "r"), *args)
    lines = result.stderr.strip().splitlines()
    assert result.returncode != 0 and len(lines) == 1
    assert lines[0].startswith("behave: error: ") and message in lines[0]
