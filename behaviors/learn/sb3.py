"""Stable-Baselines3 vector envs of behave/Traffic-v0 and of the PettingZoo env (the `integrations`
extra).

libsumo runs one simulation per process, so SB3's usual in-process `DummyVecEnv` holds one env
only: more than one get a process each (`SubprocVecEnv`). Env i is seeded `seed + i`, as SB3's
`make_vec_env` seeds, so a run is repeatable.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import supersuit as ss
from pettingzoo import ParallelEnv
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv
from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper

from behaviors.learn.gym_env import TrafficGymEnv


def sb3_vec_env(n_envs: int = 1, seed: int = 0, **settings: Any) -> VecEnv:
    """`n_envs` seeded Gym envs (`settings`: TrafficGymEnv's keywords: scenario, behaviour, net,
    sumocfg, reward_weights, max_steps, ...), each in its own process when there are several."""
    vec_env_cls = DummyVecEnv if n_envs == 1 else SubprocVecEnv
    return make_vec_env(TrafficGymEnv, n_envs=n_envs, seed=seed, vec_env_cls=vec_env_cls, env_kwargs=settings)


class _SeededSB3VecEnv(SB3VecEnvWrapper):
    """SuperSuit's SB3 wrapper with SB3 2.x's seeding: `seed(s)` keeps s for the next reset.

    SuperSuit's wrapper (3.11) inherits `VecEnvWrapper.seed`, which calls `seed` on the Gymnasium
    vector env inside; Gymnasium vector envs seed only through `reset(seed=)`, so `TD3(seed=0)`
    (which calls `env.seed(0)`) crashes with "'ConcatVecEnv' object has no attribute 'seed'"."""

    def __init__(self, venv: Any) -> None:
        super().__init__(venv)
        self._next_seed: int | None = None

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """The agents of one simulation share its seed (SB3's envs here are the agents)."""
        self._next_seed = seed
        return [seed] * self.num_envs

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> np.ndarray:
        self._next_seed = self._next_seed if seed is None else seed
        observations, self.reset_infos = self.venv.reset(seed=self._next_seed, options=options)
        self._next_seed = None
        return observations


def sb3_parallel_vec_env(env: ParallelEnv) -> VecEnv:
    """An SB3 VecEnv of a PettingZoo env, one SB3 env per agent (SuperSuit's black death zeroes
    agents that left, so the number of envs stays put); `seed(s)` seeds the next episode.

    One simulation only, in this process (libsumo runs one per process)."""
    vec_env = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(ss.black_death_v3(env)), 1, num_cpus=0)
    return _SeededSB3VecEnv(vec_env)
