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
* SUMO writes the FCD itself (so the format is exactly SUMO's), to a temporary
  file that is renamed into place only when the run completed.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from behaviors.actuation import CarModel
from behaviors.control import Fleet
from behaviors.ddpg.checkpoint import load_actor, load_checkpoint
from behaviors.env import KEEPER_TYPE, OVERTAKER_TYPE
from behaviors.errors import BehaveError
from behaviors.export import FCD_SUFFIXES, fcd_options
from behaviors.files import ensure_writable_dir
from behaviors.geometry import RoadGeometry, load_geometry
from behaviors.sensors import OBS_SIZE, OBS_SIZE_WITH_ID
from behaviors.sim import SimOptions, SumoSim, VehicleState
from behaviors.timing import PhaseTimer
from sumo_scenarios import get_scenario

BACKGROUND_TYPE = "behave_background"
CAR_FOOTPRINT = 15.0
"""Metres of lane one car needs (length + gaps at speed) when checking what a net can hold."""
PRETRAINED = Path(__file__).parent / "pretrained"
DEFAULT_POLICY = PRETRAINED / "multi.pt"


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

    def validate(self) -> None:
        if self.overtakers < 0 or self.keepers < 0 or self.background < 0:
            raise BehaveError("agent and background counts must be >= 0")
        if self.overtakers + self.keepers == 0 and self.background == 0 and self.routes is None:
            raise BehaveError("nothing to simulate: zero agents and no background traffic")
        if self.duration <= 0:
            raise BehaveError(f"duration must be positive, got {self.duration}")
        if not 0.01 <= self.step_length <= 1.0:
            raise BehaveError(f"step length must be in [0.01, 1] s, got {self.step_length}")
        if self.fcd.suffix not in FCD_SUFFIXES:
            raise BehaveError(f"FCD output must end in {', '.join(FCD_SUFFIXES)}: {self.fcd}")
        if self.precision not in PRECISIONS:
            raise BehaveError(f"unknown precision '{self.precision}' (choose from {', '.join(PRECISIONS)})")
        if self.routes is not None and not self.routes.is_file():
            raise BehaveError(f"routes file not found: {self.routes}")


@dataclass(frozen=True)
class RouteGraph:
    """Multi-lane normal edges and which of them follow each other."""

    edges: list[str]
    length: np.ndarray  # [E] metres
    lanes: np.ndarray  # [E]
    successors: list[list[int]]
    start_cdf: np.ndarray  # [E] cumulative lane-metres: a route starts on an edge in proportion to them


def route_graph(geometry: RoadGeometry, net_file: Path) -> RouteGraph:
    import sumolib

    net = sumolib.net.readNet(str(net_file))
    edges = [
        e
        for e in net.getEdges()
        if e.getFunction() == "" and e.getLaneNumber() >= 2 and e.allows("passenger")
    ]
    index = {e.getID(): k for k, e in enumerate(edges)}
    successors = [sorted({index[s.getID()] for s in e.getOutgoing() if s.getID() in index}) for e in edges]
    length = np.array([geometry.edges[e.getID()].length for e in edges])
    lanes = np.array([e.getLaneNumber() for e in edges])
    return RouteGraph(
        edges=[e.getID() for e in edges],
        length=length,
        lanes=lanes,
        successors=successors,
        start_cdf=np.cumsum(length * lanes),
    )


def random_route(graph: RouteGraph, rng: np.random.Generator, min_length: float) -> list[str]:
    """A walk along multi-lane edges from a start drawn by lane-metres, until long enough or a dead end."""
    k = int(np.searchsorted(graph.start_cdf, rng.random() * graph.start_cdf[-1], side="right"))
    route, length = [k], graph.length[k]
    while length < min_length and graph.successors[k]:
        k = graph.successors[k][int(rng.integers(len(graph.successors[k])))]
        route.append(k)
        length += graph.length[k]
    return [graph.edges[i] for i in route]


@dataclass
class PopulateSummary:
    vehicles: int = 0
    agent_steps: int = 0
    collisions: int = 0
    off_tracks: int = 0
    insert_retries: int = 0
    side_cuts: int = 0  # agent-steps whose sideways move the shield cut
    speed_cuts: int = 0  # agent-steps whose speed the shield cut
    simulated_s: float = 0.0
    wall_s: float = 0.0
    speed_sum: dict[str, float] = field(default_factory=lambda: {"keeper": 0.0, "overtaker": 0.0})
    speed_steps: dict[str, int] = field(default_factory=lambda: {"keeper": 0, "overtaker": 0})
    phases: dict[str, float] = field(default_factory=dict)

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
            "simulated_s": self.simulated_s,
            "wall_s": self.wall_s,
            "real_time_factor": self.real_time_factor,
        }
        for name in ("keeper", "overtaker"):
            if self.speed_steps[name]:
                out[f"{name}_mean_speed"] = self.speed_sum[name] / self.speed_steps[name]
        return out


