"""Faults of training and of the env found as a new user would (issue 10): real SUMO, real signals."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from behaviors import make_env
from behaviors.control import AgentRows, RoadFrame
from behaviors.sensors import SLICES


def hold_lane(obs: np.ndarray) -> np.ndarray:
    """Steer back to where the car is, full throttle: drives to the end of a straight road."""
    angle = obs[:, SLICES["angle"]][:, 0] * np.pi
    return np.stack([np.clip(-4 * angle, -1, 1), np.ones(len(obs)), np.zeros(len(obs))], 1).astype(np.float32)


@pytest.mark.parametrize("scenario", ["tiny", "highway"])
def test_the_last_agent_reaching_the_end_of_a_non_looping_road_ends_the_episode(scenario):
    env = make_env(scenario, agents=1, seed=1, max_steps=5000, start_speed=25.0)
    try:
        env.reset_arrays(1)
        last = None
        while env.agents:
            last = env.step_arrays(hold_lane(env.live_obs))
        assert last is not None and bool(last.truncated[0]) and not last.terminated[0]
        assert env.steps < 5000  # it left at the road's end, not at the time limit
    finally:
        env.close()


def test_taking_agent_rows_keeps_every_per_agent_field_in_step():
    n = 3
    frame = RoadFrame(*(np.arange(float(n)) for _ in fields(RoadFrame)))
    rows = AgentRows(
        ids=["a", "b", "c"], speed=np.arange(3.0), angle=np.zeros(n), slow_time=np.zeros(n),
        behaviour_id=np.zeros(n, np.float32), vehicle_rows=np.array([5, 6, 7]), frame=frame,
        side_limit=np.zeros((n, 2)), speed_cap=np.zeros(n),
    )  # fmt: skip
    kept = rows.take(np.array([True, False, True]))
    assert kept.ids == ["a", "c"] and list(kept.vehicle_rows) == [5, 7]
    for f in fields(AgentRows):
        assert f.name == "frame" or len(getattr(kept, f.name)) == 2, f.name
    assert all(len(getattr(kept.frame, f.name)) == 2 for f in fields(RoadFrame))
