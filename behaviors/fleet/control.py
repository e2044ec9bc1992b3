"""The learned agents of one simulation: their rows, what is read of SUMO for them, and the two
SUMO commands per agent, whatever their driver.

`Fleet` keeps what SUMO does not know about the agents (their speed and heading relative to the
road, how long they have been stuck), reads their lanes from one read of SUMO, lets its `Driver`
(drivers.py) turn that into observations and actions into moves, and writes SUMO: the moves, and
the hand-overs to SUMO's own driver (handover.py) in a phase of their own. Which agents exist and
when they leave is the caller's business (paper_env.py and traffic_env.py for training, population.py for
any network).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, is_dataclass, replace
from itertools import repeat
from typing import Any, Protocol

import numpy as np

from behaviors.car.model import Actuation, CarModel
from behaviors.fleet.handover import Handover
from behaviors.fleet.traffic_rows import TrafficRows
from behaviors.road.geometry import RoadGeometry
from behaviors.road.neighbours import Neighbours
from behaviors.sumo.sim import AgentReadings, SumoSim, VehicleState
from behaviors.sumo.timing import PhaseTimer
from behaviors.traffic.bodies import Bodies
from behaviors.traffic.lanes import lane_coordinates
from behaviors.traffic.rewards import NO_PROGRESS_SPEED
from behaviors.traffic.shield import safe_speed, search_reach, side_limits, surroundings

PROJECTION_TRUST = 2.0
"""m: a projected lane position this far from where the car's speed took it is asked of SUMO
(SUMO moved the car some other way)."""
LANE_LINE_MARGIN = 0.1
"""m: an agent whose centre is this far inside its lane's side lines and short of its end is still
in the lane it was in at the last read; nearer, its lane is asked of SUMO."""


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
    field here (or in its driver's rows, `own`), and cannot be forgotten when agents leave."""

    ids: list[str] = field(default_factory=list)
    speed: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angle: np.ndarray = field(default_factory=lambda: np.zeros(0))
    slow_time: np.ndarray = field(default_factory=lambda: np.zeros(0))
    behaviour_id: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    vehicle_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # in the last read
    frame: RoadFrame | None = None
    side_limit: np.ndarray | None = None  # [N, 2] from the last sensing, when shielded
    speed_cap: np.ndarray | None = None  # [N] from the last sensing, when shielded
    handed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # SUMO's driver has the car
    lane_row: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # at the last read, -1 = none
    last_move: np.ndarray = field(default_factory=lambda: np.zeros(0))  # sideways, sent to SUMO; NaN = none
    shape_pos: np.ndarray = field(default_factory=lambda: np.zeros(0))  # along that lane's shape, metres
    own: TrafficRows | None = None  # the traffic driver's own per-agent rows (None: the paper driver)

    def take(self, mask: np.ndarray) -> AgentRows:
        """The rows where `mask` is True, of every field."""
        return take_rows(self, mask)


def take_rows(value: Any, mask: np.ndarray) -> Any:
    """`value`'s rows where `mask` is True; None and plain numbers stay, a dataclass is taken field
    by field."""
    if value is None or isinstance(value, float):
        return value
    if is_dataclass(value) and not isinstance(value, type):
        return type(value)(**{f.name: take_rows(getattr(value, f.name), mask) for f in fields(value)})
    if len(value) != len(mask):
        raise ValueError(f"per-agent value has {len(value)} rows, the mask {len(mask)}")
    if isinstance(value, list):
        return [item for item, keep in zip(value, mask, strict=True) if keep]
    return value[mask]


def concat_rows(first: Any, second: Any) -> Any:
    """`second`'s rows after `first`'s, field by field for dataclasses; a value derived at sensing
    (None for the new rows) is None until the next sensing."""
    if first is None or second is None:
        return None
    if is_dataclass(first) and not isinstance(first, type):
        return type(first)(
            **{f.name: concat_rows(getattr(first, f.name), getattr(second, f.name)) for f in fields(first)}
        )
    if isinstance(first, list):
        return first + second
    return np.concatenate([first, second])


@dataclass(frozen=True)
class Sensing:
    """What a fleet read of SUMO for its agents this step, for its driver to observe."""

    vehicles: VehicleState
    rows: np.ndarray  # each agent's row in `vehicles`
    readings: AgentReadings  # lane, lane position and lateral offset per agent
    lane_rows: np.ndarray  # each agent's lane's row in the geometry
    entered: np.ndarray  # agents in another lane than at the last read
    reach: float  # metres within which the shield looks, when on
    bodies: Bodies  # every vehicle's size and the agents' own, read once for the driver and the shield


