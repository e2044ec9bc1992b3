"""TraCI's wire format, as far as behave reads and writes it: many commands per message (`Wire`) and
the subscription results SUMO sends with a step read by fixed-layout unpacking (`StepReader`), for
joined.JoinedSim.

Batching uses traci's private packing, socket, lock and reader (`Connection._pack`, `_socket`,
`_lock`, `_recvExact`, `_string`, `_queue`, `_subscriptionMapping`), pinned by constraints.txt
(traci 1.28) and checked by tests/sumo/test_connect.py; where one is missing (`batches`) JoinedSim
uses traci's public calls (the same values, one round trip per call).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from types import ModuleType
from typing import Any

from behaviors.errors import BehaveError

_STATUS = struct.Struct("!BBBi")  # length, command, result, description length
_VAR = struct.Struct("!BBB")  # variable id, status, value type
_INT = struct.Struct("!i")
_DOUBLE = struct.Struct("!d")
_SET_DOUBLE = struct.Struct("!BBBi")  # length, command, variable, object id length
_TYPED_DOUBLE = struct.Struct("!Bd")
_POSITION_SPEED = struct.Struct("!BBBddBBBd")  # position (2D), then speed: a vehicle's first two values
_LANE_PLACE = struct.Struct("!BBBdBBBdBBBi")  # lane position, lateral offset, then the lane id's length


def _string(content: bytes, pos: int) -> tuple[str, int]:
    (n,) = _INT.unpack_from(content, pos)
    return content[pos + 4 : pos + 4 + n].decode(), pos + 4 + n


def _strings(content: bytes, pos: int) -> tuple[tuple[str, ...], int]:
    (count,) = _INT.unpack_from(content, pos)
    pos += 4
    out = []
    for _ in range(count):
        (n,) = _INT.unpack_from(content, pos)
        out.append(content[pos + 4 : pos + 4 + n].decode())
        pos += 4 + n
    return tuple(out), pos


class Wire:
    """Many TraCI commands per message (traci sends one per message and waits for its answer).

    Set commands are queued where traci queues its own (`Connection._string` and `_queue`), so they
    go out with the next message whoever sends it, in order; `exchange` sends the queue with its own
    commands and returns the answer positioned at the first of its own."""

    def __init__(self, connection: Any, tc: ModuleType) -> None:
        self.connection, self.tc = connection, tc
        self.double = tc.TYPE_DOUBLE
        self._prefixes: dict[tuple[int, str], bytes] = {}  # (variable, vehicle) -> a set command's head
        self._ok = [bytes((7, command, 0, 0, 0, 0, 0)) for command in range(256)]  # a status: all went well

    def command(
        self, command: int, var: int | tuple[float, float] | None, obj: str, fmt: str = "", *values: Any
    ) -> bytes:
        """One command as traci's Connection._sendCmd packs it (var None: a command without one)."""
        name = obj.encode()
        packed = self.connection._pack(fmt, *values)
        if var is None:
            length = 1 + 1 + len(packed)
            head = b""
        elif isinstance(var, tuple):  # a subscription: begin and end
            length = 1 + 1 + 8 + 8 + 4 + len(name) + len(packed)
            head = struct.pack("!dd", *var) + _INT.pack(len(name)) + name
        else:
            length = 1 + 1 + 1 + 4 + len(name) + len(packed)
            head = struct.pack("!B", var) + _INT.pack(len(name)) + name
        start = (
            struct.pack("!BB", length, command)
            if length <= 255
            else struct.pack("!BiB", 0, length + 4, command)
        )
        return start + head + packed

    def set_doubles(self, var: int, ids: Iterable[str], values: Iterable[float]) -> list[bytes]:
        """Vehicle set commands of one double each (a speed, a sideways move), packed fast."""
        command, kind, pack = self.tc.CMD_SET_VEHICLE_VARIABLE, self.double, _TYPED_DOUBLE.pack
        prefixes = self._prefixes
        if len(prefixes) > 100_000:  # vehicles come and go: start afresh now and then
            prefixes.clear()
        out = []
        for vid, value in zip(ids, values, strict=True):
            prefix = prefixes.get((var, vid))
            if prefix is None:
                name = vid.encode()
                if len(name) > 239:  # the command's length no longer fits its byte
                    out.append(self.command(command, var, vid, "d", value))
                    continue
                prefix = prefixes[var, vid] = _SET_DOUBLE.pack(16 + len(name), command, var, len(name)) + name
            out.append(prefix + pack(kind, value))
        return out

    def queue(self, commands: list[bytes]) -> None:
        """Send `commands` (set commands: no answer but their status) with the next message."""
        if not commands:
            return
        connection = self.connection
        with connection._lock:
            connection._string += b"".join(commands)
            connection._queue.extend(c[1] if c[0] else c[5] for c in commands)  # each one's command id

    def exchange(self, commands: list[bytes]) -> Any:
        """Send the queue and `commands` as one message; the answer (a traci Storage) is returned past
        the queued commands' statuses (an error there raised as traci raises it), at the first of
        `commands`' statuses, which the caller reads (`status`, then any value)."""
        from traci import FatalTraCIError, TraCIException

        connection = self.connection
        with connection._lock:
            body = b"".join((connection._string, *commands))
            queued, connection._string, connection._queue = connection._queue, b"", []
            if not body:
                return None
            if connection._socket is None:
                raise FatalTraCIError("Connection already closed.")
            connection._socket.sendall(_INT.pack(len(body) + 4) + body)
            result = connection._recvExact()
            if result is None:
                connection._socket.close()
                connection._socket = None
                raise FatalTraCIError("Connection closed by SUMO.")
        ok = b"".join(map(self._ok.__getitem__, queued))  # every queued command went well: one compare
        if result._content.startswith(ok, result._pos):
            result._pos += len(ok)
            return result
        error = None
        for _ in queued:
            text = self.status(result)
            if text is not None and error is None:
                error = TraCIException(text)
        if error is not None:
            raise error
        return result

    @staticmethod
    def status(result: Any) -> str | None:
        """Read one command's status from a traci Storage: None if it went well, else SUMO's text."""
        _, _, code, n = _STATUS.unpack_from(result._content, result._pos)
        text = result._content[result._pos + 7 : result._pos + 7 + n].decode()
        result._pos += 7 + n
        return (text or "error") if code or text else None  # as traci: a text is an error too


