"""What a populate run records: the summary, SUMO's own cars measured as the agents are, each agent's
run (AgentLog) and incident, and the agents table written from them."""

from __future__ import annotations

import csv
import io
import shutil
import tempfile
from dataclasses import astuple, dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from behaviors.car.model import CarModel
from behaviors.files import atomic_path
from behaviors.fleet.control import RoadFrame
from behaviors.learn.env import KEEPER_TYPE, LORRY_TYPE, OVERTAKER_TYPE
from behaviors.report.agents_table import (
    END_REASONS,
    LONG_STANDSTILL_S,
    STYLE_COLUMNS,
    AgentRun,
    cell,
    columns,
)
from behaviors.road.geometry import RoadGeometry
from behaviors.sumo.sim import STANDSTILL_SPEED
from behaviors.traffic.styles import KINDS, Styles

AGENT_TYPE_OF = dict(zip(KINDS, (KEEPER_TYPE, OVERTAKER_TYPE, LORRY_TYPE), strict=True))
"""The vType of each kind of learned vehicle."""


@dataclass
class PopulateSummary:
    vehicles: int = 0
    agent_steps: int = 0
    collisions: int = 0
    off_tracks: int = 0
    insert_retries: int = 0
    side_cuts: int = 0  # agent-steps whose sideways move the shield cut
    speed_cuts: int = 0  # agent-steps whose speed the shield cut
    limits: dict[str, int] = field(default_factory=dict)  # agent-steps each named limit of the traffic
    # driver vetoed or bound (traffic/limits.py, in its order)
    handovers: int = 0  # times SUMO's driver took an agent (exits, lane drops, one-lane roads, signals)
    scenario_cars: int = 0  # the sumocfg's passenger cars that departed
    scenario_agents: int = 0  # ... of which became agents (--share)
    scenario_not_car_sized: int = 0  # ... drawn by --share but left to SUMO: not a car's size (CAR_SIZE_M)
    simulated_s: float = 0.0
    wall_s: float = 0.0
    speed_sum: dict[str, float] = field(default_factory=lambda: dict.fromkeys(KINDS, 0.0))
    speed_steps: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))
    ended: dict[str, int] = field(default_factory=lambda: dict.fromkeys(END_REASONS, 0))
    long_standstills: int = 0  # agents that stood still for LONG_STANDSTILL_S or more at a time
    longest_standstill_s: float = 0.0
    sumo: SumoCars | None = None  # SUMO's own vehicles, measured as the agents are
    phases: dict[str, float] = field(default_factory=dict)
    cut_short: bool = False  # stopped by Ctrl-C before the duration: simulated_s says how far it got
    left_simulation: str = ""
    """A joined run: how it ended ("" for behave's own SUMO): `simulation_over` (no vehicles left to run,
    or SUMO's --end reached), `closed_by_sumo` (SUMO ended, was stopped, or the network dropped the
    connection), `duration` (--duration simulated) or `interrupted` (Ctrl-C)."""
    handed_back: int = 0  # a joined run: agents given back to SUMO's driver when behave left
    left_note: str = ""  # a joined run: what happened at the end, one line

    @property
    def real_time_factor(self) -> float:
        return self.simulated_s / max(self.wall_s, 1e-9)

    @property
    def limits_line(self) -> str:
        """`name N, ...`: the agent-steps each named limit of the traffic driver vetoed or bound."""
        return ", ".join(f"{name} {n}" for name, n in self.limits.items())

    def as_dict(self) -> dict[str, Any]:
        out = {
            "vehicles": self.vehicles,
            "agent_steps": self.agent_steps,
            "collisions": self.collisions,
            "off_tracks": self.off_tracks,
            "insert_retries": self.insert_retries,
            "shield_side_cuts": self.side_cuts,
            "shield_speed_cuts": self.speed_cuts,
            **({"limits": self.limits_line} if self.limits else {}),
            "handovers_to_sumo": self.handovers,
            **(
                {
                    "scenario_passenger_cars": self.scenario_cars,
                    "of_them_agents": self.scenario_agents,
                    "left_to_sumo_not_car_sized": self.scenario_not_car_sized,
                }
                if self.scenario_cars
                else {}
            ),
            "simulated_s": round(self.simulated_s, 6),  # a sum of steps: 19.99999999999996 is 20
            "wall_s": self.wall_s,
            "real_time_factor": self.real_time_factor,
        }
        for name in KINDS:
            if self.speed_steps[name]:
                out[f"{name}_mean_speed"] = self.speed_sum[name] / self.speed_steps[name]
        out.update({f"agents_{reason}": n for reason, n in self.ended.items()})
        if self.left_simulation:  # a joined run
            out["agents_handed_back_to_sumo"] = self.handed_back
        out[f"agents_standing_{LONG_STANDSTILL_S:.0f}s"] = self.long_standstills
        out["longest_standstill_s"] = round(self.longest_standstill_s, 6)
        if self.sumo is not None:  # SUMO's own vehicles beside the agents
            if self.sumo.steps:
                out["sumo_mean_speed"] = self.sumo.speed_sum / self.sumo.steps
            out[f"sumo_standing_{LONG_STANDSTILL_S:.0f}s"] = self.sumo.long_standstills
            out["sumo_longest_standstill_s"] = round(self.sumo.longest_standstill_s, 6)
        return out

    def count_agents(self, ended: EndedAgents, driving: list[AgentRow]) -> None:
        """How the agents ended and stood: those whose run ended (counted as they ended) and
        those `driving` at the end."""
        self.ended = dict(ended.reasons)
        standstills = [row.longest_standstill_s for row in driving]
        self.long_standstills = ended.long_standstills + sum(t >= LONG_STANDSTILL_S for t in standstills)
        self.longest_standstill_s = max([ended.longest_standstill_s, *standstills])
        for row in driving:
            self.ended[row.end_reason] += 1


