"""Motorway nets the policies never saw, built as OSM imports are: plain XML through netconvert.

Each net is one carriageway drawn as a chain of ways (edges) whose shapes are the carriageway's
centre line with a point every few metres along curves of 600-1000 m, with an exit and an
on-ramp and its own demand (cars through, cars leaving at the exit, cars joining from the ramp,
a few lorries) and a sumocfg, so `behave populate --sumocfg` runs it as a user's scenario would:

* `motorway3`: 3 lanes of 3.5 m; the right lane drops into the exit ramp (the main road goes on
  with 2 lanes), then the on-ramp adds it back as a third lane.
* `carriageway2`: 2 lanes of SUMO's default 3.2 m (no width given, as in most OSM imports); the
  exit leaves from a deceleration lane, the ramp joins through an acceleration lane that ends.
* `lanedrop`: 3 lanes of 3.5 m that become 2 (the right lane ends), then an exit and a ramp;
  here netconvert guesses every connection, as it does for an OSM import.
* `motorway3_lefthand`: `motorway3` mirrored and built with `netconvert --lefthand` (exit and
  ramp on the left, as on British motorways).

Nothing is committed: `build_osm_like(name, folder)` writes the files into a folder of the
caller's (tests and benchmarks use a temporary or cache folder).
"""

from __future__ import annotations

import math
import subprocess
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from sumo_scenarios.build import NETCONVERT_OPTIONS, EdgeSpec, Point, fmt, fmt_shape, write_nodes, write_xml
from sumo_scenarios.errors import BehaveError
from sumo_scenarios.sumo_home import sumo_binary

SPACING = 5.0
"""Metres between shape points along a curve."""
MOTORWAY_SPEED = 33.33
RAMP_SPEED = 22.22
RAMP_SPLAY = 0.12
"""rad: how far a ramp's heading differs from the main road's where they meet."""

Piece = tuple[float, float]
"""(length m, radius m) of a piece of road; radius 0 = straight, > 0 turns left, < 0 turns right."""


@dataclass(frozen=True)
class Way:
    """One edge: lanes, lane width (None = SUMO's default 3.2 m), speed, and where it runs."""

    id: str
    src: str
    dst: str
    lanes: int
    width: float | None
    speed: float
    shape: list[Point]


@dataclass(frozen=True)
class OsmLikeNet:
    """A built net with its demand: the sumocfg names the net and the routes."""

    name: str
    net: Path
    routes: Path
    sumocfg: Path
    exit_edge: str  # the exit ramp: cars leaving end their route on it
    ramp_edge: str  # the on-ramp: cars joining start on it
    lefthand: bool


def trace(start: Point, heading: float, pieces: Sequence[Piece]) -> tuple[list[Point], float]:
    """Points along straights and circular arcs from `start`, and the heading at the end."""
    points = [start]
    x, y = start
    for length, radius in pieces:
        steps = max(1, math.ceil(length / SPACING)) if radius else 1
        for _ in range(steps):
            ds = length / steps
            if radius:
                turn = ds / radius
                x += radius * (math.sin(heading + turn) - math.sin(heading))
                y -= radius * (math.cos(heading + turn) - math.cos(heading))
                heading += turn
            else:
                x, y = x + ds * math.cos(heading), y + ds * math.sin(heading)
            points.append((x, y))
    return points, heading


def backwards(end: Point, heading: float, pieces: Sequence[Piece]) -> list[Point]:
    """A road that arrives at `end` with `heading`, drawn by driving its pieces in reverse from there."""
    flipped = [(length, -radius) for length, radius in reversed(pieces)]
    points, _ = trace(end, heading + math.pi, flipped)
    return points[::-1]


class Chain:
    """The main carriageway drawn piece by piece: each way starts where the last one ended."""

    def __init__(self) -> None:
        self.end: Point = (0.0, 0.0)
        self.heading = 0.0
        self.ways: list[Way] = []
        self.node = 0

    def way(self, id: str, lanes: int, pieces: Sequence[Piece], width: float | None) -> Way:
        shape, self.heading = trace(self.end, self.heading, pieces)
        way = Way(id, f"n{self.node}", f"n{self.node + 1}", lanes, width, MOTORWAY_SPEED, shape)
        self.end, self.node = shape[-1], self.node + 1
        self.ways.append(way)
        return way

    def exit_ramp(self, at: Way, id: str) -> Way:
        """A one-lane ramp leaving to the right where `at` ends."""
        pieces = [(100.0, 0.0), (120.0, -250.0), (150.0, 0.0)]
        shape, _ = trace(at.shape[-1], self.heading - RAMP_SPLAY, pieces)
        return self._ramp(Way(id, at.dst, f"{id}_end", 1, None, RAMP_SPEED, shape))

    def on_ramp(self, at: Way, id: str) -> Way:
        """A one-lane ramp joining from the right where `at` ends."""
        pieces = [(150.0, 0.0), (120.0, -250.0), (100.0, 0.0)]
        shape = backwards(at.shape[-1], self.heading + RAMP_SPLAY, pieces)
        return self._ramp(Way(id, f"{id}_start", at.dst, 1, None, RAMP_SPEED, shape))

    def _ramp(self, way: Way) -> Way:
        self.ways.append(way)
        return way


