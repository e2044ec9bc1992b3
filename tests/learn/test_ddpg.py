"""DDPG learner: equations 1-2, replay, exploration, checkpoints, resume exactness, learning."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from behaviors.errors import BehaveError
from behaviors.learn.ddpg import (
    Actor,
    Batch,
    DDPGConfig,
    DDPGLearner,
    IndependentLearners,
    OUNoise,
    ReplayBuffer,
    critic_targets,
    load_actor,
    load_checkpoint,
    save_actor_only,
    save_checkpoint,
    soft_update,
)
from behaviors.learn.ddpg.networks import INITIAL_BRAKE_BIAS, driving_function

torch.set_num_threads(1)

SMALL = DDPGConfig(hidden=(32, 32), batch_size=8, buffer_size=256, warmup=16)
META = {
    "algorithm": "ps-ddpg",
    "behaviours": ["lanekeeping"],
    "obs_dim": 65,
    "observation_layout": "lanekeeping",
    "normalisation": "fixed ranges to [-1, 1]",
    "hidden": [32, 32],
    "training_steps": 123,
}


def transitions(rng: np.random.Generator, n: int, obs_dim: int) -> tuple[np.ndarray, ...]:
    obs = rng.uniform(-1, 1, (n, obs_dim)).astype(np.float32)
    act = rng.uniform((-1, 0, 0), (1, 1, 1), (n, 3)).astype(np.float32)
    rew = rng.normal(size=n).astype(np.float32)
    next_obs = rng.uniform(-1, 1, (n, obs_dim)).astype(np.float32)
    terminated = (rng.uniform(size=n) < 0.2).astype(np.float32)
    return obs, act, rew, next_obs, terminated


def filled_learner(seed: int = 0, obs_dim: int = 5, config: DDPGConfig = SMALL) -> DDPGLearner:
    learner = DDPGLearner(obs_dim, config, seed)
    learner.observe(*transitions(np.random.default_rng(seed), 40, obs_dim))
    return learner


def flat_params(module: torch.nn.Module) -> torch.Tensor:
    return torch.cat([p.detach().flatten() for p in module.parameters()])


def test_critic_targets_match_hand_computation_with_target_nets() -> None:
    learner = filled_learner()
    _, _, rew, next_obs, _ = transitions(np.random.default_rng(1), 4, 5)
    terminated = np.array([0, 1, 0, 1], np.float32)
    with torch.no_grad():
        next_q = learner.critic_target(
            torch.from_numpy(next_obs), learner.actor_target(torch.from_numpy(next_obs))
        )
        y = critic_targets(torch.from_numpy(rew), torch.from_numpy(terminated), next_q, 0.9)
    for i in range(4):
        with torch.no_grad():
            s1 = torch.from_numpy(next_obs[i : i + 1])
            q1 = learner.critic_target(s1, learner.actor_target(s1)).item()
        expected = rew[i] + 0.9 * q1 * (1 - terminated[i])
        assert y[i].item() == pytest.approx(expected, abs=1e-6)
    assert y[1].item() == pytest.approx(rew[1]) and y[3].item() == pytest.approx(rew[3])


def test_soft_update_moves_each_parameter_by_tau_of_the_difference() -> None:
    source, target = Actor(5, (16, 16)), Actor(5, (16, 16))
    before = [p.detach().clone() for p in target.parameters()]
    soft_update(target, source, 0.25)
    for old, new, src in zip(before, target.parameters(), source.parameters(), strict=True):
        torch.testing.assert_close(new - old, 0.25 * (src - old), rtol=1e-5, atol=1e-7)


def test_actor_outputs_stay_in_range_for_extreme_inputs() -> None:
    actor = Actor(65)
    obs = torch.cat([torch.full((1, 65), v) for v in (-1e6, -1.0, 0.0, 1.0, 1e6)])
    obs = torch.cat([obs, torch.randn(20, 65) * 1e3])
    act = actor(obs)
    assert act.shape == (25, 3)
    assert torch.all(act[:, 0].abs() <= 1) and torch.all((act[:, 1:] >= 0) & (act[:, 1:] <= 1))
    middle = actor(torch.zeros(1, 65))[0]  # small final init: first actions near the centre
    expected = torch.tensor([0.0, 0.5, float(torch.sigmoid(torch.tensor(INITIAL_BRAKE_BIAS)))])
    torch.testing.assert_close(middle, expected, atol=0.05, rtol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
@pytest.mark.parametrize("threads", [1, 2])
def test_the_driving_function_gives_the_actors_actions_bit_for_bit_as_fleets_grow_and_shrink(
    threads, dtype
) -> None:
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        torch.manual_seed(0)
        actor = Actor(40, (64, 32))
        with torch.no_grad():
            actor.head.weight.mul_(300.0)  # actions spread over their ranges, not all near the centre
        actor = actor.to(dtype)  # bfloat16: populate's big fleets
        drive = driving_function(actor)
        rng = np.random.default_rng(0)
        kept = []
        for n in (1, 7, 300, 3, 1000, 64):
            obs = rng.standard_normal((n, 40)).astype(np.float32)
            with torch.inference_mode():
                expected = actor(torch.from_numpy(obs).to(dtype)).float().numpy()
            got = drive(obs)
            np.testing.assert_array_equal(got, expected)
            kept.append((got, got.copy()))
        assert all(np.array_equal(a, b) for a, b in kept)  # later calls leave earlier actions alone
        assert np.ptp(kept[-2][0][:, 0]) > 1.0  # steer spread over most of [-1, 1]
    finally:
        torch.set_num_threads(previous)


def test_buffer_stores_every_agents_rows_and_wraps_by_value() -> None:
    buf = ReplayBuffer(capacity=10, obs_dim=2, seed=0)

    def step(t: int, n: int) -> tuple[np.ndarray, ...]:
        ids = np.arange(n, dtype=np.float32) + 100 * t  # row value encodes (step, agent)
        obs = np.stack([ids, ids], 1)
        return obs, np.tile(ids[:, None], 3), ids, obs + 0.5, np.zeros(n, np.float32)

    buf.add(*step(0, 4))
    assert len(buf) == 4
    buf.add(*step(1, 4))
    buf.add(*step(2, 4))  # 12 rows into 10 slots: spans the wrap point
    assert len(buf) == 10
    rew = buf.state_dict()["arrays"]["rew"].numpy()
    np.testing.assert_array_equal(rew, [202, 203, 2, 3, 100, 101, 102, 103, 200, 201])
    buf.add(*step(3, 23))  # larger than the ring: only the newest 10 rows survive
    state = buf.state_dict()
    assert state["ptr"] == (2 + 23) % 10
    assert sorted(state["arrays"]["rew"].numpy()) == list(range(313, 323))
    np.testing.assert_array_equal(state["arrays"]["next_obs"][:, 0], state["arrays"]["rew"] + 0.5)


def test_buffer_sample_returns_batch_of_right_shapes() -> None:
    buf = ReplayBuffer(50, 7, seed=3)
    buf.add(*transitions(np.random.default_rng(0), 30, 7))
    batch = buf.sample(16)
    assert isinstance(batch, Batch)
    assert batch.obs.shape == (16, 7) and batch.next_obs.shape == (16, 7)
    assert batch.act.shape == (16, 3) and batch.rew.shape == (16,)
    assert batch.terminated.shape == (16,)
    assert all(t.dtype == torch.float32 for t in batch)


def test_noise_resizes_decays_and_resets() -> None:
    noise = OUNoise(seed=0, decay_steps=4)
    assert noise.sample(3).shape == (3, 3)
    assert noise.sample(5).shape == (5, 3)
    assert noise.scale == pytest.approx(0.5)
    noise.sample(5), noise.sample(5)
    assert not np.any(noise.sample(5))  # fully decayed
    noise.reset()
    np.testing.assert_array_equal(noise.state, np.zeros((5, 3)))


def test_act_is_batched_and_clipped() -> None:
    learner = DDPGLearner(5, SMALL, 0)
    obs = np.random.default_rng(0).uniform(-1, 1, (7, 5)).astype(np.float32)
    greedy = learner.act(obs, explore=False)
    np.testing.assert_array_equal(greedy, learner.act(obs, explore=False))
    noisy = learner.act(obs, explore=True)
    assert noisy.shape == (7, 3) and not np.array_equal(noisy, greedy)
    assert np.all(noisy >= [-1, 0, 0]) and np.all(noisy <= [1, 1, 1])


def test_update_is_noop_before_warmup_and_reports_losses_after() -> None:
    learner = DDPGLearner(5, SMALL, 0)
    learner.observe(*transitions(np.random.default_rng(0), 8, 5))
    assert learner.update(3) == {} and learner.updates == 0
    learner.observe(*transitions(np.random.default_rng(1), 8, 5))
    stats = learner.update(3)
    assert set(stats) == {"critic_loss", "actor_loss", "mean_q"} and learner.updates == 3
    batched = filled_learner(config=DDPGConfig(**{**SMALL.__dict__, "batched": True}))
    assert batched.update(6) and batched.updates == 1


def test_independent_learners_keep_parameters_separate() -> None:
    multi = IndependentLearners(3, 5, SMALL, seed=0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        obs, act, rew, next_obs, term = transitions(rng, 2, 5)
        multi.observe(obs, act, rew, next_obs, term, agent_slots=np.array([0, 1]))
    assert [len(lr.buffer) for lr in multi.learners] == [20, 20, 0]
    actors = [flat_params(lr.actor) for lr in multi.learners]
    assert not torch.equal(actors[0], actors[1])
    multi.learners[0].update(2)
    after = [flat_params(lr.actor) for lr in multi.learners]
    assert not torch.equal(after[0], actors[0])
    assert torch.equal(after[1], actors[1]) and torch.equal(after[2], actors[2])
    assert multi.update() and [lr.updates for lr in multi.learners] == [3, 1, 0]
    obs = rng.uniform(-1, 1, (3, 5)).astype(np.float32)
    acted = multi.act(obs, np.array([2, 0, 2]), explore=False)
    np.testing.assert_array_equal(acted[1], multi.learners[0].act(obs[1:2], explore=False)[0])
    np.testing.assert_array_equal(acted[[0, 2]], multi.learners[2].act(obs[[0, 2]], False))


def roundtrip(state: dict) -> dict:
    """Through torch.save/load(weights_only=True), as a checkpoint would."""
    buf = io.BytesIO()
    torch.save(state, buf)
    buf.seek(0)
    return torch.load(buf, weights_only=True)


def run_a_bit(learner: DDPGLearner | IndependentLearners, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    acted = []
    for _ in range(3):
        obs, _, rew, next_obs, term = transitions(rng, 4, 5)
        if isinstance(learner, IndependentLearners):
            act = learner.act(obs, np.arange(4) % 2, explore=True)
            learner.observe(obs, act, rew, next_obs, term, np.arange(4) % 2)
            learner.update()
        else:
            act = learner.act(obs, explore=True)
            learner.observe(obs, act, rew, next_obs, term)
            learner.update(4)
        acted.append(act)
    return acted


def all_critics(learner: DDPGLearner | IndependentLearners) -> torch.Tensor:
    parts = learner.learners if isinstance(learner, IndependentLearners) else [learner]
    return torch.cat([flat_params(p.critic) for p in parts])


@pytest.mark.parametrize("kind", ["shared", "independent"])
def test_state_dict_resume_is_exact(kind: str) -> None:
    def make(seed: int) -> DDPGLearner | IndependentLearners:
        return DDPGLearner(5, SMALL, seed) if kind == "shared" else IndependentLearners(2, 5, SMALL, seed)

    original = make(0)
    run_a_bit(original, 1)
    state = roundtrip(original.state_dict())
    resumed = make(99)
    resumed.load_state_dict(state)
    for a, b in zip(run_a_bit(original, 2), run_a_bit(resumed, 2), strict=True):
        np.testing.assert_array_equal(a, b)
    assert torch.equal(all_critics(original), all_critics(resumed))


def save_learner(path: Path, learner: DDPGLearner, **meta_overrides: object) -> None:
    save_checkpoint(
        path,
        actor_state=learner.actor.state_dict(),
        critic_state=learner.critic.state_dict(),
        extra_state=learner.state_dict(),
        meta={**META, **meta_overrides},
    )


def test_checkpoint_roundtrip_and_actor_only(tmp_path: Path) -> None:
    learner = filled_learner(obs_dim=65)
    learner.update(2)
    path = tmp_path / "policy.pt"
    save_learner(path, learner)
    assert os.listdir(tmp_path) == ["policy.pt"]  # no temp file left behind
    ckpt = load_checkpoint(path, expect_obs_dim=65)
    assert ckpt.meta["algorithm"] == "ps-ddpg" and ckpt.meta["format_version"] == 1
    assert ckpt.meta["action_low"] == [-1.0, 0.0, 0.0] and ckpt.meta["training_steps"] == 123
    torch.testing.assert_close(ckpt.critic_state, learner.critic.state_dict())
    assert ckpt.extra_state is not None and ckpt.extra_state["updates"] == 2

    slim = tmp_path / "slim.pt"
    save_actor_only(path, slim)
    stripped = load_checkpoint(slim)
    assert stripped.critic_state is None and stripped.extra_state is None
    assert slim.stat().st_size < path.stat().st_size
    actor = load_actor(slim, expect_obs_dim=65)
    assert not actor.training
    obs = np.random.default_rng(0).uniform(-1, 1, (4, 65)).astype(np.float32)
    with torch.no_grad():
        np.testing.assert_array_equal(actor(torch.from_numpy(obs)).numpy(), learner.act(obs, explore=False))


def test_failed_save_leaves_existing_file_intact(tmp_path: Path) -> None:
    learner = filled_learner(obs_dim=65)
    path = tmp_path / "policy.pt"
    save_learner(path, learner)
    original = path.read_bytes()
    with pytest.raises(Exception, match=r"pickle|lambda"):
        save_checkpoint(
            path,
            actor_state=learner.actor.state_dict(),
            extra_state={"unpicklable": lambda: 0},
            meta=META,
        )
    assert path.read_bytes() == original
    assert os.listdir(tmp_path) == ["policy.pt"]


def test_bad_files_give_one_line_behave_errors(tmp_path: Path) -> None:
    with pytest.raises(BehaveError, match=r"checkpoint not found: .*missing\.pt"):
        load_checkpoint(tmp_path / "missing.pt")
    good = tmp_path / "good.pt"
    save_learner(good, filled_learner(obs_dim=65))
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    noise = tmp_path / "noise.pt"
    noise.write_bytes(np.random.default_rng(0).bytes(4096))
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    for bad in (truncated, noise, foreign):
        with pytest.raises(BehaveError, match="is not a behave checkpoint") as info:
            load_actor(bad)
        assert "\n" not in str(info.value)
    with pytest.raises(
        BehaveError,
        match=r"policy expects 65 observations \(lanekeeping\) but the task gives 66 \(multi\)",
    ):
        load_actor(good, expect_obs_dim=66, expect_layout="multi")
    future = tmp_path / "future.pt"
    payload = torch.load(good, weights_only=True)
    payload["meta"]["format_version"] = 99
    torch.save(payload, future)
    with pytest.raises(BehaveError, match="format version 99"):
        load_checkpoint(future)


def bandit_reward(obs: np.ndarray, act: np.ndarray) -> np.ndarray:
    """Known optimum: steer = 0.5 * obs, accel = 0.8, brake = 0.6."""
    err = act - np.stack([0.5 * obs[:, 0], np.full(len(obs), 0.8), np.full(len(obs), 0.6)], 1)
    return -(err**2).sum(1).astype(np.float32)


@pytest.mark.train
def test_learns_a_one_step_bandit() -> None:
    """Terminal transitions, so Q is just the reward; the policy must climb the critic from its
    start (0, .5, .05) to the optimum, >= .26 away per dimension on average."""
    cfg = DDPGConfig(
        gamma=0.0, tau=0.05, actor_lr=3e-4, critic_lr=3e-3, batch_size=128,
        hidden=(128, 128), warmup=256, buffer_size=4096,
    )  # fmt: skip
    learner = DDPGLearner(1, cfg, seed=0)
    rng = np.random.default_rng(0)
    test_obs = np.linspace(-1, 1, 21, dtype=np.float32)[:, None]
    optimum = np.stack([0.5 * test_obs[:, 0], np.full(21, 0.8), np.full(21, 0.6)], 1)

    def error() -> np.ndarray:
        return np.abs(learner.act(test_obs, explore=False) - optimum).mean(0)

    assert np.all(error() > 0.25)
    obs = rng.uniform(-1, 1, (4096, 1)).astype(np.float32)
    act = rng.uniform((-1, 0, 0), (1, 1, 1), (4096, 3)).astype(np.float32)
    learner.observe(obs, act, bandit_reward(obs, act), obs, np.ones(4096, np.float32))
    learner.update(800)
    assert np.all(error() < 0.1), error()