class SumoCars:
    """SUMO's own vehicles (every vehicle that is not an agent), measured as the agents are: their mean
    speed over vehicle-steps and standstills (below STANDSTILL_SPEED, LONG_STANDSTILL_S or more at a
    time), so that a summary can show agents beside the cars SUMO drives on the same roads."""

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self.speed_sum, self.steps = 0.0, 0
        self.standing: dict[str, float] = {}  # vehicle id -> seconds it has stood so far
        self.long_standstills, self.longest_standstill_s = 0, 0.0

    def observe(self, ids: tuple[str, ...], speed: np.ndarray, sumo: np.ndarray) -> None:
        """One step's speeds of the vehicles `ids`; `sumo` marks those SUMO drives on its own."""
        self.speed_sum += float(speed[sumo].sum())
        self.steps += int(sumo.sum())
        now = {ids[k] for k in np.flatnonzero(sumo & (speed < STANDSTILL_SPEED)).tolist()}
        for vid in [v for v in self.standing if v not in now]:  # moved again, or left
            self._close(self.standing.pop(vid))
        for vid in now:
            self.standing[vid] = self.standing.get(vid, 0.0) + self.dt

    def finish(self) -> None:
        """Close the standstills still going at the end of the run."""
        for seconds in self.standing.values():
            self._close(seconds)
        self.standing = {}

    def _close(self, seconds: float) -> None:
        self.long_standstills += seconds >= LONG_STANDSTILL_S
        self.longest_standstill_s = max(self.longest_standstill_s, seconds)


@dataclass(frozen=True)
class Incident:
    """How an agent's collision or off-track looked at the read its last action was chosen from (one
    step before it), so a user sees what happened without reading FCD. Cars are taken as the agent's
    size; positions are front bumpers, sides seen from the agent's heading."""

    side: str  # where the other car was (left, right, front, rear), or the edge an agent left by
    lane: str  # the agent's SUMO lane
    lane_offset_m: float  # from that lane's centre, + = left
    other: str  # the other vehicle's id; "" for an off-track
    speed_mps: float  # the agent's SUMO speed
    other_speed_mps: float  # the other's SUMO speed (nan: none)
    headway_s: float  # front or rear: bumper gap / the follower's speed (nan: side by side, off-track)
    lateral_gap_m: float  # left or right: between the two cars' sides; off-track: to the road's edge


