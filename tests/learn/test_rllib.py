"""RLlib (2.60, new API stack) over behave's PettingZoo env through its ParallelPettingZooEnv: agents
leave one by one, and the last two end in ONE step for different reasons (one drives off the road,
the other reaches the time limit)."""

from __future__ import annotations

import numpy as np
import pytest

from behaviors.learn.env import make_env

pytest.importorskip("ray.rllib", reason="RLlib is not installed (the integrations extra)")
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.env.multi_agent_env_runner import MultiAgentEnvRunner
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
from ray.tune.registry import register_env

pytestmark = pytest.mark.sumo

STEER = {"agent_0": 1.0, "agent_1": -0.08, "agent_2": 0.0}
"""Hard right: off the road at step 2; slightly left: off the road at step 7; straight on."""
LAST_STEP = 7
ENV_NAME = "behave_scripted_ending"


class ScriptedEnding(ParallelPettingZooEnv):
    """RLlib's own wrapper, with the steering above in place of the policy's actions and the same
    start every episode, so that every episode ends the same way whatever the policy does."""

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        return super().reset(seed=0, options=options)

    def step(self, action_dict: dict):
        return super().step({name: np.array([STEER[name], 0.5, 0.0], np.float32) for name in action_dict})


def scripted_env(_config: object = None) -> ScriptedEnding:
    return ScriptedEnding(make_env("tiny", agents=3, max_steps=LAST_STEP, seed=0, start_speed=10.0))


def ppo_config() -> PPOConfig:
    register_env(ENV_NAME, scripted_env)
    return (
        PPOConfig()
        .environment(ENV_NAME)
        .env_runners(num_env_runners=0)
        .multi_agent(policies={"shared"}, policy_mapping_fn=lambda *_args, **_kwargs: "shared")
        .training(train_batch_size_per_learner=32, minibatch_size=16, num_epochs=1)
        .rl_module(model_config={"fcnet_hiddens": [16]})
    )


def test_rllib_samples_episodes_where_agents_leave_apart_and_the_last_two_for_different_reasons() -> None:
    """RLlib's multi-agent env runner drives whole episodes: each agent's episode is as long as it
    drove, the off-road ending carries its -1000 and is terminal, the time-limited agent is
    truncated, and the episode is 7 environment steps long (the wrapper's extra empty step after
    the last agents left is no environment step)."""
    runner = MultiAgentEnvRunner(config=ppo_config())
    try:
        episodes = runner.sample(num_episodes=2, random_actions=True)
    finally:
        runner.stop()
    assert len(episodes) == 2
    for episode in episodes:
        assert episode.is_done and episode.env_t == LAST_STEP
        agents = episode.agent_episodes
        assert {name: len(agents[name]) for name in STEER} == {"agent_0": 2, "agent_1": LAST_STEP,
                                                               "agent_2": LAST_STEP}  # fmt: skip
        for leaver in ("agent_0", "agent_1"):
            assert agents[leaver].is_terminated
            assert agents[leaver].get_infos(-1)["off_track"] == -1000.0
        assert agents["agent_2"].is_truncated  # RLlib also marks it terminated: see the README
        assert agents["agent_2"].get_infos(-1)["off_track"] == 0.0


@pytest.mark.train
def test_rllib_ppo_trains_an_iteration_through_those_episode_ends() -> None:
    """One PPO iteration (32 environment steps, 4+ episodes that end as above) samples and updates
    the shared module."""
    import ray

    algo = ppo_config().build_algo()
    try:
        result = algo.train()
    finally:
        algo.stop()
        ray.shutdown()
    runners = result["env_runners"]
    assert runners["num_env_steps_sampled"] >= 32 and runners["num_episodes"] >= 4
    assert runners["episode_len_mean"] == LAST_STEP
    assert result["learners"]["shared"]["num_module_steps_trained"] > 0
