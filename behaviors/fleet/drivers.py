"""Driver models: everything that differs between the paper's driver and the traffic driver.

A driver owns what its agents see (observation size, space and sensing), how actions move them
(actuation), its own per-agent rows, the critic's reward scale and its exploration noise. The fleet
(control.py), the environments, training, populate and the policy loader ask the driver; none of
them checks a driver's name. A new driver is one new class here (or in a module of its own) and
one entry in DRIVERS.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from behaviors.car.model import Actuation, CarModel, ShieldBounds
from behaviors.errors import BehaveError
from behaviors.fleet.control import Fleet, HandedRows, Observed, RoadFrame, Sensing, road_frame
from behaviors.fleet.handover import SIGNAL_DISTANCE, SIGNAL_SECONDS, Handover, LaneEnds, LanePlace, decide
from behaviors.fleet.traffic_rows import TrafficRows, desired_speed
from behaviors.paper.heading import actuate
from behaviors.paper.sensors import OBS_SIZE, OBS_SIZE_WITH_ID, OBSERVATION_LAYOUT, AgentFrame, observe
from behaviors.road.neighbours import neighbours
from behaviors.road.routes import lane_leads_on
from behaviors.sumo.sim import AgentReadings, SumoSim
from behaviors.traffic.actuation import LaneCommand, actuate_lanes
from behaviors.traffic.lanes import (
    TRAFFIC_LAYOUT,
    TRAFFIC_OBS_SIZE,
    LaneAgents,
    Surroundings,
    observe_lanes,
    search_radius,
)
from behaviors.traffic.lanes import surroundings as lane_surroundings
from behaviors.traffic.rewards import (
    TERM_NAMES,
    TRAFFIC_TERM_NAMES,
    TrafficStep,
    TrafficTerms,
    TrafficWeights,
    styled_rewards,
    traffic_rewards,
)
from behaviors.traffic.scene import AgentStyle, LaneNeighbours, Motion, RoadPlace, look_ahead
from behaviors.traffic.settings import DriverSettings, LaneDriving, LaneHabits
from behaviors.traffic.styles import (
    HEADWAY_RANGE,
    PRESETS,
    Population,
    Styles,
    action_of_headway,
    desired_fractions,
    draw_styles,
    fixed_styles,
    headway_of_action,
    unstyled,
)

JUNCTION_LEADS_ON = 1e4
"""m: inside a junction every lane counts as leading on; SUMO is asked again on the next lane."""
ONE_LANE_HORIZON = 1000.0
"""m: how far beyond the end of its edge an agent looks along its route for a road of one car lane
(SUMO drives it there); counted from the edge's end, since it is looked up once per lane entered and
a motorway edge may be longer than any horizon."""


PAPER_BOUNDS = {
    "angle": (-1, 1),
    "track": (0, 1),
    "trackPos": (-1, 1),
    "speedX": (-1, 1),
    "speedY": (-1, 1),
    "speedZ": (-1, 1),
    "wheelSpinVel": (0, 2),
    "rpm": (0, 1),
    "opponents": (0, 1),
}
"""Bounds of each normalised value of the paper's observation."""