class StepReader:
    """The subscription results SUMO sends with its answer to a step (or a subscribe), read into
    plain values."""

    def __init__(self, connection: Any, tc: ModuleType) -> None:
        self.connection, self.tc = connection, tc
        self.vehicle_response = tc.RESPONSE_SUBSCRIBE_VEHICLE_VARIABLE
        self.simulation_response = tc.RESPONSE_SUBSCRIBE_SIM_VARIABLE
        self.position, self.speed = tc.VAR_POSITION, tc.VAR_SPEED
        self.lane_vars = (tc.VAR_LANEPOSITION, tc.VAR_LANEPOSITION_LAT, tc.VAR_LANE_ID)
        self.plain_kinds = (self.position, 0, tc.POSITION_2D, self.speed, 0, tc.TYPE_DOUBLE)
        self.lane_kinds = (tc.TYPE_DOUBLE, tc.TYPE_DOUBLE, tc.TYPE_STRING)

    def read(
        self, content: bytes, pos: int
    ) -> tuple[dict[str, tuple], dict[tuple[int, str], dict[int, Any]]]:
        """({vehicle: (x, y, speed[, lane position, lateral offset, lane])},
        {(response, other object): {var: value}}: the simulation's values, the vehicle list)."""
        (count,) = _INT.unpack_from(content, pos)
        pos += 4
        vehicles: dict[str, tuple] = {}
        others: dict[tuple[int, str], dict[int, Any]] = {}
        # read_one's usual cases inlined: ~1,000 vehicles a step
        unpack_int, unpack_plain, unpack_lane = (
            _INT.unpack_from,
            _POSITION_SPEED.unpack_from,
            _LANE_PLACE.unpack_from,
        )
        plain_size, lane_size = _POSITION_SPEED.size, _LANE_PLACE.size
        response_id, plain_kinds, lane_vars, lane_kinds = (
            self.vehicle_response,
            self.plain_kinds,
            self.lane_vars,
            self.lane_kinds,
        )
        for _ in range(count):
            start = pos
            pos += 1 if content[pos] else 5
            response = content[pos]
            (n,) = unpack_int(content, pos + 1)
            name = content[pos + 5 : pos + 5 + n].decode()
            pos += 5 + n
            variables = content[pos]
            pos += 1
            if response == response_id and n and variables in (2, 5):
                v1, s1, t1, x, y, v2, s2, t2, speed = unpack_plain(content, pos)
                if (v1, s1, t1, v2, s2, t2) == plain_kinds:
                    pos += plain_size
                    if variables == 2:
                        vehicles[name] = (x, y, speed)
                        continue
                    v3, s3, t3, lane_pos, v4, s4, t4, lateral, v5, s5, t5, m = unpack_lane(content, pos)
                    if (v3, v4, v5) == lane_vars and not (s3 or s4 or s5) and (t3, t4, t5) == lane_kinds:
                        pos += lane_size
                        vehicles[name] = (x, y, speed, lane_pos, lateral, content[pos : pos + m].decode())
                        pos += m
                        continue
            pos = self.read_one(content, start, vehicles, others)
        return vehicles, others

    def read_one(
        self,
        content: bytes,
        pos: int,
        vehicles: dict[str, tuple],
        others: dict[tuple[int, str], dict[int, Any]],
    ) -> int:
        """One subscription result into `vehicles` or `others`; the position after it. SUMO 1.28 sends
        every client the subscriptions of all (merged where they name the same object): another client's
        variables come along in a vehicle's result, and results of other domains or context
        subscriptions are skipped (read by traci's own reader, kept nowhere)."""
        start = pos
        pos += 1 if content[pos] else 5  # its length: a byte, or 0 and an int
        response = content[pos]
        name, pos = _string(content, pos + 1)
        variables = content[pos]
        pos += 1
        if response == self.vehicle_response and name and variables in (2, 5):
            values, end = self._vehicle(content, pos, variables)
            if values is not None:
                vehicles[name] = values
                return end
        if response not in (self.vehicle_response, self.simulation_response):
            import traci

            storage = traci.storage.Storage(content)
            storage._pos = start
            self.connection._readSubscription(storage)
            return int(storage._pos)
        others[response, name], pos = self._generic(content, pos, variables, response)
        return pos

    def _vehicle(self, content: bytes, pos: int, variables: int) -> tuple[tuple | None, int]:
        """The usual layouts in one unpack each; None where SUMO answered otherwise (an error value)."""
        v1, s1, t1, x, y, v2, s2, t2, speed = _POSITION_SPEED.unpack_from(content, pos)
        if (v1, s1, t1, v2, s2, t2) != self.plain_kinds:
            return None, pos
        pos += _POSITION_SPEED.size
        if variables == 2:
            return (x, y, speed), pos
        v3, s3, t3, lane_pos, v4, s4, t4, lateral, v5, s5, t5, n = _LANE_PLACE.unpack_from(content, pos)
        if (v3, v4, v5) != self.lane_vars or s3 or s4 or s5 or (t3, t4, t5) != self.lane_kinds:
            return None, pos
        pos += _LANE_PLACE.size
        lane = content[pos : pos + n].decode()
        return (x, y, speed, lane_pos, lateral, lane), pos + n

    def _generic(self, content: bytes, pos: int, variables: int, response: int) -> tuple[dict[int, Any], int]:
        tc = self.tc
        out: dict[int, Any] = {}
        for _ in range(variables):
            var, status, kind = _VAR.unpack_from(content, pos)
            pos += 3
            if status:  # an error text in place of the value
                text, pos = _string(content, pos)
                out[var] = BehaveError(f"SUMO could not give variable {var:#x}: {text}")
            elif kind == tc.TYPE_DOUBLE:
                out[var], pos = _DOUBLE.unpack_from(content, pos)[0], pos + 8
            elif kind == tc.TYPE_INTEGER:
                out[var], pos = _INT.unpack_from(content, pos)[0], pos + 4
            elif kind == tc.TYPE_STRING:
                out[var], pos = _string(content, pos)
            elif kind == tc.TYPE_STRINGLIST:
                out[var], pos = _strings(content, pos)
            elif kind == tc.POSITION_2D:
                out[var], pos = struct.unpack_from("!dd", content, pos), pos + 16
            else:  # compounds (collisions): traci's own parser for the domain
                out[var], pos = self.parse(content, pos - 1, var, response)
        return out, pos

    def parse(self, content: bytes, pos: int, var: int, response: int) -> tuple[Any, int]:
        """A typed value at `pos` parsed by traci's parser of the domain answering with `response`."""
        import traci

        storage = traci.storage.Storage(content)
        storage._pos = pos
        value = self.connection._subscriptionMapping[response].parse(var, storage)
        return value, storage._pos

    def answer(self, result: Any, get: int) -> Any:
        """The value of one get command's answer at `result`'s position (None where SUMO refused it)."""
        if Wire.status(result) is not None:
            return None
        content, pos = result._content, result._pos
        pos += 1 if content[pos] else 5  # its length
        var = content[pos + 1]
        _, pos = _string(content, pos + 2)  # the object's id
        value, result._pos = self.parse(content, pos, var, get)
        return value


def batches(connection: Any) -> bool:
    """Whether traci's private pieces the batching uses are all there (else its public calls)."""
    names = ("_socket", "_lock", "_recvExact", "_string", "_queue", "_pack", "_subscriptionMapping")
    return all(hasattr(connection, name) for name in names)
