"""`behave train` logs the learner's critic loss, actor loss and mean Q to TensorBoard per block of
UPDATE_LOG_EVERY updates (step = update count), in-process, across --resume and with Ray workers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from behaviors.learn.ddpg.learner import DDPGLearner
from behaviors.learn.train import UPDATE_LOG_EVERY, prepare_run
from behaviors.learn.train_config import TrainConfig

pytestmark = [pytest.mark.sumo, pytest.mark.train]

event_accumulator = pytest.importorskip(
    "tensorboard.backend.event_processing.event_accumulator", reason="tensorboard is not installed"
)

TINY = {"scenario": "tiny", "agents": 2, "max_steps": 30, "warmup": 32, "batch_size": 16,
        "hidden": (32, 32), "buffer_size": 5000}  # fmt: skip
TAGS = ("critic_loss", "actor_loss", "mean_q")


def update_scalars(run: Path) -> dict[str, list[tuple[int, float]]]:
    """(step, value) of each update/ tag, from every event file of the run's tensorboard/ folder, in
    step order (the reader takes the files in name order, and a writer's file name ends in a counter
    of the process's writers: after writer 9 of a test session, 10 sorts first)."""
    reader = event_accumulator.EventAccumulator(str(run / "tensorboard"))
    reader.Reload()
    return {tag: sorted((e.step, e.value) for e in reader.Scalars(f"update/{tag}")) for tag in TAGS}


def record_updates(monkeypatch: pytest.MonkeyPatch) -> list[tuple[float, float, float]]:
    """Every gradient step's (critic loss, actor loss, mean Q), as the learner computed them."""
    seen: list[tuple[float, float, float]] = []
    step = DDPGLearner._step

    def recorded(learner: DDPGLearner, *args):
        stats = step(learner, *args)
        seen.append(stats)
        return stats

    monkeypatch.setattr(DDPGLearner, "_step", recorded)
    return seen


def test_update_blocks_are_the_means_of_the_learners_steps_once_each_across_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each block of UPDATE_LOG_EVERY updates appears once, at its last update number, with the
    mean of those updates' losses and Q; a resume continues the numbering with no step twice."""
    seen = record_updates(monkeypatch)
    run = tmp_path / "run"
    prepare_run(TrainConfig.from_options(**TINY, episodes=2), run, resume=False).run()
    first_run = len(seen)
    prepare_run(TrainConfig.from_options(**TINY, episodes=3), run, resume=True, episodes=3).run()
    total = torch.load(run / "state.pt", weights_only=True)["learner"]["updates"]
    assert total == len(seen) > first_run > 2 * UPDATE_LOG_EVERY  # both parts updated
    logged = update_scalars(run)
    ends = list(range(UPDATE_LOG_EVERY, total + 1, UPDATE_LOG_EVERY))
    # update number u is seen[u - 1]; the block under way when the first run ended lost its
    # first part (it is not in the state), so that block's mean starts after the first run
    every = UPDATE_LOG_EVERY
    starts = [first_run if end - every < first_run < end else end - every for end in ends]
    values = np.asarray(seen)
    for k, tag in enumerate(TAGS):
        assert [step for step, _ in logged[tag]] == ends, tag
        expected = [values[start:end, k].mean() for start, end in zip(starts, ends, strict=True)]
        assert [value for _, value in logged[tag]] == pytest.approx(expected, rel=1e-5), tag
    assert all(value >= 0 for _, value in logged["critic_loss"])  # a squared error


def test_ray_workers_log_update_blocks_too(tmp_path: Path) -> None:
    """Two rollout workers on Ray (DistributedTrainer): the learner's blocks land the same way."""
    pytest.importorskip("ray", reason="ray is not installed (the distributed extra)")
    run = tmp_path / "run"
    trainer = prepare_run(TrainConfig.from_options(**TINY, episodes=3, workers=2), run, resume=False)
    assert type(trainer).__name__ == "DistributedTrainer"
    trainer.run()
    total = torch.load(run / "state.pt", weights_only=True)["learner"]["updates"]
    assert total >= UPDATE_LOG_EVERY
    for tag, points in update_scalars(run).items():
        assert [step for step, _ in points] == list(range(UPDATE_LOG_EVERY, total + 1, UPDATE_LOG_EVERY)), tag
        assert all(np.isfinite(value) for _, value in points), tag
