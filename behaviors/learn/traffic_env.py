"""Training where the agents will drive: learned cars among SUMO's own traffic.

Each episode picks one road of a family of closed multi-lane roads (2-5 lanes, 3.0-3.75 m
lanes, curves of 300-800 m; `sumo_scenarios.training_roads`), fills it with SUMO cars at a
density and with desired speeds drawn per episode (some slow enough to be worth passing),
lets that traffic settle, then inserts the agents at free places at the speed SUMO finds
safe there: agents enter at traffic speed, as `behave populate` inserts them. The agents see
the lane observation (lanes.py), act through the traffic driver model (`actuate_lanes`) and
earn the traffic reward (rewards.traffic_rewards). Keepers and overtakers differ only by the
behaviour id and their desired speed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from behaviors.errors import BehaveError
from behaviors.fleet.drivers import TrafficDriver
from behaviors.fleet.traffic_rows import desired_speed
from behaviors.learn.env_core import (
    BACKGROUND_TYPE,
    KEEPER_TYPE,
    OVERTAKER_TYPE,
    ROAD_FAMILIES,
    TRAINING_ROADS_WITH_QUEUES,
    TRAINING_ROADS_WITH_RAMPS,
    BehaveEnv,
    EnvConfig,
    StepBatch,
)
from behaviors.road.geometry import RoadGeometry
from behaviors.road.geometry_build import load_geometry
from behaviors.road.routes import RouteGraph, RoutePool, lane_km, misplaced, route_graph
from behaviors.sumo.scenario_config import ScenarioConfig, read_sumocfg, run_as_sumocfg
from behaviors.sumo.sim import SimOptions, SumoSim
from behaviors.traffic.rewards import NO_PROGRESS_SECONDS, TrafficStep, TrafficWeights, weigh
from sumo_scenarios import Scenario, data_dir, get_scenario, route_edges, training_roads
from sumo_scenarios.build import VTYPES_FILE

SLOW_SHARE = 0.25
"""Share of SUMO's cars that drive slowly (speed factor 0.55-0.75, trucks and cautious drivers)."""
SLOW_FACTOR = (0.55, 0.75)
FAST_FACTOR = (0.8, 1.05)
WARMUP_SECONDS = 10.0
"""SUMO's cars drive alone this long before the agents enter (insertion spreads out)."""
INSERT_TRIES = 10
"""Steps an agent may wait for a free place before it sits this episode out."""
EPISODE_DRAWS = 5
"""Episodes drawn before one with room for at least one agent is given up on (NoRoomError)."""
QUEUE_GAP = 20.0
"""m: an agent this close behind its leader is queueing, not failing to make progress."""
CRAWL_EPISODES = 0.5
"""Share of `roads+queues` episodes with a queue crawling in the slow lane while the other lanes
flow, as before an exit or a merge. Without it the policy never met such a lane in training and
braked beside a queue as if its first car were the agent's leader (README, Known limitations)."""
STOP_EPISODES = 0.5
"""Share of episodes in which the traffic ahead of one agent stops in every lane of its edge and
later moves on, so that agents queue and pull away again. Without it the policy never met a standing
start and held its car on the brake while the car-following law under it would pull away
(docs/history.md)."""
STOP_AFTER_S = (5.0, 40.0)
"""When the traffic stops, seconds into the episode."""
STOP_FOR_S = (5.0, 30.0)
"""How long it stands."""
STOP_REACH = (30.0, 250.0)
"""m ahead of the agent: the nearest SUMO car in each lane in this range stops."""
CRAWL_CARS = (4, 12)
CRAWL_SPEED = (0.0, 0.2)
"""Speed of the queue as a share of the limit: from standing to about 25 km/h on a motorway."""
CRAWL_GAP = (0.0, 2.5)
"""m from one queueing car's rear to the next one's front, beyond the vType's minGap (SUMO
inserts no closer)."""


class NoRoomError(BehaveError):
    """No agent found a free place this episode (the traffic drawn was too dense): another seed may."""


def background_speed_factors(count: int, rng: np.random.Generator) -> np.ndarray:
    slow = rng.random(count) < SLOW_SHARE
    return np.where(slow, rng.uniform(*SLOW_FACTOR, count), rng.uniform(*FAST_FACTOR, count))


