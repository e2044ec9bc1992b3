"""The styled driver's network learns its first driving from a teacher: the hand-written rules, given
each agent's style (drivers.StyledDriver.teach).

Learning to drive in traffic from reward alone asks DDPG for thousands of lane changes before one
pays off; a network that starts from the rules' choices, conditioned on the style it sees, drives
at once, and then owns every choice: with the rules only forbidding (`LaneDriving.network_chooses`),
whatever the network outputs is what the car does. Data are gathered the DAgger way: the
teacher labels every state, while the state comes from the network-mode actuation of the teacher's
choice, perturbed now and then so that states off the teacher's path are labelled too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from behaviors.errors import BehaveError
from behaviors.fleet.drivers import StyledDriver
from behaviors.learn.ddpg.checkpoint import save_checkpoint
from behaviors.learn.ddpg.networks import Actor
from behaviors.learn.env import make_env
from behaviors.learn.env_core import BehaveEnv


@dataclass(frozen=True)
class Demonstrations:
    """Observations and the teacher's actions for them, row for row."""

    obs: np.ndarray  # [K, D] float32
    actions: np.ndarray  # [K, 3] float32

    def __len__(self) -> int:
        return len(self.obs)


def collect(
    episodes: int,
    seed: int,
    perturb: float = 0.05,
    scenario: str = "roads",
    agents: tuple[int, int] = (4, 4),
    max_steps: int = 500,
) -> Demonstrations:
    """`episodes` episodes of `agents` (overtakers, keepers) styled drivers on the training roads,
    each state labelled by the teacher; in a share `perturb` of agent-steps the car is given a random
    lane wish instead of the teacher's (held for a second), so that the teacher is asked about the
    states such a mistake leads to."""
    env = make_env(
        scenario, driver="styled", behaviour="multi", overtakers=agents[0], keepers=agents[1],
        max_steps=max_steps, seed=seed,
    )  # fmt: skip
    rng = np.random.default_rng(seed)
    obs_parts, action_parts = [], []
    try:
        for episode in range(episodes):
            obs = _reset(env, seed * 100_003 + episode)
            stray = np.zeros(env.config.n_agents)  # seconds of a random wish left, per slot
            wish = np.zeros(env.config.n_agents)
            while len(env.agents):
                driver = env.fleet.driver
                assert isinstance(driver, StyledDriver)
                taught = driver.teach(env.fleet)
                obs_parts.append(obs.astype(np.float32))
                action_parts.append(taught)
                slots = env.live_slots
                start = (stray[slots] <= 0) & (rng.random(len(slots)) < perturb / 5)
                wish[slots[start]] = rng.choice([-1.0, 1.0], int(start.sum()))
                stray[slots[start]] = 1.0
                acting = taught.copy()
                straying = stray[slots] > 0
                acting[straying, 0] = wish[slots[straying]]
                stray[slots] -= env.config.step_length
                batch = env.step_arrays(acting)
                obs = batch.next_obs[~(batch.terminated | batch.truncated)]
    finally:
        env.close()
    return Demonstrations(np.concatenate(obs_parts), np.concatenate(action_parts))


def _reset(env: BehaveEnv, seed: int) -> np.ndarray:
    """The first observations of an episode, drawing again where the traffic left no room."""
    for attempt in range(5):
        try:
            return env.reset_arrays(seed + 7919 * attempt)
        except BehaveError:
            continue
    raise BehaveError("no episode with room for the agents in 5 draws")


LANE_CHANGE_WEIGHT = 20.0
"""How much more a state where the teacher heads for another lane counts in the fit: such states
are about one in a hundred, and a network that never wishes for a lane is the cheap wrong answer."""


def fit_actor(
    demos: Demonstrations, hidden: tuple[int, ...], epochs: int, seed: int, batch: int = 512
) -> tuple[Actor, list[float]]:
    """An actor fitted to the teacher's actions (mean squared error on the squashed outputs; steer
    weighted up, and the states where the teacher changes lanes by LANE_CHANGE_WEIGHT: its -1/0/+1
    is the choice that matters most); and the loss of each epoch."""
    torch.manual_seed(seed)
    actor = Actor(demos.obs.shape[1], hidden)
    obs = torch.from_numpy(demos.obs)
    target = torch.from_numpy(demos.actions).clone()
    target[:, 0] = target[:, 0] * 0.98  # tanh reaches +-1 only at infinity
    changing = target[:, :1].abs() > 0.5
    weight = torch.tensor([4.0, 1.0, 1.0]) * torch.where(changing, LANE_CHANGE_WEIGHT, 1.0)
    optimiser = torch.optim.Adam(actor.parameters(), lr=1e-3)
    generator = torch.Generator().manual_seed(seed)
    losses = []
    for _ in range(epochs):
        order = torch.randperm(len(obs), generator=generator)
        total = 0.0
        for start in range(0, len(obs), batch):
            rows = order[start : start + batch]
            loss = (weight[rows] * (actor(obs[rows]) - target[rows]) ** 2).mean()
            optimiser.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(actor.parameters(), 10.0)
            optimiser.step()
            total += float(loss.detach()) * len(rows)
        losses.append(total / len(obs))
    return actor, losses


def steer_agreement(actor: Actor, demos: Demonstrations) -> tuple[float, float]:
    """Share of states where the actor's lane wish (steer beyond +-0.5) is the teacher's: over all
    states, and over those where the teacher heads for another lane."""
    with torch.no_grad():
        steer = actor(torch.from_numpy(demos.obs))[:, 0].numpy()
    wish = np.where(steer > 0.5, 1, np.where(steer < -0.5, -1, 0))
    taught = np.rint(demos.actions[:, 0])
    same = wish == taught
    changing = taught != 0
    return float(same.mean()), float(same[changing].mean()) if changing.any() else float("nan")


def save_styled(path: Path, actor: Actor, demos: Demonstrations, seed: int, note: str) -> None:
    """A styled-driver checkpoint of `actor` (no critic: it was taught, not trained by reward)."""
    driver = StyledDriver()
    meta = {
        "algorithm": "ps-ddpg",
        "driver": driver.name,
        "behaviour": "multi",
        "behaviours": ["overtaking", "lanekeeping"],
        "obs_dim": int(demos.obs.shape[1]),
        "observation_layout": driver.observation_layout(True),
        "normalisation": driver.normalisation,
        "hidden": list(actor.hidden),
        "training_steps": len(demos),
        "seed": seed,
        "step_length": 0.2,
        "taught": note,
    }
    save_checkpoint(path, actor_state=actor.state_dict(), meta=meta)
