"""The one episode loop: training, Ray's rollout workers and evaluation all drive an env through it,
so that they cannot drift apart in what a step is or what an episode's metrics count."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from behaviors.learn.env_core import BehaveEnv, StepBatch
from behaviors.learn.metrics import EpisodeStats

Choose = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(observations [n, D], their agent slots [n]) -> actions [n, 3]."""
OnStep = Callable[[np.ndarray, np.ndarray, StepBatch], None]
"""Called after each step with the observations acted on, the actions and the step's batch."""


def drive_episode(
    env: BehaveEnv,
    obs: np.ndarray,
    choose: Choose,
    on_step: OnStep | None = None,
    stop: Callable[[], bool] | None = None,
) -> EpisodeStats | None:
    """Drive an episode just reset (`obs` from `reset_arrays`) until no agent is left; None if
    `stop()` held before a step (the caller drops the partial episode)."""
    assert env.sim is not None, "drive_episode drives an episode just reset"
    stats = EpisodeStats(env.config.n_agents, env.slot_behaviour.copy(), env.config.step_length, env.sim.time)
    stats.place(env.live_slots)  # the slots whose car started (the traffic env may place fewer)
    while env.agents:
        if stop is not None and stop():
            return None
        slots = env.live_slots
        actions = choose(obs, slots)
        batch = env.step_arrays(actions)
        if on_step is not None:
            on_step(obs, actions, batch)
        stats.record(slots, batch)
        obs = env.live_obs
    return stats