NO_INCIDENT = Incident("", "", np.nan, "", np.nan, np.nan, np.nan, np.nan)
"""The incident columns of an agent that neither collided nor left the road: empty cells."""


@dataclass(frozen=True)
class AgentRow(AgentRun):
    """One learned agent's run: a line of `<fcd stem>.agents.csv`, with populate's incident columns."""

    incident: Incident = NO_INCIDENT
    style: tuple[float, ...] = (np.nan,) * len(STYLE_COLUMNS)

    def cells(self) -> list[Any]:
        """The row's CSV cells in `agents_table.columns("populate")` order."""
        return [
            *super().cells(), *(cell(value) for value in astuple(self.incident)),
            *(cell(value) for value in self.style),
        ]  # fmt: skip


def collision_incident(
    front: np.ndarray,
    heading: float,
    speed: float,
    other_front: np.ndarray,
    other_speed: float,
    car: CarModel,
    other_size: tuple[float, float] | None = None,
) -> tuple[str, float, float]:
    """(side, headway, lateral gap) of two vehicles from their front bumpers and speeds: side by side
    where they overlap lengthwise (left or right), else one follows the other (front or rear). The
    agent is `car`-sized, the other `other_size` (length, width; None: `car`-sized), so the gap to a
    lorry ahead runs to its rear, 16 m behind its front."""
    other_length, other_width = (car.length, car.width) if other_size is None else other_size
    dx, dy = other_front - front
    along = dx * np.cos(heading) + dy * np.sin(heading)
    across = -dx * np.sin(heading) + dy * np.cos(heading)
    gap = along - other_length if along > 0 else -along - car.length
    if gap <= 0:
        side_gap = abs(across) - (car.width + other_width) / 2
        return ("left" if across > 0 else "right"), np.nan, float(side_gap)
    follower_speed = speed if along > 0 else other_speed
    headway = gap / follower_speed if follower_speed > 0 else np.inf
    return ("front" if along > 0 else "rear"), float(headway), np.nan


def lane_offsets(geometry: RoadGeometry, frame: RoadFrame) -> np.ndarray:
    """Each agent's offset from its lane's centre (+ = left), from its carriageway offset."""
    rows = frame.lane_row
    lanes = geometry.lane_num_lanes[rows]
    return frame.offset - (geometry.lane_number[rows] - (lanes - 1) / 2) * geometry.lane_width[rows]


def partners(pairs: list[tuple[str, str]]) -> dict[str, str]:
    """Each vehicle in a contact and the (first) vehicle it touched."""
    other: dict[str, str] = {}
    for collider, victim in pairs:
        other.setdefault(collider, victim)
        other.setdefault(victim, collider)
    return other


