"""The running SUMO simulation with its learned agents (Population): cars asked for and admitted, a
scenario's share turned into agents, and one step of sensing, acting, SUMO stepping and taking stock."""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from behaviors.car.model import CarModel
from behaviors.errors import BehaveError
from behaviors.fleet.control import Fleet
from behaviors.fleet.drivers import make_driver
from behaviors.learn.policy import Policy
from behaviors.learn.traffic_env import VTYPES
from behaviors.report.fcd_read import fcd_options
from behaviors.road.geometry import CAR_CLASS
from behaviors.road.geometry_build import load_geometry
from behaviors.road.routes import RoutePool, misplaced, route_graph
from behaviors.run.populate_config import PopulateConfig, populate_policy
from behaviors.run.records import (
    AGENT_TYPE_OF,
    AgentLog,
    AgentRow,
    Incident,
    PopulateSummary,
    SumoCars,
    collision_incident,
    end_reasons,
    lane_offsets,
    partners,
)
from behaviors.sumo.joined import JoinedSim
from behaviors.sumo.scenario_config import (
    ScenarioConfig,
    lateral_for,
    read_sumocfg,
    run_as_sumocfg,
    share_draw,
)
from behaviors.sumo.sim import SimOptions, SumoSim, VehicleState
from behaviors.sumo.timing import PhaseTimer
from behaviors.traffic.styles import KINDS, read_population

LORRY_CLASSES = ("truck", "trailer")
"""SUMO's vehicle classes of a scenario's lorries, which --share-lorries may draw."""

BACKGROUND_TYPE = "behave_background"
CAR_FOOTPRINT = 15.0
"""Metres of lane one car needs (length + gaps at speed) when checking what a net can hold."""
CAR_SIZE_M = {"length": (2.5, 7.5), "width": (1.2, 2.3)}
"""The sizes (m, inclusive) of a vehicle --share may turn into an agent (behave's agents are 5 m x 1.8 m):
a vehicle of vClass passenger outside them (a 12 m vType that sets no vClass) is left to SUMO."""


def car_sized(length: float, width: float) -> bool:
    (short, long), (narrow, wide) = CAR_SIZE_M["length"], CAR_SIZE_M["width"]
    return short <= length <= long and narrow <= width <= wide


