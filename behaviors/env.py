"""The training environment: N learned cars on a SUMO road, as a PettingZoo ParallelEnv.

Two interfaces on one object:
* PettingZoo's dict-per-agent `reset`/`step` (agents leave and never return);
* `reset_arrays`/`step_arrays` for the trainer: one array of observations for all
  live agents, one array of actions in, no per-agent conversion.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from behaviors.actuation import CarModel
from behaviors.control import Fleet
from behaviors.drivers import DRIVERS, make_driver
from behaviors.errors import BehaveError
from behaviors.geometry import RoadGeometry, load_geometry
from behaviors.render import RENDER_MODES, check_render_mode, top_down
from behaviors.rewards import (
    NO_PROGRESS_SECONDS,
    StepTerms,
    race_positions,
    step_rewards,
)
from behaviors.sim import SimOptions, SumoSim, VehicleState
from behaviors.timing import PhaseTimer
from sumo_scenarios import SCENARIO_NAMES, Scenario, get_scenario, route_edges

BEHAVIOURS = ("lanekeeping", "overtaking", "multi")
PLACEMENTS = ("A", "B", "C")
KEEPER_TYPE = "behave_keeper"
OVERTAKER_TYPE = "behave_overtaker"
PASSIVE_TYPE = "behave_passive"
BACKGROUND_TYPE = "behave_background"
PASSIVE_SPEED = 20.0
"""m/s: maxSpeed of the behave_passive vType (the slower cars to overtake)."""
START_SPEED_FRACTION = 0.7
START_HEADWAY = 1.5
"""Seconds of headway between start places at speed (plus two car lengths)."""
TRAINING_ROADS = "roads"
"""Scenario name of the five closed roads the traffic driver trains on (the shipped policy's)."""
TRAINING_ROADS_WITH_RAMPS = "roads+ramps"
"""All seven training roads: the five and two more with an on-ramp and an exit."""
TRAINING_ROADS_WITH_QUEUES = "roads+queues"
"""The five closed roads, and in some episodes a queue crawling in the slow lane beside the flow."""
ROAD_FAMILIES = (TRAINING_ROADS, TRAINING_ROADS_WITH_RAMPS, TRAINING_ROADS_WITH_QUEUES)
ROUTE_SECONDS = 3600.0
"""Looping routes are unrolled for at least this much driving at 50 m/s."""


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines an episode; `validate` names any impossible combination."""

    scenario: str | Scenario = "ring"  # a bundled name, or a Scenario built by sumo_scenarios.build_ring
    behaviour: str = "lanekeeping"
    agents: int = 6
    overtakers: int = 0
    keepers: int = 0
    placement: str = "C"
    opponents: int | None = None  # passive slower cars ahead; None: as many as agents (overtaking), 0 (multi)
    max_steps: int = 1000
    step_length: float = 0.2
    spacing: float = 30.0  # metres between consecutive cars in the same lane at the start
    start_speed: float | None = None  # m/s for every car at the start; None: drawn per episode
    seed: int | None = None
    sumo_drives: bool = False  # reference baseline: SUMO's Krauss + SL2015 drive the "agents"
    lane_weight: float = 0.0  # lane-discipline reward term (0 = the paper's reward), see rewards.py
    shield: bool = False  # populate's safety shield (shield.py): to evaluate a policy as populate drives it
    driver: str = "paper"  # "paper": TORCS state + the paper's reward; "traffic": lanes among SUMO traffic
    traffic_density: tuple[float, float] = (4.0, 30.0)  # traffic driver: SUMO cars per lane-km, drawn
    car: CarModel = field(default_factory=CarModel)

    def validate(self) -> None:
        if self.behaviour not in BEHAVIOURS:
            raise BehaveError(f"unknown behaviour '{self.behaviour}' (choose from {', '.join(BEHAVIOURS)})")
        if self.placement not in PLACEMENTS:
            raise BehaveError(f"unknown placement '{self.placement}' (choose from {', '.join(PLACEMENTS)})")
        if self.driver not in DRIVERS:
            raise BehaveError(f"unknown driver '{self.driver}' (choose from {', '.join(DRIVERS)})")
        if make_driver(self.driver).among_traffic and self.scenario not in (*ROAD_FAMILIES, "ring"):
            raise BehaveError(
                f"the {self.driver} driver trains on {', '.join(repr(f) for f in ROAD_FAMILIES)} or 'ring'"
            )
        if isinstance(self.scenario, str) and self.scenario not in (*SCENARIO_NAMES, *ROAD_FAMILIES):
            get_scenario(self.scenario)  # raises with the list of choices
        if self.behaviour == "multi":
            if self.overtakers < 0 or self.keepers < 0 or self.overtakers + self.keepers == 0:
                raise BehaveError("multi needs --overtakers and --keepers (at least one agent in all)")
        elif self.agents < 1:
            raise BehaveError(f"need at least one agent, got {self.agents}")
        elif self.overtakers or self.keepers:
            raise BehaveError("--overtakers/--keepers only apply to the multi behaviour")
        if self.max_steps < 1:
            raise BehaveError(f"max_steps must be positive, got {self.max_steps}")
        if not 0.01 <= self.step_length <= 1.0:
            raise BehaveError(f"step length must be in [0.01, 1] s, got {self.step_length}")
        if self.start_speed is not None and self.start_speed < 0:
            raise BehaveError(f"start speed must be >= 0, got {self.start_speed}")
        if (self.opponents or 0) < 0:
            raise BehaveError(f"opponents must be >= 0, got {self.opponents}")
        low, high = self.traffic_density
        if not (np.isfinite(low) and np.isfinite(high) and 0 <= low <= high):
            raise BehaveError(f"traffic density must be a range 0 <= low <= high, got {self.traffic_density}")
        if self.lane_weight < 0:
            raise BehaveError(f"lane weight must be >= 0, got {self.lane_weight}")

    @property
    def n_agents(self) -> int:
        return self.overtakers + self.keepers if self.behaviour == "multi" else self.agents

    @property
    def n_opponents(self) -> int:
        """Passive slower cars ahead: something to overtake (the paper's multi run had none)."""
        if self.behaviour == "overtaking":
            return self.agents if self.opponents is None else self.opponents
        if self.behaviour == "multi":
            return self.opponents or 0
        return 0

    @property
    def obs_size(self) -> int:
        return make_driver(self.driver).obs_size(self.with_id)

    @property
    def with_id(self) -> bool:
        """Whether the agents see their behaviour id (multi-behaviour runs)."""
        return self.behaviour == "multi"

    def behaviour_ids(self) -> np.ndarray:
        """Behaviour id per agent slot (1 = overtaker), in start-formation order from the front."""
        if self.behaviour == "lanekeeping":
            return np.zeros(self.agents)
        if self.behaviour == "overtaking":
            return np.ones(self.agents)
        over, keep = np.ones(self.overtakers), np.zeros(self.keepers)
        if self.placement == "A":
            return np.concatenate([over, keep])
        if self.placement == "B":
            return np.concatenate([keep, over])
        mixed = np.zeros(self.n_agents)
        mixed[interleaved(self.overtakers, self.keepers)] = 1.0
        return mixed


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


def interleaved(first: int, second: int) -> np.ndarray:
    """Positions of `first` items spread evenly among `first + second` slots."""
    total = first + second
    return np.floor((np.arange(first) + 0.5) * total / max(first, 1)).astype(int)


@dataclass(frozen=True)
class StepBatch:
    """One step for the agents that acted (row i = slot `slots[i]`)."""

    slots: np.ndarray  # [n] agent slots, in the order of the actions given
    next_obs: np.ndarray  # [n, D] observation after the step (the last one for agents that left)
    reward: np.ndarray  # [n]
    terms: StepTerms  # RewardTerms, or TrafficTerms for the traffic driver
    terminated: np.ndarray  # [n] collision, off-track or no progress: no bootstrap
    truncated: np.ndarray  # [n] time limit or end of route: bootstrap
    collided: np.ndarray
    off_track: np.ndarray
    no_progress: np.ndarray
    speed: np.ndarray  # [n] m/s after the step
    lane_deviation: np.ndarray  # [n] |offset from the lane centre| / half the lane width (0 for leavers)


class BehaveEnv(ParallelEnv):
    """N learned cars (and optional passive SUMO cars) on a bundled scenario."""

    metadata: ClassVar[dict] = {
        "name": "behave_v0", "render_modes": list(RENDER_MODES), "render_fps": 5, "is_parallelizable": True
    }  # fmt: skip
    render_mode: str | None = None
    sim_extra: tuple[str, ...] = ()
    """More SUMO options, from the next episode on (`behave evaluate` records each episode's FCD)."""

    def __init__(self, config: EnvConfig, render_mode: str | None = None) -> None:
        config.validate()
        self.render_mode = check_render_mode(render_mode)
        self.config = config
        self.scenario: Scenario = (
            config.scenario if isinstance(config.scenario, Scenario) else get_scenario(config.scenario)
        )
        self.geometry: RoadGeometry = load_geometry(self.scenario.net)
        self.lap = route_edges(self.scenario)
        self.slot_behaviour = config.behaviour_ids()
        self.possible_agents = [f"agent_{i}" for i in range(config.n_agents)]
        self._obs_space = make_driver(config.driver).observation_space(config.with_id)
        self._act_space = action_space()
        self._check_capacity()
        self.sim: SumoSim | None = None
        self.timer = PhaseTimer()
        self.fleet = Fleet(
            self.geometry,
            config.car,
            config.step_length,
            self.timer,
            make_driver(config.driver),
            config.shield,
        )
        self.agents: list[str] = []
        self._live_slots = np.zeros(0, np.int64)
        self._rng = np.random.default_rng(config.seed)

    # --- PettingZoo -------------------------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Box:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Box:
        return self._act_space

    def reset(self, seed: int | None = None, options: dict | None = None):
        obs = self.reset_arrays(seed)
        names = self.agents
        return dict(zip(names, obs, strict=True)), {name: {} for name in names}

    def step(self, actions: dict):
        if not self.agents:  # wrappers (SuperSuit, RLlib) step once more after the last agent left
            return {}, {}, {}, {}, {}
        acting = list(self.agents)
        batch = self.step_arrays(np.array([actions[name] for name in acting], np.float32).reshape(-1, 3))
        obs, rew, term, trunc, info = {}, {}, {}, {}, {}
        terms = batch.terms.as_dict()
        for i, name in enumerate(acting):
            obs[name] = batch.next_obs[i]
            rew[name] = float(batch.reward[i])
            term[name] = bool(batch.terminated[i])
            trunc[name] = bool(batch.truncated[i])
            info[name] = {key: float(value[i]) for key, value in terms.items()}
        return obs, rew, term, trunc, info

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()
            self.sim = None

    def render(self) -> np.ndarray | None:
        """With render_mode "rgb_array": a top-down picture of the road, agents red, other cars blue."""
        if self.render_mode is None or self.sim is None:
            return None
        vehicles = self.sim.read_vehicles(with_distance=False)
        is_agent = np.isin(np.array(vehicles.ids, dtype=object), self.agents)
        return top_down(self.geometry.seg_a, self.geometry.seg_b, vehicles.position, is_agent)

    def state(self) -> np.ndarray:
        return self.live_obs.copy()

    # --- batched interface ------------------------------------------------------------
    @property
    def live_slots(self) -> np.ndarray:
        """Slots of the live agents, in the order observations come and actions go."""
        return self._live_slots

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

    def _check_actions(self, actions: np.ndarray) -> SumoSim:
        """The running simulation, if `actions` fit the live agents."""
        if self.sim is None or not self.agents:
            raise RuntimeError("step_arrays needs a running episode: call reset first")
        if actions.shape != (len(self.agents), 3):
            raise ValueError(f"expected actions of shape ({len(self.agents)}, 3), got {actions.shape}")
        return self.sim

    def _advance(self, sim: SumoSim, with_id: bool) -> tuple[set[str], VehicleState, np.ndarray, np.ndarray]:
        """Step SUMO once after the agents acted, drop the agents SUMO no longer has and sense the
        others: (contacts, vehicles, present [n], next observations [n, D]; an agent that left keeps
        its last observation)."""
        fleet = self.fleet
        with self.timer.phase("sumo"):
            sim.step()
        self.steps += 1
        with self.timer.phase("read"):
            contact = sim.collisions()
            vehicles = sim.read_vehicles()
        present = fleet.locate(vehicles) >= 0
        next_obs = self.live_obs.copy()
        fleet.keep(present)
        if present.any():
            next_obs[present] = fleet.sense(sim, vehicles, with_id)
        return contact, vehicles, present, next_obs

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
        terms = step_rewards(
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
        if not cfg.sumo_drives:
            sim.take_control(agent_ids)
        sim.step()
        missing = set(vids) - set(sim.vehicle_ids())
        if missing:
            raise BehaveError(f"SUMO could not insert {len(missing)} cars (spacing too small for the road)")
        self.passive_ids = vids[: cfg.n_opponents]
        self._passive_on_road = set(self.passive_ids)
        self.agents = list(agent_ids)
        self._live_slots = np.arange(len(agent_ids))
        self.fleet = Fleet(
            self.geometry, cfg.car, cfg.step_length, self.timer, make_driver(cfg.driver), cfg.shield
        )
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

    def _routes(self) -> list[str]:
        """One route per start edge: the lap rotated to start there, unrolled for looping scenarios."""
        sim = self.sim
        assert sim is not None
        if not self.scenario.looping:
            return [self.scenario.route_id] * len(self.lap)
        lap_length = sum(self.geometry.edges[e].length for e in self.lap)
        laps = int(np.ceil(ROUTE_SECONDS * 50.0 / lap_length)) + 1
        ids = []
        for k in range(len(self.lap)):
            rid = f"lap_from_{k}"
            sim.add_route(rid, (self.lap[k:] + self.lap[:k]) * laps)
            ids.append(rid)
        return ids

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

    def _slow_time(self, present: np.ndarray) -> np.ndarray:
        out = np.zeros(len(present))
        out[present] = self.fleet.slow_time
        return out

    def _leave(self, slots: np.ndarray, present: np.ndarray, leaving: np.ndarray, contact: set[str]) -> None:
        """Take agents that ended off the road (and passive cars wrecked in a collision).

        Most steps nobody leaves: then nothing is rebuilt (no per-agent Python work).
        """
        sim = self.sim
        assert sim is not None
        wrecked = sorted(self._passive_on_road & contact)
        self._passive_on_road.difference_update(wrecked)
        if not leaving.any():
            sim.remove(wrecked)
            return
        names = [self.possible_agents[s] for s in slots]
        gone = [n for n, p, leave in zip(names, present, leaving, strict=True) if p and leave]
        sim.remove(gone + wrecked)
        self.fleet.keep(~leaving[present])
        self.agents = [n for n, leave in zip(names, leaving, strict=True) if not leave]
        self._live_slots = slots[~leaving]


def action_space() -> spaces.Box:
    """steer in [-1, 1], accel in [0, 1], brake in [0, 1]."""
    return spaces.Box(np.array([-1, 0, 0], np.float32), np.array([1, 1, 1], np.float32), dtype=np.float32)


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
    if make_driver(config.driver).among_traffic:
        from behaviors.traffic_env import TrafficEnv

        env = TrafficEnv(config)
        env.render_mode = check_render_mode(render_mode)
        return env
    return BehaveEnv(config, render_mode)
