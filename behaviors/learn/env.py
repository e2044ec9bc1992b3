"""The environments' front door: `make_env`/`create_env` pick the environment a config describes,
and the names callers pass to them or get back.

Imports run one way: env_core (config, step batch, the base class) <- paper_env, traffic_env <- env.
"""

from __future__ import annotations

from typing import Any

from behaviors.fleet.drivers import make_driver
from behaviors.learn.env_core import (
    BEHAVIOURS,
    KEEPER_TYPE,
    LORRY_TYPE,
    OVERTAKER_TYPE,
    ROAD_FAMILIES,
    TRAINING_ROADS,
    BehaveEnv,
    EnvConfig,
    StepBatch,
)
from behaviors.learn.paper_env import PaperEnv
from behaviors.learn.traffic_env import TrafficEnv
from sumo_scenarios import Scenario

__all__ = [
    "BEHAVIOURS",
    "KEEPER_TYPE",
    "LORRY_TYPE",
    "OVERTAKER_TYPE",
    "ROAD_FAMILIES",
    "TRAINING_ROADS",
    "BehaveEnv",
    "EnvConfig",
    "PaperEnv",
    "StepBatch",
    "TrafficEnv",
    "create_env",
    "make_env",
]


def make_env(
    scenario: str | Scenario = "ring", *, render_mode: str | None = None, **settings: Any
) -> BehaveEnv:
    """A native PettingZoo ParallelEnv with a batched array interface for trainers.

    `settings`: any EnvConfig field by name (behaviour, agents, overtakers, keepers, seed, max_steps,
    driver, ...), with EnvConfig's defaults. `driver="traffic"` (scenario "roads" or "ring"): agents
    among SUMO's traffic with the lane observation and the traffic reward (see traffic_env.py)."""
    return create_env(EnvConfig(scenario=scenario, **settings), render_mode)


def create_env(config: EnvConfig, render_mode: str | None = None) -> BehaveEnv:
    """The environment a config describes: the paper's scenarios, or agents among traffic for the
    drivers that train there."""
    env_class = TrafficEnv if make_driver(config.driver).among_traffic else PaperEnv
    return env_class(config, render_mode)