@dataclass(frozen=True)
class HandedRows:
    """The fleet's rows after a step's hand-overs: who SUMO drives, and the speeds and headings the
    agents go on from (SUMO's for the cars it drives; as SUMO moved them for those it gives back)."""

    handed: np.ndarray
    speed: np.ndarray
    angle: np.ndarray


@dataclass(frozen=True)
class Observed:
    """A driver's observation of its agents, and what it found on the way that the fleet keeps:
    the agents' place on the road, and the hand-overs with the rows they leave."""

    obs: np.ndarray
    frame: RoadFrame
    near: Neighbours | None = None  # a neighbour search as wide as the shield's, if one was made
    handover: Handover | None = None  # agents SUMO takes or gives back this step
    handed: HandedRows | None = None  # the rows after `handover` (None: unchanged)


class Driver(Protocol):
    """What differs between driver models (drivers.py): what the agents see and how they act."""

    name: str

    @property
    def max_lateral_speed(self) -> float:
        """m/s: the fastest sideways move it makes, which SUMO is told (`SimOptions.agent_max_speed_lat`)."""
        ...

    def draw_style(self, behaviour_id: np.ndarray, rng: np.random.Generator) -> Any:
        """Each new agent's style (what `new_rows` takes), drawn for its behaviour."""
        ...

    def new_rows(self, count: int, style: Any) -> TrafficRows | None:
        """Its own per-agent rows for `count` new agents (None if it keeps none)."""
        ...

    def observe(self, fleet: Fleet, sim: SumoSim, sensing: Sensing, with_id: bool) -> Observed:
        """Observations [N, obs size], the agents' road frame and hand-overs; updates its own rows
        (`fleet.own`), never the fleet's. Reads SUMO only."""
        ...

    def actuate(self, fleet: Fleet, actions: np.ndarray) -> Actuation:
        """What the agents do with [N, 3] actions; updates its own rows. Touches no SUMO."""
        ...


def moves_to_send(move: np.ndarray, last_move: np.ndarray) -> np.ndarray:
    """[N] bool: which sideways moves SUMO needs: all but a 0 to an agent whose last move was 0.

    SUMO holds an agent's move (`changeSublane`) in one number (`MSVehicle::Influencer::myLatDist`)
    that its lane changer sets back to 0 once it has taken the move up, and sets again itself only
    to carry on a non-zero move it has not finished: after a 0, it holds 0, and sending 0 again
    would change nothing. Agents keep their lane most steps: at 1,000 agents some 860 of the 1,000
    libsumo calls a step for the moves are left out.
    """
    return (move != 0.0) | (last_move != 0.0)