def queue_places(
    edge_length: float, car_length: float, min_gap: float, rng: np.random.Generator
) -> np.ndarray:
    """Front positions on one edge for a queue of cars of a vType's length and minGap, its head
    first, as many as fit."""
    cars = int(rng.integers(CRAWL_CARS[0], CRAWL_CARS[1] + 1))
    head = rng.uniform(0.5, 1.0) * (edge_length - 1.0)
    steps = car_length + min_gap + rng.uniform(*CRAWL_GAP, cars)
    fronts = head - np.concatenate(([0.0], np.cumsum(steps[:-1])))
    return fronts[fronts >= car_length + 0.5]


@dataclass(frozen=True)
class StopAndGo:
    """The traffic ahead of `agent` stops at step `stop` (or as soon after as there is traffic ahead
    on its edge) and moves on at step `go`."""

    agent: str
    stop: int
    go: int


def plan_stop_and_go(agents: list[str], step_length: float, rng: np.random.Generator) -> StopAndGo | None:
    """This episode's stop-and-go event, or None (1 - STOP_EPISODES of the episodes)."""
    if not agents or rng.random() >= STOP_EPISODES:
        return None
    stop = rng.uniform(*STOP_AFTER_S)
    go = stop + rng.uniform(*STOP_FOR_S)
    agent = agents[int(rng.integers(len(agents)))]
    return StopAndGo(agent, round(stop / step_length), round(go / step_length))


def cars_ahead_per_lane(
    lane_ids: list[str], lane_pos: np.ndarray, own_lane: str, own_pos: float, reach: tuple[float, float]
) -> list[int]:
    """Indices of the nearest car in each lane of `own_lane`'s edge whose position lies `reach`
    (near, far) metres ahead of `own_pos`."""
    edge = own_lane.rpartition("_")[0]
    nearest: dict[str, tuple[float, int]] = {}
    for k, (lane, pos) in enumerate(zip(lane_ids, lane_pos.tolist(), strict=True)):
        ahead = pos - own_pos
        in_reach = lane.rpartition("_")[0] == edge and reach[0] <= ahead <= reach[1]
        if in_reach and (lane not in nearest or ahead < nearest[lane][0]):
            nearest[lane] = (ahead, k)
    return sorted(k for _, k in nearest.values())


VTYPES = data_dir() / "common" / VTYPES_FILE
"""behave's vehicle types (agents, SUMO's background cars), added to a user's road."""


@dataclass(frozen=True)
class OwnRoad:
    """A user's road: its net, read once, and the sumocfg whose routes bring SUMO's own traffic
    (None: SUMO's cars come from the env, at the config's traffic density)."""

    name: str
    net: Path
    geometry: RoadGeometry
    graph: RouteGraph
    scenario: ScenarioConfig | None


def own_road(config: EnvConfig) -> OwnRoad:
    """The config's net or sumocfg, read and checked (BehaveError for a missing or unreadable file
    or a net without a multi-lane edge) before any SUMO runs."""
    scenario = None if config.sumocfg is None else read_sumocfg(Path(config.sumocfg))
    net = scenario.net if scenario is not None else Path(str(config.net))
    geometry = load_geometry(net, cache=True)
    name = (scenario.path if scenario is not None else net).name
    return OwnRoad(name, net, geometry, route_graph(geometry), scenario)


def own_road_options(road: OwnRoad, step_length: float, seed: int) -> SimOptions:
    """SUMO's options on a user's road: a sumocfg runs with all its own options (its files named
    again beside behave's vTypes), as `behave populate --sumocfg` runs it."""
    options = SimOptions(net=road.net, additional=(VTYPES,), step_length=step_length, seed=seed)
    return options if road.scenario is None else run_as_sumocfg(options, road.scenario)


