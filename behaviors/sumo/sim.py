"""SumoSim: the one owner of libsumo in a process.

libsumo allows a single simulation per process, so everything that talks to
SUMO goes through this class: start with a seed, fast reset with `load`, step,
read every vehicle's state once into arrays, write the two commands per agent,
close. No other module imports libsumo. A SUMO another program runs is joined through
joined.JoinedSim, a SumoSim over a TraCI connection (`behave populate --connect`).
"""

from __future__ import annotations

import contextlib
import functools
import re
import sys
import weakref
import xml.etree.ElementTree as ET
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from itertools import chain, compress
from pathlib import Path
from types import ModuleType, SimpleNamespace

import numpy as np

from behaviors.errors import BehaveError
from behaviors.sumo.sumo_home import sumo_binary
from sumo_scenarios.build import (
    AGENT_ACTION_STEP,
    AGENT_LC_ACCEL_LAT,
    AGENT_VTYPES,
    PASSENGER_DECEL,
    SUMO_LC_ACCEL_LAT,
    SUMO_MAX_SPEED_LAT,
)

COLLISION_OPTIONS = (
    "--collision.action",
    "warn",  # report contacts, leave the cars: behave removes the crashed agent
    "--collision.mingap-factor",
    "0",  # physical contact only, not minGap violations
    "--collision.check-junctions",
    "true",
    "--time-to-teleport",
    "-1",  # a stuck car stays stuck (no progress), it is never teleported
)


STANDSTILL_SPEED = 0.1
"""m/s: below this a vehicle stands still (SUMO's own halting threshold for its waiting time)."""

SUMO_SPEED_MODE = 31
SUMO_LANE_CHANGE_MODE = 1621
"""SUMO's default speed and lane-change modes: its own safe driving and strategic lane choice."""


@dataclass(frozen=True)
class SimOptions:
    """Everything that determines a SUMO run besides the vehicles behave adds."""

    net: Path
    additional: tuple[Path, ...] = ()
    routes: tuple[Path, ...] = ()
    step_length: float = 0.2
    lateral_resolution: float = 0.8
    seed: int = 0
    extra: tuple[str, ...] = field(default_factory=tuple)
    gui: bool = False  # run in sumo-gui, driven over TraCI (see sumo_api)
    agent_max_speed_lat: float | None = None
    """m/s: the agents' vTypes' maxSpeedLat in this run, the fastest sideways move their driver makes
    (None: the vTypes' own 5 m/s, the paper driver's). SUMO's cars judge a lane-changing agent's
    reach by it over one action step (`AGENT_ACTION_STEP`), so a driver that moves slower sideways
    says so here rather than have room reserved for it that it never takes (docs/history.md)."""
    ballistic: bool = False
    """SUMO's position update: Euler (SUMO's default) unless a sumocfg asks for the ballistic one.
    Always given: SUMO turns to the ballistic update by itself once a vType sets an
    actionStepLength, as the agents' do (`AGENT_ACTION_STEP`), and every car would move otherwise."""

    def command(self) -> list[str]:
        cmd = [
            sumo_binary("sumo-gui" if self.gui else "sumo"),
            "--net-file",
            str(self.net),
            "--step-length",
            repr(self.step_length),
            "--lateral-resolution",
            repr(self.lateral_resolution),
            "--seed",
            str(self.seed),
            "--no-step-log",
            "true",
            "--no-warnings",
            "true",
            "--duration-log.disable",
            "true",
            "--step-method.ballistic",
            "true" if self.ballistic else "false",
            *COLLISION_OPTIONS,
        ]
        if self.additional:
            cmd += ["--additional-files", ",".join(str(p) for p in self.additional)]
        if self.routes:
            cmd += ["--route-files", ",".join(str(p) for p in self.routes)]
        if self.gui:  # run at once, and close the window with the simulation
            cmd += GUI_OPTIONS
        return cmd + list(self.extra)


GUI_OPTIONS = ["--start", "true", "--quit-on-end", "true"]


