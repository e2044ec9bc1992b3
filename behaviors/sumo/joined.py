"""JoinedSim: SumoSim over a TraCI connection to a SUMO that another program runs.

`behave populate --connect HOST:PORT` joins a running SUMO as one more TraCI client (SUMO's
`--num-clients N`, this client's `setOrder`) instead of starting its own through libsumo. Everything
else in behave talks to SumoSim's methods and does not know which one it has; this class answers
them over the socket, batched so that a step costs a couple of round trips, not a few per vehicle
(a round trip is ~0.1 ms on an idle machine and up to ~1 ms on a busy one, where libsumo's call
costs 0.5 us):

* reads: every vehicle is subscribed once (position and speed; the agents also lane, lane position
  and lateral offset), the simulation too (time, departed, arrived, collisions, vehicles still
  expected) and the vehicle list; SUMO sends all of it with its answer to the step, read here with
  fixed-layout unpacking (`StepReader`); the getters read that, not the socket. A vehicle's size,
  class and own vType are asked once, with its subscription, in one message for all newcomers;
* writes: the speed and sideways move of every agent (and other settings) are queued and go to SUMO
  in one message, with the next request or just before the step (`Wire`);
* asked per step in one message each: which cars beside the agents want to come over, the signals
  ahead (nets with traffic lights); per call, as through libsumo, only what concerns an agent
  entering a lane (its lanes' ends and route) and the rare hand-over.

The wire format and its batching are traci_wire.py's.

Leaving (`close`): the agents still on the road get their own vType and SUMO's driving back, then
this client closes and SUMO runs on with the others. A client that vanishes without closing ends
SUMO for everyone (SUMO 1.28 quits when a client's socket closes unannounced), so every way out of
behave closes.
"""

from __future__ import annotations

import contextlib
import weakref
from collections.abc import Iterable, Sequence
from dataclasses import replace
from itertools import chain
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from behaviors.errors import BehaveError
from behaviors.sumo.agent_vtypes import AGENT_COLORS, AGENT_TYPE_SETTINGS, BASE_VTYPE, LORRY_TYPE_SETTINGS
from behaviors.sumo.sim import (
    SUMO_LANE_CHANGE_MODE,
    SUMO_SPEED_MODE,
    SimOptions,
    SumoSim,
    VehicleState,
    _stop,
    fast_vehicle_calls,
)
from behaviors.sumo.traci_connection import (
    CONNECT_RETRIES,
    Address,
    ConnectionClosed,
    connect,
    connection_closed,
    sumo_seconds,
)
from behaviors.sumo.traci_wire import StepReader, Wire, batches
from sumo_scenarios.build import AGENT_LC_ACCEL_LAT, AGENT_VTYPES

DEFAULT_ORDER = 2
"""This client's place in each step (`traci.setOrder`): after a program that owns the simulation and
takes order 1, so behave's agents act on what that program did in the same step."""
SUMO_NET = Path("<the net SUMO runs>")
"""PopulateConfig.net of a joined run whose --net was not given: asked of SUMO when joining."""
LC_ACCEL_LAT = "laneChangeModel.lcAccelLat"


