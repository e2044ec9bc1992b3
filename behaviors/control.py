"""The per-step loop shared by training, evaluation and populate.

`Fleet` keeps what SUMO does not know about the learned agents (their speed and
heading relative to the road, how long they have been stuck), turns one read
of SUMO into their observations, and one array of actions into the two SUMO
commands per agent. Which agents exist and when they leave is the caller's
business (env.py for training, populate.py for any network).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import numpy as np

from behaviors.actuation import Actuation, CarModel, LaneDriving, actuate, actuate_lanes
from behaviors.geometry import RoadGeometry
from behaviors.lanes import SEARCH_RADIUS, LaneAgents, Surroundings, lane_coordinates, observe_lanes
from behaviors.lanes import surroundings as lane_surroundings
from behaviors.rewards import NO_PROGRESS_SPEED
from behaviors.sensors import AgentFrame, Neighbours, neighbours, observe
from behaviors.shield import safe_speed, search_reach, side_limits, surroundings
from behaviors.sim import AgentReadings, SumoSim, VehicleState
from behaviors.timing import PhaseTimer

DRIVERS = ("paper", "traffic")
"""Driver models: the paper's TORCS state, reward and heading model, or lanes.py's traffic driver."""
HANDOVER_DISTANCE = 250.0
HANDOVER_SECONDS = 10.0
"""SUMO takes an agent whose lane ends within max(250 m, 10 s at its speed) while another lane goes on."""
HANDBACK_MARGIN = 100.0
"""m: the policy gets the car back only when its lane leads on this much beyond that reach."""
HANDBACK_INSIDE = 0.2
"""m: and only when its body is also this far inside its lane's lines: SUMO may carry a car it took
over a line into a lane that then drops, which leaves it on the carriageway's edge."""
LANE_END_MARGIN = 20.0
SIGNAL_DISTANCE = 100.0
SIGNAL_SECONDS = 5.0
"""SUMO also takes an agent with a red or yellow signal within max(100 m, 5 s at its speed) on its
route (the policies never saw a traffic light), and gives it back once none is."""
JUNCTION_LEADS_ON = 1e4
"""m: inside a junction every lane counts as leading on; SUMO is asked again on the next lane."""
PROJECTION_TRUST = 2.0
"""m: a projected lane position this far from where the car's speed took it is asked of SUMO
(SUMO moved the car some other way)."""
LANE_LINE_MARGIN = 0.1
"""m: an agent whose centre is this far inside its lane's side lines and short of its end is still
in the lane it was in at the last read; nearer, its lane is asked of SUMO."""
ONE_LANE_HORIZON = 1000.0
"""m: how far beyond the end of its edge an agent looks along its route for a road of one car lane
(SUMO drives it there); counted from the edge's end, since it is looked up once per lane entered and
a motorway edge may be longer than any horizon."""


@dataclass(frozen=True)
class RoadFrame:
    """Where each agent is on the road, derived from one SUMO read."""

    centre: np.ndarray  # [N, 2]
    heading: np.ndarray  # [N] world heading = road axis + relative angle
    offset: np.ndarray  # [N] metres from the carriageway centre, positive = left
    half_width: np.ndarray  # [N] half the carriageway width
    curvature: np.ndarray  # [N] 1/m, positive = road turns left
    speed_limit: np.ndarray  # [N] m/s
    on_normal_edge: np.ndarray  # [N] bool, False inside junctions
    lane_deviation: np.ndarray  # [N] |offset from the lane centre| / half the lane width, 1 = on a line
    lane_row: np.ndarray  # [N] row of the agent's lane in the geometry's lane tables


def road_frame(
    geometry: RoadGeometry,
    readings: AgentReadings,
    rows: np.ndarray,
    front: np.ndarray,
    angle: np.ndarray,
    car: CarModel,
) -> RoadFrame:
    """Locate agents from their lane (`rows` in the geometry's lane tables), lane position and
    lateral offset; `front` is SUMO's position."""
    tangent, curvature = geometry.road_axis(rows, readings.lane_pos)
    heading = tangent + angle
    centre = front - (car.length / 2) * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    width = geometry.lane_width[rows]
    lanes = geometry.lane_num_lanes[rows]
    offset = (geometry.lane_number[rows] - (lanes - 1) / 2) * width + readings.lateral_pos
    return RoadFrame(
        centre=centre,
        heading=heading,
        offset=offset,
        half_width=lanes * width / 2,
        curvature=curvature,
        speed_limit=geometry.lane_speed[rows],
        on_normal_edge=geometry.lane_normal[rows],
        lane_deviation=np.abs(readings.lateral_pos) / (width / 2),
        lane_row=rows,
    )