@dataclass(frozen=True)
class VehicleState:
    """Every vehicle in the simulation after a step; row order = `ids`."""

    ids: tuple[str, ...]
    position: np.ndarray  # [M, 2] front bumper centre (SUMO's vehicle position), metres
    speed: np.ndarray  # [M] m/s
    distance: np.ndarray  # [M] odometer since insertion, metres (empty if not read)
    row: dict[str, int]  # id -> row; shared by consecutive states with the same ids: never mutate
    length: np.ndarray  # [M] metres, front bumper to rear bumper (the vehicle's vType)
    width: np.ndarray  # [M] metres

    @property
    def longest(self) -> float:
        """Metres: the longest vehicle's length (0 with none), which bounds how far back a car
        reaching into a neighbour's lane can start."""
        return float(self.length.max(initial=0.0))

    def without(self, removed: list[str]) -> VehicleState:
        """The same state minus vehicles removed since it was read (so nobody senses a removed car)."""
        rows = [self.row[v] for v in removed if v in self.row]
        if not rows:
            return self
        keep = np.ones(len(self.ids), bool)
        keep[rows] = False
        ids = tuple(v for v, k in zip(self.ids, keep.tolist(), strict=True) if k)
        distance = self.distance[keep] if len(self.distance) else self.distance
        row = {v: k for k, v in enumerate(ids)}
        return VehicleState(
            ids, self.position[keep], self.speed[keep], distance, row, self.length[keep], self.width[keep]
        )


@dataclass(frozen=True)
class AgentReadings:
    """What SUMO knows about the controlled agents (row i = i-th requested id)."""

    lane_id: list[str]
    lane_pos: np.ndarray  # [N] metres along the lane
    lateral_pos: np.ndarray  # [N] metres from the lane centre, positive = left


_running: weakref.ref[SumoSim] | None = None  # the process's one live simulation, if any

ONE_PER_PROCESS = (
    "a SUMO simulation is already running in this process and libsumo runs only one: close the "
    "other env (or simulation) first, or run each in its own process (see README)"
)


def _claim(sim: SumoSim) -> None:
    """Refuse a second live simulation: through libsumo it would silently drive the first one's cars."""
    global _running
    if _running is not None and _running() is not None:
        raise BehaveError(ONE_PER_PROCESS)
    _running = weakref.ref(sim)


def _release(sim: SumoSim) -> None:
    global _running
    if _running is not None and _running() is sim:
        _running = None


def _stop(libsumo: ModuleType) -> None:
    with contextlib.suppress(Exception):  # already closed: closing twice is harmless
        libsumo.close()


