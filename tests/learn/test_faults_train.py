"""Faults of training and of the env found as a new user would: real SUMO, real signals."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from dataclasses import MISSING, fields
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from helpers import BEHAVE, behave
from pettingzoo.test import parallel_seed_test

from behaviors import BehaveError, make_env
from behaviors.fleet.control import AgentRows, RoadFrame
from behaviors.learn.ddpg.checkpoint import load_actor
from behaviors.learn.train import prepare_run
from behaviors.learn.train_config import TrainConfig
from behaviors.paper.sensors import SLICES


def hold_lane(obs: np.ndarray) -> np.ndarray:
    """Steer back to where the car is, full throttle: drives to the end of a straight road."""
    angle = obs[:, SLICES["angle"]][:, 0] * np.pi
    return np.stack([np.clip(-4 * angle, -1, 1), np.ones(len(obs)), np.zeros(len(obs))], 1).astype(np.float32)


@pytest.mark.sumo
@pytest.mark.parametrize("scenario", ["tiny", "highway"])
def test_the_last_agent_reaching_the_end_of_a_non_looping_road_ends_the_episode(scenario):
    env = make_env(scenario, agents=1, seed=1, max_steps=5000, start_speed=25.0)
    try:
        env.reset_arrays(1)
        last = None
        while env.agents:
            last = env.step_arrays(hold_lane(env.live_obs))
        assert last is not None and bool(last.truncated[0]) and not last.terminated[0]
        assert env.steps < 5000  # it left at the road's end, not at the time limit
    finally:
        env.close()


def test_taking_agent_rows_keeps_every_per_agent_field_in_step():
    n, mask = 3, np.array([True, False, True])
    values: dict = {"side_limit": np.zeros((n, 2)), "speed_cap": np.arange(3.0)}
    for f in fields(AgentRows):
        default = f.default_factory() if f.default_factory is not MISSING else None
        if isinstance(default, list):
            values[f.name] = [f"{f.name}_{k}" for k in range(n)]
        elif isinstance(default, np.ndarray):
            values[f.name] = np.arange(n).astype(default.dtype).reshape(n, *([1] * (default.ndim - 1)))
    frame = RoadFrame(*(np.arange(float(n)) for _ in fields(RoadFrame)))
    kept = AgentRows(**values, frame=frame).take(mask)
    for name, value in values.items():
        assert len(getattr(kept, name)) == 2 and str(getattr(kept, name)[1]) == str(value[2]), name
    assert all(list(getattr(kept.frame, f.name)) == [0.0, 2.0] for f in fields(RoadFrame))


CONFIG = {"scenario": "tiny", "agents": 2, "max_steps": 60, "warmup": 32, "batch_size": 16,
          "hidden": (32, 32),
          "buffer_size": 5000, "checkpoint_every": 10, "seed": 4}  # fmt: skip
TOTAL = 5
COLUMNS = ["episode", "reward_sum", "steps", "updates", "collisions", "off_tracks", "progress_sum"]

# A training child that blocks inside step 3 of episode `target` until its parent's real
# signal arrives, so the signal lands mid-episode, at a known step.
CHILD = """
import sys, time
from pathlib import Path
from behaviors.learn.train import prepare_run
from behaviors.learn.train_config import TrainConfig
out, target, config = Path(sys.argv[1]), int(sys.argv[2]), eval(sys.argv[3])
trainer = prepare_run(TrainConfig.from_options(**config), out, resume=False)
step = trainer.env.step_arrays
def blocking_step(actions):
    batch = step(actions)
    if trainer.episode == target and trainer.env.steps == 3:
        (out / "mid-episode").touch()
        deadline = time.monotonic() + 60
        while not trainer.stop_requested and time.monotonic() < deadline:
            time.sleep(0.01)
    return batch