class Population:
    """The running SUMO simulation with its learned agents."""

    def __init__(self, config: PopulateConfig) -> None:
        self.config = config
        self.geometry = load_geometry(config.net)
        self.graph = route_graph(self.geometry, config.net)
        self._check_capacity()
        self.policy, self.with_id = load_policy(config)
        self.rng = np.random.default_rng(config.seed)
        self.timer = PhaseTimer()
        self.fleet = Fleet(self.geometry, CarModel(), config.step_length, self.timer, config.shield)
        self.summary = PopulateSummary()
        self.counter = {"keeper": 0, "overtaker": 0, "background": 0}
        self.pending: dict[str, str] = {}  # vehicle id -> kind, added but not yet on the road
        self.background_ids: set[str] = set()
        self.vehicles: VehicleState | None = None  # read after each step, used to sense in the next
        self.sim: SumoSim | None = None

    def _check_capacity(self) -> None:
        c = self.config
        lane_metres = float((self.graph.length * self.graph.lanes).sum())
        cars = c.overtakers + c.keepers + c.background
        if cars * CAR_FOOTPRINT > lane_metres:
            raise BehaveError(
                f"{cars} vehicles do not fit on {c.net.name}: its multi-lane edges hold about "
                f"{int(lane_metres / CAR_FOOTPRINT)}"
            )

    def start(self, fcd_tmp: Path) -> None:
        c = self.config
        vtypes = get_scenario("highway").vtypes
        routes = (c.routes,) if c.routes else ()
        extra = ("--begin", "0", *fcd_options(fcd_tmp, geo=c.geo))
        self.sim = SumoSim(
            SimOptions(net=c.net, additional=(vtypes,), routes=routes, step_length=c.step_length,
                       seed=c.seed, extra=extra)
        )  # fmt: skip
        self.insert("overtaker", c.overtakers)
        self.insert("keeper", c.keepers)
        self.insert("background", c.background)

    def insert(self, kind: str, count: int) -> None:
        """Ask SUMO for `count` new vehicles of a kind on random multi-lane routes, at free places."""
        sim = self.sim
        assert sim is not None
        vtype = {"keeper": KEEPER_TYPE, "overtaker": OVERTAKER_TYPE, "background": BACKGROUND_TYPE}[kind]
        for _ in range(count):
            vid = f"{kind}_{self.counter[kind]}"
            self.counter[kind] += 1
            edges = random_route(self.graph, self.rng, self.config.duration * 50.0)
            sim.add_route(f"route_{vid}", edges)
            sim.add_free_vehicle(vid, f"route_{vid}", vtype)
            if kind != "background":
                sim.take_control([vid])
            self.pending[vid] = kind

    def _admit(self, present: dict[str, int]) -> None:
        """Pending vehicles that SUMO placed join; the others are withdrawn and retried."""
        sim = self.sim
        assert sim is not None
        joined = [v for v in self.pending if v in present]
        failed = [v for v in self.pending if v not in present]
        agents = [v for v in joined if self.pending[v] != "background"]
        if agents:
            behaviour = np.array([1.0 if self.pending[v] == "overtaker" else 0.0 for v in agents])
            self.fleet.add(agents, sim.read_speeds(agents), behaviour)
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
        off_track = np.zeros(len(fleet), bool)
        if len(fleet):
            assert self.vehicles is not None
            obs = fleet.sense(sim, self.vehicles, self.with_id)
            with self.timer.phase("policy"):
                actions = self.policy(obs)
            actuation = fleet.act(sim, actions)
            off_track = actuation.off_track
            self.summary.side_cuts += int(actuation.side_cut.sum())
            self.summary.speed_cuts += int(actuation.speed_cut.sum())
            self._record_speeds()
        with self.timer.phase("sumo"):
            sim.step()
        with self.timer.phase("read"):
            contact = sim.collisions()
            arrived = sim.arrived()
            vehicles = sim.read_vehicles(with_distance=False)  # no race here: positions suffice
        crashed = fleet.involved(vehicles, contact)
        gone = fleet.locate(vehicles) < 0
        leaving = crashed | off_track | gone
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
        self._admit(self.vehicles.row)
        if c.keep_count:
            for kind in ("keeper", "overtaker"):
                self.insert(kind, sum(v.startswith(kind) for v in left))
            self.insert("background", len(left_background))
        self.summary.simulated_s += c.step_length

    def _record_speeds(self) -> None:
        overtaker = self.fleet.behaviour_id == 1.0
        for name, mask in (("overtaker", overtaker), ("keeper", ~overtaker)):
            self.summary.speed_sum[name] += float(self.fleet.speed[mask].sum())
            self.summary.speed_steps[name] += int(mask.sum())

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()
            self.sim = None


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
    throttle and brake by less (tests/test_populate.py): far below the exploration noise
    the policy was trained with. `float32` drives exactly as `behave evaluate` does.
    """
    if precision == "auto":
        return batch >= BFLOAT16_MIN_BATCH and native_bfloat16()
    return precision == "bfloat16"


POLICY_THREADS = 2
"""Threads for the batched actor call. SUMO never steps during it (one process, one step at a
time), so a second thread halves it where a second core exists (1,000 agents: 1.6 -> 0.8 ms)."""


def load_policy(config: PopulateConfig) -> tuple[Callable[[np.ndarray], np.ndarray], bool]:
    """The actor as a batched function, and whether it wants the behaviour id (66 inputs)."""
    if not config.policy.is_file():
        if config.policy == DEFAULT_POLICY:
            raise BehaveError(f"the bundled policy is missing ({DEFAULT_POLICY}); run `make pretrained`")
        raise BehaveError(f"checkpoint not found: {config.policy}")
    meta = load_checkpoint(config.policy).meta
    obs_dim = int(meta["obs_dim"])
    behaviour = meta.get("behaviour", "multi" if obs_dim == OBS_SIZE_WITH_ID else "lanekeeping")
    if obs_dim not in (OBS_SIZE, OBS_SIZE_WITH_ID):
        raise BehaveError(f"{config.policy} expects {obs_dim} observations; behave policies take 65 or 66")
    if obs_dim == OBS_SIZE and config.overtakers and config.keepers:
        raise BehaveError(
            f"{config.policy} is a {behaviour} policy: it cannot drive both keepers and overtakers "
            "(use a multi-behaviour policy)"
        )
    if obs_dim == OBS_SIZE and behaviour == "lanekeeping" and config.overtakers:
        raise BehaveError(f"{config.policy} is a lanekeeping policy: use --keepers, not --overtakers")
    if obs_dim == OBS_SIZE and behaviour == "overtaking" and config.keepers:
        raise BehaveError(f"{config.policy} is an overtaking policy: use --overtakers, not --keepers")
    actor = load_actor(config.policy)
    half = None if config.precision == "float32" else copy.deepcopy(actor).to(torch.bfloat16)

    def act(obs: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            x = torch.from_numpy(obs)
            if half is not None and use_bfloat16(config.precision, len(obs)):
                return half(x.to(torch.bfloat16)).float().numpy()
            return actor(x).numpy()

    return act, obs_dim == OBS_SIZE_WITH_ID


def partial_path(final: Path) -> Path:
    """Where SUMO writes while running: beside the target, same suffix (SUMO picks the format by it)."""
    return final.with_name(f".{final.stem}.{os.getpid()}.partial{final.suffix}")


def finish_fcd(partial: Path, final: Path, config: PopulateConfig) -> None:
    """Move SUMO's FCD into place; XML gets a deterministic header so equal seeds give equal bytes."""
    if final.suffix != ".xml":
        os.replace(partial, final)
        return
    header = (
        f"<!-- behave populate: net={config.net.name} overtakers={config.overtakers} "
        f"keepers={config.keepers} background={config.background} duration={config.duration} "
        f"step-length={config.step_length} seed={config.seed} -->\n"
    )
    staged = partial.with_name(partial.name + ".staged")
    with open(partial, encoding="utf-8") as src, open(staged, "w", encoding="utf-8") as dst:
        in_comment = False
        for line in src:
            if not in_comment and line.startswith("<!-- generated on"):
                in_comment = True
                dst.write(header)
            if in_comment:
                in_comment = "-->" not in line
                continue
            dst.write(line)
    os.replace(staged, final)
    partial.unlink()


def populate(config: PopulateConfig, on_step: Callable[[float], None] | None = None) -> PopulateSummary:
    """Run the whole simulation; the FCD file appears only if the run completed."""
    config.validate()
    ensure_writable_dir(config.fcd.parent)
    torch.set_num_threads(POLICY_THREADS)
    population = Population(config)
    partial = partial_path(config.fcd)
    start = time.perf_counter()
    try:
        population.start(partial)
        steps = round(config.duration / config.step_length)
        for _ in range(steps):
            population.step()
            if on_step:
                on_step(population.summary.simulated_s)
        population.close()
        finish_fcd(partial, config.fcd, config)
    finally:
        population.close()
        for leftover in (partial, partial.with_name(partial.name + ".staged")):
            with contextlib.suppress(FileNotFoundError):
                leftover.unlink()
    population.summary.wall_s = time.perf_counter() - start
    population.summary.phases = dict(population.timer.seconds)
    return population.summary
