"""The environments' front door: `make_env`/`create_env` pick the environment a config describes,
and the names callers pass to them or get back.

Imports run one way: env_core (config, step batch, the base class) <- paper_env, traffic_env <- env.
"""

from __future__ import annotations

from behaviors.drivers import make_driver
from behaviors.env_core import (
    BEHAVIOURS,
    KEEPER_TYPE,
    OVERTAKER_TYPE,
    ROAD_FAMILIES,
    TRAINING_ROADS,
    BehaveEnv,
    EnvConfig,
    StepBatch,
)
from behaviors.paper_env import PaperEnv
from behaviors.traffic_env import TrafficEnv
from sumo_scenarios import Scenario

__all__ = [
    "BEHAVIOURS",
    "KEEPER_TYPE",
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
    scenario: str | Scenario = "ring",
    *,
    behaviour: str = "lanekeeping",
    agents: int = 6,
    overtakers: int = 0,
    keepers: int = 0,
    placement: str = "C",
    opponents: int | None = None,
    seed: int | None = None,
    max_steps: int = 1000,
    step_length: float = 0.2,
    start_speed: float | None = None,
    lane_weight: float = 0.0,
    shield: bool = False,
    driver: str = "paper",
    render_mode: str | None = None,
) -> BehaveEnv:
    """A native PettingZoo ParallelEnv with a batched array interface for trainers.

    `driver="traffic"` (scenario "roads" or "ring"): agents among SUMO's traffic with the lane
    observation and the traffic reward (see traffic_env.py)."""
    return create_env(
        EnvConfig(
            scenario=scenario,
            behaviour=behaviour,
            agents=agents,
            overtakers=overtakers,
            keepers=keepers,
            placement=placement,
            opponents=opponents,
            seed=seed,
            max_steps=max_steps,
            step_length=step_length,
            start_speed=start_speed,
            lane_weight=lane_weight,
            shield=shield,
            driver=driver,
        ),
        render_mode,
    )


def create_env(config: EnvConfig, render_mode: str | None = None) -> BehaveEnv:
    """The environment a config describes: the paper's scenarios, or agents among traffic for the
    drivers that train there."""
    env_class = TrafficEnv if make_driver(config.driver).among_traffic else PaperEnv
    return env_class(config, render_mode)
