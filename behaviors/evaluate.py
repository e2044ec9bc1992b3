"""Run a fixed policy (no exploration, no learning) and measure the paper's metrics.

Used by `behave evaluate`, the learn-check benchmark and the model cards.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from behaviors.ddpg.networks import Actor
from behaviors.env import BehaveEnv, EnvConfig
from behaviors.metrics import EpisodeStats, passed_fraction, summary
from behaviors.train import episode_seed

Policy = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(observations [n, D], agent slots [n]) -> actions [n, 3]."""


def actor_policy(actor: Actor) -> Policy:
    """The whole fleet through one batched forward pass."""

    def act(obs: np.ndarray, slots: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return actor(torch.as_tensor(obs)).numpy()

    return act


def evaluate(config: EnvConfig, policy: Policy, episodes: int, seed: int) -> list[dict[str, Any]]:
    """`episodes` rows of `summary`, each from a fresh, seeded episode."""
    env = BehaveEnv(config)
    limit = max(info.speed for info in env.geometry.edges.values() if info.normal)
    rows = []
    try:
        for episode in range(episodes):
            obs = env.reset_arrays(episode_seed(seed, 1_000_000 + episode))
            stats = EpisodeStats(config.n_agents, env.slot_behaviour.copy())
            while env.agents:
                slots = env.live_slots
                batch = env.step_arrays(policy(obs, slots).astype(np.float32))
                stats.record(slots, batch)
                obs = env.live_obs
            rows.append({"episode": episode, **summary(stats, limit, passed_fraction(env))})
    finally:
        env.close()
    return rows
