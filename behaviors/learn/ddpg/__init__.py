"""DDPG learner for behave: shared (PS-DDPG) and independent (multi-DDPG) variants."""

from behaviors.learn.ddpg.buffer import Batch, ReplayBuffer
from behaviors.learn.ddpg.checkpoint import (
    Checkpoint,
    load_actor,
    load_checkpoint,
    save_actor_only,
    save_checkpoint,
)
from behaviors.learn.ddpg.learner import (
    DDPGConfig,
    DDPGLearner,
    IndependentLearners,
    critic_targets,
    soft_update,
)
from behaviors.learn.ddpg.networks import Actor, Critic
from behaviors.learn.ddpg.noise import OUNoise

__all__ = [
    "Actor",
    "Batch",
    "Checkpoint",
    "Critic",
    "DDPGConfig",
    "DDPGLearner",
    "IndependentLearners",
    "OUNoise",
    "ReplayBuffer",
    "critic_targets",
    "load_actor",
    "load_checkpoint",
    "save_actor_only",
    "save_checkpoint",
    "soft_update",
]