Connection = tuple[str, str, int, int]  # from edge, to edge, from lane, to lane


def motorway3() -> tuple[list[Way], list[Connection], str, str]:
    """3 lanes; the right lane becomes the exit, the ramp becomes the right lane again."""
    c = Chain()
    m0 = c.way("m0", 3, [(900.0, 0.0)], 3.5)
    m1 = c.way("m1", 3, [(500.0, 800.0), (200.0, 0.0)], 3.5)
    m2 = c.way("m2", 3, [(400.0, -1000.0)], 3.5)
    exit_ramp = c.exit_ramp(m2, "exit")
    m3 = c.way("m3", 2, [(600.0, 0.0), (300.0, 600.0)], 3.5)
    ramp = c.on_ramp(m3, "ramp")
    c.way("m4", 3, [(500.0, -700.0), (700.0, 0.0)], 3.5)
    connections = [
        *lane_for_lane(m0, m1, 3), *lane_for_lane(m1, m2, 3),
        ("m2", exit_ramp.id, 0, 0), ("m2", "m3", 1, 0), ("m2", "m3", 2, 1),
        (ramp.id, "m4", 0, 0), ("m3", "m4", 0, 1), ("m3", "m4", 1, 2),
    ]  # fmt: skip
    return c.ways, connections, exit_ramp.id, ramp.id


def carriageway2() -> tuple[list[Way], list[Connection], str, str]:
    """2 lanes of SUMO's default width; a deceleration lane to the exit, an acceleration lane from
    the ramp."""
    c = Chain()
    c.way("m0", 2, [(800.0, 0.0), (400.0, 700.0)], None)
    m1 = c.way("m1", 3, [(250.0, 0.0)], None)
    exit_ramp = c.exit_ramp(m1, "exit")
    m2 = c.way("m2", 2, [(500.0, -900.0), (300.0, 0.0)], None)
    ramp = c.on_ramp(m2, "ramp")
    m3 = c.way("m3", 3, [(300.0, 0.0)], None)
    m4 = c.way("m4", 2, [(400.0, 600.0), (600.0, 0.0)], None)
    connections = [
        ("m0", "m1", 0, 1), ("m0", "m1", 1, 2), ("m1", exit_ramp.id, 0, 0), *lane_for_lane(m1, m2, 2, 1),
        (ramp.id, "m3", 0, 0), ("m2", "m3", 0, 1), ("m2", "m3", 1, 2), *lane_for_lane(m3, m4, 2, 1),
    ]  # fmt: skip
    return c.ways, connections, exit_ramp.id, ramp.id


def lanedrop() -> tuple[list[Way], list[Connection], str, str]:
    """3 lanes become 2, then an exit and a ramp; the connections are netconvert's guesses."""
    c = Chain()
    c.way("m0", 3, [(700.0, 0.0), (400.0, -800.0)], 3.5)
    c.way("m1", 2, [(600.0, 0.0)], 3.5)
    m2 = c.way("m2", 2, [(300.0, 900.0)], 3.5)
    exit_ramp = c.exit_ramp(m2, "exit")
    m3 = c.way("m3", 2, [(800.0, 0.0)], 3.5)
    ramp = c.on_ramp(m3, "ramp")
    c.way("m4", 2, [(400.0, -700.0), (500.0, 0.0)], 3.5)
    return c.ways, [], exit_ramp.id, ramp.id


def lane_for_lane(a: Way, b: Way, lanes: int, shift: int = 0) -> list[Connection]:
    """Lane i + shift of `a` goes on as lane i of `b`."""
    return [(a.id, b.id, i + shift, i) for i in range(lanes)]


LAYOUTS = {"motorway3": motorway3, "carriageway2": carriageway2, "lanedrop": lanedrop}
OSM_LIKE_NAMES: tuple[str, ...] = ("motorway3", "carriageway2", "lanedrop", "motorway3_lefthand")
LEFTHAND_SUFFIX = "_lefthand"


def mirrored(ways: list[Way]) -> list[Way]:
    """The same roads reflected in the x axis: ramps on the left, curves the other way."""
    return [Way(w.id, w.src, w.dst, w.lanes, w.width, w.speed, [(x, -y) for x, y in w.shape]) for w in ways]


