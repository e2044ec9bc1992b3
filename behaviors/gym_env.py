"""Gymnasium single-agent entry: one learned car among SUMO's traffic.

    import gymnasium
    import behaviors.gym_env  # registers behave/Traffic-v0

    env = gymnasium.make("behave/Traffic-v0", scenario="roads", behaviour="lanekeeping")
    env = gymnasium.make("behave/Traffic-v0", net="my.net.xml", behaviour="multi")

A thin wrapper over the traffic env (traffic_env.py) with one agent: the 27-value lane
observation (the behaviour id last), (steer, accel, brake) actions and the traffic reward.
libsumo runs one simulation per process: close an env before another one resets (or use one
process per env).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium
import numpy as np

from behaviors.env import ROAD_FAMILIES, TRAINING_ROADS, EnvConfig, make_env
from behaviors.errors import BehaveError
from behaviors.render import RENDER_MODES
from behaviors.traffic_env import NoRoomError, TrafficEnv

ENV_ID = "behave/Traffic-v0"
SCENARIOS = (*ROAD_FAMILIES, "ring")
BEHAVIOURS = ("lanekeeping", "overtaking", "multi")
"""multi: the car is a keeper or an overtaker, drawn per episode from the env's seeded generator."""
DRAWN = ("lanekeeping", "overtaking")
"""What multi draws from, by behaviour id (0 keeper, 1 overtaker)."""
ONE_CAR = ("agents", "overtakers", "keepers", "placement", "driver")
"""EnvConfig fields the Gym env sets itself: one car of the traffic driver."""
RESET_TRIES = 10
"""Episodes drawn before giving up when traffic leaves the car no free place to enter."""


class TrafficGymEnv(gymnasium.Env):
    """One keeper or overtaker among SUMO's cars on the training roads (or the ring)."""

    metadata: dict[str, Any] = {"render_modes": list(RENDER_MODES), "render_fps": 5}  # noqa: RUF012 (gymnasium's type)

    def __init__(
        self,
        scenario: str = TRAINING_ROADS,
        behaviour: str = "lanekeeping",
        render_mode: str | None = None,
        **settings: Any,
    ) -> None:
        """`settings`: EnvConfig fields by name (max_steps, step_length, net, sumocfg, reward_weights,
        traffic_density, ...); with net or sumocfg the car drives the user's road, not `scenario`."""
        if scenario not in SCENARIOS:
            raise BehaveError(f"unknown scenario '{scenario}' (choose from {', '.join(SCENARIOS)})")
        if behaviour not in BEHAVIOURS:
            raise BehaveError(f"unknown behaviour '{behaviour}' (choose from {', '.join(BEHAVIOURS)})")
        check_settings(settings)
        counts = {"overtakers": 1} if behaviour == "multi" else {"agents": 1}
        env = make_env(
            scenario, behaviour=behaviour, driver="traffic", render_mode=render_mode, **counts, **settings
        )
        assert isinstance(env, TrafficEnv)
        self.traffic = env
        self.behaviour = behaviour
        self.render_mode = render_mode
        self.observation_space = env.observation_space("agent_0")
        self.action_space = env.action_space("agent_0")

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """A new episode; a draw with no free place for the car is redrawn with the next seed."""
        super().reset(seed=seed)
        behaviour = self.behaviour
        if behaviour == "multi":
            behaviour_id = int(self.np_random.integers(len(DRAWN)))
            self.traffic.assign_behaviours(np.array([float(behaviour_id)]))
            behaviour = DRAWN[behaviour_id]
        for attempt in range(RESET_TRIES):
            try:
                obs = self.traffic.reset_arrays(None if seed is None else seed + attempt)
            except NoRoomError:
                continue
            return observation(obs[0]), {"road": self.traffic.road_name, "behaviour": behaviour}
        raise BehaveError(f"no free place for the car in {RESET_TRIES} episodes: traffic too dense")

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        batch = self.traffic.step_arrays(np.asarray(action, np.float32).reshape(1, 3))
        info = {name: float(value[0]) for name, value in batch.terms.as_dict().items()}
        return (
            observation(batch.next_obs[0]),
            float(batch.reward[0]),
            bool(batch.terminated[0]),
            bool(batch.truncated[0]),
            info,
        )

    def render(self) -> Any:  # gymnasium types frames with a free TypeVar; this is an RGB array or None
        return self.traffic.render()

    def close(self) -> None:
        """Ends the SUMO simulation, so that another env may start one in this process."""
        self.traffic.close()


def check_settings(settings: dict[str, Any]) -> None:
    """BehaveError for a setting EnvConfig does not have (a misspelling) or one the Gym env owns."""
    fields = {f.name for f in dataclasses.fields(EnvConfig)}
    unknown = sorted(set(settings) - fields)
    if unknown:
        raise BehaveError(
            f"unknown setting {', '.join(map(repr, unknown))} (EnvConfig has {', '.join(sorted(fields))})"
        )
    owned = sorted(set(settings) & set(ONE_CAR))
    if owned:
        raise BehaveError(
            f"the Gym env drives one car of the traffic driver: {', '.join(owned)} cannot be set"
        )


def observation(row: np.ndarray) -> np.ndarray:
    """A fresh float32 copy: callers keep observations, the env reuses its arrays."""
    return np.array(row, np.float32)


gymnasium.register(id=ENV_ID, entry_point=f"{__name__}:TrafficGymEnv")