class JoinedSim(SumoSim):
    """A SUMO another program started and steps, joined as one more TraCI client. Use as a context
    manager or call close(), which gives the agents back to SUMO and leaves the simulation running."""

    def __init__(
        self,
        address: Address,
        order: int = DEFAULT_ORDER,
        net: Path | None = None,
        retries: int = CONNECT_RETRIES,
        batch: bool = True,
    ) -> None:
        from traci import constants as tc

        self.address, self.order = address, order
        connection = connect(address, retries)
        self._sumo: Any = connection
        self._tc = tc
        self._fast = fast_vehicle_calls(connection)  # a connection has no compiled calls: its own
        self._batch = batch and batches(connection)
        self._wire = Wire(connection, tc)
        self._reader = StepReader(connection, tc)
        self._closer = weakref.finalize(self, _stop, connection)  # closes a connection as it closes libsumo
        self._sizes: dict[str, tuple[float, float]] = {}
        self._last = VehicleState(
            (), np.zeros((0, 2)), np.zeros(0), np.zeros(0), {}, np.zeros(0), np.zeros(0)
        )
        self._values: dict[str, tuple] = {}  # this step's subscribed values per vehicle
        self._facts: dict[str, tuple[str, str, str]] = {}  # vehicle -> (vClass, vType, lcAccelLat)
        self._original: dict[str, tuple[str, str]] = {}  # agent -> (its own vType, its lcAccelLat)
        self._type_sizes: dict[str, tuple[float, float]] = {}
        self._entered: set[str] = set()  # agents in another lane than at the step before
        self._ahead: dict[str, tuple[tuple, str, int]] = {}  # this step's (best lanes, route, index)
        self._had_traffic = False  # whether SUMO had vehicles to run at some step since joining
        self.gone = ""  # why the connection ended, once it has
        self.handed_back = 0  # how many agents `close` gave back to SUMO's driver
        try:
            connection.setOrder(order)
            self.step_length = connection.simulation.getDeltaT()
            self.agent_action_step = self.step_length
            self.lateral_resolution = float(connection.simulation.getOption("lateral-resolution"))
            self.end = sumo_seconds(connection.simulation.getOption("end"))
            self.net = net if net is not None else self._net_file()
            self.options = SimOptions(net=self.net, step_length=self.step_length)
            self._subscribe_step()
        except BaseException:
            self.close()
            raise

    # --- joining ----------------------------------------------------------------------------------

    def _net_file(self) -> Path:
        """The net SUMO runs, found here: its `net-file` as given, against the folder of SUMO's
        configuration file (where SUMO resolves it), else against this folder."""
        simulation = self._sumo.simulation
        given = Path(simulation.getOption("net-file"))
        config = simulation.getOption("configuration-file")
        candidates = [given] if given.is_absolute() or not config else [Path(config).parent / given, given]
        for path in candidates:
            if path.is_file():
                return path
        raise BehaveError(
            f"SUMO at {self.address} runs the net '{given}', which is not found here (SUMO on another "
            "machine or started in another folder): give its .net.xml with --net"
        )

    def check_net(self, edges: Iterable[str]) -> None:
        """BehaveError unless the net behave loaded has the edges of the one SUMO runs."""
        running = {e for e in self._sumo.edge.getIDList() if not e.startswith(":")}
        loaded = {e for e in edges if not e.startswith(":")}  # junctions' inner edges: built alike
        if running != loaded:
            differ = sorted(running - loaded)[:3] or sorted(loaded - running)[:3]
            raise BehaveError(
                f"{self.net} is not the net SUMO at {self.address} runs (edges differ: {', '.join(differ)}): "
                "give SUMO's .net.xml with --net"
            )

    def prepare_agents(self, max_speed_lat: float | None) -> None:
        """The agents' vTypes in the other simulation: its own if it loaded behave's vtypes file, else
        copies of its default type with the agents' settings (AGENT_TYPE_SETTINGS), acting at every step:
        with the agents' 1 s action step SUMO would turn the whole simulation to the ballistic update
        (SUMO 1.28 does so when a vType with an action step appears and the option was not set)."""
        types = self._sumo.vehicletype
        have = set(types.getIDList())
        for vtype in AGENT_VTYPES:
            if vtype not in have:
                types.copy(BASE_VTYPE, vtype)
                lorry = LORRY_TYPE_SETTINGS if vtype == AGENT_VTYPES[2] else ()
                for setter, value in (*AGENT_TYPE_SETTINGS, *lorry):
                    getattr(types, setter)(vtype, value)
                types.setColor(vtype, AGENT_COLORS[vtype])
            else:  # loaded from behave's vtypes file: keep its action step
                self.agent_action_step = types.getActionStepLength(vtype)
            if max_speed_lat is not None:
                types.setMaxSpeedLat(vtype, max_speed_lat)
            self._type_sizes[vtype] = (types.getLength(vtype), types.getWidth(vtype))

    def _subscribe_step(self) -> None:
        tc = self._tc
        sim_vars = (tc.VAR_TIME, tc.VAR_DEPARTED_VEHICLES_IDS, tc.VAR_ARRIVED_VEHICLES_IDS,
                    tc.VAR_COLLISIONS, tc.VAR_MIN_EXPECTED_VEHICLES)  # fmt: skip
        self._sumo.simulation.subscribe(sim_vars)
        self._sumo.vehicle.subscribe("", [tc.TRACI_ID_LIST])
        sim = dict(self._sumo.simulation.getSubscriptionResults())
        sim.update({tc.VAR_DEPARTED_VEHICLES_IDS: (), tc.VAR_ARRIVED_VEHICLES_IDS: (), tc.VAR_COLLISIONS: ()})
        self._sim = sim
        self._ids: tuple[str, ...] = tuple(self._sumo.vehicle.getIDList())
        self._subscribe(self._ids, agents=False)

    def _subscribe(self, ids: Sequence[str], agents: bool) -> None:
        """Subscribe vehicles (their position and speed; `agents` also their lane, lane position and
        lateral offset), whose values now come with the answer; newcomers' class, size and vType asked
        with it, all in one message."""
        if not ids:
            return
        tc = self._tc
        variables = (tc.VAR_POSITION, tc.VAR_SPEED, *(self._reader.lane_vars if agents else ()))
        if not self._batch:
            for vid in ids:
                self._subscribe_one(vid, variables)
            return
        w, get = self._wire, tc.CMD_GET_VEHICLE_VARIABLE
        span = (tc.INVALID_DOUBLE_VALUE, tc.INVALID_DOUBLE_VALUE)
        subscribe_fmt = "u" * (len(variables) + 1)
        commands, asked = [], []
        for vid in ids:
            commands.append(w.command(tc.CMD_SUBSCRIBE_VEHICLE_VARIABLE, span, vid, subscribe_fmt,
                                      len(variables), *variables))  # fmt: skip
            if vid not in self._facts:
                asked.append(vid)
                commands += [
                    w.command(get, tc.VAR_VEHICLECLASS, vid), w.command(get, tc.VAR_TYPE, vid),
                    w.command(get, tc.VAR_PARAMETER, vid, "s", LC_ACCEL_LAT),
                    w.command(get, tc.VAR_LENGTH, vid), w.command(get, tc.VAR_WIDTH, vid),
                ]  # fmt: skip
        result = self._exchange(commands)
        content = result._content
        others: dict[tuple[int, str], dict[int, Any]] = {}
        asking = set(asked)
        for vid in ids:
            error = w.status(result)
            if error is not None:
                raise BehaveError(f"SUMO would not report vehicle '{vid}': {error}")
            result._pos = self._reader.read_one(content, result._pos, self._values, others)
            if vid in asking:
                vclass, vtype, accel_lat, length, width = (self._reader.answer(result, get) for _ in range(5))
                self._facts[vid] = (str(vclass), str(vtype), str(accel_lat or ""))
                self._sizes[vid] = (float(length), float(width))
        for (_, vid), got in others.items():  # a layout the fast reader did not take: in full
            self._values[vid] = self._tuple(got)
        if agents:  # new agents' lanes ahead are asked for, with those of agents entering a lane
            self._entered.update(ids)

    def _subscribe_one(self, vid: str, variables: tuple[int, ...]) -> None:
        self._sumo.vehicle.subscribe(vid, variables)
        got = self._sumo.vehicle.getAllSubscriptionResults().pop(vid, {})  # traci never empties its store
        self._values[vid] = self._tuple(got)

    def _tuple(self, got: dict[int, Any]) -> tuple:
        tc = self._tc
        x, y = got[tc.VAR_POSITION]
        if tc.VAR_LANE_ID not in got:
            return (x, y, got[tc.VAR_SPEED])
        return (
            x,
            y,
            got[tc.VAR_SPEED],
            got[tc.VAR_LANEPOSITION],
            got[tc.VAR_LANEPOSITION_LAT],
            got[tc.VAR_LANE_ID],
        )

    def _exchange(self, commands: list[bytes]) -> Any:
        try:
            return self._wire.exchange(commands)
        except Exception as exc:
            raise self._closed(exc) from None

    def _closed(self, exc: Exception) -> Exception:
        if connection_closed(exc):
            self.gone = self.gone or str(exc) or type(exc).__name__
            return ConnectionClosed(self.gone)
        return exc

    def _get_many(self, var: int, ids: Sequence[str], fmt: str = "", params: Sequence[Any] = ()) -> list[Any]:
        """One vehicle variable of each of `ids` (with its parameter, one per id, if `fmt`), in one
        message."""
        args = [(p,) for p in params] if fmt else [()] * len(ids)
        return self._gets([(var, v, fmt, a) for v, a in zip(ids, args, strict=True)])

    def _gets(self, requests: Sequence[tuple[int, str, str, tuple]]) -> list[Any]:
        """Vehicle variables, each (variable, vehicle, parameter format, parameters), in one message;
        a refusal by SUMO raised as BehaveError."""
        if not requests:
            return []
        if not self._batch:
            universal = self._sumo.vehicle._getUniversal
            return [universal(var, vid, fmt, *args) for var, vid, fmt, args in requests]
        w, get = self._wire, self._tc.CMD_GET_VEHICLE_VARIABLE
        result = self._exchange([w.command(get, var, vid, fmt, *args) for var, vid, fmt, args in requests])
        values = [self._reader.answer(result, get) for _ in requests]
        refused = [
            f"{vid} ({var:#x})" for (var, vid, _, _), x in zip(requests, values, strict=True) if x is None
        ]
        if refused:
            raise BehaveError(f"SUMO refused to report {', '.join(refused[:3])}")
        return values

    # --- stepping ---------------------------------------------------------------------------------

    @property
    def time(self) -> float:
        return float(self._sim[self._tc.VAR_TIME])

    @property
    def over(self) -> bool:
        """Whether the simulation has nothing left to run: no vehicle on the road or still to come
        (a TraCI script's usual end) after there were some (a co-simulation may add its vehicles
        through TraCI later), or SUMO's --end reached (with clients SUMO leaves the end to them)."""
        expected = self._sim.get(self._tc.VAR_MIN_EXPECTED_VEHICLES, 1)
        self._had_traffic = self._had_traffic or expected > 0
        return (self._had_traffic and expected == 0) or (self.end >= 0 and self.time >= self.end - 1e-9)

    @property
    def _constants(self) -> ModuleType:
        return self._tc

    def step(self) -> None:
        """One step in lockstep with the other clients: SUMO answers once every client asked for it.
        The queued commands (the agents' speeds and moves) go just before it, in one message."""
        tc = self._tc
        try:
            if self._batch:
                # the queue first, in a message of its own: SUMO 1.28 with several clients sends the
                # answers to commands that came in one message with the step to the next client
                self._wire.exchange([])
                result = self._wire.exchange([self._wire.command(tc.CMD_SIMSTEP, None, "", "D", 0.0)])
                error = self._wire.status(result)
                if error is not None:
                    raise BehaveError(f"SUMO could not step: {error}")
                for kept in self._sumo._subscriptionMapping.values():  # as traci's own step does: what
                    kept.reset()  # its reader kept of other clients' results goes
                vehicles, others = self._reader.read(result._content, result._pos)
            else:
                self._sumo.simulationStep()
                vehicles, others = self._public_results()
        except Exception as exc:
            raise self._closed(exc) from None
        self._sim = others.get((tc.RESPONSE_SUBSCRIBE_SIM_VARIABLE, ""), {})
        listed = others.get((tc.RESPONSE_SUBSCRIBE_VEHICLE_VARIABLE, ""), {})
        self._ids = tuple(listed.get(tc.TRACI_ID_LIST, ()))
        for (response, vid), got in others.items():  # a layout the fast reader did not take: in full
            if (
                response == tc.RESPONSE_SUBSCRIBE_VEHICLE_VARIABLE
                and vid
                and {tc.VAR_POSITION, tc.VAR_SPEED} <= got.keys()
            ):
                vehicles[vid] = self._tuple(got)  # with another client's variables (or ours not yet)
        lane_before = {vid: values[5] for vid, values in self._values.items() if len(values) == 6}
        self._entered = {
            vid for vid, now in vehicles.items() if len(now) == 6 and now[5] != lane_before.get(vid)
        }
        self._values, self._ahead = vehicles, {}

    def _public_results(self) -> tuple[dict[str, tuple], dict[tuple[int, str], dict[int, Any]]]:
        """The same values through traci's public results (no batching here)."""
        tc = self._tc
        vehicles = {
            vid: self._tuple(got)
            for vid, got in self._sumo.vehicle.getAllSubscriptionResults().items()
            if vid
        }
        return vehicles, {
            (tc.RESPONSE_SUBSCRIBE_SIM_VARIABLE, ""): dict(self._sumo.simulation.getSubscriptionResults()),
            (tc.RESPONSE_SUBSCRIBE_VEHICLE_VARIABLE, ""): dict(self._sumo.vehicle.getSubscriptionResults("")),
        }

    def read_vehicles(self, with_distance: bool = True) -> VehicleState:
        ids, values = self._ids, self._values
        missing = [v for v in ids if v not in values]
        if missing:
            self._subscribe(missing, agents=False)
        if ids == self._last.ids:
            row, length, width = self._last.row, self._last.length, self._last.width
        else:
            row = {vid: k for k, vid in enumerate(ids)}
            length, width = self._read_sizes(ids)
        n = len(ids)
        flat = np.fromiter(chain.from_iterable(values[v][:3] for v in ids), float, 3 * n).reshape(-1, 3)
        distance = (
            np.array(self._get_many(self._tc.VAR_DISTANCE, ids), float) if with_distance else np.zeros(0)
        )
        self._last = VehicleState(ids, flat[:, :2].copy(), flat[:, 2].copy(), distance, row, length, width)
        return self._last

    def _lane_values(self, ids: Sequence[str]) -> list[tuple]:
        """(x, y, speed, lane position, lateral offset, lane) of each of `ids`; vehicles not subscribed
        with their lanes are subscribed so now."""
        values = self._values
        plain = [v for v in ids if len(values.get(v, ())) < 6]
        if plain:
            self._subscribe(plain, agents=True)
        return [values[v] for v in ids]

    def read_lanes(self, ids: Sequence[str]) -> list[str]:
        return [values[5] for values in self._lane_values(ids)]

    def read_lane_places(self, ids: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        values, n = self._lane_values(ids), len(ids)
        return np.fromiter((v[3] for v in values), float, n), np.fromiter((v[4] for v in values), float, n)

    def read_speeds(self, ids: Sequence[str]) -> np.ndarray:
        values = self._values
        missing = [v for v in ids if v not in values]
        if missing:
            self._subscribe(missing, agents=False)
        return np.fromiter((values[v][2] for v in ids), float, len(ids))

    def read_lateral_speeds(self, ids: Sequence[str]) -> np.ndarray:
        return np.array(self._get_many(self._tc.VAR_SPEED_LAT, ids), float)

    def wants_to_change(self, ids: Sequence[str], direction: np.ndarray) -> np.ndarray:
        tc = self._tc
        sides = direction.tolist()
        states = self._get_many(tc.CMD_CHANGELANE, ids, "i", sides)
        side = {1: tc.LCA_LEFT, -1: tc.LCA_RIGHT}
        wish = [tc.LCA_STRATEGIC | side[d] for d in sides]
        return np.fromiter((s[1] & w == w for s, w in zip(states, wish, strict=True)), bool, len(ids))

    def signal_ahead(self, ids: Sequence[str], reach: np.ndarray) -> np.ndarray:
        stop = {"r", "R", "y", "Y", "u"}
        ahead = self._get_many(self._tc.VAR_NEXT_TLS, ids)
        pairs = zip(ahead, reach.tolist(), strict=True)
        return np.array([any(d <= r and s in stop for _, _, d, s in signals) for signals, r in pairs], bool)

    def _lanes_ahead(self, vid: str) -> tuple[tuple, str, int]:
        """`vid`'s best lanes, route and index in it, asked with those of every agent that entered
        another lane this step (the driver asks for each of them in turn), in one message."""
        if vid not in self._ahead:
            tc = self._tc
            more = (v for v in self._entered if v != vid and v not in self._ahead and v in self._values)
            ask = [vid, *more]
            variables = (tc.VAR_BEST_LANES, tc.VAR_ROUTE_ID, tc.VAR_ROUTE_INDEX)
            got = self._gets([(var, v, "", ()) for v in ask for var in variables])
            for k, v in enumerate(ask):
                self._ahead[v] = (got[3 * k], got[3 * k + 1], got[3 * k + 2])
        return self._ahead[vid]

    def lane_lengths_ahead(self, vid: str) -> dict[str, float]:
        return {lane[0]: lane[1] for lane in self._lanes_ahead(vid)[0]}

    def route_place(self, vid: str) -> tuple[str, int]:
        _, route, index = self._lanes_ahead(vid)
        return route, index

    def command_agents(
        self, ids: Sequence[str], speed: np.ndarray, lateral: np.ndarray, send_move: np.ndarray | None = None
    ) -> None:
        """SumoSim's two writes per agent, queued: they go to SUMO with the step."""
        if not self._batch:
            super().command_agents(ids, speed, lateral, send_move)
            return
        if not len(ids) == len(speed) == len(lateral):
            raise ValueError("command_agents needs one speed and one lateral move per agent")
        tc, w = self._tc, self._wire
        commands = w.set_doubles(tc.VAR_SPEED, ids, speed.tolist())
        if send_move is None:
            commands += w.set_doubles(tc.CMD_CHANGESUBLANE, ids, lateral.tolist())
        else:
            sending = send_move.tolist()
            moving = [v for v, s in zip(ids, sending, strict=True) if s]
            commands += w.set_doubles(tc.CMD_CHANGESUBLANE, moving, lateral[send_move].tolist())
        w.queue(commands)

    def take_control(self, ids: Sequence[str]) -> None:
        """As SumoSim's (queued), and each agent's lane values come with every step from now on."""
        if self._batch:
            tc, w = self._tc, self._wire
            sets = tc.CMD_SET_VEHICLE_VARIABLE
            w.queue([w.command(sets, tc.VAR_SPEEDSETMODE, v, "i", 0) for v in ids]
                    + [w.command(sets, tc.VAR_LANECHANGE_MODE, v, "i", 0) for v in ids])  # fmt: skip
        else:
            super().take_control(ids)
        self._subscribe([v for v in ids if len(self._values.get(v, ())) < 6], agents=True)

    def set_agent_type(self, vid: str, vtype: str) -> None:
        """As SumoSim's (queued, at the simulation's step: see `prepare_agents`); the car's own vType and
        lateral acceleration are kept for when behave leaves."""
        if vid not in self._original:
            facts = self._facts.get(vid)
            if facts is None:
                v = self._sumo.vehicle
                facts = (v.getVehicleClass(vid), v.getTypeID(vid), v.getParameter(vid, LC_ACCEL_LAT))
            self._original[vid] = facts[1:]
        if not self._batch:
            v = self._sumo.vehicle
            v.setActionStepLength(vid, self.agent_action_step, True)
            v.setType(vid, vtype)
            v.setParameter(vid, LC_ACCEL_LAT, f"{AGENT_LC_ACCEL_LAT:g}")
            self._sizes.pop(vid, None)
            self._last = replace(self._last, ids=())
            return
        tc, w = self._tc, self._wire
        sets = tc.CMD_SET_VEHICLE_VARIABLE
        w.queue([
            w.command(sets, tc.VAR_ACTIONSTEPLENGTH, vid, "d", self.agent_action_step),
            w.command(sets, tc.VAR_TYPE, vid, "s", vtype),
            w.command(sets, tc.VAR_PARAMETER, vid, "tss", 2, LC_ACCEL_LAT, f"{AGENT_LC_ACCEL_LAT:g}"),
        ])  # fmt: skip
        if vtype in self._type_sizes:
            self._sizes[vid] = self._type_sizes[vtype]
        else:
            self._sizes.pop(vid, None)
        self._last = replace(self._last, ids=())  # the next read builds its sizes anew

    def set_vehicle_size(self, vid: str, length: float, width: float) -> None:
        """As SumoSim's (queued)."""
        if not self._batch:
            super().set_vehicle_size(vid, length, width)
            return
        tc, w = self._tc, self._wire
        sets = tc.CMD_SET_VEHICLE_VARIABLE
        w.queue(
            [w.command(sets, tc.VAR_LENGTH, vid, "d", length), w.command(sets, tc.VAR_WIDTH, vid, "d", width)]
        )
        self._sizes[vid] = (length, width)
        self._last = replace(self._last, ids=())

    def vehicle_class(self, vid: str) -> str:
        facts = self._facts.get(vid)
        return facts[0] if facts is not None else super().vehicle_class(vid)

    def vehicle_size(self, vid: str) -> tuple[float, float]:
        size = self._sizes.get(vid)
        return size if size is not None else super().vehicle_size(vid)

    def remove(self, ids: Sequence[str], reason: int = 0) -> None:
        super().remove(ids, reason)
        for vid in ids:
            self._forget(vid)

    def _forget(self, vid: str) -> None:
        for store in (self._original, self._values, self._facts):
            store.pop(vid, None)

    def collisions(self) -> set[str]:
        hit: set[str] = set()
        for c in self._sim.get(self._tc.VAR_COLLISIONS, ()):
            hit.add(c.collider)
            hit.add(c.victim)
        return hit

    def collision_pairs(self) -> list[tuple[str, str]]:
        return [(c.collider, c.victim) for c in self._sim.get(self._tc.VAR_COLLISIONS, ())]

    def arrived(self) -> set[str]:
        arrived = set(self._sim.get(self._tc.VAR_ARRIVED_VEHICLES_IDS, ()))
        for vid in arrived:
            self._forget(vid)
        return arrived

    def departed(self) -> list[str]:
        return list(self._sim.get(self._tc.VAR_DEPARTED_VEHICLES_IDS, ()))

    def vehicle_ids(self) -> list[str]:
        return list(self._ids)

    def restart(self, options: SimOptions) -> None:
        raise BehaveError(
            "a joined simulation belongs to the program that started it: behave cannot reload it"
        )

    # --- leaving ----------------------------------------------------------------------------------

    def close(self) -> None:
        """Give the agents still on the road back to SUMO (their own vType, SUMO's speed and lane
        choice) and close this client; SUMO runs on with the others. Once; closing again is harmless."""
        if self._closer.alive and not self.gone:
            with contextlib.suppress(Exception):  # the connection may have gone meanwhile
                self._give_back()
        self._closer()

    def _give_back(self) -> None:
        still = set(self._ids)
        back = [(vid, own) for vid, own in self._original.items() if vid in still]
        if self._batch:
            tc, w = self._tc, self._wire
            sets = tc.CMD_SET_VEHICLE_VARIABLE
            for vid, (vtype, accel_lat) in back:
                w.queue([
                    w.command(sets, tc.VAR_SPEED, vid, "d", -1.0),
                    w.command(sets, tc.CMD_CHANGESUBLANE, vid, "d", 0.0),
                    w.command(sets, tc.VAR_SPEEDSETMODE, vid, "i", SUMO_SPEED_MODE),
                    w.command(sets, tc.VAR_LANECHANGE_MODE, vid, "i", SUMO_LANE_CHANGE_MODE),
                    w.command(sets, tc.VAR_TYPE, vid, "s", vtype),
                ])  # fmt: skip
                if accel_lat:
                    w.queue([w.command(sets, tc.VAR_PARAMETER, vid, "tss", 2, LC_ACCEL_LAT, accel_lat)])
            self._exchange([])
        else:
            v = self._sumo.vehicle
            for vid, (vtype, accel_lat) in back:
                v.setSpeed(vid, -1.0)
                v.changeSublane(vid, 0.0)
                v.setSpeedMode(vid, SUMO_SPEED_MODE)
                v.setLaneChangeMode(vid, SUMO_LANE_CHANGE_MODE)
                v.setType(vid, vtype)
                if accel_lat:
                    v.setParameter(vid, LC_ACCEL_LAT, accel_lat)
        self.handed_back = len(back)
        self._original = {}
