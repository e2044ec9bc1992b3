"""Short real training runs on the tiny scenario: outputs, resume exactness, curriculum, bad input."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import torch

from behaviors.errors import BehaveError
from behaviors.fleet.drivers import make_driver
from behaviors.learn.ddpg.checkpoint import load_actor, load_checkpoint
from behaviors.learn.train import Trainer, prepare_run
from behaviors.learn.train_config import TrainConfig
from behaviors.report.agents_table import END_REASONS, columns

TINY = {"scenario": "tiny", "agents": 2, "max_steps": 40, "warmup": 32, "batch_size": 16,
        "hidden": (32, 32), "checkpoint_every": 2, "buffer_size": 5000}  # fmt: skip


def train(out: Path, resume: bool = False, **overrides) -> list[dict]:
    config = TrainConfig.from_options(**{**TINY, **overrides})
    trainer = prepare_run(config, out, resume=resume, episodes=config.episodes if resume else None)
    return trainer.run()


@pytest.mark.sumo
@pytest.mark.train
def test_a_short_run_writes_config_metrics_checkpoints_and_curve(tmp_path):
    rows = train(tmp_path / "run", episodes=3)
    run = tmp_path / "run"
    assert len(rows) == 3
    metrics = pd.read_csv(run / "metrics.csv")
    expected = {"episode", "reward_sum", "progress_sum", "colliding_steps_pct", "collisions", "off_tracks",
                "steps", "wall_s", "updates"}  # fmt: skip
    assert expected <= set(metrics.columns) and len(metrics) == 3
    agents = pd.read_csv(run / "agents.csv")
    assert tuple(agents.columns) == columns("train") and len(agents) == 3 * 2  # each agent of each episode
    assert list(agents["policy"].unique()) == ["run"] and set(agents["end_reason"]) <= set(END_REASONS)
    by_episode = agents.groupby("episode")["reward"].sum()
    assert by_episode.to_numpy() == pytest.approx(metrics["reward_sum"].to_numpy(), rel=1e-3)
    assert metrics["updates"].sum() > 0  # the paper's schedule: one update per live agent per step
    for name in ("last", "best", "final", "episode_00002"):
        ckpt = load_checkpoint(run / "checkpoints" / f"{name}.pt", expect_obs_dim=65)
        assert ckpt.meta["algorithm"] == "ps-ddpg" and ckpt.meta["behaviour"] == "lanekeeping"
    assert (run / "curve.png").stat().st_size > 1000
    assert (run / "config.json").is_file() and (run / "state.pt").is_file()
    assert not [p for p in run.rglob(".*") if p.is_file()]  # no temp files left behind


@pytest.mark.parametrize("driver", ["paper", "traffic"])
def test_the_driver_gives_reward_scale_exploration_and_the_checkpoint_meta(tmp_path, driver):
    """No driver's name is looked up in training (train.py, train_config.py): its settings and its
    checkpoint meta are the object's."""
    model = make_driver(driver)
    among_traffic = {"scenario": "roads", "behaviour": "multi", "overtakers": 1, "keepers": 1}
    config = TrainConfig.from_options(
        **{**TINY, **(among_traffic if model.among_traffic else {}), "driver": driver}
    )
    trainer = Trainer(config, tmp_path)
    meta = trainer.meta()
    trainer.env.close()
    assert meta["driver"] == driver and meta["normalisation"] == model.normalisation
    assert meta["observation_layout"] == model.observation_layout(trainer.env.config.with_id)
    assert config.critic_reward_scale == model.reward_scale
    learner = config.ddpg_config()
    assert all(getattr(learner, name) == value for name, value in model.exploration.items())


@pytest.mark.sumo
@pytest.mark.train
def test_resume_continues_where_the_run_stopped_and_matches_an_uninterrupted_run(tmp_path):
    whole = train(tmp_path / "whole", episodes=4)
    train(tmp_path / "split", episodes=2)
    resumed = train(tmp_path / "split", resume=True, episodes=4)
    assert [r["episode"] for r in resumed] == [0, 1, 2, 3]
    compared = ["reward_sum", "steps", "updates", "collisions", "off_tracks"]
    for got, want in zip(resumed, whole, strict=True):
        assert [got[c] for c in compared] == pytest.approx([want[c] for c in compared])
    split, whole_agents = (pd.read_csv(tmp_path / name / "agents.csv") for name in ("split", "whole"))
    assert set(split["policy"]) == {"split"}  # the run's directory names its policy
    pd.testing.assert_frame_equal(split.drop(columns="policy"), whole_agents.drop(columns="policy"))
    a = load_actor(tmp_path / "whole" / "checkpoints" / "final.pt").state_dict()
    b = load_actor(tmp_path / "split" / "checkpoints" / "final.pt").state_dict()
    for key in a:
        torch.testing.assert_close(a[key], b[key])


@pytest.mark.sumo
@pytest.mark.train
def test_baselines_train_one_agent_alone_or_one_learner_per_agent(tmp_path):
    single = prepare_run(
        TrainConfig.from_options(**TINY, algo="ddpg", episodes=1), tmp_path / "ddpg", resume=False
    )
    assert single.env.config.n_agents == 1
    single.run()
    multi = prepare_run(
        TrainConfig.from_options(**TINY, algo="multi-ddpg", episodes=1), tmp_path / "multi", resume=False
    )
    multi.run()
    ckpt = load_checkpoint(tmp_path / "multi" / "checkpoints" / "final.pt")
    assert ckpt.meta["algorithm"] == "multi-ddpg" and len(ckpt.extra_state["actors"]) == 2


