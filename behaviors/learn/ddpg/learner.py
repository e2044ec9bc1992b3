"""PS-DDPG learner (one actor, critic and replay buffer shared by all agents) and the
multi-DDPG baseline (one independent learner per agent); paper section II, equations 1-2."""

from __future__ import annotations

import copy
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from behaviors.learn.ddpg.buffer import Batch, ReplayBuffer
from behaviors.learn.ddpg.networks import ACT_DIM, ACTION_HIGH, ACTION_LOW, Actor, Critic
from behaviors.learn.ddpg.noise import DEFAULT_MU, DEFAULT_SIGMA, DEFAULT_THETA, OUNoise

_LOW = np.asarray(ACTION_LOW, np.float32)
_HIGH = np.asarray(ACTION_HIGH, np.float32)
UpdateStats = tuple[float, float, float]
"""One gradient step's critic loss, actor loss and mean Q."""


@dataclass(frozen=True)
class DDPGConfig:
    """Hyper-parameters; defaults are the DDPG paper's / TORCS reference's.

    batched: when update(n) is asked for n updates, do ONE gradient step on n * batch_size
    samples instead of n steps on batch_size each (same samples, fewer optimiser steps; the
    target nets then move by 1 - (1 - tau)^n so they lag the same number of env steps).
    """

    gamma: float = 0.99
    tau: float = 0.001
    actor_lr: float = 1e-4
    critic_lr: float = 1e-3
    batch_size: int = 64
    buffer_size: int = 100_000
    hidden: tuple[int, ...] = (256, 256)
    warmup: int = 1000
    explore_decay_steps: int = 100_000
    weight_decay: float = 0.0
    ou_mu: tuple[float, ...] = DEFAULT_MU
    ou_theta: tuple[float, ...] = DEFAULT_THETA
    ou_sigma: tuple[float, ...] = DEFAULT_SIGMA
    batched: bool = False


@dataclass(frozen=True)
class Transitions:
    """One step's transitions of the live agents (row i = agent slot `agent_slots[i]`)."""

    obs: np.ndarray
    act: np.ndarray
    rew: np.ndarray
    next_obs: np.ndarray
    terminated: np.ndarray  # no bootstrap (time-limit truncation is not termination)
    agent_slots: np.ndarray


def critic_targets(
    rew: torch.Tensor, terminated: torch.Tensor, next_q: torch.Tensor, gamma: float
) -> torch.Tensor:
    """Equation 1: y = r + gamma * Q'(s', mu'(s')), not bootstrapped past a true termination
    (truncated transitions are stored with terminated = 0, so they do bootstrap)."""
    return rew + gamma * (1.0 - terminated) * next_q


def _params(module: nn.Module) -> list[torch.Tensor]:
    return [p.detach() for p in module.parameters()]


@torch.no_grad()
def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """theta' <- theta' + tau * (theta - theta'), fused over all parameters."""
    torch._foreach_lerp_(_params(target), _params(source), tau)


def clip_actions(act: np.ndarray) -> np.ndarray:
    return np.clip(act, _LOW, _HIGH)


def _seeds(seed: int, n: int) -> list[int]:
    """Independent child seeds so buffer, noise and nets don't share random streams."""
    return [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(n)]


