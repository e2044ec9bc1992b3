"""The per-step loop shared by training, evaluation and populate.

`Fleet` keeps what SUMO does not know about the learned agents (their speed and
heading relative to the road, how long they have been stuck), turns one read
of SUMO into their observations, and one array of actions into the two SUMO
commands per agent. Which agents exist and when they leave is the caller's
business (env.py for training, populate.py for any network).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from behaviors.actuation import Actuation, CarModel, actuate
from behaviors.geometry import RoadGeometry
from behaviors.rewards import NO_PROGRESS_SPEED
from behaviors.sensors import AgentFrame, observe
from behaviors.shield import safe_speed, search_reach, side_limits, surroundings
from behaviors.sim import AgentReadings, SumoSim, VehicleState
from behaviors.timing import PhaseTimer


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


def road_frame(
    geometry: RoadGeometry,
    readings: AgentReadings,
    front: np.ndarray,
    angle: np.ndarray,
    car: CarModel,
) -> RoadFrame:
    """Locate agents from their lane, lane position and lateral offset; `front` is SUMO's position."""
    rows = np.array([geometry.lane_index[lane] for lane in readings.lane_id], np.int64)
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
    )


class Fleet:
    """State and stepping of N learned agents (row i = `ids[i]`), vectorised."""

    def __init__(
        self, geometry: RoadGeometry, car: CarModel, dt: float, timer: PhaseTimer, shield: bool = False
    ) -> None:
        """`shield`: keep agents off the cars beside and ahead of them (populate only, see shield.py)."""
        self.timer = timer
        self.shield = shield
        self.side_limit: np.ndarray | None = None  # [N, 2] from the last sensing, when shielded
        self.speed_cap: np.ndarray | None = None  # [N] from the last sensing, when shielded
        self.geometry = geometry
        self.car = car
        self.dt = dt
        self.ids: list[str] = []
        self.speed = np.zeros(0)
        self.angle = np.zeros(0)
        self.slow_time = np.zeros(0)
        self.behaviour_id = np.zeros(0, np.float32)
        self.frame: RoadFrame | None = None
        self.vehicle_rows = np.zeros(0, np.int64)  # each agent's row in the last VehicleState sensed
        self._located: tuple[dict[str, int], list[str], np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.ids)

    def add(self, ids: list[str], speed: np.ndarray, behaviour_id: np.ndarray) -> None:
        self.ids = self.ids + ids
        self.speed = np.concatenate([self.speed, speed])
        self.angle = np.concatenate([self.angle, np.zeros(len(ids))])
        self.slow_time = np.concatenate([self.slow_time, np.zeros(len(ids))])
        self.behaviour_id = np.concatenate([self.behaviour_id, behaviour_id.astype(np.float32)])

    def keep(self, mask: np.ndarray) -> None:
        """Drop the rows where `mask` is False (agents that left)."""
        if mask.all():
            return
        self.ids = [vid for vid, k in zip(self.ids, mask, strict=True) if k]
        self.speed, self.angle = self.speed[mask], self.angle[mask]
        self.slow_time, self.behaviour_id = self.slow_time[mask], self.behaviour_id[mask]
        if self.side_limit is not None and self.speed_cap is not None:
            self.side_limit, self.speed_cap = self.side_limit[mask], self.speed_cap[mask]
        if self.frame is not None:
            self.frame = RoadFrame(*(getattr(self.frame, f.name)[mask] for f in fields(RoadFrame)))

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
            readings = sim.read_agents(self.ids)
            rows = self.locate(vehicles)
            if (rows < 0).any():
                raise RuntimeError("Fleet.sense with agents SUMO no longer has: keep() them out first")
            self.vehicle_rows = rows
        with self.timer.phase("sensors"):
            obs = self._observe(readings, vehicles, rows, with_id)
        if self.shield:
            with self.timer.phase("shield"):
                self._shield(sim, vehicles, rows)
        return obs

    def _observe(self, readings: AgentReadings, vehicles: VehicleState, rows: np.ndarray, with_id: bool):
        self.frame = road_frame(self.geometry, readings, vehicles.position[rows], self.angle, self.car)
        centres = vehicles.position.copy()
        centres[rows] = self.frame.centre  # agents' centres are known exactly; others' fronts suffice
        agents = AgentFrame(
            centre=self.frame.centre,
            heading=self.frame.heading,
            angle=self.angle,
            speed=self.speed,
            track_pos=np.clip(self.frame.offset / self.frame.half_width, -1.0, 1.0),
        )
        return observe(agents, centres, rows, self.geometry, self.behaviour_id if with_id else None)

    def _shield(self, sim: SumoSim, vehicles: VehicleState, rows: np.ndarray) -> None:
        """Side limits and speed caps for the next action; reads the speed of SUMO cars leading agents."""
        f = self.frame
        assert f is not None
        reach = search_reach(float(self.speed.max(initial=0.0)), self.dt, self.car)
        road_axis = f.heading - self.angle  # lanes run along the road, not along a swerving car
        fronts = vehicles.position
        around = surroundings(fronts[rows], road_axis, fronts, rows, self.car, reach)
        agent_of = np.full(len(vehicles.ids), -1, np.int64)
        agent_of[rows] = np.arange(len(rows))
        leader_speed = np.zeros(len(rows))
        led = np.flatnonzero(around.leader >= 0)
        by_agent = agent_of[around.leader[led]]
        along_road = self.speed * np.cos(self.angle)
        leader_speed[led[by_agent >= 0]] = along_road[by_agent[by_agent >= 0]]
        by_sumo = led[by_agent < 0]
        if len(by_sumo):
            leader_speed[by_sumo] = sim.read_speeds([vehicles.ids[r] for r in around.leader[by_sumo]])
        self.side_limit = side_limits(around.side_room)
        self.speed_cap = safe_speed(around.leader_gap, leader_speed, self.speed, self.dt, self.car)

    def act(self, sim: SumoSim, actions: np.ndarray) -> Actuation:
        """Apply [N, 3] actions (steer, accel, brake) for the next step; returns what was commanded."""
        f = self.frame
        if f is None:
            raise RuntimeError("Fleet.act before Fleet.sense")
        with self.timer.phase("actuation"):
            result = actuate(
                actions, self.speed, self.angle, f.offset, f.half_width, f.curvature, f.speed_limit,
                self.dt, self.car, self.side_limit, self.speed_cap,
            )  # fmt: skip
            sim.command_agents(self.ids, result.lane_speed, result.lateral_move)
        self.speed, self.angle = result.speed, result.angle
        self.slow_time = np.where(result.speed < NO_PROGRESS_SPEED, self.slow_time + self.dt, 0.0)
        return result
