"""The Gymnasium single-agent entry behave/Traffic-v0: one learned car among SUMO's traffic."""

from __future__ import annotations

import dataclasses

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import behaviors.learn.gym_env
from behaviors.errors import BehaveError
from behaviors.learn.gym_env import ENV_ID, RESET_TRIES
from behaviors.report.render import AGENT
from behaviors.traffic.lanes import TRAFFIC_OBS_SIZE


@pytest.mark.sumo
def test_registered_env_passes_gymnasium_check_and_close_frees_sumo() -> None:
    """check_env on the registered id (seeded resets and steps deterministic, spaces honoured,
    fresh arrays each call); after close() another env can run SUMO in this process."""
    env = gymnasium.make(ENV_ID, scenario="ring")
    assert isinstance(env.unwrapped, behaviors.learn.gym_env.TrafficGymEnv)
    # the render check would start a second SUMO while this one lives: rendering is tested below
    check_env(env.unwrapped, skip_render_check=True)
    env.close()
    other = gymnasium.make(ENV_ID, scenario="ring")
    obs, _ = other.reset(seed=1)
    assert obs.shape == (TRAFFIC_OBS_SIZE,)
    other.close()


@pytest.mark.sumo
def test_rollout_to_the_time_limit_with_the_traffic_reward() -> None:
    """A seeded rollout on the training roads: observations in the space, reward = sum of the
    traffic terms in info, and the episode ends by the time limit at the latest."""
    env = gymnasium.make(ENV_ID, behaviour="overtaking", max_steps=25)
    try:
        obs, info = env.reset(seed=4)
        assert info["road"].startswith("road_")
        env.action_space.seed(4)
        steps, done = 0, False
        while not done:
            assert obs in env.observation_space
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert np.isfinite(reward) and reward == pytest.approx(sum(info.values()))
            steps, done = steps + 1, terminated or truncated
        assert steps <= 25
        assert truncated == (steps == 25 and not terminated)
    finally:
        env.close()


@pytest.mark.sumo
def test_rgb_array_shows_the_car() -> None:
    env = gymnasium.make(ENV_ID, scenario="ring", render_mode="rgb_array")
    try:
        env.reset(seed=2)
        image = env.render()
        assert image.shape == (256, 256, 3) and image.dtype == np.uint8
        assert (image == AGENT).all(axis=-1).any()
    finally:
        env.close()


@pytest.mark.sumo
def test_reset_redraws_when_no_car_fits_then_says_so() -> None:
    """Traffic too dense for the car to enter: every try is redrawn, then one clear error."""
    env = gymnasium.make(ENV_ID, scenario="ring")
    traffic = env.unwrapped.traffic
    traffic.config = dataclasses.replace(traffic.config, traffic_density=(400.0, 400.0))
    seeds = []
    reset_arrays = traffic.reset_arrays
    traffic.reset_arrays = lambda seed: seeds.append(seed) or reset_arrays(seed)
    try:
        with pytest.raises(BehaveError, match=f"no free place for the car in {RESET_TRIES} episodes"):
            env.reset(seed=7)
        assert seeds == list(range(7, 7 + RESET_TRIES))
    finally:
        env.close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"behaviour": "racing"}, "unknown behaviour 'racing'"),
        ({"scenario": "tiny"}, "unknown scenario 'tiny'"),
        ({"max_step": 10}, "unknown setting 'max_step'"),
        ({"agents": 2}, "drives one car of the traffic driver: agents"),
    ],
)
def test_bad_arguments_are_one_clear_error(kwargs: dict, message: str) -> None:
    with pytest.raises(BehaveError, match=message):
        gymnasium.make(ENV_ID, **kwargs)
