"""Ornstein-Uhlenbeck exploration, one process per agent and action dimension, with a linear decay.

Defaults and why they differ from the DDPG-TORCS reference (yanpanlau/DDPG-Keras-Torcs):
there the "OU" term is theta * (mu - a) + sigma * N(0, 1) computed from the *action* a, with
steer (mu 0, theta 0.6, sigma 0.3), accel (0.5, 1.0, 0.1), brake (-0.1, 1.0, 0.05). With
theta = 1 that replaces accel and brake outright by mu + noise, i.e. mu is a target action.
Here the noise is a proper OU state x added to the action (a = mu(s) + eps * x), so a non-zero
mu would be a constant action offset; the defaults therefore keep the reference's theta and sigma
and use mu = 0. Stationary std (dt = 1): steer 0.33 (correlated over ~2 steps), accel 0.1,
brake 0.05 (white, as theta = 1). Pass mu explicitly (e.g. accel +0.3, brake -0.3) to bias early
exploration towards driving, which is what the reference's mu achieved.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

DEFAULT_MU = (0.0, 0.0, 0.0)
DEFAULT_THETA = (0.6, 1.0, 1.0)
DEFAULT_SIGMA = (0.3, 0.1, 0.05)
DEFAULT_DECAY_STEPS = 100_000


def exploration_scale(step: int, decay_steps: int) -> float:
    """eps: 1 at step 0, linearly down to 0 at decay_steps and after (the reference's schedule)."""
    if decay_steps <= 0:
        return 0.0
    return max(0.0, 1.0 - step / decay_steps)


class OUNoise:
    """x <- x + theta * (mu - x) + sigma * N(0, 1) per dimension; state [N,3] for N agents."""

    def __init__(
        self,
        mu: Sequence[float] = DEFAULT_MU,
        theta: Sequence[float] = DEFAULT_THETA,
        sigma: Sequence[float] = DEFAULT_SIGMA,
        seed: int = 0,
        decay_steps: int = DEFAULT_DECAY_STEPS,
    ) -> None:
        self.mu = np.asarray(mu, np.float32)
        self.theta = np.asarray(theta, np.float32)
        self.sigma = np.asarray(sigma, np.float32)
        if not self.mu.shape == self.theta.shape == self.sigma.shape:
            raise ValueError("OU mu, theta and sigma need one value per action dimension")
        self.decay_steps = decay_steps
        self.rng = np.random.default_rng(seed)
        self.state = np.zeros((0, len(self.mu)), np.float32)
        self.steps = 0

    @property
    def scale(self) -> float:
        return exploration_scale(self.steps, self.decay_steps)

    def reset(self) -> None:
        """Back to the mean for every agent (e.g. at an episode start); the decay continues."""
        self.state[:] = self.mu

    def _resize(self, n_agents: int) -> None:
        """Keep the first rows' processes; rows for new agents start at the mean."""
        state = np.tile(self.mu, (n_agents, 1))
        keep = min(n_agents, len(self.state))
        state[:keep] = self.state[:keep]
        self.state = state

    def sample(self, n_agents: int) -> np.ndarray:
        """Advance every agent's process one env step; returns eps * x, float32 [n_agents, 3]."""
        if len(self.state) != n_agents:
            self._resize(n_agents)
        shocks = self.rng.standard_normal(self.state.shape, dtype=np.float32)
        self.state += self.theta * (self.mu - self.state) + self.sigma * shocks
        noise = np.float32(self.scale) * self.state
        self.steps += 1
        return noise

    def state_dict(self) -> dict[str, Any]:
        return {
            "state": self.state.tolist(),
            "steps": self.steps,
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.state = np.asarray(state["state"], np.float32).reshape(-1, len(self.mu))
        self.steps = state["steps"]
        self.rng.bit_generator.state = state["rng"]
