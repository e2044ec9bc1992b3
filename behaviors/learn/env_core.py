"""What every training environment shares: the episode's config, the step's batch and the
base class with the PettingZoo interface over the batched one.

Two interfaces on one object:
* PettingZoo's dict-per-agent `reset`/`step` (agents leave and never return);
* `reset_arrays`/`step_arrays` for the trainer: one array of observations for all
  live agents, one array of actions in, no per-agent conversion.

The environments (paper_env.PaperEnv, traffic_env.TrafficEnv) subclass `BehaveEnv`; env.py
picks one for a config.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from behaviors.car.model import CarModel
from behaviors.errors import BehaveError
from behaviors.fleet.control import Fleet
from behaviors.fleet.drivers import DRIVERS, make_driver
from behaviors.report.render import RENDER_MODES, check_render_mode, top_down
from behaviors.road.geometry import RoadGeometry
from behaviors.sumo.sim import SumoSim, VehicleState
from behaviors.sumo.timing import PhaseTimer
from behaviors.traffic.rewards import StepTerms, check_reward_weights
from sumo_scenarios import SCENARIO_NAMES, Scenario, get_scenario
from sumo_scenarios.build import AGENT_VTYPES

BEHAVIOURS = ("lanekeeping", "overtaking", "multi")
PLACEMENTS = ("A", "B", "C")
KEEPER_TYPE, OVERTAKER_TYPE, LORRY_TYPE = AGENT_VTYPES
PASSIVE_TYPE = "behave_passive"
BACKGROUND_TYPE = "behave_background"
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
    net: str | Path | None = None  # traffic driver: a user's .net.xml instead of `scenario`
    sumocfg: str | Path | None = None  # traffic driver: a user's .sumocfg instead; its routes are SUMO's cars
    reward_weights: Mapping[str, float] | None = None  # reward term name -> weight (others: 1)

    @property
    def own_road(self) -> bool:
        """Whether the agents drive a user's net or sumocfg rather than a bundled scenario."""
        return self.net is not None or self.sumocfg is not None

    def validate(self) -> None:
        if self.behaviour not in BEHAVIOURS:
            raise BehaveError(f"unknown behaviour '{self.behaviour}' (choose from {', '.join(BEHAVIOURS)})")
        if self.placement not in PLACEMENTS:
            raise BehaveError(f"unknown placement '{self.placement}' (choose from {', '.join(PLACEMENTS)})")
        if self.driver not in DRIVERS:
            raise BehaveError(f"unknown driver '{self.driver}' (choose from {', '.join(DRIVERS)})")
        driver = make_driver(self.driver)
        check_reward_weights(self.reward_weights or {}, driver.reward_terms, driver.name)
        if self.own_road:
            self._check_own_road(driver.among_traffic)
        elif driver.among_traffic and self.scenario not in (*ROAD_FAMILIES, "ring"):
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

    def _check_own_road(self, among_traffic: bool) -> None:
        """A user's road: one of net or sumocfg, each the right kind of file, for a driver that
        drives among traffic (the files themselves are read, and checked, when the env starts)."""
        if not among_traffic:
            raise BehaveError(
                f"net= and sumocfg= need a driver that drives among traffic, not '{self.driver}'"
            )
        if self.net is not None and self.sumocfg is not None:
            raise BehaveError("net= and sumocfg= both name a network: the sumocfg's net is used, drop net=")
        if self.net is not None and Path(self.net).suffix == ".sumocfg":
            raise BehaveError(f"net={self.net} is a SUMO configuration, not a network: pass it as sumocfg=")

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
    """N learned cars on a SUMO road: the interfaces and the step's shared parts; a subclass starts
    episodes (`reset_arrays`) and scores steps (`step_arrays`)."""

    metadata: ClassVar[dict] = {
        "name": "behave_v0", "render_modes": list(RENDER_MODES), "render_fps": 5, "is_parallelizable": True
    }  # fmt: skip
    render_mode: str | None = None
    sim_extra: tuple[str, ...] = ()
    """More SUMO options, from the next episode on (`behave evaluate` records each episode's FCD)."""

    scenario: Scenario
    """The bundled road of this episode (set by the subclass; not on a user's road)."""
    lap: list[str]
    """Its route's edges, one lap."""

    def __init__(self, config: EnvConfig, geometry: RoadGeometry, render_mode: str | None = None) -> None:
        self.render_mode = check_render_mode(render_mode)
        self.config = config
        self.geometry = geometry
        self.slot_behaviour = config.behaviour_ids()
        self.possible_agents = [f"agent_{i}" for i in range(config.n_agents)]
        self._obs_space = make_driver(config.driver).observation_space(config.with_id)
        self._act_space = action_space()
        self.sim: SumoSim | None = None
        self.timer = PhaseTimer()
        self.fleet = self._new_fleet()
        self.agents: list[str] = []
        self._live_slots = np.zeros(0, np.int64)
        self._rng = np.random.default_rng(config.seed)
        self.passive_ids: list[str] = []
        self._passive_on_road: set[str] = set()

    def _new_fleet(self) -> Fleet:
        """An empty fleet on the current road (each episode starts one)."""
        cfg = self.config
        return Fleet(self.geometry, cfg.car, cfg.step_length, self.timer, make_driver(cfg.driver), cfg.shield)

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
        """Start an episode; returns observations [n_live, D] in `live_slots` order."""
        raise NotImplementedError

    def step_arrays(self, actions: np.ndarray) -> StepBatch:
        """Act for the live agents (rows in `live_slots` order) and advance SUMO one step."""
        raise NotImplementedError

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