class DDPGLearner:
    """DDPG with everything shared: act() on all agents' rows at once, observe() all of a
    step's transitions, update(n) with n = number of agents reproduces the paper's
    "every agent updates the shared networks at each step"."""

    def __init__(self, obs_dim: int, config: DDPGConfig | None = None, seed: int = 0) -> None:
        self.obs_dim = obs_dim
        self.config = cfg = config or DDPGConfig()
        net_seed, buffer_seed, noise_seed = _seeds(seed, 3)
        with torch.random.fork_rng(devices=[]):  # deterministic init, global RNG left alone
            torch.manual_seed(net_seed)
            self.actor = Actor(obs_dim, cfg.hidden)
            self.critic = Critic(obs_dim, ACT_DIM, cfg.hidden)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.actor_lr)
        self.critic_opt = torch.optim.Adam(
            self.critic.parameters(), lr=cfg.critic_lr, weight_decay=cfg.weight_decay
        )
        self.buffer = ReplayBuffer(cfg.buffer_size, obs_dim, ACT_DIM, buffer_seed)
        self.noise = OUNoise(cfg.ou_mu, cfg.ou_theta, cfg.ou_sigma, noise_seed, cfg.explore_decay_steps)
        self.transitions = 0
        self.updates = 0

    @property
    def buffers(self) -> list[ReplayBuffer]:
        """The replay buffers (one here), alike for both learner kinds."""
        return [self.buffer]

    @property
    def learners(self) -> list[DDPGLearner]:
        """The networks' owners (this one), alike for both learner kinds."""
        return [self]

    def act_for(self, obs: np.ndarray, agent_slots: np.ndarray, explore: bool) -> np.ndarray:
        """Actions for the rows of these agent slots: all share one actor."""
        return self.act(obs, explore)

    def learn(self, step: Transitions, updates_per_step: int | None, each: list[UpdateStats] | None) -> None:
        """Store a step's transitions and update: one update per live agent (the paper's schedule)
        unless `updates_per_step` says otherwise."""
        self.observe(step.obs, step.act, step.rew, step.next_obs, step.terminated)
        self.update(len(step.obs) if updates_per_step is None else updates_per_step, each)

    def checkpoint_states(self) -> tuple[dict, dict, dict | None]:
        """Actor, critic and extra state a policy checkpoint holds."""
        return self.actor.state_dict(), self.critic.state_dict(), None

    def act(self, obs: np.ndarray, explore: bool) -> np.ndarray:
        """One batched forward pass for all N rows; exploration noise added, then clipped."""
        with torch.inference_mode():
            act = self.actor(torch.as_tensor(obs, dtype=torch.float32)).numpy()
        if explore:
            act = act + self.noise.sample(len(act))
        return clip_actions(act)

    def observe(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        rew: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """Store one step's N transitions; `terminated` excludes time-limit truncation."""
        self.buffer.add(obs, act, rew, next_obs, terminated)
        self.transitions += len(obs)

    @property
    def ready(self) -> bool:
        return len(self.buffer) >= max(self.config.warmup, 1)

    def update(self, n_updates: int = 1, each: list[UpdateStats] | None = None) -> dict[str, float]:
        """n gradient steps (or one n-fold batch if config.batched); {} during warm-up.
        Returns the mean critic loss, actor loss and Q over the steps taken; `each`, if given,
        gets every step's (critic loss, actor loss, mean Q) appended (TensorBoard's per-update log)."""
        if not self.ready or n_updates < 1:
            return {}
        cfg = self.config
        if cfg.batched:
            tau = 1.0 - (1.0 - cfg.tau) ** n_updates
            stats = [self._step(self.buffer.sample(n_updates * cfg.batch_size), tau)]
        else:
            batches = (self.buffer.sample(cfg.batch_size) for _ in range(n_updates))
            stats = [self._step(batch, cfg.tau) for batch in batches]
        if each is not None:
            each.extend(stats)
        keys = ("critic_loss", "actor_loss", "mean_q")
        return {k: float(np.mean([s[i] for s in stats])) for i, k in enumerate(keys)}

    def _step(self, batch: Batch, tau: float) -> UpdateStats:
        """One critic step (equation 1), one actor step (equation 2), then the soft updates."""
        with torch.no_grad():
            next_q = self.critic_target(batch.next_obs, self.actor_target(batch.next_obs))
            y = critic_targets(batch.rew, batch.terminated, next_q, self.config.gamma)
        q = self.critic(batch.obs, batch.act)
        critic_loss = nn.functional.mse_loss(q, y)
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()

        actor_loss = -self.critic(batch.obs, self.actor(batch.obs)).mean()
        self.actor_opt.zero_grad()
        actor_loss.backward(inputs=list(self.actor.parameters()))  # no wasted critic grads
        self.actor_opt.step()

        soft_update(self.actor_target, self.actor, tau)
        soft_update(self.critic_target, self.critic, tau)
        self.updates += 1
        return critic_loss.item(), actor_loss.item(), q.mean().item()

    def state_dict(self, replay_rows: bool = True) -> dict[str, Any]:
        """Everything a resumed run needs to continue bit-identically (nets, targets,
        optimisers, replay, noise, counters, torch RNG); loadable with weights_only=True.
        `replay_rows` False leaves out the replay rows (see ReplayBuffer.rows_since)."""
        return {
            "obs_dim": self.obs_dim,
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "actor_target": self.actor_target.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "buffer": self.buffer.state_dict(replay_rows),
            "noise": self.noise.state_dict(),
            "transitions": self.transitions,
            "updates": self.updates,
            "torch_rng": torch.get_rng_state(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["obs_dim"] != self.obs_dim:
            raise ValueError(f"learner state has obs_dim {state['obs_dim']}, not {self.obs_dim}")
        for name in ("actor", "critic", "actor_target", "critic_target"):
            getattr(self, name).load_state_dict(state[name])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.buffer.load_state_dict(state["buffer"])
        self.noise.load_state_dict(state["noise"])
        self.transitions = state["transitions"]
        self.updates = state["updates"]
        torch.set_rng_state(state["torch_rng"])


class IndependentLearners:
    """Multi-DDPG baseline: agent slot k has its own actor, critic, buffer and noise."""

    def __init__(self, n_agents: int, obs_dim: int, config: DDPGConfig | None = None, seed: int = 0) -> None:
        self.learners = [DDPGLearner(obs_dim, config, s) for s in _seeds(seed, n_agents)]

    def _routes(self, agent_slots: Sequence[int] | np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
        """(slot, row indices) for every slot present, in slot order."""
        slots = np.asarray(agent_slots)
        for k in np.unique(slots):
            if not 0 <= k < len(self.learners):
                raise ValueError(f"agent slot {k} outside 0..{len(self.learners) - 1}")
            yield int(k), np.flatnonzero(slots == k)

    def act(self, obs: np.ndarray, agent_slots: Sequence[int] | np.ndarray, explore: bool) -> np.ndarray:
        act = np.empty((len(obs), ACT_DIM), np.float32)
        for k, rows in self._routes(agent_slots):
            act[rows] = self.learners[k].act(obs[rows], explore)
        return act

    def observe(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        rew: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
        agent_slots: Sequence[int] | np.ndarray,
    ) -> None:
        for k, rows in self._routes(agent_slots):
            self.learners[k].observe(obs[rows], act[rows], rew[rows], next_obs[rows], terminated[rows])

    def update(self, each: list[UpdateStats] | None = None) -> dict[str, float]:
        """One update per learner (the baseline's per-step budget); metrics averaged."""
        stats = [s for s in (lr.update(1, each) for lr in self.learners) if s]
        if not stats:
            return {}
        return {k: float(np.mean([s[k] for s in stats])) for k in stats[0]}

    @property
    def buffers(self) -> list[ReplayBuffer]:
        return [lr.buffer for lr in self.learners]

    @property
    def transitions(self) -> int:
        return sum(lr.transitions for lr in self.learners)

    @property
    def updates(self) -> int:
        return sum(lr.updates for lr in self.learners)

    def act_for(self, obs: np.ndarray, agent_slots: np.ndarray, explore: bool) -> np.ndarray:
        """Actions for the rows of these agent slots, each from its slot's actor."""
        return self.act(obs, agent_slots, explore)

    def learn(self, step: Transitions, updates_per_step: int | None, each: list[UpdateStats] | None) -> None:
        """Store a step's transitions with their slots' learners; one update per learner per step
        (the baseline's budget: `updates_per_step` does not apply)."""
        self.observe(step.obs, step.act, step.rew, step.next_obs, step.terminated, step.agent_slots)
        self.update(each)

    def checkpoint_states(self) -> tuple[dict, dict, dict | None]:
        """The first learner's actor and critic, and every slot's actor as extra state."""
        first = self.learners[0]
        return (
            first.actor.state_dict(),
            first.critic.state_dict(),
            {"actors": [lr.actor.state_dict() for lr in self.learners]},
        )

    def state_dict(self, replay_rows: bool = True) -> dict[str, Any]:
        return {"learners": [lr.state_dict(replay_rows) for lr in self.learners]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if len(state["learners"]) != len(self.learners):
            raise ValueError(f"state has {len(state['learners'])} learners, not {len(self.learners)}")
        for learner, sub in zip(self.learners, state["learners"], strict=True):
            learner.load_state_dict(sub)


Learner = DDPGLearner | IndependentLearners
"""Either kind: the trainer uses only what both have (`learners`, `buffers`, `act_for`, `learn`,
`checkpoint_states`, `transitions`, `updates`, `state_dict`, `load_state_dict`)."""