@pytest.mark.sumo
@pytest.mark.train
def test_curriculum_initialises_from_a_checkpoint_and_widens_to_the_behaviour_id(tmp_path):
    train(tmp_path / "lk", episodes=1)
    source = tmp_path / "lk" / "checkpoints" / "final.pt"
    trainer = prepare_run(
        TrainConfig.from_options(**{**TINY, "agents": 6}, behaviour="multi", overtakers=1, keepers=1,
                                 init=str(source), episodes=1),
        tmp_path / "multi", resume=False,
    )  # fmt: skip
    old = load_actor(source).body[0].weight
    new = trainer.learner.actor.body[0].weight
    torch.testing.assert_close(new[:, :65], old)
    assert torch.all(new[:, 65] == 0)
    trainer.env.close()


@pytest.mark.sumo
@pytest.mark.train
def test_bad_runs_fail_with_a_clear_message(tmp_path):
    train(tmp_path / "lk", episodes=1)
    with pytest.raises(BehaveError, match="already holds a run"):
        train(tmp_path / "lk", episodes=1)
    with pytest.raises(BehaveError, match="nothing to resume"):
        train(tmp_path / "empty", resume=True)
    with pytest.raises(BehaveError, match="unknown algorithm 'ppo'"):
        TrainConfig.from_options(algo="ppo").validate()
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes((tmp_path / "lk" / "checkpoints" / "final.pt").read_bytes()[:500])
    with pytest.raises(BehaveError, match="corrupt or truncated"):
        train(tmp_path / "x", init=str(truncated), episodes=1)
    multi_run = tmp_path / "m"
    train(multi_run, behaviour="multi", agents=6, overtakers=1, keepers=1, episodes=1)
    with pytest.raises(BehaveError, match="66 observations"):
        train(tmp_path / "y", init=str(multi_run / "checkpoints" / "final.pt"), episodes=1)


@pytest.mark.sumo
@pytest.mark.train
def test_sigterm_saves_a_checkpoint_and_the_state_to_resume(tmp_path):
    out = tmp_path / "run"
    code = (
        "import os, signal, threading, time\n"
        "from pathlib import Path\n"
        "from behaviors.learn.train import prepare_run\n"
        "from behaviors.learn.train_config import TrainConfig\n"
        f"t = prepare_run(TrainConfig.from_options(scenario='tiny', agents=2, max_steps=40, warmup=32, "
        f"batch_size=16, hidden=(32, 32), episodes=10000), Path({str(out)!r}), resume=False)\n"
        "def stop_after_first_episode():\n"
        f"    while not Path({str(out / 'metrics.csv')!r}).exists():\n"
        "        time.sleep(0.05)\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "threading.Thread(target=stop_after_first_episode, daemon=True).start()\n"
        "t.run()\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert (out / "checkpoints" / "interrupted.pt").is_file()
    episodes = len(pd.read_csv(out / "metrics.csv"))
    assert 0 < episodes < 10000
    resumed = train(out, resume=True, episodes=episodes + 1)
    assert len(resumed) == episodes + 1


FLAT_CONFIG = """{"actor_lr": 0.0001, "agents": 2, "algo": "ps-ddpg", "batch_size": 16,
  "batched_updates": false, "behaviour": "lanekeeping", "buffer_size": 5000, "checkpoint_every": 2,
  "critic_lr": 0.001, "driver": "paper", "episodes": 1, "explore_decay_steps": 100000, "gamma": 0.99,
  "hidden": [32, 32], "init": null, "keepers": 0, "lane_weight": 0.0, "max_minutes": null, "max_steps": 40,
  "opponents": null, "overtakers": 0, "placement": "C", "reward_scale": null, "scenario": "tiny", "seed": 0,
  "step_length": 0.2, "tau": 0.001, "updates_per_step": null, "warmup": 32, "workers": 1}"""
"""config.json as runs wrote it before TrainConfig held an EnvConfig and a DDPGConfig: one flat object."""


@pytest.mark.sumo
@pytest.mark.train
def test_config_json_round_trips_and_a_run_written_flat_still_resumes(tmp_path):
    config = TrainConfig.from_options(**TINY, episodes=1)
    assert TrainConfig.from_json(config.to_json()) == config
    assert TrainConfig.from_json(FLAT_CONFIG) == config
    run = tmp_path / "old"
    train(run, episodes=1)
    (run / "config.json").write_text(FLAT_CONFIG)  # the run as an older behave left it
    resumed = train(run, resume=True, episodes=2)
    assert [row["episode"] for row in resumed] == [0, 1]
    assert TrainConfig.from_json((run / "config.json").read_text()).episodes == 2  # rewritten nested
    with pytest.raises(BehaveError, match="unknown keys: colour"):
        TrainConfig.from_json(config.to_json().replace('"algo"', '"colour": 1, "algo"'))
    with pytest.raises(BehaveError, match="unknown training settings: colour"):
        TrainConfig.from_json(FLAT_CONFIG.replace('"algo"', '"colour": 1, "algo"'))