class Population:
    """The running SUMO simulation with its learned agents."""

    def __init__(
        self,
        config: PopulateConfig,
        on_status: Callable[[str], None] | None = None,
        policy: Policy | None = None,
        joined: JoinedSim | None = None,
    ) -> None:
        self.config = config
        self.joined = joined  # a running SUMO joined over TraCI (config.connect), used by start()
        self.scenario: ScenarioConfig | None = read_sumocfg(config.sumocfg) if config.sumocfg else None
        self.policy = populate_policy(config, policy)  # a wrong policy is found before set-up
        self.geometry = load_geometry(config.net, cache=True, on_status=on_status)
        self.graph = route_graph(self.geometry)
        self.lane_ids = list(self.geometry.lane_index)  # by lane row: names the lane of an incident
        self._check_capacity()
        self.rng = np.random.default_rng(config.seed)
        self.timer = PhaseTimer()
        population = None if config.population is None else read_population(config.population)
        driver = make_driver(self.policy.driver, population)
        self.fleet = Fleet(self.geometry, CarModel(), config.step_length, self.timer, driver, config.shield)
        self.summary = PopulateSummary(sumo=SumoCars(config.step_length))
        self.log = AgentLog(config.step_length, self.policy.label)
        self.routes: RoutePool | None = None  # made with the simulation it hands routes to
        self.counter = {**dict.fromkeys(KINDS, 0), "background": 0}
        self.pending: dict[str, str] = {}  # vehicle id -> kind, added but not yet on the road
        self.background_ids: set[str] = set()
        self.vehicles: VehicleState | None = None  # read after each step, used to sense in the next
        self.sim: SumoSim | None = None
        self.now = 0.0  # SUMO's time after the last whole step: what the outputs hold if SUMO fails

    def _check_capacity(self) -> None:
        c = self.config
        lane_metres = float((self.graph.length * self.graph.lanes).sum())
        cars = c.overtakers + c.keepers + c.background
        if cars * CAR_FOOTPRINT > lane_metres:
            raise BehaveError(
                f"{cars} vehicles do not fit on {c.net.name}: its multi-lane edges hold about "
                f"{int(lane_metres / CAR_FOOTPRINT)}"
            )

    def start(self, fcd_tmp: Path | None, precise: bool = False) -> None:
        """Start SUMO writing FCD to `fcd_tmp` (None: no FCD, for benchmarks) and ask for the cars;
        `precise`: at every decimal (fcd_read.fcd_options), for the csv a ParquetStream reads."""
        if self.joined is not None:
            self._join(self.joined)
            return
        c, scenario = self.config, self.scenario
        routes = (c.routes,) if c.routes else ()
        fcd = () if fcd_tmp is None else tuple(fcd_options(fcd_tmp, geo=c.geo, precise=precise))
        options = SimOptions(net=c.net, additional=(VTYPES,), routes=routes, step_length=c.step_length,
                             seed=c.seed, extra=fcd, gui=c.gui,
                             agent_max_speed_lat=self.fleet.driver.max_lateral_speed)  # fmt: skip
        with tempfile.TemporaryDirectory(prefix="behave-scenario-") as staging:  # read by SUMO as it starts
            if scenario is not None:
                lateral = c.lateral_resolution
                lateral = lateral_for(scenario, c.has_agents) if lateral is None else lateral
                options = run_as_sumocfg(options, scenario, lateral, c.outputs, Path(staging))
            else:  # a sumocfg keeps its own begin time; a net starts at 0
                options = replace(options, extra=("--begin", "0", *fcd))
            self.sim = SumoSim(options)
        self.now = self.sim.time
        self.routes = RoutePool(self.graph, c.duration * 50.0, self.sim.add_route)
        self.insert("overtaker", c.overtakers)
        self.insert("keeper", c.keepers)
        self.insert("lorry", c.lorries)
        self.insert("background", c.background)

    def _join(self, sim: JoinedSim) -> None:
        """Take up the joined simulation: the agents' vTypes there, and the share of the passenger cars
        already on the road (those that depart later are drawn as they depart, `_convert`)."""
        self.sim = sim
        sim.prepare_agents(self.fleet.driver.max_lateral_speed)
        self.vehicles = sim.read_vehicles(with_distance=False)
        self.summary.vehicles += len(self.vehicles.ids)
        self._convert(list(self.vehicles.ids), sim.time)

    def insert(self, kind: str, count: int) -> None:
        """Ask SUMO for `count` new vehicles of a kind on random multi-lane routes, at free places."""
        sim, routes = self.sim, self.routes
        assert sim is not None and routes is not None
        vtype = {**AGENT_TYPE_OF, "background": BACKGROUND_TYPE}[kind]
        for _ in range(count):
            vid = f"{kind}_{self.counter[kind]}"
            self.counter[kind] += 1
            # agents enter at the highest speed SUMO finds safe there: at traffic speed
            speed = "desired" if kind == "background" else "max"
            sim.add_free_vehicle(
                vid, routes.draw(self.rng), vtype, speed, "first" if kind == "lorry" else "random"
            )
            if kind != "background":
                sim.take_control([vid])
            self.pending[vid] = kind

    def _admit(self, present: dict[str, int], time: float) -> None:
        """Pending vehicles that SUMO placed join; the others are withdrawn and retried."""
        sim = self.sim
        assert sim is not None
        placed = [v for v in self.pending if v in present]
        assert self.vehicles is not None
        keeper = np.array([self.pending[v] in ("keeper", "lorry") for v in placed], bool)
        withdraw = misplaced(sim, self.vehicles, self.geometry, placed, keeper).tolist()
        joined = [v for v, out in zip(placed, withdraw, strict=True) if not out]
        withdrawn = [v for v, out in zip(placed, withdraw, strict=True) if out]
        self.vehicles = self.vehicles.without(withdrawn)  # withdrawn below: nobody senses them
        failed = [v for v in self.pending if v not in present] + withdrawn
        agents = [v for v in joined if self.pending[v] != "background"]
        if agents:
            behaviour = np.array([KINDS.index(self.pending[v]) for v in agents], float)
            style = self.fleet.driver.draw_style(behaviour, self.rng)
            self.fleet.add(agents, sim.read_speeds(agents), behaviour, style)
            self.log.join(agents, [self.pending[v] for v in agents], time, style)
        self.background_ids.update(v for v in joined if self.pending[v] == "background")
        self.summary.vehicles += len(joined)
        kinds = [self.pending[v] for v in failed]
        self.pending = {}
        if failed:
            sim.remove(failed)
            self.summary.insert_retries += len(failed)
            for kind in sorted(set(kinds)):
                self.insert(kind, kinds.count(kind))

    def step(self) -> None:
        """Sense, act, let SUMO step, then take stock: the one read of SUMO serves the next step too."""
        sim, fleet, c = self.sim, self.fleet, self.config
        assert sim is not None
        before = self.vehicles  # the read this step's actions are chosen from
        off_track = np.zeros(len(fleet), bool)
        if len(fleet):
            assert self.vehicles is not None
            obs = fleet.sense(sim, self.vehicles, self.policy.with_id)
            with self.timer.phase("policy"):
                actions = self.policy.act(obs, None)
            actuation = fleet.act(sim, actions)
            off_track = actuation.off_track
            self.summary.side_cuts += int(actuation.side_cut.sum())
            self.summary.speed_cuts += int(actuation.speed_cut.sum())
            for name, count in actuation.limits.items():
                self.summary.limits[name] = self.summary.limits.get(name, 0) + count
            self.summary.handovers = fleet.handovers
        with self.timer.phase("sumo"):
            sim.step()
        with self.timer.phase("read"):
            contact = sim.collisions()
            arrived = sim.arrived()
            vehicles = sim.read_vehicles(with_distance=False)  # no race here: positions suffice
            now = sim.time
        crashed = fleet.involved(vehicles, contact)
        rows = fleet.locate(vehicles)
        gone = rows < 0
        if len(fleet):
            self._observe_agents(~gone, vehicles.speed[rows[~gone]])
        self._observe_sumo(vehicles, rows[~gone])
        leaving = crashed | off_track | gone
        if leaving.any():  # most steps nobody leaves: no per-agent reasons to build
            reasons = end_reasons(crashed, off_track, gone, self._arrived(gone, arrived))
            incidents = self._incidents(reasons, before, partners(sim.collision_pairs()) if contact else {})
            self.log.end(reasons, now, incidents)
        self.summary.collisions += int(crashed.sum())
        self.summary.off_tracks += int((off_track & ~crashed).sum())
        self.summary.agent_steps += len(fleet)
        left = [fleet.ids[k] for k in np.flatnonzero(leaving)]
        wrecked_background = sorted(v for v in contact if v in self.background_ids)
        removed = [fleet.ids[k] for k in np.flatnonzero(leaving & ~gone)] + wrecked_background
        sim.remove(removed)
        self.vehicles = vehicles.without(removed)
        fleet.keep(~leaving)
        # background cars leave at the end of their route, or wrecked
        left_background = {v for v in arrived if v in self.background_ids}.union(wrecked_background)
        self.background_ids -= left_background
        if self.scenario is not None or self.joined is not None:  # before _admit: behave's own are pending
            departed = [v for v in sim.departed() if v not in self.pending]
            self.summary.vehicles += len(departed)  # the scenario's own; behave's count as they join
            self._convert(departed, now)
        self._admit(self.vehicles.row, now)
        if c.keep_count:
            for kind in KINDS:
                self.insert(kind, sum(v.startswith(f"{kind}_") for v in left))
            self.insert("background", len(left_background))
        self.summary.simulated_s += c.step_length
        self.now = now

    def _convert(self, departed: list[str], time: float) -> None:
        """The share of the scenario's passenger cars (and with --share-lorries of its lorries) that
        departed this step become agents: behave's vehicle type (a lorry keeps its own size), SUMO's
        checks off, into the fleet. The rest stay SUMO's, untouched."""
        sim, c = self.sim, self.config
        assert sim is not None
        mine = [v for v in departed if not v.startswith(c.leave_alone)]
        classes = {v: sim.vehicle_class(v) for v in mine}
        cars = [v for v in mine if classes[v] == CAR_CLASS]
        draws = {v: share_draw(c.seed, v) for v in cars}
        drawn = [v for v in cars if draws[v] < c.share]
        agents = [v for v in drawn if car_sized(*sim.vehicle_size(v))]  # a bus typed passenger stays SUMO's
        self.summary.scenario_cars += len(cars)
        self.summary.scenario_not_car_sized += len(drawn) - len(agents)
        kinds = ["overtaker" if draws[v] < c.share * c.overtaker_fraction else "keeper" for v in agents]
        if c.share_lorries:
            lorries = [v for v in mine if classes[v] in LORRY_CLASSES and share_draw(c.seed, v) < c.share]
            agents, kinds = agents + lorries, kinds + ["lorry"] * len(lorries)
        self.summary.scenario_agents += len(agents)
        if not agents:
            return
        for vid, kind in zip(agents, kinds, strict=True):
            size = sim.vehicle_size(vid) if kind == "lorry" else None  # a car takes the agents' size
            sim.set_agent_type(vid, AGENT_TYPE_OF[kind])
            if size is not None and sim.vehicle_size(vid) != size:
                sim.set_vehicle_size(vid, *size)
        sim.take_control(agents)
        behaviour = np.array([KINDS.index(kind) for kind in kinds], float)
        style = self.fleet.driver.draw_style(behaviour, self.rng)
        self.fleet.add(agents, sim.read_speeds(agents), behaviour, style)
        self.log.join(agents, kinds, time, style)

    def _observe_agents(self, present: np.ndarray, speed: np.ndarray) -> None:
        """Log SUMO's `speed` of each agent it still has, not the one commanded: SUMO may hold a
        car back (a lane that does not lead on stops it dead) whatever the policy asks."""
        self.log.observe(present, speed)
        behaviour = self.fleet.behaviour_id[present]
        for flag, name in enumerate(KINDS):
            mask = behaviour == flag
            self.summary.speed_sum[name] += float(speed[mask].sum())
            self.summary.speed_steps[name] += int(mask.sum())

    def _observe_sumo(self, vehicles: VehicleState, agent_rows: np.ndarray) -> None:
        """SUMO's own vehicles' speeds after a step: every vehicle but the agents (`agent_rows`)."""
        assert self.summary.sumo is not None
        sumo = np.ones(len(vehicles.ids), bool)
        sumo[agent_rows] = False
        self.summary.sumo.observe(vehicles.ids, vehicles.speed, sumo)

    def _incidents(
        self, reasons: np.ndarray, before: VehicleState | None, other: dict[str, str]
    ) -> dict[int, Incident]:
        """The incident of each agent (by row) that collided or left the road this step, as things
        stood at `before`, the read its action was chosen from."""
        fleet, frame = self.fleet, self.fleet.frame
        lost = np.flatnonzero((reasons == "collision") | (reasons == "off_track"))
        if before is None or frame is None or not len(lost):
            return {}
        offsets = lane_offsets(self.geometry, frame)
        out = {}
        for k in lost.tolist():
            row = fleet.vehicle_rows[k]
            speed, lane, offset = (
                float(before.speed[row]),
                self.lane_ids[frame.lane_row[k]],
                float(offsets[k]),
            )
            if reasons[k] == "off_track":
                side = "left" if frame.offset[k] > 0 else "right"
                edge_gap = float(frame.half_width[k] - abs(frame.offset[k]) - fleet.car.width / 2)
                out[k] = Incident(side, lane, offset, "", speed, np.nan, np.nan, edge_gap)
                continue
            partner = other.get(fleet.ids[k], "")
            o = before.row.get(partner)
            if o is None:  # a car that was not on the road before this step
                out[k] = Incident("", lane, offset, partner, speed, np.nan, np.nan, np.nan)
                continue
            other_speed = float(before.speed[o])
            heading = float(frame.heading[k])
            side, headway, lateral = collision_incident(
                before.position[row], heading, speed, before.position[o], other_speed, fleet.car,
                (float(before.length[o]), float(before.width[o])),
            )  # fmt: skip
            out[k] = Incident(side, lane, offset, partner, speed, other_speed, headway, lateral)
        return out

    def _arrived(self, gone: np.ndarray, arrived: set[str]) -> np.ndarray:
        """Which agents SUMO took out this step because they reached the end of their route."""
        ids = self.fleet.ids
        out = np.zeros(len(ids), bool)
        for k in np.flatnonzero(gone):
            out[k] = ids[k] in arrived
        return out

    def driving_rows(self) -> list[AgentRow]:
        """The agents still on the road now (`still_driving`); those whose run ended are in
        `self.log.ended`."""
        assert self.sim is not None
        return self.log.driving(self.sim.time)

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()
            self.sim = None