@dataclass
class AgentRows:
    """Every per-agent value of a Fleet (row i = `ids[i]`), in one place so that `take`
    drops a leaving agent's row from all of them at once: a new per-agent array is a new
    field here, and cannot be forgotten when agents leave."""

    ids: list[str] = field(default_factory=list)
    speed: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angle: np.ndarray = field(default_factory=lambda: np.zeros(0))
    slow_time: np.ndarray = field(default_factory=lambda: np.zeros(0))
    behaviour_id: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    vehicle_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # in the last read
    frame: RoadFrame | None = None
    side_limit: np.ndarray | None = None  # [N, 2] from the last sensing, when shielded
    speed_cap: np.ndarray | None = None  # [N] from the last sensing, when shielded
    # traffic driver only (see lanes.py): set by `add` and `sense`
    desired_fraction: np.ndarray = field(default_factory=lambda: np.zeros(0))  # of the local speed limit
    lateral_speed: np.ndarray = field(default_factory=lambda: np.zeros(0))  # + = fast side
    lateral_accel: np.ndarray = field(default_factory=lambda: np.zeros(0))  # + = fast side
    changing: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # see actuation.lane_intent
    lane_number: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # -1 = not sensed yet
    lane_count: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lane_changed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # at the last sensing
    lane_ends: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # own/fast/slow, lane coords
    best_end: np.ndarray = field(default_factory=lambda: np.zeros(0))  # the edge's farthest-leading lane
    one_lane_at: np.ndarray = field(
        default_factory=lambda: np.zeros(0)
    )  # route's next 1-lane road, lane coords
    handed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # SUMO's driver has the car
    lane_row: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # at the last read, -1 = none
    shape_pos: np.ndarray = field(default_factory=lambda: np.zeros(0))  # along that lane's shape, metres
    around: Surroundings | None = None
    lanes: LaneAgents | None = None  # the traffic driver's agents in their lanes, at the last sensing

    def take(self, mask: np.ndarray) -> AgentRows:
        """The rows where `mask` is True, of every field."""
        return AgentRows(**{f.name: take_rows(getattr(self, f.name), mask) for f in fields(self)})


def take_rows(value, mask: np.ndarray):
    """`value`'s rows where `mask` is True; None stays None, a RoadFrame is taken field by field."""
    if value is None or isinstance(value, float):
        return value
    if isinstance(value, RoadFrame | Surroundings | LaneAgents):
        return type(value)(*(take_rows(getattr(value, f.name), mask) for f in fields(value)))
    if len(value) != len(mask):
        raise ValueError(f"per-agent value has {len(value)} rows, the mask {len(mask)}")
    if isinstance(value, list):
        return [item for item, keep in zip(value, mask, strict=True) if keep]
    return value[mask]


def lane_leads_on(lane_ends: np.ndarray, best_end: np.ndarray, lane_pos: np.ndarray) -> np.ndarray:
    """Metres each of the own/fast/slow lanes leads on; a lane that goes as far as the edge's best
    lane (the route itself ends there, or the road goes on) counts as leading on for ever: the end
    of a route is not a lane that ends."""
    ending = lane_ends < best_end[:, None] - LANE_END_MARGIN
    return np.where(ending, lane_ends - lane_pos[:, None], np.inf)


