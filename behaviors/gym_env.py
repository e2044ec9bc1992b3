"""Gymnasium single-agent entry: one learned car among SUMO's traffic.

    import gymnasium
    import behaviors.gym_env  # registers behave/Traffic-v0

    env = gymnasium.make("behave/Traffic-v0", scenario="roads", behaviour="lanekeeping")

A thin wrapper over the traffic env (traffic_env.py) with one agent: the 26-value lane
observation, (steer, accel, brake) actions and the traffic reward. libsumo runs one simulation
per process: close an env before another one resets (or use one process per env).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from behaviors.env import ROAD_FAMILIES, TRAINING_ROADS, make_env
from behaviors.errors import BehaveError
from behaviors.render import RENDER_MODES
from behaviors.traffic_env import NoRoomError, TrafficEnv

ENV_ID = "behave/Traffic-v0"
SCENARIOS = (*ROAD_FAMILIES, "ring")
BEHAVIOURS = ("lanekeeping", "overtaking")
RESET_TRIES = 10
"""Episodes drawn before giving up when traffic leaves the car no free place to enter."""


class TrafficGymEnv(gymnasium.Env):
    """One keeper or overtaker among SUMO's cars on the training roads (or the ring)."""

    metadata: dict[str, Any] = {"render_modes": list(RENDER_MODES), "render_fps": 5}  # noqa: RUF012 (gymnasium's type)

    def __init__(
        self,
        scenario: str = TRAINING_ROADS,
        behaviour: str = "lanekeeping",
        max_steps: int = 1000,
        step_length: float = 0.2,
        render_mode: str | None = None,
    ) -> None:
        if scenario not in SCENARIOS:
            raise BehaveError(f"unknown scenario '{scenario}' (choose from {', '.join(SCENARIOS)})")
        if behaviour not in BEHAVIOURS:
            raise BehaveError(f"unknown behaviour '{behaviour}' (choose from {', '.join(BEHAVIOURS)})")
        env = make_env(
            scenario,
            behaviour=behaviour,
            agents=1,
            driver="traffic",
            max_steps=max_steps,
            step_length=step_length,
            render_mode=render_mode,
        )
        assert isinstance(env, TrafficEnv)
        self.traffic = env
        self.render_mode = render_mode
        self.observation_space = env.observation_space("agent_0")
        self.action_space = env.action_space("agent_0")

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """A new episode; a draw with no free place for the car is redrawn with the next seed."""
        super().reset(seed=seed)
        for attempt in range(RESET_TRIES):
            try:
                obs = self.traffic.reset_arrays(None if seed is None else seed + attempt)
            except NoRoomError:
                continue
            return observation(obs[0]), {"road": self.traffic.scenario.name}
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


def observation(row: np.ndarray) -> np.ndarray:
    """A fresh float32 copy: callers keep observations, the env reuses its arrays."""
    return np.array(row, np.float32)


gymnasium.register(id=ENV_ID, entry_point=f"{__name__}:TrafficGymEnv")