class Fleet:
    """State and stepping of N learned agents (row i = `ids[i]`), vectorised."""

    def __init__(
        self,
        geometry: RoadGeometry,
        car: CarModel,
        dt: float,
        timer: PhaseTimer,
        driver: Driver,
        shield: bool = False,
    ) -> None:
        """`driver`: a drivers.py driver model, one per fleet. `shield`: keep agents off the cars
        beside and ahead of them (populate only, see shield.py)."""
        self.driver = driver
        self.timer = timer
        self.shield = shield
        self.geometry = geometry
        self.car = car
        self.dt = dt
        self.rows = AgentRows(own=driver.new_rows(0, None))
        self.handovers = 0  # agents handed to SUMO's driver (exits, lane drops, signals)
        self._located: tuple[dict[str, int], list[str], np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.rows.ids)

    # read-only views of the per-agent rows that callers use
    ids = property(lambda self: self.rows.ids)
    speed = property(lambda self: self.rows.speed)
    slow_time = property(lambda self: self.rows.slow_time)
    behaviour_id = property(lambda self: self.rows.behaviour_id)
    frame = property(lambda self: self.rows.frame)
    vehicle_rows = property(lambda self: self.rows.vehicle_rows)

    @property
    def own(self) -> TrafficRows:
        """The traffic driver's own rows (a paper-driver fleet has none)."""
        if self.rows.own is None:
            raise TypeError(f"the {self.driver.name} driver keeps no rows of its own")
        return self.rows.own

    def add(
        self,
        ids: list[str],
        speed: np.ndarray,
        behaviour_id: np.ndarray,
        style: Any = None,
    ) -> None:
        """New agents at the end; their derived rows come with the next `sense`.

        `style` (drivers that use one, `Driver.draw_style`): how each agent wants to drive, such as
        the share of the local speed limit it holds when its lane is free."""
        r, zeros, n = self.rows, np.zeros(len(ids)), len(ids)
        self.rows = AgentRows(
            ids=r.ids + ids,
            speed=np.concatenate([r.speed, speed]),
            angle=np.concatenate([r.angle, zeros]),
            slow_time=np.concatenate([r.slow_time, zeros]),
            behaviour_id=np.concatenate([r.behaviour_id, behaviour_id.astype(np.float32)]),
            handed=np.concatenate([r.handed, np.zeros(n, bool)]),
            lane_row=np.concatenate([r.lane_row, np.full(n, -1, np.int64)]),
            last_move=np.concatenate([r.last_move, np.full(n, np.nan)]),
            shape_pos=np.concatenate([r.shape_pos, zeros]),
            own=concat_rows(r.own, self.driver.new_rows(n, style)),
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
        rows = np.fromiter(map(vehicles.row.get, self.ids, repeat(-1)), np.int64, len(self.ids))
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
        """Read the agents' lanes from SUMO and return their observations; then hand agents to
        SUMO's driver or take them back (its own phase), then the shield's limits."""
        with self.timer.phase("read"):
            rows = self.locate(vehicles)
            if (rows < 0).any():
                raise RuntimeError("Fleet.sense with agents SUMO no longer has: keep() them out first")
            self.rows.vehicle_rows = rows
            readings, lane_rows, entered = self._read_lanes(sim, vehicles, rows)
        bodies = Bodies(vehicles.length, vehicles.width, vehicles.length[rows], vehicles.width[rows])
        reach = search_reach(
            float(self.rows.speed.max(initial=0.0)), self.dt, self.car, vehicles.longest, bodies.own_longest
        )
        with self.timer.phase("sensors"):
            sensing = Sensing(vehicles, rows, readings, lane_rows, entered, reach, bodies)
            observed = self.driver.observe(self, sim, sensing, with_id)
        self.rows.frame = observed.frame
        if observed.handed is not None:
            r, h = self.rows, observed.handed
            r.handed, r.speed, r.angle = h.handed, h.speed, h.angle
        if observed.handover is not None:
            self._hand_over(sim, observed.handover)
        if self.shield:
            with self.timer.phase("shield"):
                self._shield(sensing, observed.near)
        return observed.obs

    def _hand_over(self, sim: SumoSim, handover: Handover) -> None:
        """Send the driver's hand-overs to SUMO (its rows already count them as decided)."""
        r = self.rows
        if handover.give.any():
            sim.hand_to_sumo([r.ids[i] for i in np.flatnonzero(handover.give)])
            self.handovers += int(handover.give.sum())
        if handover.take.any():
            sim.take_back([r.ids[i] for i in np.flatnonzero(handover.take)])

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
        (tests/learn/test_traffic.py): the same lane in every step, places equal to 1e-8 m in 99% of
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
        names = g.lane_name_array[lane_rows].tolist()
        return AgentReadings(names, lane_pos, lateral), lane_rows, entered

    def _shield(self, sensing: Sensing, near: Neighbours | None) -> None:
        """Side limits and speed caps for the next action (SUMO cars leading agents at SUMO's speed);
        the sensing's `reach` bounds the search, `near` is the sensors' search if they made one as wide."""
        vehicles, rows, reach, bodies = sensing.vehicles, sensing.rows, sensing.reach, sensing.bodies
        r = self.rows
        f = r.frame
        assert f is not None
        road_axis = f.heading - r.angle  # lanes run along the road, not along a swerving car
        fronts = vehicles.position
        around = surroundings(fronts[rows], road_axis, fronts, rows, self.car, reach, near, bodies)
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
        if r.frame is None:
            raise RuntimeError("Fleet.act before Fleet.sense")
        with self.timer.phase("actuation"):
            result = self.driver.actuate(self, actions)
            send_move = moves_to_send(result.lateral_move, r.last_move)
            if r.handed.any():
                result = self._without_handed(result)
                mine = ~r.handed
                ids = [vid for vid, m in zip(r.ids, mine.tolist(), strict=True) if m]
                moves = result.lateral_move[mine]
                sim.command_agents(ids, result.lane_speed[mine], moves, send_move[mine])
                r.last_move = np.where(mine, result.lateral_move, np.nan)  # SUMO's driver moves the others
            else:
                sim.command_agents(r.ids, result.lane_speed, result.lateral_move, send_move)
                r.last_move = result.lateral_move
        r.angle = result.angle
        self.record_speed(result.speed)
        return result