class Fleet:
    """State and stepping of N learned agents (row i = `ids[i]`), vectorised."""

    def __init__(
        self,
        geometry: RoadGeometry,
        car: CarModel,
        dt: float,
        timer: PhaseTimer,
        shield: bool = False,
        driver: str = "paper",
    ) -> None:
        """`shield`: keep agents off the cars beside and ahead of them (populate only, see shield.py).
        `driver`: "paper" (TORCS state and heading model) or "traffic" (lanes.py, `actuate_lanes`)."""
        if driver not in DRIVERS:
            raise ValueError(f"unknown driver model {driver!r}")
        self.driver = driver
        self.lateral = LaneDriving()
        self.timer = timer
        self.shield = shield
        self.geometry = geometry
        self.car = car
        self.dt = dt
        self.rows = AgentRows()
        self.handovers = 0  # agents handed to SUMO's driver (traffic driver: exits, lane drops)
        self._located: tuple[dict[str, int], list[str], np.ndarray] | None = None
        self._one_lane_at: dict[tuple[str, int], float] = {}  # (route, index) -> `_one_lane_road_at`

    def __len__(self) -> int:
        return len(self.rows.ids)

    # read-only views of the per-agent rows that callers use
    ids = property(lambda self: self.rows.ids)
    speed = property(lambda self: self.rows.speed)
    slow_time = property(lambda self: self.rows.slow_time)
    behaviour_id = property(lambda self: self.rows.behaviour_id)
    frame = property(lambda self: self.rows.frame)
    vehicle_rows = property(lambda self: self.rows.vehicle_rows)

    def add(
        self,
        ids: list[str],
        speed: np.ndarray,
        behaviour_id: np.ndarray,
        desired_fraction: np.ndarray | None = None,
    ) -> None:
        """New agents at the end; their derived rows come with the next `sense`.

        `desired_fraction` (traffic driver): the share of the local speed limit each agent
        holds when its lane is free."""
        r, zeros, n = self.rows, np.zeros(len(ids)), len(ids)
        desired = np.zeros(n) if desired_fraction is None else np.asarray(desired_fraction, float)
        self.rows = AgentRows(
            ids=r.ids + ids,
            speed=np.concatenate([r.speed, speed]),
            angle=np.concatenate([r.angle, zeros]),
            slow_time=np.concatenate([r.slow_time, zeros]),
            behaviour_id=np.concatenate([r.behaviour_id, behaviour_id.astype(np.float32)]),
            desired_fraction=np.concatenate([r.desired_fraction, desired]),
            lateral_speed=np.concatenate([r.lateral_speed, zeros]),
            lateral_accel=np.concatenate([r.lateral_accel, zeros]),
            changing=np.concatenate([r.changing, np.zeros(n, np.int64)]),
            lane_number=np.concatenate([r.lane_number, np.full(n, -1, np.int64)]),
            lane_count=np.concatenate([r.lane_count, np.zeros(n, np.int64)]),
            lane_changed=np.concatenate([r.lane_changed, np.zeros(n, bool)]),
            lane_ends=np.concatenate([r.lane_ends, np.zeros((n, 3))]),
            best_end=np.concatenate([r.best_end, np.zeros(n)]),
            one_lane_at=np.concatenate([r.one_lane_at, np.full(n, np.inf)]),
            handed=np.concatenate([r.handed, np.zeros(n, bool)]),
            lane_row=np.concatenate([r.lane_row, np.full(n, -1, np.int64)]),
            shape_pos=np.concatenate([r.shape_pos, zeros]),
        )

    def keep(self, mask: np.ndarray) -> None:
        """Drop the rows where `mask` is False (agents that left)."""
        if not mask.all():
            self.rows = self.rows.take(mask)

    def record_speed(self, speed: np.ndarray) -> None:
        """The agents' new speeds (from the actuation, or SUMO's when SUMO drives) and how long
        each has been below the no-progress speed."""
        r = self.rows
        r.slow_time = np.where(speed < NO_PROGRESS_SPEED, r.slow_time + self.dt, 0.0)
        r.speed = speed

    def locate(self, vehicles: VehicleState) -> np.ndarray:
        """Each agent's row in `vehicles`, -1 for agents SUMO no longer has.

        Remembered while neither the vehicles' rows nor the agents change (most steps),
        so a big fleet is looked up once, not once per step.
        """
        last = self._located
        if last is not None and last[0] is vehicles.row and last[1] is self.ids:
            return last[2]
        get = vehicles.row.get
        rows = np.array([get(vid, -1) for vid in self.ids], np.int64)
        self._located = (vehicles.row, self.ids, rows)
        return rows

    def involved(self, vehicles: VehicleState, names: set[str]) -> np.ndarray:
        """Which agents are among `names` (e.g. this step's collisions), matched through their rows
        in `vehicles`, so the cost follows the few names, not the size of the fleet."""
        hit = [vehicles.row[v] for v in names if v in vehicles.row]
        if not hit:
            return np.zeros(len(self.ids), bool)
        return np.isin(self.locate(vehicles), hit)

    def sense(self, sim: SumoSim, vehicles: VehicleState, with_id: bool) -> np.ndarray:
        """Read the agents' lanes from SUMO and return their observations [N, 65 or 66]."""
        with self.timer.phase("read"):
            rows = self.locate(vehicles)
            if (rows < 0).any():
                raise RuntimeError("Fleet.sense with agents SUMO no longer has: keep() them out first")
            self.rows.vehicle_rows = rows
            readings, lane_rows, entered = self._read_lanes(sim, vehicles, rows)
        reach = search_reach(float(self.rows.speed.max(initial=0.0)), self.dt, self.car)
        near = None
        with self.timer.phase("sensors"):
            if self.driver == "traffic":  # one neighbour search for the lanes and the shield
                radius = max(SEARCH_RADIUS, reach) if self.shield else SEARCH_RADIUS
                near = neighbours(vehicles.position[rows], vehicles.position, radius, exclude=rows)
                obs = self._observe_lanes(sim, readings, lane_rows, entered, vehicles, rows, near)
            else:
                obs = self._observe(readings, lane_rows, vehicles, rows, with_id)
        if self.shield:
            with self.timer.phase("shield"):
                self._shield(vehicles, rows, reach, near)
        return obs

    def _read_lanes(
        self, sim: SumoSim, vehicles: VehicleState, rows: np.ndarray
    ) -> tuple[AgentReadings, np.ndarray, np.ndarray]:
        """Each agent's lane, lane position and lateral offset, its lane rows in the geometry, and
        which agents entered another lane than at the last read (new agents too: their last row is -1).

        Mostly without asking SUMO: an agent's position projected onto the shape of its lane at the
        last read gives its lane position and lateral offset there, which is how SUMO placed it. A car
        leaves its lane only across a side line (SUMO's sublane model moves it to the next lane when
        its centre crosses one) or past the lane's end, so where the projection puts the centre
        LANE_LINE_MARGIN inside both lines and short of the end, the lane is still that one (1,000
        agents: some 2,900 of 3,000 libsumo calls a step saved). The others (near a line or the
        lane's end, new agents, a junction lane drawn with no length, or a projection that lands far
        from where the car's speed took it) have their lane read from SUMO, and their lane places
        too where the lane is new or the projection untrusted. Measured against SUMO's own values
        (tests/test_traffic.py): the same lane in every step, places equal to 1e-8 m in 99% of
        steps, 3 mm at most.
        """
        r, g = self.rows, self.geometry
        lane_rows = r.lane_row.copy()
        lane_pos, lateral = np.empty(len(lane_rows)), np.empty(len(lane_rows))
        known = np.flatnonzero((lane_rows >= 0) & (g.lane_length_scale[lane_rows] > 0))
        guess = r.shape_pos[known] + vehicles.speed[rows[known]] * self.dt  # SUMO moves by v(t+dt) * dt
        along, across = lane_coordinates(
            g,
            lane_rows[known],
            guess,
            vehicles.position[rows[known]],
            np.arange(len(known)),
            np.zeros((len(known), 2)),
        )
        shape_pos = guess + along
        half_width = g.lane_width[lane_rows[known]] / 2
        trusted = np.abs(along) < PROJECTION_TRUST
        inside = (
            trusted
            & (np.abs(across) < half_width - LANE_LINE_MARGIN)
            & (shape_pos < g.lane_shape_length[lane_rows[known]] - LANE_LINE_MARGIN)
        )
        derived = np.zeros(len(lane_rows), bool)
        derived[known] = trusted & (np.abs(across) < 2 * half_width)
        lane_pos[known] = shape_pos / g.lane_length_scale[lane_rows[known]]
        lateral[known] = -across if g.lefthand else across  # SUMO's posLat grows to the fast side
        unsure = np.ones(len(lane_rows), bool)
        unsure[known[inside]] = False
        if unsure.any():
            ask = np.flatnonzero(unsure)
            read = sim.read_lanes([r.ids[k] for k in ask])
            now = np.fromiter(map(g.lane_index.__getitem__, read), np.int64, len(read))
            derived[ask[now != lane_rows[ask]]] = False  # another lane: its places are SUMO's to give
            lane_rows[ask] = now
        if not derived.all():
            ask = np.flatnonzero(~derived)
            lane_pos[ask], lateral[ask] = sim.read_lane_places([r.ids[k] for k in ask])
        entered = np.flatnonzero(lane_rows != r.lane_row)
        r.lane_row, r.shape_pos = lane_rows, lane_pos * g.lane_length_scale[lane_rows]
        names = g.lane_names
        return AgentReadings([names[k] for k in lane_rows.tolist()], lane_pos, lateral), lane_rows, entered

    def _observe(
        self,
        readings: AgentReadings,
        lane_rows: np.ndarray,
        vehicles: VehicleState,
        rows: np.ndarray,
        with_id: bool,
    ) -> np.ndarray:
        r = self.rows
        front = vehicles.position[rows]
        r.frame = frame = road_frame(self.geometry, readings, lane_rows, front, r.angle, self.car)
        centres = vehicles.position.copy()
        centres[rows] = frame.centre  # agents' centres are known exactly; others' fronts suffice
        agents = AgentFrame(
            centre=frame.centre,
            heading=frame.heading,
            angle=r.angle,
            speed=r.speed,
            track_pos=np.clip(frame.offset / frame.half_width, -1.0, 1.0),
        )
        return observe(agents, centres, rows, self.geometry, r.behaviour_id if with_id else None)

    def _observe_lanes(
        self,
        sim: SumoSim,
        readings: AgentReadings,
        lane_rows: np.ndarray,
        entered: np.ndarray,
        vehicles: VehicleState,
        rows: np.ndarray,
        near: Neighbours,
    ) -> np.ndarray:
        """The traffic observation (lanes.py); also keeps what the traffic reward needs.
        `entered`: the agents in another lane than at the last read."""
        r, g = self.rows, self.geometry
        r.frame = frame = road_frame(g, readings, lane_rows, vehicles.position[rows], r.angle, self.car)
        number = g.lane_number[frame.lane_row]
        count = g.lane_num_lanes[frame.lane_row]
        normal = frame.on_normal_edge
        r.lane_changed = (r.lane_number >= 0) & (number != r.lane_number) & (count == r.lane_count) & normal
        r.lane_number = np.where(normal, number, r.lane_number)
        r.lane_count = np.where(normal, count, r.lane_count)
        speeds = vehicles.speed.copy()  # SUMO's; the agents' own are put in below
        self._refresh_lane_ends(sim, readings, entered)
        self._hand_over(sim, readings, count, normal, speeds[rows])
        agents = LaneAgents(
            front=vehicles.position[rows],
            lane_row=frame.lane_row,
            shape_pos=readings.lane_pos * g.lane_length_scale[frame.lane_row],
            curvature=frame.curvature,
            speed=r.speed,
            lateral_speed=r.lateral_speed,
            changing=r.changing,
            desired_speed=r.desired_fraction * frame.speed_limit,
            speed_limit=frame.speed_limit,
            lane_offset=readings.lateral_pos,
            lane_width=g.lane_width[frame.lane_row],
            lane_number=number,
            lanes=count,
            lane_leads_on=lane_leads_on(r.lane_ends, r.best_end, readings.lane_pos),
            behaviour_id=r.behaviour_id,
            # SUMO's lane indices and posLat grow towards the fast side in both kinds of net; the
            # world frame's left is the fast side only in keep-right nets
            fast_side_sign=-1.0 if g.lefthand else 1.0,
        )
        r.lanes = agents
        speeds[rows] = r.speed
        r.around = around = lane_surroundings(agents, vehicles.position, speeds, rows, g, near)
        return observe_lanes(agents, around)

    def _refresh_lane_ends(self, sim: SumoSim, readings: AgentReadings, entered: np.ndarray) -> None:
        """Where the own and neighbouring lanes stop leading on, asked of SUMO only for the agents
        that `entered` a new lane (a few per step), kept in lane coordinates otherwise."""
        r = self.rows
        for i in entered.tolist():
            lane = readings.lane_id[i]
            if lane.startswith(":"):  # a junction leads on to the lane SUMO routes it to
                r.lane_ends[i] = readings.lane_pos[i] + JUNCTION_LEADS_ON
                continue
            ahead = sim.lane_lengths_ahead(r.ids[i])
            edge, _, index = lane.rpartition("_")
            k = int(index)
            r.lane_ends[i] = [ahead.get(f"{edge}_{j}", 0.0) for j in (k, k + 1, k - 1)]
            r.best_end[i] = max(ahead.values(), default=0.0)
            place = sim.route_place(r.ids[i])
            if place not in self._one_lane_at:  # agents on one route share it (a route can be long)
                self._one_lane_at[place] = self._one_lane_road_at(edge, sim.route_ahead(r.ids[i]))
            r.one_lane_at[i] = self._one_lane_at[place]

    def _one_lane_road_at(self, edge: str, route_ahead: list[str]) -> float:
        """Metres from the start of `edge` to the first road of the route ahead with fewer than two car
        lanes (a ramp, a slip road, a street), within ONE_LANE_HORIZON of the end of `edge`; inf if
        there is none."""
        edges = self.geometry.edges
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

    def _hand_over(
        self,
        sim: SumoSim,
        readings: AgentReadings,
        lanes: np.ndarray,
        normal: np.ndarray,
        sumo_speed: np.ndarray,
    ) -> None:
        """SUMO's strategic layer takes an agent whose lane stops leading on soon while another lane
        of its edge goes on (an exit or a lane drop ahead), or that is on a one-lane road, and
        hands it back once it is inside a lane that leads on; likewise at a red or yellow signal ahead.
        The policies learnt on roads where every lane goes on and no light turns red; SUMO knows
        where each route needs to be and stops at the line."""
        r = self.rows
        own_left = r.lane_ends[:, 0] - readings.lane_pos
        reach = np.maximum(HANDOVER_DISTANCE, HANDOVER_SECONDS * r.speed)
        one_lane_left = r.one_lane_at - readings.lane_pos
        # a ramp usually leaves from lane 0: SUMO gets the reach once per lane it has to cross
        ramp_reach = reach * (1 + np.maximum(r.lane_number, 0))
        ending = (own_left < reach) & (r.best_end > r.lane_ends[:, 0] + LANE_END_MARGIN)
        ending |= one_lane_left < ramp_reach  # leaving the carriageway: SUMO takes the car to the ramp
        half_room = self._half_room()
        straddling = self._straddling_an_ending_lane(readings, lanes, reach, half_room)
        ending |= straddling
        signal = (
            sim.signal_ahead(r.ids, np.maximum(SIGNAL_DISTANCE, SIGNAL_SECONDS * r.speed))
            if sim.has_signals
            else np.zeros(len(r.ids), bool)  # most motorway nets: no per-agent query at all
        )
        needs_sumo = (normal & (ending | (lanes < 2))) | signal
        free = (
            normal
            & (lanes >= 2)
            & ~((own_left < reach + HANDBACK_MARGIN) & (r.best_end > r.lane_ends[:, 0]))
            & (one_lane_left >= ramp_reach + HANDBACK_MARGIN)
            & ~straddling
            & ~signal
            & (np.abs(readings.lateral_pos) <= half_room - HANDBACK_INSIDE)
        )
        give = needs_sumo & ~r.handed
        take = r.handed & free
        if give.any():
            sim.hand_to_sumo([r.ids[i] for i in np.flatnonzero(give)])
            self.handovers += int(give.sum())
        if take.any():
            sim.take_back([r.ids[i] for i in np.flatnonzero(take)])
            r.lateral_speed[take] = 0.0
            r.angle[take] = 0.0
        r.handed = (r.handed | give) & ~take
        r.speed = np.where(r.handed, sumo_speed, r.speed)  # SUMO drives them: their speed is SUMO's

    def _half_room(self) -> np.ndarray:
        """Metres each agent's centre may move from its lane centre before its body meets a line."""
        assert self.rows.frame is not None
        return (self.geometry.lane_width[self.rows.frame.lane_row] - self.car.width) / 2

    def _straddling_an_ending_lane(
        self, readings: AgentReadings, lanes: np.ndarray, reach: np.ndarray, half_room: np.ndarray
    ) -> np.ndarray:
        """Agents whose body reaches over the line into a neighbouring lane that ends within `reach`:
        where that lane drops, the road narrows under them. SUMO takes them and centres them in a
        lane that goes on (the policies never trained beside a lane drop)."""
        r = self.rows
        leads = r.lane_ends - readings.lane_pos[:, None]
        short = (leads < reach[:, None]) & (r.lane_ends < r.best_end[:, None] - LANE_END_MARGIN)
        fast_exists = r.lane_number < lanes - 1
        slow_exists = r.lane_number > 0
        over_fast = (readings.lateral_pos > half_room) & fast_exists & short[:, 1]
        over_slow = (readings.lateral_pos < -half_room) & slow_exists & short[:, 2]
        return over_fast | over_slow

    def _shield(
        self, vehicles: VehicleState, rows: np.ndarray, reach: float, near: Neighbours | None
    ) -> None:
        """Side limits and speed caps for the next action (SUMO cars leading agents at SUMO's speed);
        `reach` bounds the search, `near` is the sensors' search if they made one as wide."""
        r = self.rows
        f = r.frame
        assert f is not None
        road_axis = f.heading - r.angle  # lanes run along the road, not along a swerving car
        fronts = vehicles.position
        around = surroundings(fronts[rows], road_axis, fronts, rows, self.car, reach, near)
        agent_of = np.full(len(vehicles.ids), -1, np.int64)
        agent_of[rows] = np.arange(len(rows))
        leader_speed = np.zeros(len(rows))
        led = np.flatnonzero(around.leader >= 0)
        by_agent = agent_of[around.leader[led]]
        along_road = r.speed * np.cos(r.angle)
        leader_speed[led[by_agent >= 0]] = along_road[by_agent[by_agent >= 0]]
        by_sumo = led[by_agent < 0]
        leader_speed[by_sumo] = vehicles.speed[around.leader[by_sumo]]
        limits = side_limits(around.side_room)  # geometric (left, right)
        # moves are signed like SUMO's lane indices: + is the geometric right in left-hand nets
        r.side_limit = limits[:, ::-1] if self.geometry.lefthand else limits
        r.speed_cap = safe_speed(around.leader_gap, leader_speed, r.speed, self.dt, self.car)

    def _without_handed(self, result: Actuation) -> Actuation:
        """What the agents SUMO drives really do: SUMO's speed, no sideways move, never off-track."""
        r = self.rows
        mine = ~r.handed
        lateral = None if result.lateral_speed is None else np.where(mine, result.lateral_speed, 0.0)
        return replace(
            result,
            speed=np.where(mine, result.speed, r.speed),
            angle=np.where(mine, result.angle, 0.0),
            lateral_move=np.where(mine, result.lateral_move, 0.0),
            off_track=result.off_track & mine,
            lateral_speed=lateral,
        )

    def act(self, sim: SumoSim, actions: np.ndarray) -> Actuation:
        """Apply [N, 3] actions (steer, accel, brake) for the next step; returns what was commanded."""
        r = self.rows
        f = r.frame
        if f is None:
            raise RuntimeError("Fleet.act before Fleet.sense")
        with self.timer.phase("actuation"):
            if self.driver == "traffic":
                lanes, around = r.lanes, r.around
                assert lanes is not None and around is not None
                leaders = [0, 2, 4]  # own, fast-side and slow-side leader (lanes.NEIGHBOUR_SLOTS)
                command = actuate_lanes(
                    actions, r.speed, lanes.desired_speed, around.gap[:, leaders],
                    around.other_speed[:, leaders], r.lateral_speed, r.lateral_accel, r.changing,
                    lanes.lane_offset, lanes.lane_width, lanes.lanes - 1 - lanes.lane_number,
                    lanes.lane_number, f.offset, f.half_width, f.speed_limit, self.dt, self.car,
                    self.lateral, r.side_limit, r.speed_cap,
                )  # fmt: skip
                # a junction's internal edge holds only the lanes of some connections, not the
                # carriageway: the move stays clamped to it, but leaving it is not off the road
                result = replace(command.actuation, off_track=command.actuation.off_track & f.on_normal_edge)
                mine = ~r.handed  # SUMO drives the others: no lane change of ours goes on
                r.changing = np.where(mine, command.changing, 0)
                r.lateral_accel = np.where(mine, command.lateral_accel, 0.0)
            else:
                result = actuate(
                    actions, r.speed, r.angle, f.offset, f.half_width, f.curvature, f.speed_limit,
                    self.dt, self.car, r.side_limit, r.speed_cap,
                )  # fmt: skip
            if r.handed.any():
                result = self._without_handed(result)
                mine = ~r.handed
                ids = [vid for vid, m in zip(r.ids, mine.tolist(), strict=True) if m]
                sim.command_agents(ids, result.lane_speed[mine], result.lateral_move[mine])
            else:
                sim.command_agents(r.ids, result.lane_speed, result.lateral_move)
        if result.lateral_speed is not None:
            r.lateral_speed = result.lateral_speed
        r.angle = result.angle
        self.record_speed(result.speed)
        return result
