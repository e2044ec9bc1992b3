"""`behave populate`: learned keepers and overtakers on any SUMO network with multi-lane edges.

Design choices (see README, "Populate"):
* Agents only get routes made of multi-lane edges (following the network's
  connections between them): the learned behaviour was trained on multi-lane
  carriageways, so single-lane ramps and side roads are never entered; the
  junctions between two multi-lane edges are driven by the policy (their lane
  axes are known, their borders are the neighbouring edges').
* SUMO picks free insertion places (`departPos="random_free"`), so nobody is
  inserted on top of another car; an agent that could not be inserted is
  withdrawn and tried again elsewhere on the next step.
* A safety shield (shield.py, on by default) cuts sideways moves towards a car
  alongside and speeds that could not stop behind the car ahead: the policies
  learnt among a few cars and, in dense traffic, drift into their neighbours and
  run into slower cars. `shield=False` drives with the bare policy.
* The whole fleet acts through one batched policy call per step.
* `--sumocfg` runs a user's scenario as its sumocfg sets it (scenario_config.py), and
  `share` turns that fraction of its passenger cars into agents when they depart: which
  cars is fixed by the seed and the car's id (a hash), not by what happens in the run, and
  the others stay SUMO's, driving as in the plain SUMO run until they meet an agent.
* SUMO writes the FCD itself (so the format is exactly SUMO's), to a temporary
  file that is renamed into place only when the run completed. Ctrl-C ends the run
  after the step under way: what was simulated is kept as a whole FCD (and agents
  table), and `populate` raises PopulateInterrupted with the summary marked cut short.
* `gui` runs the same simulation in sumo-gui (libsumo's own GUI), coloured by vType.
* `connect` joins a SUMO another program runs, as one more TraCI client (joined.py, `populate_joined`):
  the same share rules and driver, no FCD of its own (SUMO's outputs hold every vehicle), the
  agents still on the road handed back to SUMO when behave leaves (docs/manual/connect.md).
"""

from __future__ import annotations

import contextlib
import csv
import functools
import io
import math
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import astuple, dataclass, field, replace
from pathlib import Path
from typing import IO, Any

import numpy as np
import torch

from behaviors.errors import BehaveError
from behaviors.files import atomic_path, check_output_path, temp_path
from behaviors.fleet.control import Fleet, RoadFrame
from behaviors.fleet.drivers import DRIVERS, make_driver
from behaviors.learn.ddpg.checkpoint import load_checkpoint
from behaviors.learn.env import KEEPER_TYPE, OVERTAKER_TYPE
from behaviors.learn.env_core import EnvConfig
from behaviors.learn.policy import PRETRAINED, RULES, Policy, load_policy, rules_policy
from behaviors.learn.policy import resolve as resolve_policy
from behaviors.learn.traffic_env import VTYPES
from behaviors.report.agents_table import (
    END_REASONS,
    LONG_STANDSTILL_S,
    STYLE_COLUMNS,
    AgentRun,
    agents_path,
    cell,
    columns,
)
from behaviors.report.export import (
    FCD_SUFFIXES,
    fcd_options,
    last_whole_step,
    require_projection,
    seal_fcd,
)
from behaviors.road.geometry import CAR_CLASS, RoadGeometry, load_geometry
from behaviors.road.routes import RoutePool, misplaced, route_graph
from behaviors.sumo.fcd_parquet import PRECISION as PARQUET_PRECISION
from behaviors.sumo.fcd_parquet import ParquetStream
from behaviors.sumo.interrupt import sigint_between_steps
from behaviors.sumo.joined import SUMO_NET, JoinedSim, connection_closed, parse_address
from behaviors.sumo.scenario_config import (
    LATERAL_RESOLUTION,
    SUMO_STEP_LENGTH,
    ScenarioConfig,
    lateral_for,
    plan_run,
    read_sumocfg,
    run_as_sumocfg,
    share_draw,
)
from behaviors.sumo.sim import (
    STANDSTILL_SPEED,
    SimOptions,
    SumoSim,
    SumoStopped,
    VehicleState,
    check_display,
    sumo_stopped,
)
from behaviors.sumo.timing import PhaseTimer
from behaviors.traffic.actuation import CarModel
from behaviors.traffic.styles import Styles, read_population
from sumo_scenarios import get_scenario

BACKGROUND_TYPE = "behave_background"
CAR_FOOTPRINT = 15.0
"""Metres of lane one car needs (length + gaps at speed) when checking what a net can hold."""
DEFAULT_POLICY = PRETRAINED / "traffic.pt"


