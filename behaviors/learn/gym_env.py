"""Gymnasium single-agent entry: one learned car among SUMO's traffic.

    import gymnasium
    import behaviors.learn.gym_env  # registers behave/Traffic-v0

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

from behaviors.errors import BehaveError
from behaviors.learn.env import ROAD_FAMILIES, TRAINING_ROADS, EnvConfig, make_env
from behaviors.learn.traffic_env import NoRoomError, TrafficEnv
from behaviors.report.render import RENDER_MODES
from behaviors.road.geometry import RoadGeometry
from behaviors.road.routes import RouteGraph, route_graph
from behaviors.sumo.sim import SumoSim

ENV_ID = "behave/Traffic-v0"
SCENARIOS = (*ROAD_FAMILIES, "ring")
BEHAVIOURS = ("lanekeeping", "overtaking", "multi")
"""multi: the car is a keeper or an overtaker, drawn per episode from the env's seeded generator."""
DRAWN = ("lanekeeping", "overtaking")
"""What multi draws from, by behaviour id (0 keeper, 1 overtaker)."""
ONE_CAR = ("agents", "overtakers", "keepers", "placement", "driver")
"""EnvConfig fields the Gym env sets itself: one car of the traffic driver."""
RESET_TRIES = 10
"""Episodes drawn before giving up when traffic leaves the car no free place to enter, or no place
with room ahead for its episode."""
MIN_RUN_S = 20.0
"""s: the car starts only where its route leaves room for this long at the start edge's speed limit
(or for the whole episode, if shorter), so that no episode ends a few steps after it begins
(docs/history.md)."""
ROOM_SHARE = 0.5
"""... but never more room than this share of the longest drive the road offers from any edge's start
(a short road has no place with 20 s ahead)."""


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
        self._longest: dict[str, float] = {}  # per road: longest_drive, as far as it matters
        self.render_mode = render_mode
        self.observation_space = env.observation_space("agent_0")
        self.action_space = env.action_space("agent_0")

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """A new episode; a draw with no free place for the car, or with too little road ahead of it for
        its episode (MIN_RUN_S), is redrawn with the next seed."""
        super().reset(seed=seed)
        behaviour = self.behaviour
        if behaviour == "multi":
            behaviour_id = int(self.np_random.integers(len(DRAWN)))
            self.traffic.assign_behaviours(np.array([float(behaviour_id)]))
            behaviour = DRAWN[behaviour_id]
        short = 0
        for attempt in range(RESET_TRIES):
            try:
                obs = self.traffic.reset_arrays(None if seed is None else seed + attempt)
            except NoRoomError:
                continue
            if self._room_ahead() < self._room_needed():
                short += 1
                continue
            return observation(obs[0]), {"road": self.traffic.road_name, "behaviour": behaviour}
        if short:
            raise BehaveError(
                f"no place for the car with room ahead for its episode in {RESET_TRIES} draws "
                f"({short} too near the end of the road, {RESET_TRIES - short} with no free place)"
            )
        raise BehaveError(f"no free place for the car in {RESET_TRIES} episodes: traffic too dense")

    def _room_ahead(self) -> float:
        """Metres left on the car's route from where it was put down."""
        traffic = self.traffic
        assert traffic.sim is not None
        return room_ahead(traffic.sim, traffic.geometry, traffic.agents[0])

    def _room_needed(self) -> float:
        """Metres of route the car must have ahead at the start: MIN_RUN_S (or the episode, if shorter)
        at its edge's limit, at most ROOM_SHARE of the longest drive on this road."""
        traffic = self.traffic
        assert traffic.sim is not None
        config = traffic.config
        lane = traffic.sim.read_lanes(traffic.agents[:1])[0]
        edge = traffic.geometry.edges.get(lane.rpartition("_")[0])
        limit = edge.speed if edge is not None else max(e.speed for e in traffic.geometry.edges.values())
        need = min(MIN_RUN_S, config.max_steps * config.step_length) * limit
        road = traffic.road_name
        if road not in self._longest:
            self._longest[road] = longest_drive(route_graph(traffic.geometry), need / ROOM_SHARE)
        return min(need, ROOM_SHARE * self._longest[road])

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


def room_ahead(sim: SumoSim, geometry: RoadGeometry, vid: str) -> float:
    """Metres `vid` can still drive along its route: the rest of its edge and the edges after it
    (junctions left out; an internal lane counts from the next edge)."""
    (lane,), (pos,) = sim.read_lanes([vid]), sim.read_lane_places([vid])[0]
    edges = geometry.edges
    here = edges.get(lane.rpartition("_")[0])
    rest = max(here.length - float(pos), 0.0) if here is not None else 0.0
    return rest + sum(edges[e].length for e in sim.route_ahead(vid) if e in edges)


def longest_drive(graph: RouteGraph, cap: float) -> float:
    """The longest drive along the multi-lane edges from any edge's start (as routes.RoutePool walks
    them), counted up to `cap` metres (loops make it endless)."""
    if not graph.edges:
        return 0.0
    source = np.array([k for k, ahead in enumerate(graph.successors) for _ in ahead], np.int64)
    target = np.array([t for ahead in graph.successors for t in ahead], np.int64)
    reach = np.minimum(graph.length.astype(float), cap)
    rounds = len(graph.edges) + int(cap / max(float(graph.length.min()), 1.0)) + 1
    for _ in range(rounds):  # each round extends the drives by one edge, until none grows
        best = np.zeros(len(reach))
        np.maximum.at(best, source, reach[target])
        grown = np.minimum(graph.length + best, cap)
        if np.array_equal(grown, reach):
            break
        reach = grown
    return float(reach.max())


def observation(row: np.ndarray) -> np.ndarray:
    """A fresh float32 copy: callers keep observations, the env reuses its arrays."""
    return np.array(row, np.float32)


gymnasium.register(id=ENV_ID, entry_point=f"{__name__}:TrafficGymEnv")
