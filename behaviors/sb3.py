"""Stable-Baselines3 vector envs of behave/Traffic-v0 (the `integrations` extra).

libsumo runs one simulation per process, so SB3's usual in-process `DummyVecEnv` holds one env
only: more than one get a process each (`SubprocVecEnv`). Env i is seeded `seed + i`, as SB3's
`make_vec_env` seeds, so a run is repeatable.
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from behaviors.gym_env import TrafficGymEnv


def sb3_vec_env(n_envs: int = 1, seed: int = 0, **settings: Any) -> VecEnv:
    """`n_envs` seeded Gym envs (`settings`: TrafficGymEnv's keywords: scenario, behaviour, net,
    sumocfg, reward_weights, max_steps, ...), each in its own process when there are several."""
    vec_env_cls = DummyVecEnv if n_envs == 1 else SubprocVecEnv
    return make_vec_env(TrafficGymEnv, n_envs=n_envs, seed=seed, vec_env_cls=vec_env_cls, env_kwargs=settings)
