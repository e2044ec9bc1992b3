"""`behave train` logs every numeric metrics column to TensorBoard per episode, also across --resume."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from behaviors.learn.train import prepare_run
from behaviors.learn.train_config import TrainConfig

pytestmark = [pytest.mark.sumo, pytest.mark.train]

event_accumulator = pytest.importorskip(
    "tensorboard.backend.event_processing.event_accumulator", reason="tensorboard is not installed"
)

TINY = {"scenario": "tiny", "agents": 2, "max_steps": 30, "warmup": 32, "batch_size": 16,
        "hidden": (32, 32), "buffer_size": 5000}  # fmt: skip


def scalars(run: Path) -> dict[str, list[tuple[int, float]]]:
    """(step, value) per tag, from every event file of the run's tensorboard/ folder."""
    reader = event_accumulator.EventAccumulator(str(run / "tensorboard"))
    reader.Reload()
    return {tag: [(e.step, e.value) for e in reader.Scalars(tag)] for tag in reader.Tags()["scalars"]}


def test_episodes_are_logged_once_each_with_every_numeric_column_and_resume_appends(tmp_path: Path) -> None:
    run = tmp_path / "run"
    prepare_run(TrainConfig.from_options(**TINY, episodes=2), run, resume=False).run()
    prepare_run(TrainConfig.from_options(**TINY, episodes=3), run, resume=True, episodes=3).run()
    metrics = pd.read_csv(run / "metrics.csv")
    logged = scalars(run)
    numeric = set(metrics.select_dtypes("number").columns)
    assert {"reward_sum", "progress_sum", "colliding_steps_pct", "agent_steps"} <= numeric
    assert {tag for tag in logged if not tag.startswith("update/")} == numeric  # update/: per update
    for column in numeric:
        steps = [step for step, _ in logged[column]]
        assert steps == [0, 1, 2], column  # each episode once, in order, across the resume
        values = [value for _, value in logged[column]]
        assert values == pytest.approx(metrics[column].tolist(), rel=1e-6), column