class PaperDriver:
    """The paper's TORCS-like state (65 floats, 66 with the behaviour id), its reward and its
    heading model: steer turns a heading of the car's own (paper/heading.py)."""

    name = "paper"
    max_lateral_speed = CarModel.max_lateral_speed
    """m/s: its steer moves a car sideways up to the vTypes' maxSpeedLat."""
    among_traffic = False
    """Trains in the paper's formations on the bundled roads (paper_env.PaperEnv), not among traffic."""
    reward_scale = 0.01
    """The paper's rewards are ~100 per step (km/h): the critic sees them scaled by this."""
    reward_terms = TERM_NAMES
    """The named terms of its reward (rewards.step_rewards): what `reward_weights` may weigh."""
    exploration: ClassVar[dict[str, tuple[float, float, float]]] = {}
    """The learner's default Ornstein-Uhlenbeck noise."""
    normalisation = "angle/pi, rays/200 m, speeds km/h/300, wheel spin/100, rpm/10000"
    """How the observation's values are scaled, as checkpoints record it."""

    def observation_layout(self, with_id: bool) -> str:
        """The observation's parts in order, as checkpoints record them."""
        names = "+".join(name for name, _ in OBSERVATION_LAYOUT)
        return f"torcs65:{names}" + ("+behaviour_id" if with_id else "")

    def obs_size(self, with_id: bool) -> int:
        return OBS_SIZE_WITH_ID if with_id else OBS_SIZE

    def observation_space(self, with_id: bool) -> spaces.Box:
        """Bounds of every normalised value (see sensors.OBSERVATION_LAYOUT)."""
        low = np.concatenate([np.full(n, PAPER_BOUNDS[name][0]) for name, n in OBSERVATION_LAYOUT])
        high = np.concatenate([np.full(n, PAPER_BOUNDS[name][1]) for name, n in OBSERVATION_LAYOUT])
        if with_id:
            low, high = np.append(low, 0.0), np.append(high, 1.0)
        return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)

    def draw_style(self, behaviour_id: np.ndarray, rng: np.random.Generator) -> Styles:
        """Desired speeds, which the paper's driver does not use: drawn all the same, so that a run's
        random stream does not depend on the driver."""
        return unstyled(desired_fractions(behaviour_id, rng))

    def new_rows(self, count: int, style: Styles | None) -> None:
        return None

    def observe(self, fleet: Fleet, sim: SumoSim, sensing: Sensing, with_id: bool) -> Observed:
        r, vehicles, rows = fleet.rows, sensing.vehicles, sensing.rows
        front = vehicles.position[rows]
        frame = road_frame(fleet.geometry, sensing.readings, sensing.lane_rows, front, r.angle, fleet.car)
        centres = vehicles.position.copy()
        centres[rows] = frame.centre  # agents' centres are known exactly; others' fronts suffice
        agents = AgentFrame(
            centre=frame.centre,
            heading=frame.heading,
            angle=r.angle,
            speed=r.speed,
            track_pos=np.clip(frame.offset / frame.half_width, -1.0, 1.0),
        )
        obs = observe(agents, centres, rows, fleet.geometry, r.behaviour_id if with_id else None)
        return Observed(obs, frame)

    def actuate(self, fleet: Fleet, actions: np.ndarray) -> Actuation:
        r, f = fleet.rows, fleet.rows.frame
        assert f is not None
        return actuate(
            actions, r.speed, r.angle, f.offset, f.half_width, f.curvature, f.speed_limit,
            fleet.dt, fleet.car, ShieldBounds(r.side_limit, r.speed_cap),
        )  # fmt: skip