class AgentLog:
    """What each learned agent did according to SUMO (its speed after each step), from insertion
    to its end. Rows follow the fleet's: agents join and leave with it."""

    def __init__(self, step_length: float, policy: str) -> None:
        self.dt = step_length
        self.policy = policy
        self.ids: list[str] = []
        self.behaviour: list[str] = []
        self.depart = np.zeros(0)
        self.distance = np.zeros(0)  # SUMO's speed x step: its odometer under its Euler update
        self.standing = np.zeros(0)  # seconds standing still up to now
        self.longest = np.zeros(0)
        self.style = np.zeros((0, len(STYLE_COLUMNS)))
        self.ended = EndedAgents()

    def join(self, ids: list[str], behaviour: list[str], time: float, style: Styles) -> None:
        zeros = np.zeros(len(ids))
        self.ids, self.behaviour = self.ids + ids, self.behaviour + behaviour
        drawn = np.stack(
            [style.desired_fraction, style.time_headway, style.eagerness, style.lane_bias], axis=1
        )
        self.style = np.concatenate([self.style, drawn])
        self.depart = np.concatenate([self.depart, zeros + time])
        self.distance = np.concatenate([self.distance, zeros])
        self.standing = np.concatenate([self.standing, zeros])
        self.longest = np.concatenate([self.longest, zeros])

    def observe(self, present: np.ndarray, speed: np.ndarray) -> None:
        """SUMO's speeds after a step of the agents it still has (`present` rows, in order)."""
        self.distance[present] += speed * self.dt
        standing = self.standing[present]
        self.standing[present] = np.where(speed < STANDSTILL_SPEED, standing + self.dt, 0.0)
        np.maximum(self.longest, self.standing, out=self.longest)

    def end(self, reasons: np.ndarray, time: float, incidents: dict[int, Incident]) -> None:
        """Close the rows whose reason is not empty, with their `incidents` (by row), and drop them
        (as the fleet drops them)."""
        ending = reasons != ""
        if not ending.any():
            return
        for k in np.flatnonzero(ending):
            self.ended.append(self._row(int(k), str(reasons[k]), time, incidents.get(int(k), NO_INCIDENT)))
        keep = ~ending
        self.ids = [v for v, k in zip(self.ids, keep.tolist(), strict=True) if k]
        self.behaviour = [b for b, k in zip(self.behaviour, keep.tolist(), strict=True) if k]
        self.depart, self.distance = self.depart[keep], self.distance[keep]
        self.standing, self.longest = self.standing[keep], self.longest[keep]
        self.style = self.style[keep]

    def driving(self, time: float) -> list[AgentRow]:
        """The agents still on the road, ending `still_driving` at `time`."""
        return [self._row(k, "still_driving", time) for k in range(len(self.ids))]

    def _row(self, k: int, reason: str, time: float, incident: Incident = NO_INCIDENT) -> AgentRow:
        vtype = AGENT_TYPE_OF[self.behaviour[k]]
        depart, distance, longest = float(self.depart[k]), float(self.distance[k]), float(self.longest[k])
        return AgentRow(
            self.ids[k], self.behaviour[k], vtype, self.policy, round(depart, 3), round(time, 3), reason,
            round(distance, 2), round(longest, 3), incident, tuple(round(float(v), 3) for v in self.style[k]),
        )  # fmt: skip


class EndedAgents:
    """The rows of agents whose run ended, as CSV lines in an unnamed temporary file, and what the
    summary counts of them. A long run ends agents without bound (with --keep-count each one that
    leaves comes back as a new agent), so kept in a list they would grow populate with simulated
    time (docs/benchmarks.md, "Long runs")."""

    def __init__(self) -> None:
        self._file = tempfile.TemporaryFile("w+", encoding="utf-8", newline="")  # noqa: SIM115 (closed by close())
        self._writer = csv.writer(self._file, lineterminator="\n")
        self.count = 0
        self.reasons = dict.fromkeys(END_REASONS, 0)
        self.long_standstills = 0
        self.longest_standstill_s = 0.0

    def __len__(self) -> int:
        return self.count

    def append(self, row: AgentRow) -> None:
        self._writer.writerow(row.cells())
        self.count += 1
        self.reasons[row.end_reason] += 1
        self.long_standstills += row.longest_standstill_s >= LONG_STANDSTILL_S
        self.longest_standstill_s = max(self.longest_standstill_s, row.longest_standstill_s)

    def copy_to(self, out: IO[str]) -> None:
        """Write the rows so far to `out`, in the order the agents ended."""
        self._file.flush()
        self._file.seek(0)
        shutil.copyfileobj(self._file, out, 1 << 20)
        self._file.seek(0, io.SEEK_END)

    def close(self) -> None:
        self._file.close()


def write_agents_csv(path: Path, ended: EndedAgents, driving: list[AgentRow]) -> None:
    """The per-agent table (the agents that ended, then those `driving`), complete or absent
    (temp file + rename)."""
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as out:
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(columns("populate"))
        ended.copy_to(out)
        writer.writerows(row.cells() for row in driving)


def end_reasons(
    crashed: np.ndarray, off_track: np.ndarray, gone: np.ndarray, arrived: np.ndarray
) -> np.ndarray:
    """Each agent's end this step ("" = drives on); a crash counts before leaving the track, and an
    agent SUMO took out without arriving counts as no progress."""
    return np.select(
        [crashed, gone & arrived, off_track, gone], ["collision", "arrived", "off_track", "no_progress"], ""
    )