class TrafficEnv(BehaveEnv):
    """Keepers and overtakers among SUMO's traffic (drivers that train among traffic)."""

    def __init__(self, config: EnvConfig, render_mode: str | None = None) -> None:
        config.validate()
        self.own = own_road(config) if config.own_road else None
        self.roads: list[Scenario] = (
            []
            if self.own is not None
            else training_roads(ramps=config.scenario == TRAINING_ROADS_WITH_RAMPS)
            if config.scenario in ROAD_FAMILIES
            else [get_scenario(str(config.scenario))]
        )
        self.queues = config.scenario == TRAINING_ROADS_WITH_QUEUES and self.own is None
        self._geometries: dict[str, RoadGeometry] = {}
        geometry = self.own.geometry if self.own is not None else self._geometry(self.roads[0])
        super().__init__(config, geometry, render_mode)
        self.road_name = self.own.name if self.own is not None else self.roads[0].name
        self.weights = TrafficWeights()
        self.progress = np.zeros(config.n_agents)

    def assign_behaviours(self, behaviour_ids: np.ndarray) -> None:
        """Behaviour id per slot (1 = overtaker) from the next episode on: the Gym env's multi draws
        its car's behaviour per episode."""
        if behaviour_ids.shape != self.slot_behaviour.shape:
            raise ValueError(f"expected {self.slot_behaviour.shape} behaviour ids, got {behaviour_ids.shape}")
        self.slot_behaviour = behaviour_ids.astype(float)

    def _geometry(self, road: Scenario) -> RoadGeometry:
        if road.name not in self._geometries:
            self._geometries[road.name] = load_geometry(road.net)
        return self._geometries[road.name]

    def reset_arrays(self, seed: int | None = None) -> np.ndarray:
        """A new episode on a road drawn from the family; observations [n_inserted, D] in slot order.

        Dense traffic on a short road can leave no free place for any agent: the episode is then
        drawn again (road, traffic and all), up to EPISODE_DRAWS times."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        for _ in range(EPISODE_DRAWS - 1):
            try:
                return self._start_episode()
            except NoRoomError:
                continue
        return self._start_episode()

    def _start_episode(self) -> np.ndarray:
        if self.own is None:
            self._start_on_training_road()
        else:
            self._start_on_own_road(self.own)
        sim = self.sim
        assert sim is not None
        self.steps = 0
        self.stop_and_go = plan_stop_and_go(self.agents, self.config.step_length, self._rng)
        self.stopped: list[str] = []
        vehicles = sim.read_vehicles()
        self.live_obs = self.fleet.sense(sim, vehicles, True)
        return self.live_obs

    def _start_sim(self, options: SimOptions) -> SumoSim:
        """SUMO started, or restarted (libsumo keeps one simulation per process), with `options`
        and the agents' sideways speed as their driver moves them."""
        options = replace(options, agent_max_speed_lat=self.fleet.driver.max_lateral_speed)
        if self.sim is None:
            self.sim = SumoSim(options)
        else:
            self.sim.restart(options)
        return self.sim

    def _start_on_training_road(self) -> None:
        """A road drawn from the family, looping routes filled with SUMO's cars, then the agents."""
        rng, cfg = self._rng, self.config
        self.scenario = self.roads[int(rng.integers(len(self.roads)))]
        self.road_name = self.scenario.name
        self.geometry = self._geometry(self.scenario)
        self.lap = route_edges(self.scenario)
        options = SimOptions(
            net=self.scenario.net,
            additional=(self.scenario.vtypes,),
            routes=(self.scenario.routes,),
            step_length=cfg.step_length,
            seed=int(rng.integers(2**31 - 1)),
        )
        sim = self._start_sim(options)
        routes = self._routes()
        weights = np.array([self.geometry.edges[e].length for e in self.lap])
        weights /= weights.sum()
        lanes = min(self.geometry.edges[e].lanes for e in self.lap)
        lap_km = sum(self.geometry.edges[e].length for e in self.lap) / 1000.0
        count = int(rng.uniform(*cfg.traffic_density) * lap_km * lanes)
        if self.queues and rng.random() < CRAWL_EPISODES:
            self._add_queue(routes, weights)
        self._add_traffic(count, lambda: routes[int(rng.choice(len(routes), p=weights))])
        for _ in range(int(WARMUP_SECONDS / cfg.step_length)):
            sim.step()
        self._insert_agents(routes, weights)

    def _start_on_own_road(self, road: OwnRoad) -> None:
        """The user's net with SUMO's cars at a drawn density, or the user's sumocfg with its own
        traffic; the agents on routes of multi-lane edges, put down as `behave populate` does."""
        rng, cfg = self._rng, self.config
        sim = self._start_sim(own_road_options(road, cfg.step_length, int(rng.integers(2**31 - 1))))
        drive_s = WARMUP_SECONDS + cfg.max_steps * cfg.step_length
        pool = RoutePool(road.graph, drive_s * 50.0, sim.add_route)  # long enough at 50 m/s, or a dead end
        if road.scenario is None:
            self._add_traffic(
                int(rng.uniform(*cfg.traffic_density) * lane_km(road.graph)), lambda: pool.draw(rng)
            )
        for _ in range(int(WARMUP_SECONDS / cfg.step_length)):
            sim.step()
        self._place_agents(pool)

    def _add_traffic(self, count: int, route: Callable[[], str]) -> None:
        """`count` of SUMO's cars at free places on the routes `route` draws, some of them slow."""
        sim = self.sim
        assert sim is not None
        for k, factor in enumerate(background_speed_factors(count, self._rng)):
            vid = f"traffic_{k}"
            sim.add_free_vehicle(vid, route(), BACKGROUND_TYPE)
            sim.set_speed_factor(vid, float(factor))

    def _add_queue(self, routes: list[str], weights: np.ndarray) -> None:
        """A queue in the slow lane of one edge: SUMO's cars that crawl and never change lanes, so
        the queue stays while the lanes beside it flow (it moves on around the closed road)."""
        sim, rng = self.sim, self._rng
        assert sim is not None
        k = int(rng.choice(len(self.lap), p=weights))
        edge = self.geometry.edges[self.lap[k]]
        speed = rng.uniform(*CRAWL_SPEED) * edge.speed
        for n, front in enumerate(queue_places(edge.length, *sim.vtype_size(BACKGROUND_TYPE), rng)):
            vid = f"queue_{n}"
            sim.add_vehicle(vid, routes[k], BACKGROUND_TYPE, lane=0, pos=float(front), speed=float(speed))
            sim.set_max_speed(vid, max(float(speed), 0.1))
            sim.hold_lane(vid)

    def _stop_and_go(self, sim: SumoSim) -> None:
        """Stop the traffic ahead of the event's agent, or let it move on, when the event says."""
        event = self.stop_and_go
        if event is None:
            return
        waiting = event.stop <= self.steps < event.go and not self.stopped  # the agent may be near
        if waiting and event.agent in self.agents:  # its edge's end: then it is tried again next step
            (own_lane,), (own_pos,) = sim.read_lanes([event.agent]), sim.read_lane_places([event.agent])[0]
            cars = [v for v in sim.vehicle_ids() if v.startswith("traffic_")]
            if not own_lane.startswith(":") and cars:
                rows = cars_ahead_per_lane(
                    sim.read_lanes(cars), sim.read_lane_places(cars)[0], own_lane, own_pos, STOP_REACH
                )
                self.stopped = [cars[k] for k in rows]
                sim.hold_speed(self.stopped, 0.0)
        elif self.steps == event.go:
            present = set(sim.vehicle_ids())
            sim.hold_speed([v for v in self.stopped if v in present], -1.0)
            self.stopped = []

    def _insert_agents(self, routes: list[str], weights: np.ndarray) -> None:
        """Agents at free places of the road, at the speed SUMO finds safe there."""
        sim, rng = self.sim, self._rng
        assert sim is not None
        names = self.possible_agents
        for slot, name in enumerate(names):
            sim.add_free_vehicle(
                name, routes[int(rng.choice(len(routes), p=weights))], self._vtype(slot), speed="max"
            )
        pending = set(names)
        for _ in range(INSERT_TRIES):
            sim.step()
            pending -= set(sim.vehicle_ids())
            if not pending:
                break
        sim.remove(sorted(pending))  # no free place this episode: the slot sits it out
        self._join(np.array([k for k, name in enumerate(names) if name not in pending], np.int64))

    def _place_agents(self, pool: RoutePool) -> None:
        """Agents put down as populate puts them: at free places of routes from `pool`, at the speed
        SUMO finds safe there; one SUMO did not place, or placed too close to another car or in a
        lane that runs out (routes.misplaced), is withdrawn and tried again elsewhere after the next step."""
        sim, rng = self.sim, self._rng
        assert sim is not None
        names = self.possible_agents
        waiting = list(range(len(names)))
        for _ in range(INSERT_TRIES):
            for slot in waiting:
                sim.add_free_vehicle(names[slot], pool.draw(rng), self._vtype(slot), speed="max")
            sim.step()
            vehicles = sim.read_vehicles(with_distance=False)
            placed = [slot for slot in waiting if names[slot] in vehicles.row]
            ids = [names[s] for s in placed]
            close = misplaced(sim, vehicles, self.geometry, ids)
            waiting = [s for s in waiting if names[s] not in vehicles.row]
            waiting += [s for s, near in zip(placed, close.tolist(), strict=True) if near]
            sim.remove([names[s] for s in waiting])
            if not waiting:
                break
        self._join(np.array(sorted(set(range(len(names))) - set(waiting)), np.int64))

    def _vtype(self, slot: int) -> str:
        return OVERTAKER_TYPE if self.slot_behaviour[slot] else KEEPER_TYPE

    def _join(self, slots: np.ndarray) -> None:
        """The agents of `slots`, on the road now, join the fleet under the policy's control; the
        others sit this episode out."""
        sim, rng = self.sim, self._rng
        assert sim is not None
        if not len(slots):
            raise NoRoomError(f"no agent could be inserted on {self.road_name}: traffic too dense")
        ids = [self.possible_agents[k] for k in slots]
        sim.take_control(ids)
        behaviour = self.slot_behaviour[slots]
        self.fleet = self._new_fleet()
        self.fleet.add(ids, sim.read_speeds(ids), behaviour, self.fleet.driver.draw_style(behaviour, rng))
        self.agents = ids
        self._live_slots = slots
        self.progress = np.zeros(self.config.n_agents)
        self.start_progress = np.zeros(self.config.n_agents)

    def step_arrays(self, actions: np.ndarray) -> StepBatch:
        """Act for the live agents (rows in `live_slots` order) and advance SUMO one step."""
        sim = self._check_actions(actions)
        fleet, dt = self.fleet, self.config.step_length
        slots = self._live_slots
        n = len(slots)
        assert fleet.rows.frame is not None
        desired = desired_speed(fleet.own, fleet.rows.frame.speed_limit)
        style_headway, style_eagerness = fleet.own.time_headway.copy(), fleet.own.eagerness.copy()
        before_speed, before_lateral = fleet.rows.speed.copy(), fleet.own.lateral_speed.copy()
        self._stop_and_go(sim)
        actuation = fleet.act(sim, actions)
        assert actuation.lateral_speed is not None
        contact, vehicles, present, next_obs = self._advance(sim, True)
        gap = np.full((n, 6), np.inf)
        other = np.full((n, 6), np.nan)
        deviation = np.zeros(n)
        changed = np.zeros(n, bool)
        if present.any():
            around, frame = fleet.own.around, fleet.rows.frame
            assert around is not None and frame is not None
            gap[present], other[present] = around.gap, around.other_speed
            deviation[present] = frame.lane_deviation
            changed[present] = fleet.own.lane_changed
        collided = np.zeros(n, bool)
        collided[present] = fleet.involved(vehicles, contact)
        off_track = actuation.off_track & present
        queueing = gap[:, 0] < QUEUE_GAP
        no_progress = (self._slow_time(present) >= NO_PROGRESS_SECONDS) & present & ~queueing
        speed = actuation.speed
        step = TrafficStep(
            speed=speed,
            desired_speed=desired,
            acceleration=(speed - before_speed) / dt,
            lateral_acceleration=(actuation.lateral_speed - before_lateral) / dt,
            lane_deviation=deviation,
            lane_changed=changed,
            behaviour_id=self.slot_behaviour[slots],
            gap=gap,
            other_speed=other,
            collided=collided,
            off_track=off_track,
            no_progress=no_progress,
            time_headway=style_headway,
            eagerness=style_eagerness,
        )
        driver = fleet.driver
        assert isinstance(driver, TrafficDriver)  # the drivers that train among traffic
        terms = weigh(driver.rewards(step, self.weights), self.config.reward_weights)
        terminated = collided | off_track | no_progress
        truncated = ~terminated & (~present | (self.steps >= self.config.max_steps))
        self._leave(slots, present, terminated | truncated, contact)
        self.live_obs = next_obs[~(terminated | truncated)]
        self.progress[slots] += speed * dt
        return StepBatch(
            slots, next_obs, terms.total, terms, terminated, truncated, collided, off_track, no_progress,
            speed, deviation,
        )  # fmt: skip