class SumoSim:
    """A libsumo simulation; use as a context manager or call close(). One at a time per process:
    a second raises BehaveError until the first is closed (or garbage collected, which closes it)."""

    def __init__(self, options: SimOptions) -> None:
        libsumo = sumo_api(options.gui)
        _claim(self)
        self._sumo = libsumo
        self._fast = fast_vehicle_calls(libsumo)
        self.options = options
        try:
            with contextlib.redirect_stdout(sys.stderr):  # TraCI prints its connection attempts
                libsumo.start(options.command(), **({"stdout": sys.stderr} if options.gui else {}))
        except Exception as exc:  # libsumo raises its own TraCIException/FatalSumoError types
            _release(self)
            raise sumo_error(exc, options, "could not start") from None
        self._closer = weakref.finalize(self, _stop, libsumo)
        self.step_length = options.step_length
        self._set_agent_vtypes(options)
        self._sizes: dict[str, tuple[float, float]] = {}  # id -> (length, width), read once per vehicle
        self._last = VehicleState(
            (), np.zeros((0, 2)), np.zeros(0), np.zeros(0), {}, np.zeros(0), np.zeros(0)
        )

    def __enter__(self) -> SumoSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def restart(self, options: SimOptions) -> None:
        """A new episode at time 0 (libsumo's fast `load`): another seed, network, files or outputs."""
        self._sumo.load(options.command()[1:])
        self.options = options
        self.step_length = options.step_length
        self._set_agent_vtypes(options)
        self.__dict__.pop("has_signals", None)  # another net: ask again

    def _set_agent_vtypes(self, options: SimOptions) -> None:
        if options.agent_max_speed_lat is not None:
            for vtype in AGENT_VTYPES:
                self._sumo.vehicletype.setMaxSpeedLat(vtype, options.agent_max_speed_lat)

    def close(self) -> None:
        """Stop SUMO (once; closing again is harmless) and let another simulation start."""
        self._closer()
        _release(self)

    @property
    def time(self) -> float:
        return self._sumo.simulation.getTime()

    def step(self) -> None:
        try:
            self._sumo.simulationStep()
        except Exception as exc:  # SUMO loads routes as time goes on: a bad one can stop it here
            raise SumoStopped(str(sumo_error(exc, self.options, "stopped"))) from None

    def read_vehicles(self, with_distance: bool = True) -> VehicleState:
        """Position, speed (and odometer) of every vehicle: the one per-step read of the whole fleet."""
        v = self._fast
        ids = self._sumo.vehicle.getIDList()
        if ids == self._last.ids:  # nobody came or left: the same row numbers (and dict) hold
            ids, row = self._last.ids, self._last.row
            length, width = self._last.length, self._last.width
        else:
            row = {vid: k for k, vid in enumerate(ids)}
            length, width = self._read_sizes(ids)
        # one flat pass over SUMO's (x, y) tuples: twice as fast as np.array on the list of them
        position = np.fromiter(chain.from_iterable(map(v.getPosition, ids)), float, 2 * len(ids)).reshape(
            -1, 2
        )
        speed = np.fromiter(map(v.getSpeed, ids), float, len(ids))
        distance = np.fromiter(map(v.getDistance, ids), float, len(ids)) if with_distance else np.zeros(0)
        self._last = VehicleState(ids, position, speed, distance, row, length, width)
        return self._last

    def _read_sizes(self, ids: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Length and width of each vehicle in `ids`: asked of SUMO once per vehicle (a vehicle keeps
        its vType's size; `set_agent_type` forgets the old one), kept for the vehicles still there."""
        sizes, v = self._sizes, self._sumo.vehicle
        for vid in ids:
            if vid not in sizes:
                sizes[vid] = (v.getLength(vid), v.getWidth(vid))
        if len(sizes) > 2 * len(ids) + 64:  # forget those that left, now and then
            self._sizes = sizes = {vid: sizes[vid] for vid in ids}
        flat = np.fromiter(chain.from_iterable(map(sizes.__getitem__, ids)), float, 2 * len(ids)).reshape(
            -1, 2
        )
        return flat[:, 0].copy(), flat[:, 1].copy()

    def read_agents(self, ids: Sequence[str]) -> AgentReadings:
        """Lane, lane position and lateral offset of the controlled vehicles."""
        return AgentReadings(self.read_lanes(ids), *self.read_lane_places(ids))

    def read_lanes(self, ids: Sequence[str]) -> list[str]:
        return list(map(self._fast.getLaneID, ids))

    def read_lane_places(self, ids: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """Lane position and lateral offset from the lane centre of each vehicle."""
        v, n = self._fast, len(ids)
        return (
            np.fromiter(map(v.getLanePosition, ids), float, n),
            np.fromiter(map(v.getLateralLanePosition, ids), float, n),
        )

    def command_agents(
        self, ids: Sequence[str], speed: np.ndarray, lateral: np.ndarray, send_move: np.ndarray | None = None
    ) -> None:
        """The two writes per agent: speed for the next step and a sideways move in metres;
        `send_move` [N] bool leaves out the moves that would not change what SUMO holds (None: all)."""
        if not len(ids) == len(speed) == len(lateral):
            raise ValueError("command_agents needs one speed and one lateral move per agent")
        v = self._fast
        # map() drives the compiled calls without a Python loop body (docs/benchmarks.md)
        deque(map(v.setSpeed, ids, speed.tolist()), maxlen=0)
        if send_move is not None:
            ids, lateral = list(compress(ids, send_move.tolist())), lateral[send_move]
        deque(map(v.changeSublane, ids, lateral.tolist()), maxlen=0)

    def wants_to_change(self, ids: Sequence[str], direction: np.ndarray) -> np.ndarray:
        """[K] bool: whether SUMO's lane-change model of each vehicle wants to move one lane in
        `direction` [K] (+1 towards higher lane indices) for its route (a strategic wish, as before an
        exit or where its lane ends), by the state it saved at the last step."""
        state = self._sumo.vehicle.getLaneChangeState
        constants = self._constants
        side = {1: constants.LCA_LEFT, -1: constants.LCA_RIGHT}
        wish = [constants.LCA_STRATEGIC | side[d] for d in direction.tolist()]
        return np.fromiter(
            (state(v, d)[1] & w == w for v, d, w in zip(ids, direction.tolist(), wish, strict=True)),
            bool,
            len(ids),
        )

    @property
    def _constants(self) -> ModuleType:
        """TraCI's constants (libsumo's module and traci's have the same)."""
        return self._sumo.constants

    def collisions(self) -> set[str]:
        """Ids of every vehicle in contact this step: both parties (SUMO may swap them in side hits)."""
        hit: set[str] = set()
        for c in self._sumo.simulation.getCollisions():
            hit.add(c.collider)
            hit.add(c.victim)
        return hit

    def collision_pairs(self) -> list[tuple[str, str]]:
        """(collider, victim) of every contact this step: who hit whom, which `collisions` forgets.
        Only asked for in steps with a contact, to explain it."""
        return [(c.collider, c.victim) for c in self._sumo.simulation.getCollisions()]

    def arrived(self) -> set[str]:
        """Vehicles that left the network this step at the end of their route."""
        return set(self._sumo.simulation.getArrivedIDList())

    def add_vehicle(self, vid: str, route: str, vtype: str, *, lane: int, pos: float, speed: float) -> None:
        """Insert a vehicle now at an exact place; behave-controlled types drive with checks off."""
        v = self._sumo.vehicle
        v.add(
            vid,
            route,
            typeID=vtype,
            depart="now",
            departLane=str(lane),
            departPos=repr(pos),
            departSpeed=repr(speed),
        )

    def add_free_vehicle(
        self, vid: str, route: str, vtype: str, speed: str = "desired", lane: str = "random"
    ) -> None:
        """Insert a vehicle at a random free place of its route's first edge; `speed` is SUMO's
        departSpeed ("desired", or "max": the highest speed that is safe where it is put), `lane` its
        departLane ("random", or "first": the slowest lane the vehicle's class may use)."""
        self._sumo.vehicle.add(
            vid, route, typeID=vtype, depart="now", departLane=lane, departPos="random_free",
            departSpeed=speed,
        )  # fmt: skip

    def lane_lengths_ahead(self, vid: str) -> dict[str, float]:
        """For each lane of `vid`'s edge: metres from that lane's start that can be driven on it
        along the route without a lane change (SUMO's best lanes; a lane that does not lead on
        has its own length)."""
        return {lane[0]: lane[1] for lane in self._sumo.vehicle.getBestLanes(vid)}

    def route_ahead(self, vid: str) -> list[str]:
        """The edges of `vid`'s route after the one it is on (or, inside a junction, came from)."""
        v = self._sumo.vehicle
        return list(v.getRoute(vid)[v.getRouteIndex(vid) + 1 :])

    def route_place(self, vid: str) -> tuple[str, int]:
        """`vid`'s route id and its index in it: SUMO never changes a route's edges (a reroute
        makes a new route), so the pair names what lies ahead."""
        v = self._sumo.vehicle
        return v.getRouteID(vid), v.getRouteIndex(vid)

    def vtype_size(self, vtype: str) -> tuple[float, float]:
        """A vehicle type's length and minGap (the gap it keeps standing), metres."""
        t = self._sumo.vehicletype
        return t.getLength(vtype), t.getMinGap(vtype)

    def hold_lane(self, vid: str) -> None:
        """SUMO's driver keeps `vid` in its lane: it follows and never changes lanes."""
        self._sumo.vehicle.setLaneChangeMode(vid, 0)

    def hold_speed(self, ids: Sequence[str], speed: float) -> None:
        """SUMO's drivers of `ids` drive at `speed` (braking as hard as their vType may to reach it)
        and keep their lanes; a negative speed gives them back their own speed and lane choice."""
        v = self._sumo.vehicle
        for vid in ids:
            v.setSpeed(vid, speed)
            v.setLaneChangeMode(vid, SUMO_LANE_CHANGE_MODE if speed < 0 else 0)

    def set_speed_factor(self, vid: str, factor: float) -> None:
        self._sumo.vehicle.setSpeedFactor(vid, factor)

    def read_speeds(self, ids: Sequence[str]) -> np.ndarray:
        return np.fromiter(map(self._fast.getSpeed, ids), float, len(ids))

    def read_lateral_speeds(self, ids: Sequence[str]) -> np.ndarray:
        """Sideways speed in the last step, m/s, signed as `posLat` (+ towards higher lane indices)."""
        return np.fromiter(map(self._sumo.vehicle.getLateralSpeed, ids), float, len(ids))

    def take_control(self, ids: Sequence[str]) -> None:
        """Speed mode 0 and lane-change mode 0: SUMO applies no safety, the policy drives."""
        v = self._sumo.vehicle
        for vid in ids:
            v.setSpeedMode(vid, 0)
            v.setLaneChangeMode(vid, 0)

    def hand_to_sumo(self, ids: Sequence[str]) -> None:
        """SUMO's own driver takes these agents (default speed and lane-change modes), with the
        lateral comfort of SUMO's drivers (1 m/s^2, 1 m/s) instead of the agents' exact moves, their
        reaction at every step instead of the agents' vType's once a second (`AGENT_ACTION_STEP`), and
        a passenger car's braking (`PASSENGER_DECEL`, what followers keep room for; docs/history.md).
        SUMO holds those limits in a copy of the car's vType, `TYPE@id`, which FCD shows while
        SUMO drives it."""
        v = self._sumo.vehicle
        for vid in ids:
            v.setSpeed(vid, -1.0)  # the agent's last commanded speed would otherwise hold for good
            # and so would its last sideways move if it was too small for SUMO to ever complete
            # (below ~0.5 mm): a pending request that overrules every lane change SUMO wants,
            # strategic ones too (such a car stops at the end of an exit lane); 0 cancels it
            v.changeSublane(vid, 0.0)
            v.setSpeedMode(vid, SUMO_SPEED_MODE)
            v.setLaneChangeMode(vid, SUMO_LANE_CHANGE_MODE)
            v.setParameter(vid, "laneChangeModel.lcAccelLat", f"{SUMO_LC_ACCEL_LAT:g}")
            v.setMaxSpeedLat(vid, SUMO_MAX_SPEED_LAT)
            v.setDecel(vid, PASSENGER_DECEL)  # as its vType shows followers (apparentDecel): no harder
        self.react_every_step(ids)

    def react_every_step(self, ids: Sequence[str]) -> None:
        """SUMO's driver of these agent-typed cars works its plans out at every step, as for its own
        cars, not once a second as the agents' vType has it (`AGENT_ACTION_STEP`): agents handed over
        (`hand_to_sumo`) and SUMO's baseline (`behave evaluate --baseline sumo`). SUMO keeps the change
        in a copy of the car's vType, `TYPE@id`."""
        for vid in ids:
            self._sumo.vehicle.setActionStepLength(vid, self.step_length, True)

    def take_back(self, ids: Sequence[str]) -> None:
        """The policy drives again: its own vType back in place of SUMO's copy (so FCD tells who
        drives), checks off, and `changeSublane` exact again (see vtypes)."""
        v = self._sumo.vehicle
        for vid in ids:
            size = self.vehicle_size(vid)
            self.set_agent_type(vid, v.getTypeID(vid).removesuffix(f"@{vid}"))
            if self.vehicle_size(vid) != size:  # a lorry of the scenario's keeps its own size
                self.set_vehicle_size(vid, *size)
        self.take_control(ids)

    def remove(self, ids: Sequence[str], reason: int = 0) -> None:
        v = self._sumo.vehicle
        for vid in ids:
            v.remove(vid, reason)

    def add_route(self, route_id: str, edges: Sequence[str]) -> None:
        self._sumo.route.add(route_id, list(edges))

    def vehicle_ids(self) -> list[str]:
        return list(self._sumo.vehicle.getIDList())

    def set_max_speed(self, vid: str, speed: float) -> None:
        self._sumo.vehicle.setMaxSpeed(vid, speed)

    def departed(self) -> list[str]:
        """Vehicles that entered the network this step (the scenario's own and behave's)."""
        return list(self._sumo.simulation.getDepartedIDList())

    def vehicle_class(self, vid: str) -> str:
        return self._sumo.vehicle.getVehicleClass(vid)

    def vehicle_size(self, vid: str) -> tuple[float, float]:
        """(length, width) in m of a vehicle's type."""
        return self._sumo.vehicle.getLength(vid), self._sumo.vehicle.getWidth(vid)

    def set_agent_type(self, vid: str, vtype: str) -> None:
        """An agent's vType for a car SUMO inserted with another: SUMO builds a car's lane-change
        model once, from the vType it departs with, and `setType` leaves it, so the agents' lcAccelLat
        is set on the car itself (a scenario's lcAccelLat would slow the policy's sideways moves;
        docs/history.md).

        First the agents' action step, with an action point in the coming step: a car SUMO was
        moving sideways carries SUMO's move on until its next action point, which the agents' type
        alone would put up to a second away, so the policy's first move would overshoot."""
        v = self._sumo.vehicle
        v.setActionStepLength(vid, AGENT_ACTION_STEP, True)
        v.setType(vid, vtype)
        v.setParameter(vid, "laneChangeModel.lcAccelLat", f"{AGENT_LC_ACCEL_LAT:g}")
        self._sizes.pop(vid, None)  # another vType, maybe another size
        self._last = replace(self._last, ids=())  # the next read builds its sizes anew

    def set_vehicle_size(self, vid: str, length: float, width: float) -> None:
        """A vehicle's own length and width in place of its vType's (SUMO keeps them in a copy of the
        type, `TYPE@id`): a scenario's lorry that becomes an agent stays as long as it was."""
        v = self._sumo.vehicle
        v.setLength(vid, length)
        v.setWidth(vid, width)
        self._sizes[vid] = (length, width)
        self._last = replace(self._last, ids=())  # the next read builds its sizes anew

    @functools.cached_property
    def has_signals(self) -> bool:
        """Whether the net has traffic lights (fixed for a run)."""
        return self._sumo.trafficlight.getIDCount() > 0

    def signal_ahead(self, ids: Sequence[str], reach: np.ndarray) -> np.ndarray:
        """Whether a red or yellow (or red-yellow) signal lies on each vehicle's route within `reach` m."""
        next_tls = self._sumo.vehicle.getNextTLS
        stop = {"r", "R", "y", "Y", "u"}
        pairs = zip(ids, reach.tolist(), strict=True)
        return np.array([any(d <= r and s in stop for _, _, d, s in next_tls(vid)) for vid, r in pairs], bool)


FAST_CALLS = ("getPosition", "getDistance", "getLaneID", "getLanePosition", "getLateralLanePosition",
              "getSpeed", "setSpeed", "changeSublane")  # fmt: skip


def sumo_api(gui: bool) -> ModuleType:
    """libsumo (SUMO inside this process), or for sumo-gui TraCI: the same calls over a socket to a
    sumo-gui process. libsumo's own GUI (the wheel has one) hung in `close` after runs with vehicles
    (SUMO 1.28), and a GUI in its own process cannot take behave down with it."""
    if gui:
        import traci

        return traci
    import libsumo  # deferred: importing libsumo is slow and prints nothing useful at import

    return libsumo


def fast_vehicle_calls(libsumo: ModuleType) -> SimpleNamespace:
    """The per-vehicle calls of the hot path, bound to libsumo's compiled functions.

    libsumo's `vehicle.setSpeed` etc. are generated Python wrappers around
    `_libsumo.vehicle_setSpeed`; calling the compiled function directly skips the wrapper's cost
    on every call (docs/benchmarks.md). Falls back to the wrappers if a libsumo build lacks them.
    """
    compiled = getattr(libsumo, "_libsumo", None)
    calls = {name: getattr(compiled, f"vehicle_{name}", None) for name in FAST_CALLS}
    return SimpleNamespace(**{name: call or getattr(libsumo.vehicle, name) for name, call in calls.items()})


class SumoStopped(BehaveError):
    """SUMO failed while a simulation ran: a route or vehicle it loads as time goes on, a simulation
    closed under the run, sumo-gui's window closed. The outputs it wrote so far are whole up to the
    last step (SUMO closes them as it closes)."""


def sumo_stopped(exc: BaseException, options: SimOptions) -> SumoStopped | None:
    """`exc` as a SumoStopped if SUMO raised it (SumoSim.step, or any of libsumo's or TraCI's own
    errors from a call into a simulation that is gone), else None: behave's own errors stay theirs."""
    if isinstance(exc, SumoStopped):
        return exc
    if type(exc).__module__.split(".")[0] in ("libsumo", "traci"):
        return SumoStopped(str(sumo_error(exc, options, "stopped")))
    return None


def sumo_error(exc: BaseException, options: SimOptions, what: str) -> BehaveError:
    """SUMO's whole message on one line, with the route files and the vehicles it concerns.

    SUMO spreads an error over lines ("unterminated start tag" / "In file ..." / "At
    line/column ..."), names a file only for XML syntax errors and a route, not its vehicle,
    for unknown edges.
    """
    text = " ".join(line.strip() for line in str(exc).splitlines() if line.strip()) or type(exc).__name__
    if options.routes and "In file" not in text:
        text += f" (route files: {', '.join(str(p) for p in options.routes)})"
    route = re.search(r"within the route '([^']+)'", text)
    users = _route_users(options.routes, route[1]) if route else []
    if users:
        text += f" (route '{route[1]}' is driven by vehicle {', '.join(users)})"  # type: ignore[index]
    return BehaveError(f"SUMO {what}: {text}")


def _route_users(files: Sequence[Path], route: str, most: int = 3) -> list[str]:
    """Ids of the first vehicles, trips or flows in `files` that use the route named `route`."""
    users: list[str] = []
    for path in files:
        with contextlib.suppress(ET.ParseError, OSError):
            for _, elem in ET.iterparse(path):
                if elem.tag in ("vehicle", "trip", "flow") and elem.get("route") == route:
                    users.append(f"'{elem.get('id')}'")
                    if len(users) == most:
                        return users
    return users
