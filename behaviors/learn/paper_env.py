"""The paper's training episodes: learned cars (and passive slower cars to overtake) inserted in
a staggered start formation on a bundled scenario, scored by the paper's reward (rewards.step_rewards).
"""

from __future__ import annotations

import numpy as np

from behaviors.errors import BehaveError
from behaviors.learn.env_core import (
    KEEPER_TYPE,
    OVERTAKER_TYPE,
    PASSIVE_TYPE,
    BehaveEnv,
    EnvConfig,
    StepBatch,
)
from behaviors.road.geometry_build import load_geometry
from behaviors.sumo.sim import SimOptions, SumoSim, VehicleState
from behaviors.traffic.rewards import NO_PROGRESS_SECONDS, race_positions, step_rewards, weigh
from sumo_scenarios import Scenario, get_scenario, route_edges

PASSIVE_SPEED = 20.0
"""m/s: maxSpeed of the behave_passive vType (the slower cars to overtake)."""
START_SPEED_FRACTION = 0.7
START_HEADWAY = 1.5
"""Seconds of headway between start places at speed (plus two car lengths)."""


def formation(n_opponents: int, n_agents: int, lanes: int, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Start places, front to back: metres behind the front car and lane offsets.

    Passive cars go ahead, two spacings apart and one lane over each time, so
    they never form a rolling wall across all lanes (overtaking stays possible);
    agents follow one spacing behind them, staggered: each next car a lane over
    and spacing/lanes further back (so cars in the same lane are `spacing` apart).
    """
    opponents = np.arange(n_opponents) * 2 * spacing
    start = opponents[-1] + 2 * spacing if n_opponents else 0.0
    agents = start + np.arange(n_agents) * spacing / lanes
    lanes_used = np.concatenate([np.arange(n_opponents), np.arange(n_agents)])
    return np.concatenate([opponents, agents]), lanes_used


class PaperEnv(BehaveEnv):
    """The paper's episodes: N learned cars (and optional passive SUMO cars) in a start formation
    on a bundled scenario."""

    def __init__(self, config: EnvConfig, render_mode: str | None = None) -> None:
        config.validate()
        scenario = config.scenario if isinstance(config.scenario, Scenario) else get_scenario(config.scenario)
        self.scenario, self.lap = scenario, route_edges(scenario)
        super().__init__(config, load_geometry(scenario.net), render_mode)
        self._check_capacity()

    def reset_arrays(self, seed: int | None = None) -> np.ndarray:
        """Start an episode; returns observations [n_agents, D] in slot order."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        options = self._sim_options(int(self._rng.integers(2**31 - 1)))
        if self.sim is None:
            self.sim = SumoSim(options)
        else:
            self.sim.restart(options)
        self._populate()
        self.steps = 0
        vehicles = self.sim.read_vehicles()
        self.live_obs = self.fleet.sense(self.sim, vehicles, self.config.behaviour == "multi")
        self._update_progress(vehicles, self._live_slots)
        return self.live_obs

    def step_arrays(self, actions: np.ndarray) -> StepBatch:
        """Act for the live agents (rows in `live_slots` order) and advance SUMO one step."""
        sim, fleet = self._check_actions(actions), self.fleet
        slots = self.live_slots
        actuation = None if self.config.sumo_drives else fleet.act(sim, actions)
        contact, vehicles, present, next_obs = self._advance(sim, self.config.behaviour == "multi")
        self._update_progress(vehicles, slots[present])
        if actuation is None:
            speed, angle, off_track = (
                self._follow_sumo(present),
                np.zeros(len(slots)),
                np.zeros(len(slots), bool),
            )
        else:
            speed, angle, off_track = actuation.speed, actuation.angle, actuation.off_track & present
        collided = np.zeros(len(slots), bool)
        collided[present] = fleet.involved(vehicles, contact)
        no_progress = (self._slow_time(present) >= NO_PROGRESS_SECONDS) & present
        race = race_positions(self.progress)[slots]
        lane_deviation = np.zeros(len(slots))
        if fleet.frame is not None and present.any():
            lane_deviation[present] = fleet.frame.lane_deviation
        raw = step_rewards(
            speed,
            angle,
            self.slot_behaviour[slots],
            race,
            len(self.progress),
            collided,
            off_track,
            no_progress,
            lane_deviation,
            self.config.lane_weight,
        )
        terms = weigh(raw, self.config.reward_weights)
        terminated = collided | off_track | no_progress
        truncated = ~terminated & (~present | (self.steps >= self.config.max_steps))
        self._leave(slots, present, terminated | truncated, contact)
        self.live_obs = next_obs[~(terminated | truncated)]
        return StepBatch(
            slots,
            next_obs,
            terms.total,
            terms,
            terminated,
            truncated,
            collided,
            off_track,
            no_progress,
            speed,
            lane_deviation,
        )

    # --- internals --------------------------------------------------------------------
    def _sim_options(self, seed: int) -> SimOptions:
        s = self.scenario
        return SimOptions(
            net=s.net,
            additional=(s.vtypes,),
            routes=(s.routes,),
            step_length=self.config.step_length,
            seed=seed,
            extra=self.sim_extra,
        )

    def _check_capacity(self) -> None:
        lanes = max(info.lanes for info in self.geometry.edges.values() if info.normal)
        cars = self.config.n_agents + self.config.n_opponents
        spacing = self._spacing(self._max_start_speed())
        needed = self._formation_length(cars, lanes, spacing)
        route_length = sum(self.geometry.edges[e].length for e in self.lap)
        usable = route_length * (0.9 if self.scenario.looping else 0.5)
        if needed > usable:
            most = int(usable / spacing * lanes)
            raise BehaveError(
                f"{cars} cars do not fit on scenario '{self.scenario.name}' "
                f"({route_length:.0f} m, {lanes} lanes, {spacing:.0f} m spacing at the start speed): "
                f"at most about {most}"
            )

    def _spacing(self, speed: float) -> float:
        """Same-lane distance between start places: the configured spacing, or more at speed
        (SUMO refuses to insert a car closer than a safe gap behind another)."""
        return max(self.config.spacing, START_HEADWAY * speed + 2 * self.config.car.length)

    def _formation_length(self, cars: int, lanes: int, spacing: float) -> float:
        behind, _ = formation(self.config.n_opponents, cars - self.config.n_opponents, lanes, spacing)
        return float(behind.max(initial=0.0)) + 2 * spacing

    def _populate(self) -> None:
        """Insert passive cars ahead and the agents behind them in a staggered formation."""
        sim, cfg = self.sim, self.config
        assert sim is not None
        lanes = min(self.geometry.edges[e].lanes for e in self.lap)
        lap_length = sum(self.geometry.edges[e].length for e in self.lap)
        cars = cfg.n_opponents + cfg.n_agents
        speed = self._start_speed()
        spacing = self._spacing(speed)
        behind, lane_of = formation(cfg.n_opponents, cfg.n_agents, lanes, spacing)
        if self.scenario.looping:
            front = float(self._rng.uniform(0, lap_length))
        else:
            front = self._formation_length(cars, lanes, spacing)
        first_lane = int(self._rng.integers(lanes))
        names = self.possible_agents
        routes = self._routes()
        self.start_progress = np.zeros(cars)
        vids, types = [], []
        for k in range(cars):  # formation order: front (opponents) to back
            at = front - behind[k]
            is_agent = k >= cfg.n_opponents
            slot = k - cfg.n_opponents
            vid = names[slot] if is_agent else f"passive_{k}"
            vtype = (
                (OVERTAKER_TYPE if self.slot_behaviour[slot] else KEEPER_TYPE) if is_agent else PASSIVE_TYPE
            )
            edge_index, pos = self._locate(at % lap_length if self.scenario.looping else at)
            lane = int(first_lane + lane_of[k]) % lanes
            v0 = speed if is_agent else min(speed, PASSIVE_SPEED)
            sim.add_vehicle(vid, routes[edge_index], vtype, lane=lane, pos=pos, speed=v0)
            self.start_progress[k] = at
            vids.append(vid)
            types.append(is_agent)
        agent_ids = [v for v, a in zip(vids, types, strict=True) if a]
        if cfg.sumo_drives:
            sim.react_every_step(agent_ids)
        else:
            sim.take_control(agent_ids)
        sim.step()
        missing = set(vids) - set(sim.vehicle_ids())
        if missing:
            raise BehaveError(f"SUMO could not insert {len(missing)} cars (spacing too small for the road)")
        self.passive_ids = vids[: cfg.n_opponents]
        self._passive_on_road = set(self.passive_ids)
        self.agents = list(agent_ids)
        self._live_slots = np.arange(len(agent_ids))
        self.fleet = self._new_fleet()
        self.fleet.add(agent_ids, np.full(len(agent_ids), speed), self.slot_behaviour)
        self.progress = self.start_progress.copy()
        self._car_row = {vid: k for k, vid in enumerate(vids)}

    def _max_start_speed(self) -> float:
        if self.config.start_speed is not None:
            return self.config.start_speed
        return START_SPEED_FRACTION * min(self.geometry.edges[e].speed for e in self.lap)

    def _start_speed(self) -> float:
        """The configured start speed, or one drawn in [0, 0.7 x limit] so that policies learn to
        take over at any speed (populate inserts agents at traffic speed)."""
        if self.config.start_speed is not None:
            return self.config.start_speed
        return float(self._rng.uniform(0.0, self._max_start_speed()))

    def _locate(self, distance: float) -> tuple[int, float]:
        """Route edge index and front position for a distance along the lap, kept clear of junctions."""
        for k, edge in enumerate(self.lap):
            length = self.geometry.edges[edge].length
            if distance < length or k == len(self.lap) - 1:
                return k, float(np.clip(distance, self.config.car.length + 0.5, length - 0.5))
            distance -= length
        raise AssertionError("unreachable")

    def _update_progress(self, vehicles: VehicleState, sensed_slots: np.ndarray) -> None:
        """Progress along the route of every scenario car: start position plus odometer.

        The agents just sensed come with their vehicle rows (no per-car lookup); only the few
        passive cars are looked up by id.
        """
        cars = self.config.n_opponents + sensed_slots
        self.progress[cars] = self.start_progress[cars] + vehicles.distance[self.fleet.vehicle_rows]
        for k, vid in enumerate(self.passive_ids):
            row = vehicles.row.get(vid)
            if row is not None:
                self.progress[k] = self.start_progress[k] + vehicles.distance[row]

    def _follow_sumo(self, present: np.ndarray) -> np.ndarray:
        """Baseline: take the speeds SUMO chose (heading stays along the lane)."""
        sim, fleet = self.sim, self.fleet
        assert sim is not None
        fleet.record_speed(sim.read_speeds(fleet.ids))
        speed = np.zeros(len(present))
        speed[present] = fleet.speed
        return speed