trainer.env.step_arrays = blocking_step
trainer.run()
"""


def final_actor(run: Path) -> dict:
    return load_actor(run / "checkpoints" / "final.pt").state_dict()


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """Rows and final policy of a run that nothing stopped."""
    out = tmp_path_factory.mktemp("whole") / "run"
    rows = prepare_run(TrainConfig.from_options(**CONFIG, episodes=TOTAL), out, resume=False).run()
    return rows, final_actor(out)


def wait_for(predicate, seconds: float = 120.0) -> None:
    deadline = time.monotonic() + seconds
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def assert_same_run(rows: list[dict], actor: dict, uninterrupted) -> None:
    want_rows, want_actor = uninterrupted
    assert [[r[c] for c in COLUMNS] for r in rows] == [[r[c] for c in COLUMNS] for r in want_rows]
    for key, value in want_actor.items():
        torch.testing.assert_close(actor[key], value, rtol=0, atol=0)


@pytest.mark.sumo
@pytest.mark.train
@pytest.mark.parametrize("target", [0, 1])
def test_a_run_stopped_mid_episode_by_sigterm_resumes_exactly_like_an_uninterrupted_run(
    tmp_path, uninterrupted, target
):
    out = tmp_path / "run"
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(out), str(target), repr({**CONFIG, "episodes": TOTAL})]
    )
    try:
        wait_for(lambda: (out / "mid-episode").exists())
        child.send_signal(signal.SIGTERM)
        assert child.wait(timeout=60) == 0
    finally:
        child.kill()
    assert (out / "checkpoints" / "interrupted.pt").is_file()
    trainer = prepare_run(TrainConfig(), out, resume=True)  # no --episodes: the stored total holds
    assert trainer.episode == target and trainer.config.episodes == TOTAL
    rows = trainer.run()
    assert_same_run(rows, final_actor(out), uninterrupted)
    assert len(pd.read_csv(out / "metrics.csv")) == TOTAL


@pytest.mark.sumo
@pytest.mark.train
def test_a_killed_run_resumes_from_its_last_finished_episode(tmp_path, uninterrupted):
    out = tmp_path / "run"
    config = {**CONFIG, "episodes": 1000}  # checkpoint_every 10: no numbered checkpoint before the kill
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(out), "-1", repr(config)])
    try:
        wait_for(lambda: (out / "metrics.csv").exists() and len(pd.read_csv(out / "metrics.csv")) >= 2)
        child.kill()
        child.wait(timeout=60)
    finally:
        child.kill()
    finished = len(pd.read_csv(out / "metrics.csv"))
    trainer = prepare_run(TrainConfig(), out, resume=True, episodes=TOTAL)
    assert trainer.episode >= finished  # no finished episode is redone
    assert_same_run(trainer.run(), final_actor(out), uninterrupted)


TINY_CLI = ["train", "lanekeeping", "--scenario", "tiny", "--agents", "2", "--hidden", "32,32",
            "--batch-size", "16"]  # fmt: skip


@pytest.mark.sumo
@pytest.mark.parametrize(("stop", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupted_training_exits_non_zero_with_one_line_on_how_to_resume(tmp_path, stop, code):
    out = tmp_path / "run"
    args = [*BEHAVE, *TINY_CLI, "--max-steps", "60", "--out", str(out)]
    child = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: (out / "metrics.csv").exists())
        child.send_signal(stop)
        _, err = child.communicate(timeout=60)
    finally:
        child.kill()
    assert child.returncode == code, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1].endswith(f"continue with: behave train lanekeeping --resume {out}")


@pytest.mark.sumo
def test_a_budget_of_0_minutes_leaves_a_run_that_resumes_to_its_stored_total(tmp_path):
    out = tmp_path / "run"
    budget = behave(*TINY_CLI, "--max-steps", "5", "--episodes", "2", "--max-minutes", "0", "--out", str(out))
    assert budget.returncode == 0, budget.stderr
    assert f"after 0 of 2 episodes in {out}; continue with: behave train lanekeeping --resume" in (
        budget.stdout
    )
    resumed = behave(*TINY_CLI, "--resume", str(out))  # no --episodes: the stored 2, not the default 100
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads((out / "config.json").read_text())["episodes"] == 2
    assert len(pd.read_csv(out / "metrics.csv")) == 2


@pytest.mark.sumo
def test_zero_episodes_are_refused_in_one_line(tmp_path):
    done = behave(*TINY_CLI, "--max-steps", "5", "--episodes", "0", "--out", str(tmp_path / "run"))
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [done.stderr.strip()] and "episodes" in done.stderr
    assert not (tmp_path / "run" / "metrics.csv").exists()


class RunsCode:
    """Unpickling this creates `marker`: what a hostile state.pt could do instead."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def test_resume_reads_the_state_as_data_and_never_runs_code_in_it(tmp_path):
    out, marker = tmp_path / "run", tmp_path / "code-ran"
    prepare_run(TrainConfig.from_options(**CONFIG, episodes=1), out, resume=False)
    torch.save({"version": 2, "learner": RunsCode(marker)}, out / "state.pt")
    with pytest.raises(BehaveError, match="corrupt or truncated"):
        prepare_run(TrainConfig(), out, resume=True)
    assert not marker.exists()


@pytest.mark.sumo
def test_a_second_live_simulation_in_one_process_is_refused_until_the_first_is_closed():
    first, second = make_env("tiny", agents=1, seed=1), make_env("tiny", agents=1, seed=1)
    made = []

    def make():
        made.append(make_env("tiny", agents=1, seed=1))
        return made[-1]

    try:
        first.reset_arrays(1)
        with pytest.raises(BehaveError, match="already running in this process"):
            second.reset_arrays(1)
        with pytest.raises(BehaveError, match="already running in this process"):
            parallel_seed_test(make)  # it steps two live envs side by side: see README
        first.close()
        assert second.reset_arrays(1).shape == (1, 65)
    finally:
        for env in (first, second, *made):
            env.close()


@pytest.mark.sumo
def test_envs_made_one_after_another_repeat_each_other_exactly():
    """What parallel_seed_test checks, with one live simulation at a time."""
    traces = []
    for _ in range(2):
        env = make_env("tiny", agents=2, seed=42)
        try:
            trace = [env.reset_arrays(42).copy()]
            for _ in range(30):
                if not env.agents:
                    break
                batch = env.step_arrays(hold_lane(env.live_obs))
                trace += [batch.next_obs.copy(), batch.reward.copy()]
        finally:
            env.close()
        traces.append(trace)
    assert len(traces[0]) == len(traces[1]) > 10
    for a, b in zip(*traces, strict=True):
        np.testing.assert_array_equal(a, b)