def write_plain(folder: Path, name: str, ways: list[Way], connections: list[Connection]) -> None:
    write_nodes(folder / f"{name}.nod.xml", [EdgeSpec(w.id, w.src, w.dst, w.shape) for w in ways])
    edges = ET.Element("edges")
    for way in ways:
        attrs = {"id": way.id, "from": way.src, "to": way.dst, "numLanes": str(way.lanes),
                 "speed": fmt(way.speed), "spreadType": "center", "shape": fmt_shape(way.shape)}  # fmt: skip
        if way.width is not None:
            attrs["width"] = fmt(way.width)
        ET.SubElement(edges, "edge", attrs)
    root = ET.Element("connections")
    for src, dst, from_lane, to_lane in connections:
        ET.SubElement(root, "connection", {"from": src, "to": dst, "fromLane": str(from_lane),
                                           "toLane": str(to_lane)})  # fmt: skip
    write_xml(edges, folder / f"{name}.edg.xml")
    write_xml(root, folder / f"{name}.con.xml")


def run_netconvert(folder: Path, name: str, lefthand: bool) -> Path:
    net = folder / f"{name}.net.xml"
    command = [sumo_binary("netconvert"), "-n", f"{name}.nod.xml", "-e", f"{name}.edg.xml",
               "-x", f"{name}.con.xml", "-o", net.name, *NETCONVERT_OPTIONS,
               *(("--lefthand",) if lefthand else ())]  # fmt: skip
    done = subprocess.run(command, cwd=folder, capture_output=True, text=True)
    if done.returncode != 0:
        raise BehaveError(f"netconvert failed for {name}: {(done.stderr or done.stdout).strip()}")
    return net


FLOWS = (
    # id, route (from, to), vehicle type, per hour: about 800 vehicles an hour per lane where the
    # main road has 2 lanes
    ("through", ("main", "main"), "car", 1400),
    ("leaving", ("main", "exit"), "car", 300),
    ("joining", ("ramp", "main"), "car", 300),
    ("lorries", ("main", "main"), "lorry", 160),
)


@dataclass(frozen=True)
class Demand:
    """How much traffic (a factor on FLOWS) and how much its drivers dawdle (Krauss sigma)."""

    end: float = 3600.0
    scale: float = 1.0
    sigma: float = 0.5


def write_demand(path: Path, ways: list[Way], exit_edge: str, ramp_edge: str, demand: Demand) -> None:
    """Flows through, off at the exit, on from the ramp (cars as OSM demand draws them, lorries)."""
    main = [w.id for w in ways if w.id not in (exit_edge, ramp_edge)]
    starts = {"main": main[0], "ramp": ramp_edge}
    ends = {"main": main[-1], "exit": exit_edge}
    routes = ET.Element("routes")
    ET.SubElement(
        routes,
        "vType",
        id="car",
        vClass="passenger",
        sigma=fmt(demand.sigma),
        speedFactor="normc(1,0.1,0.2,2)",
    )
    ET.SubElement(
        routes, "vType", id="lorry", vClass="truck", length="12", maxSpeed="25", sigma=fmt(demand.sigma)
    )
    for flow, (src, dst), vtype, per_hour in FLOWS:
        attrs = {"id": flow, "type": vtype, "begin": "0", "end": fmt(demand.end), "from": starts[src],
                 "to": ends[dst], "vehsPerHour": fmt(per_hour * demand.scale), "departLane": "best",
                 "departSpeed": "max"}  # fmt: skip
        ET.SubElement(routes, "flow", attrs)
    write_xml(routes, path)


def write_sumocfg(path: Path, net: Path, routes: Path, end: float) -> None:
    root = ET.Element("configuration")
    inputs = ET.SubElement(root, "input")
    ET.SubElement(inputs, "net-file", value=net.name)
    ET.SubElement(inputs, "route-files", value=routes.name)
    times = ET.SubElement(root, "time")
    ET.SubElement(times, "begin", value="0")
    ET.SubElement(times, "end", value=fmt(end))
    write_xml(root, path)


def build_osm_like(name: str, folder: Path, demand: Demand = Demand()) -> OsmLikeNet:
    """Build one of OSM_LIKE_NAMES into `folder` (net, plain XML, its demand, sumocfg)."""
    if name not in OSM_LIKE_NAMES:
        raise BehaveError(f"unknown test net '{name}' (choose from {', '.join(OSM_LIKE_NAMES)})")
    lefthand = name.endswith(LEFTHAND_SUFFIX)
    ways, connections, exit_edge, ramp_edge = LAYOUTS[name.removesuffix(LEFTHAND_SUFFIX)]()
    if lefthand:
        ways = mirrored(ways)
    folder.mkdir(parents=True, exist_ok=True)
    write_plain(folder, name, ways, connections)
    net = run_netconvert(folder, name, lefthand)
    routes = folder / f"{name}.rou.xml"
    write_demand(routes, ways, exit_edge, ramp_edge, demand)
    sumocfg = folder / f"{name}.sumocfg"
    write_sumocfg(sumocfg, net, routes, demand.end)
    return OsmLikeNet(name, net, routes, sumocfg, exit_edge, ramp_edge, lefthand)