class TrafficDriver:
    """Lanes among SUMO's traffic (lanes.py): steer chooses a lane, accel and brake adjust a
    car-following law (actuation.actuate_lanes); SUMO's driver takes the car where the policies
    never trained (handover.py)."""

    name = "traffic"
    among_traffic = True
    """Trains among SUMO's traffic on the family of training roads (traffic_env.TrafficEnv)."""
    reward_scale = 0.1
    """The traffic reward's terms are ~1 per step."""
    reward_terms = TRAFFIC_TERM_NAMES
    """The named terms of its reward (rewards.traffic_rewards): what `reward_weights` may weigh."""
    exploration: ClassVar[dict[str, tuple[float, float, float]]] = {
        "ou_theta": (0.15, 1.0, 1.0),
        "ou_sigma": (0.2, 0.1, 0.05),
    }
    """Steer noise correlated over ~7 steps (theta 0.15, stationary std 0.38), so that exploring
    asks for a lane long enough to start a change."""
    normalisation = (
        "speeds/40 m/s, speed error/10 m/s, lateral speed/2 m/s, lane width/4 m, lanes/3, "
        "lane ends/500 m, gaps/150 m, relative speeds/15 m/s"
    )
    """How the observation's values are scaled (lanes.observe_lanes), as checkpoints record it."""

    def __init__(self, lateral: LaneDriving | None = None) -> None:
        self.lateral = LaneDriving() if lateral is None else lateral
        self._one_lane_at: dict[tuple[str, int], float] = {}  # (route, index) -> `_one_lane_road_at`

    @property
    def max_lateral_speed(self) -> float:
        """m/s: its lane changes' top sideways speed."""
        return self.lateral.max_lateral_speed

    def obs_size(self, with_id: bool) -> int:
        return TRAFFIC_OBS_SIZE

    def observation_layout(self, with_id: bool) -> str:
        """The observation's parts in order (the behaviour id always among them)."""
        return "traffic:" + "+".join(name for name, _ in TRAFFIC_LAYOUT)

    def observation_space(self, with_id: bool) -> spaces.Box:
        """Every value of the traffic observation (lanes.TRAFFIC_LAYOUT) lies within [-1.5, 1.5]."""
        return spaces.Box(
            np.full(TRAFFIC_OBS_SIZE, -1.5, np.float32),
            np.full(TRAFFIC_OBS_SIZE, 1.5, np.float32),
            dtype=np.float32,
        )

    def draw_style(self, behaviour_id: np.ndarray, rng: np.random.Generator) -> Styles:
        """Each agent's desired speed as a share of the local limit (its law's headway is the same for
        all, and its habits are its behaviour's)."""
        return unstyled(desired_fractions(behaviour_id, rng))

    def new_rows(self, count: int, style: Styles | None) -> TrafficRows:
        zeros = np.zeros(count)
        desired = zeros if style is None else np.asarray(style.desired_fraction, float)
        top = np.full(count, np.inf) if style is None else np.asarray(style.top_speed, float)
        return TrafficRows(
            desired_fraction=desired,
            top_speed=top,
            lateral_speed=zeros,
            lateral_accel=zeros,
            changing=np.zeros(count, np.int64),
            held_for=zeros,
            lane_number=np.full(count, -1, np.int64),
            lane_count=np.zeros(count, np.int64),
            lane_changed=np.zeros(count, bool),
            lane_ends=np.zeros((count, 3)),
            best_end=zeros,
            one_lane_at=np.full(count, np.inf),
            around=None,
            lanes=None,
            asking=None,
            time_headway=zeros,
            eagerness=zeros,
            lane_bias=zeros,
        )

    def observe(self, fleet: Fleet, sim: SumoSim, sensing: Sensing, with_id: bool) -> Observed:
        """The traffic observation (lanes.py); also keeps what the traffic reward and the actuation
        need, and decides the hand-overs (sent to SUMO by the fleet after sensing)."""
        r, g, own = fleet.rows, fleet.geometry, fleet.own
        vehicles, rows, readings = sensing.vehicles, sensing.rows, sensing.readings
        bodies = sensing.bodies
        radius = search_radius(bodies.longest)
        radius = max(radius, sensing.reach) if fleet.shield else radius
        front = vehicles.position[rows]  # read only below: one gather serves the search, frame and lanes
        near = neighbours(front, vehicles.position, radius, exclude=rows)
        frame = road_frame(g, readings, sensing.lane_rows, front, r.angle, fleet.car)
        number = g.lane_number[frame.lane_row]
        count = g.lane_num_lanes[frame.lane_row]
        normal = frame.on_normal_edge
        own.lane_changed = (
            (own.lane_number >= 0) & (number != own.lane_number) & (count == own.lane_count) & normal
        )
        own.lane_number = np.where(normal, number, own.lane_number)
        own.lane_count = np.where(normal, count, own.lane_count)
        speeds = vehicles.speed.copy()  # SUMO's; the agents' own are put in below
        self._refresh_lane_ends(fleet, sim, readings, sensing.entered)
        handover, handed = self._hand_over(fleet, sim, frame, readings, count, normal, speeds[rows])
        agents = LaneAgents(
            front=front,
            lane_row=frame.lane_row,
            shape_pos=r.shape_pos,  # the lane places just read, on the lanes' shapes
            curvature=frame.curvature,
            speed=handed.speed,
            lateral_speed=own.lateral_speed,
            changing=own.changing,
            desired_speed=desired_speed(own, frame.speed_limit),
            speed_limit=frame.speed_limit,
            lane_offset=readings.lateral_pos,
            lane_width=g.lane_width[frame.lane_row],
            lane_number=number,
            lanes=count,
            lane_leads_on=lane_leads_on(own.lane_ends, own.best_end, readings.lane_pos),
            behaviour_id=r.behaviour_id,
            # SUMO's lane indices and posLat grow towards the fast side in both kinds of net; the
            # world frame's left is the fast side only in keep-right nets
            fast_side_sign=-1.0 if g.lefthand else 1.0,
        )
        own.lanes = agents
        speeds[rows] = handed.speed
        own.around = around = lane_surroundings(agents, vehicles.position, speeds, rows, g, near, bodies)
        own.asking = self._asking_over(sim, around, handed.speed, rows[~handed.handed], vehicles.ids)
        return Observed(observe_lanes(agents, around), frame, near, handover, handed)

    def _asking_over(
        self, sim: SumoSim, around: Surroundings, speed: np.ndarray, driving: np.ndarray, ids: tuple[str, ...]
    ) -> np.ndarray:
        """[N, 2] bool: whether the fast-side and the slow-side leader within `look_ahead` wants to come
        over into the agent's lane for its route (an exit, a lane that ends for it), as SUMO's own
        lane-change model says of the cars it drives: what a driver reads from a car ahead in the next
        lane that slows and signals. Asked of those few cars only; `driving` are the rows of the
        agents that drive themselves, whose own wish to leave a lane the lane ends tell."""
        rows, gaps = around.side_leader_row, around.gap[:, [2, 4]]
        candidate = (rows >= 0) & (gaps < look_ahead(speed, self.lateral)[:, None])  # gap 0: alongside
        agent = np.zeros(len(ids), bool)
        agent[driving] = True
        candidate &= ~agent[np.maximum(rows, 0)]
        out = np.zeros(rows.shape, bool)
        if candidate.any():
            k, side = np.nonzero(candidate)
            # the fast-side leader comes over towards the slow side, the slow-side one towards the fast
            asked, which = np.unique(rows[k, side] * 2 + side, return_inverse=True)
            wishes = sim.wants_to_change(
                [ids[a // 2] for a in asked.tolist()], np.where(asked % 2 == 0, -1, 1)
            )
            out[k, side] = wishes[which]
        return out

    def _refresh_lane_ends(self, fleet: Fleet, sim: SumoSim, readings: Any, entered: np.ndarray) -> None:
        """Where the own and neighbouring lanes stop leading on, asked of SUMO only for the agents
        that `entered` a new lane (a few per step), kept in lane coordinates otherwise."""
        r, own = fleet.rows, fleet.own
        for i in entered.tolist():
            lane = readings.lane_id[i]
            if lane.startswith(":"):  # a junction leads on to the lane SUMO routes it to
                own.lane_ends[i] = readings.lane_pos[i] + JUNCTION_LEADS_ON
                continue
            ahead = sim.lane_lengths_ahead(r.ids[i])
            edge, _, index = lane.rpartition("_")
            k = int(index)
            own.lane_ends[i] = [ahead.get(f"{edge}_{j}", 0.0) for j in (k, k + 1, k - 1)]
            own.best_end[i] = max(ahead.values(), default=0.0)
            place = sim.route_place(r.ids[i])
            if place not in self._one_lane_at:  # agents on one route share it (a route can be long)
                self._one_lane_at[place] = self._one_lane_road_at(fleet, edge, sim.route_ahead(r.ids[i]))
            own.one_lane_at[i] = self._one_lane_at[place]

    @staticmethod
    def _one_lane_road_at(fleet: Fleet, edge: str, route_ahead: list[str]) -> float:
        """Metres from the start of `edge` to the first road of the route ahead with fewer than two car
        lanes (a ramp, a slip road, a street), within ONE_LANE_HORIZON of the end of `edge`; inf if
        there is none."""
        edges = fleet.geometry.edges
        info = edges.get(edge)
        edge_length = info.length if info is not None else 0.0
        at = edge_length
        for following in route_ahead:
            if at - edge_length > ONE_LANE_HORIZON:
                break
            info = edges.get(following)
            if info is None or info.lanes < 2:
                return at
            at += info.length
        return np.inf

    @staticmethod
    def _hand_over(
        fleet: Fleet,
        sim: SumoSim,
        frame: RoadFrame,
        readings: AgentReadings,
        lanes: np.ndarray,
        normal: np.ndarray,
        sumo_speed: np.ndarray,
    ) -> tuple[Handover, HandedRows]:
        """The hand-overs (handover.py) and the fleet's rows as they will be once sent: SUMO's speed
        for the cars it drives; those it gives back go on sideways as SUMO moved them (taken back at
        no sideways speed, a car SUMO was moving over at 1 m/s would stop its sideways motion within
        a step, docs/history.md)."""
        r, own = fleet.rows, fleet.own
        signal = (
            sim.signal_ahead(r.ids, np.maximum(SIGNAL_DISTANCE, SIGNAL_SECONDS * r.speed))
            if sim.has_signals
            else np.zeros(len(r.ids), bool)  # most motorway nets: no per-agent query at all
        )
        half_room = (fleet.geometry.lane_width[frame.lane_row] - fleet.car.width) / 2
        ends = LaneEnds(own.lane_ends, own.best_end, own.one_lane_at)
        place = LanePlace(
            readings.lane_pos, readings.lateral_pos, own.lane_number, lanes, half_room,
            own.lateral_speed,  # 0 where SUMO drives (`actuate`)
        )  # fmt: skip
        handover = decide(ends, place, r.handed, r.speed, normal, signal)
        angle = r.angle
        if handover.take.any():
            taken = np.flatnonzero(handover.take)
            own.lateral_speed[taken] = sim.read_lateral_speeds([r.ids[i] for i in taken])
            angle = r.angle.copy()  # the heading as `actuate_lanes` gives it
            angle[taken] = np.arctan2(own.lateral_speed[taken], np.maximum(r.speed[taken], 0.1))
        handed = (r.handed | handover.give) & ~handover.take
        speed = np.where(handed, sumo_speed, r.speed)  # SUMO drives them: their speed is SUMO's
        return handover, HandedRows(handed, speed, angle)

    def habits(self, lanes: LaneAgents) -> LaneHabits:
        """How the two behaviours use the lanes. Overtakers pass any leader slower than they want
        and go back right after a pass, wherever they are, as the law asks. Keepers keep the lane
        they are in, as lane keepers do: they pass only a much slower leader that has held them up
        a while, and move right only where their lane ends or their route asks (keepers that also
        kept right unasked changed lanes far more than lane keepers do: docs/history.md)."""
        overtaker = lanes.behaviour_id > 0.5
        ruled = self.lateral
        margin = np.where(overtaker, ruled.pass_margin, ruled.keeper_pass_margin)
        patience = np.where(overtaker, ruled.patience, ruled.keeper_patience)
        return LaneHabits(overtaker, margin, patience)

    @staticmethod
    def rewards(step: TrafficStep, weights: TrafficWeights) -> TrafficTerms:
        """The terms of its reward (rewards.traffic_rewards): the behaviour id's."""
        return traffic_rewards(step, weights)

    def may_begin(self, fleet: Fleet) -> np.ndarray:
        """[N] bool: where an agent may begin a lane change: not inside a junction (its lanes are a
        connection's, not the carriageway's), nor near the start of an edge nothing leads onto."""
        r, f = fleet.rows, fleet.rows.frame
        assert f is not None
        entering = fleet.geometry.lane_on_entry[f.lane_row] & (r.shape_pos < self.lateral.entry_clearance)
        return f.on_normal_edge & ~entering

    def actuate(self, fleet: Fleet, actions: np.ndarray) -> Actuation:
        lanes = fleet.own.lanes
        assert lanes is not None
        return self._carry(fleet, self._command(fleet, actions, self.lateral, self.habits(lanes)))

    def _command(
        self,
        fleet: Fleet,
        actions: np.ndarray,
        lateral: LaneDriving,
        habits: LaneHabits | None,
        time_headway: np.ndarray | None = None,
        lane_bias: np.ndarray | None = None,
    ) -> LaneCommand:
        """What `actuate_lanes` makes of `actions` for the fleet as last sensed (changes no rows)."""
        r, f, own = fleet.rows, fleet.rows.frame, fleet.own
        lanes, around = own.lanes, own.around
        assert f is not None and lanes is not None and around is not None
        motion = Motion(
            r.speed, lanes.desired_speed, own.lateral_speed, own.lateral_accel, own.changing, own.held_for
        )
        place = RoadPlace(
            lanes.lane_offset, lanes.lane_width, lanes.lanes - 1 - lanes.lane_number, lanes.lane_number,
            f.offset, f.half_width, f.speed_limit, lanes.lane_leads_on, self.may_begin(fleet),
        )  # fmt: skip
        return actuate_lanes(
            actions, motion, place, LaneNeighbours.sensed(around, own.asking),
            DriverSettings(lateral, fleet.dt, fleet.car), AgentStyle(habits, time_headway, lane_bias),
            ShieldBounds(r.side_limit, r.speed_cap),
        )  # fmt: skip

    @staticmethod
    def _carry(fleet: Fleet, command: LaneCommand, held_for: bool = True) -> Actuation:
        """The command's actuation; the state it carries to the next step goes into the rows of the
        agents that drive themselves (`held_for`: the seconds held up too)."""
        r, f, own = fleet.rows, fleet.rows.frame, fleet.own
        assert f is not None
        mine = ~r.handed  # SUMO drives the others: no lane change of ours goes on
        result = replace(
            command.actuation,
            # a junction's internal edge holds only the lanes of some connections, not the
            # carriageway: the move stays clamped to it, but leaving it is not off the road
            off_track=command.actuation.off_track & f.on_normal_edge,
            limits={name: int((hit & mine).sum()) for name, hit in command.limited.items()},
        )
        assert result.lateral_speed is not None
        own.changing = np.where(mine, command.changing, 0)
        own.lateral_accel = np.where(mine, command.lateral_accel, 0.0)
        if held_for:
            own.held_for = np.where(mine, command.held_for, 0.0)
        own.lateral_speed = np.where(mine, result.lateral_speed, 0.0)
        return result


STYLED_LAYOUT = (*TRAFFIC_LAYOUT[:-1], ("time_headway", 1), ("eagerness", 1))
"""The traffic observation with the driver's style in place of the behaviour id (its desired speed
is already among it)."""
STYLED_OBS_SIZE = TRAFFIC_OBS_SIZE + 1
STYLED_LANES = LaneDriving(network_chooses=True, min_time_headway=0.5)
"""The envelope of the styled driver: the network chooses lanes and headways; no car follows closer
than 0.5 s, well under any human style (HEADWAY_RANGE starts there too)."""


class StyledDriver(TrafficDriver):
    """The learned traffic driver: each agent has a style (styles.py: desired speed, time headway,
    eagerness to pass), which the one shared network sees and drives. The network chooses: its steer
    is the lane wish, both ways, and its accel the headway to follow at (`headway_of_action`); what
    stays hand-written only forbids (`LaneDriving.network_chooses`). The hand-written traffic driver's
    rules, given each style's habits, are its teacher (`teach`)."""

    name = "styled"
    normalisation = TrafficDriver.normalisation + ", time headway/3 s, eagerness in [0, 1]"

    def __init__(self, lateral: LaneDriving | None = None, population: Population | None = None) -> None:
        super().__init__(STYLED_LANES if lateral is None else lateral)
        self.population = PRESETS["default"] if population is None else population
        self._teacher_lanes = replace(self.lateral, network_chooses=False)

    def obs_size(self, with_id: bool) -> int:
        return STYLED_OBS_SIZE

    def observation_layout(self, with_id: bool) -> str:
        return "styled:" + "+".join(name for name, _ in STYLED_LAYOUT)

    def observation_space(self, with_id: bool) -> spaces.Box:
        return spaces.Box(
            np.full(STYLED_OBS_SIZE, -1.5, np.float32),
            np.full(STYLED_OBS_SIZE, 1.5, np.float32),
            dtype=np.float32,
        )

    def draw_style(self, behaviour_id: np.ndarray, rng: np.random.Generator) -> Styles:
        return draw_styles(behaviour_id, rng, self.population)

    def new_rows(self, count: int, style: Styles | None) -> TrafficRows:
        rows = super().new_rows(count, style)
        style = fixed_styles(np.ones(count)) if style is None else style
        rows.time_headway, rows.eagerness, rows.lane_bias = (
            style.time_headway,
            style.eagerness,
            style.lane_bias,
        )
        return rows

    def observe(self, fleet: Fleet, sim: SumoSim, sensing: Sensing, with_id: bool) -> Observed:
        observed = super().observe(fleet, sim, sensing, with_id)
        own = fleet.own
        style = np.stack([own.time_headway / HEADWAY_RANGE[1], own.eagerness], axis=1).astype(np.float32)
        return replace(observed, obs=np.concatenate([observed.obs[:, :-1], style], axis=1))

    @staticmethod
    def rewards(step: TrafficStep, weights: TrafficWeights) -> TrafficTerms:
        """The terms of its reward judged against each agent's style (rewards.styled_rewards)."""
        return styled_rewards(step, weights)

    def teacher_habits(self, eagerness: np.ndarray) -> LaneHabits:
        """The rules' habits of a style: every driver keeps right; the eager pass a leader a little
        slower than they want at once, the reluctant only a much slower one after a while."""
        return LaneHabits(np.ones(len(eagerness), bool), 8.0 - 6.0 * eagerness, 10.0 - 9.5 * eagerness)

    def teach(self, fleet: Fleet) -> np.ndarray:
        """[N, 3] float32: the actions that ask for what the hand-written rules, with each style's
        habits and headway, would do now: the lane they head for as steer (-1, 0, +1), the style's
        headway as accel, no brake. Keeps the seconds each agent has been held up (the rules'
        patience), which the network's own actuation leaves alone."""
        own = fleet.own
        n = len(own.eagerness)
        habits = self.teacher_habits(own.eagerness)
        neutral = np.tile(np.array([0.0, 0.5, 0.0]), (n, 1))  # the law as it is: no push, no brake
        command = self._command(fleet, neutral, self._teacher_lanes, habits, own.time_headway, own.lane_bias)
        own.held_for = np.where(~fleet.rows.handed, command.held_for, 0.0)
        steer = command.changing.astype(np.float32)
        return np.stack([steer, action_of_headway(own.time_headway), np.zeros(n)], axis=1).astype(np.float32)

    def actuate(self, fleet: Fleet, actions: np.ndarray) -> Actuation:
        headway = headway_of_action(actions[:, 1])
        command = self._command(fleet, actions, self.lateral, None, headway, fleet.own.lane_bias)
        return self._carry(fleet, command, held_for=False)


DRIVERS: dict[str, type[PaperDriver] | type[TrafficDriver]] = {
    PaperDriver.name: PaperDriver,
    TrafficDriver.name: TrafficDriver,
    StyledDriver.name: StyledDriver,
}
"""Every driver model by name: `--driver NAME`, and the name a checkpoint records."""


def make_driver(name: str, population: Population | None = None) -> PaperDriver | TrafficDriver:
    """A new driver of that name (one per fleet: a driver may cache per road); `population`: the style
    distributions its agents draw from (only a driver with styles takes one)."""
    if name not in DRIVERS:
        raise BehaveError(f"unknown driver '{name}' (choose from {', '.join(DRIVERS)})")
    if population is None:
        return DRIVERS[name]()
    if name != StyledDriver.name:
        raise BehaveError(
            f"--population draws driver styles, which the {name} driver has none of (use a styled policy)"
        )
    return StyledDriver(population=population)


def driver_of_obs_size(obs_dim: int) -> tuple[str, bool]:
    """The driver a policy of `obs_dim` inputs was trained for, and whether it takes the behaviour id;
    for checkpoints that do not name their driver."""
    for name, kind in DRIVERS.items():
        for with_id in (False, True):
            if kind().obs_size(with_id) == obs_dim:
                return name, with_id and kind().obs_size(False) != obs_dim
    sizes = sorted({kind().obs_size(w) for kind in DRIVERS.values() for w in (False, True)})
    raise BehaveError(f"no driver takes {obs_dim} observations (behave policies take {sizes})")