@dataclass(frozen=True)
class PopulateConfig:
    net: Path = field(default_factory=lambda: get_scenario("highway").net)
    overtakers: int = 4
    keepers: int = 4
    policy: Path = DEFAULT_POLICY
    background: int = 20
    routes: Path | None = None
    duration: float = 180.0
    step_length: float = 0.2
    seed: int = 0
    fcd: Path = Path("fcd.xml")
    geo: bool = False
    keep_count: bool = False
    shield: bool = True
    precision: str = "auto"  # the actor's arithmetic: float32, bfloat16, or auto (see use_bfloat16)
    sumocfg: Path | None = None  # the user's scenario; `net` is then its net
    share: float = 0.0  # of the scenario's passenger cars, the fraction that become agents
    overtaker_fraction: float = 0.5  # of those agents, the fraction that are overtakers
    gui: bool = False  # run in sumo-gui (needs a display)
    driver: str | None = None  # None: the policy's own; "rules": the traffic driver's rules, no policy
    lateral_resolution: float | None = None  # with a sumocfg: SUMO's sublane width (m); None: lateral_for
    outputs: Path | None = None  # with a sumocfg: the folder its own outputs (detectors, summary, ...) go to
    population: str | None = None  # the styled driver's: a preset name or a JSON file of style distributions
    connect: str | None = None  # HOST:PORT: join that running SUMO as a TraCI client (populate_joined)
    order: int = 2  # with connect: this client's place in each step (traci.setOrder)
    agents_csv: Path | None = None  # the agents table; None: beside the FCD (fcd.agents.csv)
    leave_alone: tuple[str, ...] = ()  # with connect: vehicle id prefixes never drawn (another client's)

    @property
    def has_agents(self) -> bool:
        """Whether a policy drives in this run (agents of the share or of behave's own)."""
        return self.share > 0 or self.keepers + self.overtakers > 0

    @property
    def share_kinds(self) -> tuple[bool, bool]:
        """Whether the share brings (keepers, overtakers)."""
        return self.share * (1 - self.overtaker_fraction) > 0, self.share * self.overtaker_fraction > 0

    def validate(self) -> None:
        if self.overtakers < 0 or self.keepers < 0 or self.background < 0:
            raise BehaveError("agent and background counts must be >= 0")
        empty = self.overtakers + self.keepers == 0 and self.background == 0
        if empty and self.routes is None and self.sumocfg is None and self.connect is None:
            raise BehaveError("nothing to simulate: zero agents and no background traffic")
        if self.duration <= 0:
            raise BehaveError(f"duration must be positive, got {self.duration}")
        top = 1.0 if self.has_agents or self.background else 60.0  # a scenario alone: any step SUMO takes
        if not 0.01 <= self.step_length <= top:
            raise BehaveError(f"step length must be in [0.01, {top:g}] s, got {self.step_length}")
        if self.fcd.suffix not in FCD_SUFFIXES:
            raise BehaveError(f"FCD output must end in {', '.join(FCD_SUFFIXES)}: {self.fcd}")
        if self.precision not in PRECISIONS:
            raise BehaveError(f"unknown precision '{self.precision}' (choose from {', '.join(PRECISIONS)})")
        if self.routes is not None and not self.routes.is_file():
            raise BehaveError(f"routes file not found: {self.routes}")
        for name in ("share", "overtaker_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise BehaveError(f"{name.replace('_', ' ')} must be in [0, 1], got {getattr(self, name)}")
        if self.leave_alone and self.connect is None:
            raise BehaveError("--leave-alone names another client's vehicles: it goes with --connect")
        if self.connect is not None:
            self._validate_joined()
        elif self.share > 0 and self.sumocfg is None:
            raise BehaveError("--share converts a scenario's own cars: it needs --sumocfg (or --connect)")
        if self.outputs is not None and self.sumocfg is None:
            raise BehaveError("--outputs takes a scenario's own outputs: it needs --sumocfg")
        if self.lateral_resolution is not None and self.sumocfg is None:
            raise BehaveError("--lateral-resolution sets a scenario's sublanes: it needs --sumocfg")
        if self.driver is not None and self.driver not in (*DRIVERS, RULES):
            raise BehaveError(f"unknown driver '{self.driver}' (choose from {', '.join((*DRIVERS, RULES))})")
        if self.gui:
            check_display()

    def _validate_joined(self) -> None:
        """A joined run drives a share of the running simulation's cars; what would change that
        simulation otherwise is set on its own side."""
        parse_address(self.connect or "")
        if self.order < 1:
            raise BehaveError(f"--order must be 1 or more, got {self.order}")
        if self.share <= 0:
            raise BehaveError(
                "--connect drives a share of the running simulation's passenger cars: give --share F > 0"
            )
        not_here = {
            "--sumocfg": self.sumocfg is not None, "--routes": self.routes is not None, "--gui": self.gui,
            "--geo": self.geo, "--keep-count": self.keep_count, "--outputs": self.outputs is not None,
            "--lateral-resolution": self.lateral_resolution is not None,
            "--keepers, --overtakers or --background": self.keepers + self.overtakers + self.background > 0,
        }  # fmt: skip
        for option, given in not_here.items():
            if given:
                raise BehaveError(
                    f"--connect drives a share of the running simulation's cars: {option} does not apply "
                    "(set it where that simulation is started; docs/manual/connect.md)"
                )


def config_from(
    sumocfg: Path | None, notes: list[str] | None = None, agent_settings: bool = False, **given: Any
) -> PopulateConfig:
    """The config for the options a user gave (None = not given). Agents drive at the step their policy
    was trained at (`trained_step`). With a sumocfg, its net, and behave adds no cars of its own unless
    asked (--keepers, --overtakers, --background); its step, duration and lateral resolution as
    scenario_config.plan_run decides (as SUMO runs it, except what agents need), each difference from
    `sumo -c` a line appended to `notes`. `agent_settings`: a run without agents runs as one with
    agents would (a sweep's share 0 beside its other shares)."""
    values = {name: value for name, value in given.items() if value is not None}
    if values.get("driver") == RULES and "policy" in values:
        raise BehaveError("--driver rules drives with no network: drop --policy")
    if values.get("connect") is not None and sumocfg is None:
        return joined_config(values)
    if sumocfg is not None:
        if "net" in values:
            raise BehaveError(
                "--net and --sumocfg both name a network: the sumocfg's net is used, drop --net"
            )
        scenario = read_sumocfg(sumocfg)
        values["net"] = scenario.net
        values.update({k: 0 for k in ("overtakers", "keepers", "background") if k not in values})
    counts = [values.get(kind, getattr(PopulateConfig, kind)) for kind in ("keepers", "overtakers")]
    agents = values.get("share", 0.0) > 0 or sum(counts) > 0
    step = trained_step(values) if agents or agent_settings else TRAINED_STEP
    if agents and "step_length" in values:
        check_step(policy_name(values), values["step_length"], step)
    if sumocfg is not None:
        plan = plan_run(
            scenario, agents=agents or agent_settings, policy_step=step,
            default_duration=PopulateConfig.duration, seed=values.get("seed", PopulateConfig.seed),
            step_length=values.get("step_length"), duration=values.get("duration"),
            lateral_resolution=values.get("lateral_resolution"),
        )  # fmt: skip
        values.update(step_length=plan.step_length, duration=plan.duration)
        values.update(lateral_resolution=plan.lateral_resolution)
        if notes is not None:
            notes.extend(plan.notes)
        if notes is not None and Path(values.get("fcd", "")).suffix == ".parquet":
            notes.append(
                f"the parquet FCD is written from SUMO's csv at {PARQUET_PRECISION} decimals, and SUMO's "
                f"--precision is for all its outputs: {sumocfg.name}'s own outputs get {PARQUET_PRECISION} "
                "decimals too (--fcd .xml or .csv keeps theirs)"
            )
        own = lateral_for(scenario, False), scenario.step_length or SUMO_STEP_LENGTH
        ran = plan.lateral_resolution, plan.step_length
        if notes is not None and agent_settings and not agents and own != ran:
            notes.append(
                f"{sumocfg.name}'s runs without agents run as those with agents do (at {ran[1]:g} s "
                f"steps, --lateral-resolution {ran[0]:g}), so that they compare"
            )
    elif agents:
        values.setdefault("step_length", step)
    return PopulateConfig(sumocfg=sumocfg, **values)


def joined_config(values: dict[str, Any]) -> PopulateConfig:
    """The config of a joined run (--connect): no cars of behave's own unless asked (validate refuses
    them), until the simulation ends unless --duration; the net and step are the running simulation's,
    filled in when joining (`populate_joined`), so a step given here is refused."""
    if "step_length" in values:
        raise BehaveError(
            "--connect runs at the step of the simulation it joins: drop --step-length (start SUMO with "
            "the policy's step, --step-length 0.2 for the bundled ones)"
        )
    values.update({k: 0 for k in ("overtakers", "keepers", "background") if k not in values})
    values.setdefault("duration", math.inf)
    values.setdefault("net", SUMO_NET)
    values["step_length"] = trained_step(values)  # checked against SUMO's when joining
    return PopulateConfig(**values)


TRAINED_STEP = EnvConfig.step_length
"""s: the step of a policy whose checkpoint records none (training's default), and the rules driver's."""


def trained_step(given: dict[str, Any]) -> float:
    """The step (s) the policy the options name (`policy`, `driver`) was trained at."""
    if given.get("driver") == RULES:
        return TRAINED_STEP
    return checkpoint_step(resolve_policy(given.get("policy") or DEFAULT_POLICY)[0])


def policy_name(given: dict[str, Any]) -> str:
    """The policy the options name, as messages name it."""
    return RULES if given.get("driver") == RULES else str(given.get("policy") or "traffic")


def check_step(policy: str | Path, step: float, trained: float) -> None:
    """BehaveError if the policy, trained at `trained` s steps, would drive at `step`: a policy drives
    at the step it was trained at or not at all."""
    if not math.isclose(step, trained):
        raise BehaveError(
            f"{policy} was trained at {trained:g} s steps and drives at no other: --step-length {step:g} "
            f"would run it at {step:g} s (leave --step-length out)"
        )


def checkpoint_step(path: Path) -> float:
    """The step (s) a checkpoint's policy was trained at, as its metadata records it."""
    if not Path(path).is_file():  # a policy made in Python, not loaded from a file
        return TRAINED_STEP
    return _recorded_step(Path(path).resolve(), Path(path).stat().st_mtime_ns)


@functools.cache
def _recorded_step(path: Path, mtime_ns: int) -> float:
    return float(load_checkpoint(path).meta.get("step_length") or TRAINED_STEP)


@dataclass
class PopulateSummary:
    vehicles: int = 0
    agent_steps: int = 0
    collisions: int = 0
    off_tracks: int = 0
    insert_retries: int = 0
    side_cuts: int = 0  # agent-steps whose sideways move the shield cut
    speed_cuts: int = 0  # agent-steps whose speed the shield cut
    handovers: int = 0  # times SUMO's driver took an agent (exits, lane drops, one-lane roads, signals)
    scenario_cars: int = 0  # the sumocfg's passenger cars that departed
    scenario_agents: int = 0  # ... of which became agents (--share)
    scenario_not_car_sized: int = 0  # ... drawn by --share but left to SUMO: not a car's size (CAR_SIZE_M)
    simulated_s: float = 0.0
    wall_s: float = 0.0
    speed_sum: dict[str, float] = field(default_factory=lambda: {"keeper": 0.0, "overtaker": 0.0})
    speed_steps: dict[str, int] = field(default_factory=lambda: {"keeper": 0, "overtaker": 0})
    ended: dict[str, int] = field(default_factory=lambda: dict.fromkeys(END_REASONS, 0))
    long_standstills: int = 0  # agents that stood still for LONG_STANDSTILL_S or more at a time
    longest_standstill_s: float = 0.0
    sumo: SumoCars | None = None  # SUMO's own vehicles, measured as the agents are
    phases: dict[str, float] = field(default_factory=dict)
    cut_short: bool = False  # stopped by Ctrl-C before the duration: simulated_s says how far it got
    left_simulation: str = ""  # a joined run: how it ended (JOINED_ENDS), "" for behave's own SUMO
    handed_back: int = 0  # a joined run: agents given back to SUMO's driver when behave left
    left_note: str = ""  # a joined run: what happened at the end, one line

    @property
    def real_time_factor(self) -> float:
        return self.simulated_s / max(self.wall_s, 1e-9)

    def as_dict(self) -> dict[str, Any]:
        out = {
            "vehicles": self.vehicles,
            "agent_steps": self.agent_steps,
            "collisions": self.collisions,
            "off_tracks": self.off_tracks,
            "insert_retries": self.insert_retries,
            "shield_side_cuts": self.side_cuts,
            "shield_speed_cuts": self.speed_cuts,
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
        for name in ("keeper", "overtaker"):
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


CAR_SIZE_M = {"length": (2.5, 7.5), "width": (1.2, 2.3)}
"""The sizes (m, inclusive) of a vehicle --share may turn into an agent (behave's agents are 5 m x 1.8 m):
a vehicle of vClass passenger outside them (a 12 m vType that sets no vClass) is left to SUMO."""


def car_sized(length: float, width: float) -> bool:
    (short, long), (narrow, wide) = CAR_SIZE_M["length"], CAR_SIZE_M["width"]
    return short <= length <= long and narrow <= width <= wide


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
        vtype = OVERTAKER_TYPE if self.behaviour[k] == "overtaker" else KEEPER_TYPE
        depart, distance, longest = float(self.depart[k]), float(self.distance[k]), float(self.longest[k])
        return AgentRow(
            self.ids[k], self.behaviour[k], vtype, self.policy, round(depart, 3), round(time, 3), reason,
            round(distance, 2), round(longest, 3), incident, tuple(round(float(v), 3) for v in self.style[k]),
        )  # fmt: skip


class EndedAgents:
    """The rows of agents whose run ended, as CSV lines in an unnamed temporary file, and what the
    summary counts of them. A long run ends agents without bound (with --keep-count each one that
    leaves comes back as a new agent: ~4,600 rows per simulated hour with 80 agents on the bundled
    highway); kept in a list they grew populate by ~1.8 MB per simulated hour."""

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
        self.counter = {"keeper": 0, "overtaker": 0, "background": 0}
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
        `precise`: at every decimal (export.fcd_options), for the csv a ParquetStream reads."""
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
        vtype = {"keeper": KEEPER_TYPE, "overtaker": OVERTAKER_TYPE, "background": BACKGROUND_TYPE}[kind]
        for _ in range(count):
            vid = f"{kind}_{self.counter[kind]}"
            self.counter[kind] += 1
            # agents enter at the highest speed SUMO finds safe there: at traffic speed
            sim.add_free_vehicle(
                vid, routes.draw(self.rng), vtype, "desired" if kind == "background" else "max"
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
        keeper = np.array([self.pending[v] == "keeper" for v in placed], bool)
        withdraw = misplaced(sim, self.vehicles, self.geometry, placed, keeper).tolist()
        joined = [v for v, out in zip(placed, withdraw, strict=True) if not out]
        withdrawn = [v for v, out in zip(placed, withdraw, strict=True) if out]
        self.vehicles = self.vehicles.without(withdrawn)  # withdrawn below: nobody senses them
        failed = [v for v in self.pending if v not in present] + withdrawn
        agents = [v for v in joined if self.pending[v] != "background"]
        if agents:
            behaviour = np.array([1.0 if self.pending[v] == "overtaker" else 0.0 for v in agents])
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
            for kind in ("keeper", "overtaker"):
                self.insert(kind, sum(v.startswith(kind) for v in left))
            self.insert("background", len(left_background))
        self.summary.simulated_s += c.step_length
        self.now = now

    def _convert(self, departed: list[str], time: float) -> None:
        """The share of the scenario's passenger cars that departed this step become agents: behave's
        vehicle type, SUMO's checks off, into the fleet. The rest stay SUMO's, untouched."""
        sim, c = self.sim, self.config
        assert sim is not None
        cars = [v for v in departed if sim.vehicle_class(v) == CAR_CLASS and not v.startswith(c.leave_alone)]
        draws = {v: share_draw(c.seed, v) for v in cars}
        drawn = [v for v in cars if draws[v] < c.share]
        agents = [v for v in drawn if car_sized(*sim.vehicle_size(v))]  # a bus typed passenger stays SUMO's
        self.summary.scenario_cars += len(cars)
        self.summary.scenario_not_car_sized += len(drawn) - len(agents)
        self.summary.scenario_agents += len(agents)
        if not agents:
            return
        kinds = ["overtaker" if draws[v] < c.share * c.overtaker_fraction else "keeper" for v in agents]
        for vid, kind in zip(agents, kinds, strict=True):
            sim.set_agent_type(vid, OVERTAKER_TYPE if kind == "overtaker" else KEEPER_TYPE)
        sim.take_control(agents)
        behaviour = np.array([1.0 if kind == "overtaker" else 0.0 for kind in kinds])
        style = self.fleet.driver.draw_style(behaviour, self.rng)
        self.fleet.add(agents, sim.read_speeds(agents), behaviour, style)
        self.log.join(agents, kinds, time, style)

    def _observe_agents(self, present: np.ndarray, speed: np.ndarray) -> None:
        """Log SUMO's `speed` of each agent it still has, not the one commanded: SUMO may hold a
        car back (a lane that does not lead on stops it dead) whatever the policy asks."""
        self.log.observe(present, speed)
        overtaker = self.fleet.behaviour_id[present] == 1.0
        for name, mask in (("overtaker", overtaker), ("keeper", ~overtaker)):
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


def end_reasons(
    crashed: np.ndarray, off_track: np.ndarray, gone: np.ndarray, arrived: np.ndarray
) -> np.ndarray:
    """Each agent's end this step ("" = drives on); a crash counts before leaving the track, and an
    agent SUMO took out without arriving counts as no progress."""
    return np.select(
        [crashed, gone & arrived, off_track, gone], ["collision", "arrived", "off_track", "no_progress"], ""
    )


PRECISIONS = ("auto", "float32", "bfloat16")


@functools.cache
def native_bfloat16() -> bool:
    """Whether this CPU multiplies bfloat16 in hardware (AVX512-BF16 or AMX); emulated it is slower."""
    cpu = torch.cpu
    checks = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    return any(getattr(cpu, name, lambda: False)() for name in checks)


BFLOAT16_MIN_BATCH = 128
"""With `auto`, fleets from this size on use bfloat16; below it the conversions cost more than they save."""


def use_bfloat16(precision: str, batch: int) -> bool:
    """Whether a batch of `batch` observations goes through the actor in bfloat16.

    `auto` takes bfloat16 for big fleets where the CPU has it natively: it more than halves
    the batched actor call (1,000 agents: 0.80 -> 0.32 ms measured). On real highway
    observations it moves the steering by 0.003 (median) to 0.06 (max) of full lock, and
    throttle and brake by less (tests/run/test_populate.py): far below the exploration noise
    the policy was trained with. `float32` drives exactly as `behave evaluate` does.
    """
    if precision == "auto":
        return batch >= BFLOAT16_MIN_BATCH and native_bfloat16()
    return precision == "bfloat16"


POLICY_THREADS = 1
"""Threads for the batched actor call. A second thread saved ~0.2 ms at 1,000 agents on an idle
2-core machine, but cost tens of milliseconds per call when any other process kept a core busy
(a sweep's other runs, a training): 1,000 agents 0.67 ms with 1 thread, 67 ms with 2
(benchmarks/bench_policy_threads.py, docs/benchmarks.md)."""


def populate_policy(config: PopulateConfig, given: Policy | None = None) -> Policy:
    """The configured policy (policy.load_policy, in config.precision; with `driver` "rules" the
    rules' constant action, policy.rules_policy), or the policy `given` already loaded, checked
    against the agents it must drive before anything is set up."""
    if given is not None:
        policy = given
    elif config.driver == RULES:
        policy = rules_policy()
    else:
        half = None if config.precision == "float32" else functools.partial(use_bfloat16, config.precision)
        policy = load_policy(config.policy, half=half)
    if config.driver not in (None, RULES, policy.driver):
        raise BehaveError(
            f"{policy.path} drives the {policy.driver} driver, not the {config.driver} one "
            f"(drop --driver, or give a {config.driver}-driver policy)"
        )
    check_fits(config, policy)
    return policy


def check_fits(config: PopulateConfig, policy: Policy) -> None:
    """BehaveError if the policy cannot drive the agents asked for: one not told the behaviour drives
    only its own, and one that never trained among traffic only on the multi-lane roads behave routes
    its own cars on."""
    keepers, overtakers = config.share_kinds
    keepers, overtakers = keepers or config.keepers > 0, overtakers or config.overtakers > 0
    if keepers or overtakers:
        trained = TRAINED_STEP if policy.label == RULES else checkpoint_step(policy.path)
        check_step(policy.label, config.step_length, trained)
    if not make_driver(policy.driver).among_traffic and config.share > 0:
        raise BehaveError(
            f"{policy.path} drives the {policy.driver} driver, which cannot leave multi-lane roads: "
            "--share needs a traffic-driver policy"
        )
    if policy.sees_behaviour:
        return
    if overtakers and keepers:
        raise BehaveError(
            f"{policy.path} is a {policy.behaviour} policy: it cannot drive both keepers and overtakers "
            "(use a multi-behaviour policy)"
        )
    if policy.behaviour == "lanekeeping" and overtakers:
        raise BehaveError(f"{policy.path} is a lanekeeping policy: use --keepers, not --overtakers")
    if policy.behaviour == "overtaking" and keepers:
        raise BehaveError(f"{policy.path} is an overtaking policy: use --overtakers, not --keepers")


def partial_path(final: Path) -> Path:
    """Where SUMO writes while running: a temp file beside the target with its suffix (SUMO picks
    the format by it), named so that a later run removes it if this one is killed."""
    return temp_path(final)


def finish_fcd(
    partial: Path,
    final: Path,
    config: PopulateConfig,
    last_time: float,
    cut_short: bool = False,
    stream: ParquetStream | None = None,
    stopped: bool = False,
) -> float:
    """Check SUMO's FCD is whole and move it into place; XML gets a deterministic header (equal
    seeds give equal bytes) that says whether it holds lon/lat, and where Ctrl-C cut the run short; a
    parquet `stream` the same settings as its file metadata (fcd_parquet.METADATA_KEY). `stopped`: SUMO
    failed, and the FCD ends at its own last whole step, whichever (SUMO may have written the step it
    failed in); returns the last step's time."""
    if stopped:
        if stream is not None:
            stream.wait()
        found = stream.last_time if stream is not None else last_whole_step(partial)
        if found is None:
            raise BehaveError(f"it stopped before a whole step: {final} not written")
        last_time = found
    cut = f" cut-short-after={last_time + config.step_length:g}" if cut_short else ""
    settings = (
        f"behave populate: net={config.net.name} overtakers={config.overtakers} "
        f"keepers={config.keepers} background={config.background} duration={config.duration} "
        f"step-length={config.step_length} seed={config.seed}{' geo=true' if config.geo else ''}"
        f"{f' driver={config.driver}' if config.driver else ''}"
        f"{f' sumocfg={config.sumocfg.name} share={config.share}' if config.sumocfg else ''}{cut}"
    )
    if stream is not None:
        stream.finish(settings)
    header = f"<!-- {settings} -->\n"
    seal_fcd(partial, final, header=header, geo=config.geo, last_time=last_time, step=config.step_length)
    return last_time


def populate(
    config: PopulateConfig,
    on_step: Callable[[float], None] | None = None,
    on_status: Callable[[str], None] | None = None,
    policy: Policy | None = None,
) -> PopulateSummary:
    """Run the whole simulation; the FCD file and the per-agent table beside it appear only if the
    run completed. `policy`: one already loaded drives instead of config.policy (the Python API's
    way to hold a policy's actions constant, policy.held_constant, or to record them)."""
    if config.connect is not None:
        return populate_joined(config, on_step, on_status, policy)
    config.validate()
    check_output_path(config.fcd)
    check_output_path(agents_path(config.fcd))
    if config.geo:
        require_projection(config.net, "--geo writes lon/lat: the net needs a geo projection")
    torch.set_num_threads(POLICY_THREADS)
    population = Population(config, on_status, policy)
    partial = partial_path(config.fcd)
    stream: ParquetStream | None = None
    stopped: SumoStopped | None = None
    start = time.perf_counter()
    try:
        if on_status:
            on_status("starting SUMO")
        if config.fcd.suffix == ".parquet":  # SUMO's own parquet writer keeps the whole trace in memory
            stream = ParquetStream(partial, geo=config.geo, final=config.fcd)
        population.start(partial if stream is None else stream.source, precise=stream is not None)
        steps = round(config.duration / config.step_length)
        with sigint_between_steps() as interrupted:
            for _ in range(steps):
                try:
                    population.step()
                except Exception as exc:  # SUMO failing mid-run: keep what it simulated
                    stopped = sumo_stopped(exc, population.sim.options) if population.sim else None
                    if stopped is None:
                        raise
                    population.summary.cut_short = True
                    break
                if on_step:
                    on_step(population.summary.simulated_s)
                if interrupted():
                    population.summary.cut_short = True
                    break
        driving = population.log.driving(population.now)
        population.close()  # SUMO closes its outputs
        last_time = finish_fcd(partial, config.fcd, config, population.now - config.step_length,
                               population.summary.cut_short, stream, stopped is not None)  # fmt: skip
        write_agents_csv(agents_path(config.fcd), population.log.ended, driving)
        population.summary.count_agents(population.log.ended, driving)
        if population.summary.sumo is not None:
            population.summary.sumo.finish()
    except BehaveError as err:
        if stopped is None or err is stopped:
            raise
        raise BehaveError(f"{stopped}; {err}") from None  # nothing kept: the first error, then why
    finally:
        population.close()
        if stream is not None:
            stream.close()
        population.log.ended.close()
        with contextlib.suppress(FileNotFoundError):
            partial.unlink()
    population.summary.wall_s = time.perf_counter() - start
    population.summary.phases = dict(population.timer.seconds)
    if stopped is not None:
        raise PopulateStopped(
            f"{stopped}; {config.fcd} and its agents table hold the run up to t={last_time:g} s (cut short)",
            population.summary,
        )
    if population.summary.cut_short:
        raise PopulateInterrupted(population.summary)
    return population.summary


class PopulateStopped(BehaveError):
    """SUMO failed during `populate` (sim.SumoStopped); the FCD and agents table up to its last whole
    step were written, marked cut short as a Ctrl-C's are, and `.summary` is the run's. The message is
    SUMO's error and what was kept, one line."""

    def __init__(self, message: str, summary: PopulateSummary) -> None:
        super().__init__(message)
        self.summary = summary


class PopulateInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped `populate` between two steps; the FCD and agents table up to the last whole
    step were written (complete files, sealed as a finished run's). Still a KeyboardInterrupt, so a
    caller that does not look for it stops as on any Ctrl-C."""

    def __init__(self, summary: PopulateSummary) -> None:
        super().__init__(f"interrupted after {summary.simulated_s:g} simulated seconds")
        self.summary = summary


JOINED_ENDS = ("simulation_over", "closed_by_sumo", "duration", "interrupted")
"""How a joined run ends: the simulation had no vehicles left to run (or reached SUMO's --end), SUMO
closed the connection (it ended, was stopped, or the network dropped it), --duration simulated, Ctrl-C."""


def joined_agents_path(config: PopulateConfig) -> Path:
    return config.agents_csv if config.agents_csv is not None else agents_path(config.fcd)


def populate_joined(
    config: PopulateConfig,
    on_step: Callable[[float], None] | None = None,
    on_status: Callable[[str], None] | None = None,
    policy: Policy | None = None,
) -> PopulateSummary:
    """`populate` inside a simulation another program runs (config.connect, docs/manual/connect.md):
    join it as TraCI client number config.order, turn config.share of its passenger cars into agents
    as `--sumocfg --share` does, step in lockstep with the other clients until the simulation is over,
    SUMO closes the connection, config.duration or Ctrl-C; then give the agents still on the road back
    to SUMO's driver and close this client only (SUMO runs on with the others). Writes the agents
    table (`joined_agents_path`), no FCD: SUMO's own outputs hold every vehicle."""
    config.validate()
    table = joined_agents_path(config)
    check_output_path(table)
    torch.set_num_threads(POLICY_THREADS)
    address = parse_address(config.connect or "")
    if on_status:
        on_status(f"joining SUMO at {address} as client {config.order}")
    sim = JoinedSim(address, config.order, None if config.net == SUMO_NET else config.net)
    population: Population | None = None
    start = time.perf_counter()
    end = "simulation_over"
    try:
        config = joinable(sim, config, policy)
        population = Population(config, on_status, policy, joined=sim)
        sim.check_net(set(population.geometry.edges))
        population.start(None)
        summary = population.summary
        with sigint_between_steps() as interrupted:
            while not sim.over:
                if summary.simulated_s >= config.duration - 1e-9:
                    end = "duration"
                    break
                try:
                    population.step()
                except Exception as exc:
                    if not connection_closed(exc):
                        raise
                    sim.gone = sim.gone or str(exc) or type(exc).__name__
                    end = "closed_by_sumo"
                    break
                if on_step:
                    on_step(summary.simulated_s)
                if interrupted():
                    end = "interrupted"
                    break
        driving = population.driving_rows()
        population.close()  # the agents still driving go back to SUMO, this client leaves
        write_agents_csv(table, population.log.ended, driving)
        summary.count_agents(population.log.ended, driving)
        if summary.sumo is not None:
            summary.sumo.finish()
        summary.left_simulation, summary.handed_back = end, sim.handed_back
        summary.left_note = joined_note(end, address, sim, summary)
    finally:
        if population is not None:
            population.close()
            population.log.ended.close()
        sim.close()
    summary.wall_s = time.perf_counter() - start
    assert population is not None
    summary.phases = dict(population.timer.seconds)
    if end == "interrupted":
        summary.cut_short = True
        raise PopulateInterrupted(summary)
    return summary


def joinable(sim: JoinedSim, config: PopulateConfig, policy: Policy | None) -> PopulateConfig:
    """The config with the joined simulation's net and step, or BehaveError if the agents cannot drive
    in it: a step their policy was not trained at, or no sublanes to move sideways in."""
    given = {"policy": config.policy, "driver": config.driver}
    trained = checkpoint_step(policy.path) if policy is not None else trained_step(given)
    name = (
        policy.label if policy is not None else RULES if config.driver == RULES else Path(config.policy).stem
    )
    if not math.isclose(sim.step_length, trained):
        raise BehaveError(
            f"SUMO at {sim.address} steps {sim.step_length:g} s; {name} was trained at {trained:g} s steps "
            f"and drives at no other: start SUMO with --step-length {trained:g}"
        )
    if sim.lateral_resolution <= 0:
        raise BehaveError(
            f"SUMO at {sim.address} runs without sublanes, and the agents move sideways within their lanes: "
            f"start SUMO with --lateral-resolution {LATERAL_RESOLUTION:g}"
        )
    return replace(config, net=sim.net, step_length=sim.step_length)


def joined_note(end: str, address: Any, sim: JoinedSim, summary: PopulateSummary) -> str:
    """What happened at the end of a joined run, one line."""
    at = f"at t={sim.time:g} s"
    back = (
        f"{sim.handed_back} agents handed back to SUMO's driver, SUMO runs on with the other clients"
        if sim.handed_back
        else "SUMO runs on with the other clients"
    )
    return {
        "simulation_over": f"the simulation at {address} ended {at} (no vehicles left to run): left it",
        "closed_by_sumo": f"SUMO at {address} closed the connection {at} ({sim.gone}): ended or stopped",
        "duration": f"left SUMO at {address} after {summary.simulated_s:g} simulated s {at}; {back}",
        "interrupted": f"interrupted (Ctrl-C) {at}: left SUMO at {address}; {back}",
    }[end]
