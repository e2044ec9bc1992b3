"""Write plain SUMO XML (nodes, edges, connections, routes, vTypes) and run netconvert.

Only the standard library is imported here so that importing `sumo_scenarios` stays cheap;
netconvert is located lazily through `sumo_scenarios.sumo_home`.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, replace
from itertools import pairwise
from pathlib import Path

from sumo_scenarios.errors import BehaveError
from sumo_scenarios.sumo_home import sumo_binary

Point = tuple[float, float]

# Enough laps for 100,000 s at the agents' top speed (50 m/s): cars must never run out of route.
LOOP_SECONDS = 100_000.0
LOOP_MAX_SPEED = 50.0
ARC_SPACING = 3.0  # metres of arc between shape points on curves: smooth lane angles
VTYPES_FILE = "vtypes.add.xml"

# Munich lies in UTM zone 32; the highway's node coordinates are real UTM metres there.
UTM32 = "+proj=utm +zone=32 +ellps=WGS84 +datum=WGS84 +units=m +no_defs"
HIGHWAY_ORIGIN: Point = (690_000.0, 5_336_000.0)
HIGHWAY_LENGTH = 3000.0
# lon/lat box of HIGHWAY_ORIGIN + (0..HIGHWAY_LENGTH, 0), inverse UTM computed once offline
# (informative only: SUMO projects with projParameter).
HIGHWAY_LONLAT_BOUNDARY = "11.554519,48.147943,11.594811,48.148846"

DESCRIPTIONS = {
    "ring": "closed 3-lane oval, 3.0 km, curve radius 200 m",
    "highway": "straight 3-lane motorway, 3 km, UTM-32 projection (geo FCD)",
    "tiny": "straight 2-lane road, 600 m, for fast tests",
    "motorway": "curved 3-lane motorway, 4.4 km; the on-ramp's lane runs on as a 4th to the exit (a "
    "1.2 km weave); never trained on",
}

# --precision 4: with 2 decimals, rounding alone bends 3 m curve segments by up to +-40 %.
NETCONVERT_OPTIONS = ("--no-turnarounds", "--junctions.corner-detail", "0", "--precision", "4")


@dataclass(frozen=True)
class Scenario:
    """A bundled (or freshly built) road network with its route and the shared vTypes."""

    name: str
    net: Path
    routes: Path
    vtypes: Path
    route_id: str
    looping: bool
    description: str


@dataclass(frozen=True)
class EdgeSpec:
    """One directed edge: its shape runs from the `src` node to the `dst` node.

    `distance` is the kilometrage at the edge's start (netconvert's edge attribute, which SUMO
    reports as FCD `distance`); None leaves it out.
    """

    id: str
    src: str
    dst: str
    shape: list[Point]
    distance: float | None = None


def split_segment(a: Point, b: Point, pieces: int) -> list[Point]:
    """Points from a to b (both included) that cut the segment into equal pieces."""
    return [(a[0] + (b[0] - a[0]) * i / pieces, a[1] + (b[1] - a[1]) * i / pieces) for i in range(pieces + 1)]


def arc(centre: Point, radius: float, start: float, sweep: float) -> list[Point]:
    """Dense counter-clockwise arc (angles in radians), both ends included."""
    n = max(2, math.ceil(abs(sweep) * radius / ARC_SPACING))
    return [
        (
            centre[0] + radius * math.cos(start + sweep * i / n),
            centre[1] + radius * math.sin(start + sweep * i / n),
        )
        for i in range(n + 1)
    ]


def ring_edges(radius: float, straight: float, edge_length: float) -> list[EdgeSpec]:
    """A counter-clockwise oval: straights split into ~edge_length pieces, each semicircle one edge.

    Junction nodes sit only on the straights (or at the tangent points where a straight
    meets a curve), so no junction lies on a curve.
    """
    pieces = max(1, round(straight / edge_length))
    bottom = split_segment((0.0, -radius), (straight, -radius), pieces)
    top = split_segment((straight, radius), (0.0, radius), pieces)
    right = arc((straight, 0.0), radius, -math.pi / 2, math.pi)
    left = arc((0.0, 0.0), radius, math.pi / 2, math.pi)
    shapes = [[p, q] for p, q in pairwise(bottom)]
    shapes.append(right)
    shapes += [[p, q] for p, q in pairwise(top)]
    shapes.append(left)
    n = len(shapes)
    return [EdgeSpec(f"e{i}", f"n{i}", f"n{(i + 1) % n}", shape) for i, shape in enumerate(shapes)]


def straight_edges(length: float, edge_length: float, origin: Point = (0.0, 0.0)) -> list[EdgeSpec]:
    """A straight road along +x, split into ~edge_length pieces."""
    pieces = max(1, round(length / edge_length))
    points = split_segment(origin, (origin[0] + length, origin[1]), pieces)
    return [EdgeSpec(f"e{i}", f"n{i}", f"n{i + 1}", [p, q]) for i, (p, q) in enumerate(pairwise(points))]


def with_kilometrage(edges: Sequence[EdgeSpec], start: float = 0.0) -> list[EdgeSpec]:
    """The edges of one road in driving order, each starting where the previous one ends."""
    out = []
    for edge in edges:
        out.append(replace(edge, distance=start))
        start += sum(math.dist(p, q) for p, q in pairwise(edge.shape))
    return out


def fmt(value: float) -> str:
    return f"{value:.4f}".rstrip("0").rstrip(".")


def fmt_shape(shape: Sequence[Point]) -> str:
    return " ".join(f"{fmt(x)},{fmt(y)}" for x, y in shape)


def write_xml(root: ET.Element, path: Path) -> None:
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="UTF-8", xml_declaration=True)


def write_nodes(path: Path, edges: Sequence[EdgeSpec], location: ET.Element | None = None) -> None:
    root = ET.Element("nodes")
    if location is not None:
        root.append(location)
    seen: set[str] = set()
    for edge in edges:
        for node, (x, y) in ((edge.src, edge.shape[0]), (edge.dst, edge.shape[-1])):
            if node not in seen:
                seen.add(node)
                ET.SubElement(root, "node", id=node, x=fmt(x), y=fmt(y), type="priority")
    write_xml(root, path)


def write_edges(path: Path, edges: Sequence[EdgeSpec], lanes: int, lane_width: float, speed: float) -> None:
    """spreadType center: the shape is the carriageway's centre line."""
    root = ET.Element("edges")
    for edge in edges:
        attrs = {
            "id": edge.id,
            "from": edge.src,
            "to": edge.dst,
            "numLanes": str(lanes),
            "speed": fmt(speed),
            "width": fmt(lane_width),
            "spreadType": "center",
        }
        if len(edge.shape) > 2:
            attrs["shape"] = fmt_shape(edge.shape)
        if edge.distance is not None:
            attrs["distance"] = fmt(edge.distance)
        ET.SubElement(root, "edge", attrs)
    write_xml(root, path)


def write_connections(path: Path, edges: Sequence[EdgeSpec], lanes: int, closed: bool) -> None:
    """Lane i continues on lane i of the next edge (no merges, no crossings)."""
    root = ET.Element("connections")
    pairs = list(pairwise(edges))
    if closed:
        pairs.append((edges[-1], edges[0]))
    for a, b in pairs:
        for lane in range(lanes):
            ET.SubElement(
                root,
                "connection",
                {"from": a.id, "to": b.id, "fromLane": str(lane), "toLane": str(lane)},
            )
    write_xml(root, path)


def write_routes(path: Path, route_id: str, edge_ids: Sequence[str], repeat: int = 0) -> None:
    root = ET.Element("routes")
    attrs = {"id": route_id, "edges": " ".join(edge_ids)}
    if repeat:
        attrs["repeat"] = str(repeat)
    ET.SubElement(root, "route", attrs)
    write_xml(root, path)


PASSENGER_DECEL = 4.5
"""m/s^2: SUMO's passenger car's braking (its vType default), which agents show SUMO's followers
(`apparentDecel`) and brake with at most while SUMO drives them (`SumoSim.hand_to_sumo`)."""


PASSENGER_MIN_GAP = 2.5
"""m: SUMO's passenger car's standing gap (its vType default), the agents' and SUMO's cars' alike;
the agents' car-following law stands as far behind a car (`settings.CarFollowing.min_gap`)."""

AGENT_LC_ACCEL_LAT = 100.0
"""m/s^2: the agents' lcAccelLat, so large that SUMO's sublane model moves a car exactly as far
sideways in one step as `changeSublane` asks (with SUMO's default of 1 it smooths the request)."""
SUMO_LC_ACCEL_LAT = 1.0
"""m/s^2: SUMO's default lcAccelLat, the lateral comfort an agent gets back while SUMO's driver has it
(`SumoSim.hand_to_sumo`)."""
SUMO_MAX_SPEED_LAT = 1.0
"""m/s: SUMO's default maxSpeedLat, likewise."""
AGENT_VTYPES = ("behave_keeper", "behave_overtaker", "behave_lorry")
"""The vTypes of the learned vehicles (keepers, overtakers and lorries)."""
LORRY_SIZE = (16.5, 2.55)
"""m: a learned lorry's length and width (an EU articulated lorry's legal maximum)."""
LORRY_ACCEL = 0.8
"""m/s^2: the most a loaded lorry gains from rest (SUMO's speed mode caps the policy's commands)."""
LORRY_TOP_SPEED = 25.0
"""m/s: the speed limiter every EU lorry carries (90 km/h)."""
AGENT_ACTION_STEP = 1.0
"""s: how often SUMO works out its own driver's plans for an agent (its vType's actionStepLength).
The policy drives (speed and lane-change modes 0), so those plans go unused; the policy's speed
and sideways move still take effect at every step, between action points too (tests/learn/test_traffic.py).
Worked out once a second instead of at every step, SUMO's own plans for the agents cost a third
less of its step (docs/benchmarks.md). `SumoSim.hand_to_sumo` gives an agent SUMO's
every-step reaction back. Such a vType turns SUMO to the ballistic update: see `SimOptions.ballistic`."""


def write_vtypes(path: Path) -> None:
    """The project's vehicle types, shared by every scenario.

    Agents get a huge lcAccelLat so `changeSublane(v, d)` moves exactly d metres in one step,
    sigma 0 because the policy (not Krauss) drives, and SUMO's plans for them once a second
    (`AGENT_ACTION_STEP`). Their decel (7.5 m/s^2, the policy's full
    brake) is what SUMO's followers would keep room for, so `apparentDecel` shows them SUMO's
    passenger car's 4.5, and SUMO's cars follow an agent at their usual gap (docs/history.md).
    """
    agent = {
        "vClass": "passenger",
        "length": "5",
        "width": "1.8",
        "minGap": f"{PASSENGER_MIN_GAP:g}",
        "maxSpeed": "50",
        "speedFactor": "1",
        "speedDev": "0",
        "accel": "3.0",
        "decel": "7.5",
        "apparentDecel": f"{PASSENGER_DECEL:g}",
        "emergencyDecel": "9",
        "carFollowModel": "Krauss",
        "sigma": "0",
        "lcModel": "SL2015",
        "lcAccelLat": f"{AGENT_LC_ACCEL_LAT:g}",
        "maxSpeedLat": "5",
        "latAlignment": "center",
        "actionStepLength": f"{AGENT_ACTION_STEP:g}",
    }
    sumo_driven = {
        "vClass": "passenger",
        "length": "5",
        "width": "1.8",
        "minGap": f"{PASSENGER_MIN_GAP:g}",
        "carFollowModel": "Krauss",
        "lcModel": "SL2015",
    }
    root = ET.Element("additional")
    # attributes as one dict: typeshed's SubElement would match a `**dict` to its `attrib` parameter too
    keeper, overtaker, lorry_type = AGENT_VTYPES
    for vtype, color in ((keeper, "0,200,0"), (overtaker, "230,120,0")):
        ET.SubElement(root, "vType", {"id": vtype, "color": color, **agent})
    lorry = {
        **agent,
        "vClass": "truck",
        "guiShape": "truck/semitrailer",
        "length": f"{LORRY_SIZE[0]:g}",
        "width": f"{LORRY_SIZE[1]:g}",
        "accel": f"{LORRY_ACCEL:g}",
        "maxSpeed": f"{LORRY_TOP_SPEED:g}",
    }
    ET.SubElement(root, "vType", {"id": lorry_type, "color": "120,60,200", **lorry})
    passive = {"maxSpeed": "20", "speedFactor": "1", "speedDev": "0", "sigma": "0"}
    ET.SubElement(root, "vType", {"id": "behave_passive", "color": "0,0,255", **passive, **sumo_driven})
    background = {"sigma": "0.5", "speedFactor": "norm(1,0.1)"}
    ET.SubElement(
        root, "vType", {"id": "behave_background", "color": "150,150,150", **background, **sumo_driven}
    )
    write_xml(root, path)


def utm_location(edges: Sequence[EdgeSpec]) -> ET.Element:
    """A <location> for nodes given in real UTM-32 metres, so `--fcd-output.geo` works."""
    xs = [x for e in edges for x, _ in e.shape]
    ys = [y for e in edges for _, y in e.shape]
    return ET.Element(
        "location",
        netOffset="0.00,0.00",
        convBoundary=",".join(fmt(v) for v in (min(xs), min(ys), max(xs), max(ys))),
        origBoundary=HIGHWAY_LONLAT_BOUNDARY,
        projParameter=UTM32,
    )


def netconvert(out_dir: Path, name: str) -> Path:
    """Run netconvert on <name>.nod/.edg/.con.xml in out_dir (relative paths: no temp dirs leak
    into the committed net's header)."""
    net = f"{name}.net.xml"
    cmd = [
        sumo_binary("netconvert"),
        "-n", f"{name}.nod.xml",
        "-e", f"{name}.edg.xml",
        "-x", f"{name}.con.xml",
        "-o", net,
        *NETCONVERT_OPTIONS,
    ]  # fmt: skip
    try:
        subprocess.run(cmd, cwd=out_dir, check=True, capture_output=True, text=True)
    except subprocess.CalledProcessError as err:
        message = (err.stderr or err.stdout).strip()
        raise BehaveError(f"netconvert failed for scenario '{name}': {message}") from None
    return out_dir / net


def shared_vtypes(out_dir: Path) -> Path:
    """The vTypes file for a scenario built into out_dir: <out_dir>/../common/vtypes.add.xml."""
    path = out_dir.parent / "common" / VTYPES_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    write_vtypes(path)
    return path


def write_plain(
    out_dir: Path,
    name: str,
    edges: Sequence[EdgeSpec],
    *,
    lanes: int,
    lane_width: float,
    speed: float,
    closed: bool,
    location: ET.Element | None = None,
) -> None:
    """The plain XML netconvert reads: nodes, edges and lane-to-lane connections (see `netconvert`)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    write_nodes(out_dir / f"{name}.nod.xml", edges, location)
    write_edges(out_dir / f"{name}.edg.xml", edges, lanes, lane_width, speed)
    write_connections(out_dir / f"{name}.con.xml", edges, lanes, closed)


RAMP_SPEED = 22.22
"""m/s (80 km/h) on the training roads' ramps."""


def ramp_edges(ring: Sequence[EdgeSpec]) -> tuple[EdgeSpec, EdgeSpec, str, str]:
    """An on-ramp into the end node of the ring's first edge and an exit from the end node of the
    first edge of its second straight (both straights run through ring_edges' node order), each
    250 m long, reaching the road from outside at a shallow angle; and the edges they join/leave."""
    first = ring[0]
    (x0, y0), (x1, y1) = first.shape[0], first.shape[-1]
    ux, uy = (x1 - x0) / math.hypot(x1 - x0, y1 - y0), (y1 - y0) / math.hypot(x1 - x0, y1 - y0)
    out_x, out_y = uy, -ux  # the right of the direction of travel: outside a counter-clockwise oval
    on_ramp = EdgeSpec("ramp_in", "ramp_start", first.dst, [
        (x1 - 250 * ux + 30 * out_x, y1 - 250 * uy + 30 * out_y),
        (x1 - 100 * ux + 10 * out_x, y1 - 100 * uy + 10 * out_y),
        (x1, y1),
    ])  # fmt: skip
    straights = [k for k, e in enumerate(ring) if len(e.shape) == 2]
    second = next(ring[k] for k in straights if ring[k].shape[0][1] * y0 < 0)  # on the other straight
    (a0, b0), (a1, b1) = second.shape[0], second.shape[-1]
    vx, vy = (a1 - a0) / math.hypot(a1 - a0, b1 - b0), (b1 - b0) / math.hypot(a1 - a0, b1 - b0)
    exit_ = EdgeSpec("ramp_out", second.dst, "ramp_end", [
        (a1, b1),
        (a1 + 100 * vx + 10 * vy, b1 + 100 * vy - 10 * vx),
        (a1 + 250 * vx + 30 * vy, b1 + 250 * vy - 30 * vx),
    ])  # fmt: skip
    joined = ring[(ring.index(first) + 1) % len(ring)].id
    return on_ramp, exit_, joined, second.id


def add_ramps(out_dir: Path, name: str, ring: Sequence[EdgeSpec]) -> None:
    """Add ramp_in (merging into lane 0 of the next ring edge) and ramp_out (leaving from lane 0)
    to the plain XML of a ring written by `write_plain`."""
    on_ramp, exit_, joined, left = ramp_edges(ring)
    files = {kind: out_dir / f"{name}.{kind}.xml" for kind in ("nod", "edg", "con")}
    trees = {kind: ET.parse(path) for kind, path in files.items()}
    for edge, node in ((on_ramp, on_ramp.src), (exit_, exit_.dst)):
        x, y = edge.shape[0] if node == edge.src else edge.shape[-1]
        ET.SubElement(trees["nod"].getroot(), "node", id=node, x=fmt(x), y=fmt(y), type="priority")
        ET.SubElement(trees["edg"].getroot(), "edge", {
            "id": edge.id, "from": edge.src, "to": edge.dst, "numLanes": "1", "speed": fmt(RAMP_SPEED),
            "width": "3.5", "shape": fmt_shape(edge.shape),
        })  # fmt: skip
    connections = trees["con"].getroot()
    for src, dst in ((on_ramp.id, joined), (left, exit_.id)):
        ET.SubElement(connections, "connection", {"from": src, "to": dst, "fromLane": "0", "toLane": "0"})
    for kind, tree in trees.items():
        write_xml(tree.getroot(), files[kind])


def add_ramp_flow(routes: Path, ring: Sequence[EdgeSpec]) -> None:
    """RAMP_FLOW SUMO cars per hour join by the on-ramp, drive most of a lap and leave by the exit."""
    on_ramp, exit_, joined, left = ramp_edges(ring)
    ids = [e.id for e in ring]
    start, end = ids.index(joined), ids.index(left)
    through = ids[start : end + 1] if start <= end else ids[start:] + ids[: end + 1]
    tree = ET.parse(routes)
    root = tree.getroot()
    ET.SubElement(root, "route", id="joining", edges=" ".join([on_ramp.id, *through, exit_.id]))
    ET.SubElement(root, "flow", id="ramp", route="joining", type="behave_background", begin="0",
                  end=fmt(LOOP_SECONDS), vehsPerHour=str(RAMP_FLOW), departSpeed="max")  # fmt: skip
    write_xml(root, routes)


def build_ring(
    out_dir: Path,
    *,
    name: str = "ring",
    radius: float = 200.0,
    straight: float = 870.0,
    lanes: int = 3,
    lane_width: float = 3.5,
    edge_length: float = 300.0,
    speed: float = 33.33,
    ramps: bool = False,
) -> Scenario:
    """A closed oval (two straights, two semicircles); the route `loop` circles it for 100,000 s.

    With `ramps`, SUMO's cars also join from an on-ramp on the first straight (merging into
    lane 0 at a junction, yielding to the ring) and leave by an exit on the second."""
    edges = ring_edges(radius, straight, edge_length)
    write_plain(out_dir, name, edges, lanes=lanes, lane_width=lane_width, speed=speed, closed=True)
    if ramps:
        add_ramps(out_dir, name, edges)
    net = netconvert(out_dir, name)
    lap = 2 * straight + 2 * math.pi * radius
    routes = out_dir / f"{name}.rou.xml"
    write_routes(routes, "loop", [e.id for e in edges], math.ceil(LOOP_SECONDS * LOOP_MAX_SPEED / lap))
    if ramps:
        add_ramp_flow(routes, edges)
    return Scenario(
        name=name,
        net=net,
        routes=routes,
        vtypes=shared_vtypes(out_dir),
        route_id="loop",
        looping=True,
        description=f"closed {lanes}-lane oval, {lap / 1000:.1f} km, curve radius {radius:.0f} m",
    )


def build_straight(
    out_dir: Path,
    *,
    name: str,
    length: float,
    edge_length: float,
    lanes: int,
    lane_width: float,
    speed: float = 33.33,
    geo: bool = False,
    kilometrage: bool = False,
    description: str,
) -> Scenario:
    """A straight road along +x; with geo=True it lies at real UTM-32 coordinates.

    kilometrage=True gives the edges a continuous `distance` (0 at the start), so FCD `distance`
    is the road position instead of the position on the current edge.
    """
    edges = straight_edges(length, edge_length, HIGHWAY_ORIGIN if geo else (0.0, 0.0))
    if kilometrage:
        edges = with_kilometrage(edges)
    location = utm_location(edges) if geo else None
    write_plain(out_dir, name, edges, lanes=lanes, lane_width=lane_width, speed=speed, closed=False,
                location=location)  # fmt: skip
    net = netconvert(out_dir, name)
    routes = out_dir / f"{name}.rou.xml"
    write_routes(routes, "main", [e.id for e in edges])
    return Scenario(
        name=name,
        net=net,
        routes=routes,
        vtypes=shared_vtypes(out_dir),
        route_id="main",
        looping=False,
        description=description,
    )


def build_named(name: str, out_dir: Path) -> Scenario:
    """Build one of the bundled scenarios (see SCENARIO_NAMES) into out_dir."""
    if out_dir.exists():
        shutil.rmtree(out_dir)
    if name == "ring":
        return replace(build_ring(out_dir), description=DESCRIPTIONS["ring"])
    if name == "highway":
        return build_straight(
            out_dir,
            name="highway",
            length=HIGHWAY_LENGTH,
            edge_length=300.0,
            lanes=3,
            lane_width=3.5,
            geo=True,
            kilometrage=True,
            description=DESCRIPTIONS["highway"],
        )
    if name == "tiny":
        return build_straight(
            out_dir,
            name="tiny",
            length=600.0,
            edge_length=300.0,
            lanes=2,
            lane_width=3.2,
            description=DESCRIPTIONS["tiny"],
        )
    if name == "motorway":
        return build_motorway(out_dir)
    raise BehaveError(f"no builder for scenario '{name}'")


@dataclass(frozen=True)
class TrainingRoad:
    """One closed road of the traffic driver's training family."""

    lanes: int
    lane_width: float  # m
    radius: float  # m, of both curves
    ramps: bool = False  # an on-ramp and an exit on the straights, with SUMO traffic using them

    @property
    def name(self) -> str:
        return f"road_{self.lanes}x{self.lane_width:g}_r{self.radius:.0f}" + ("_ramps" if self.ramps else "")

    @property
    def description(self) -> str:
        ramps = ", an on-ramp and an exit" if self.ramps else ""
        lanes = f"{self.lanes}-lane road, {self.lane_width:g} m lanes"
        return f"closed {lanes}, curves of {self.radius:.0f} m{ramps}"


TRAINING_ROADS: tuple[TrainingRoad, ...] = (
    TrainingRoad(2, 3.2, 400.0),
    TrainingRoad(3, 3.5, 300.0),
    TrainingRoad(3, 3.0, 600.0),
    TrainingRoad(4, 3.75, 500.0),
    TrainingRoad(5, 3.5, 800.0),
    TrainingRoad(2, 3.5, 500.0, ramps=True),
    TrainingRoad(3, 3.75, 700.0, ramps=True),
)
"""The closed roads the traffic driver trains on: 2-5 lanes, 3.0-3.75 m, curves of 300-800 m."""

RAMP_FLOW = 700
"""veh/h joining from the on-ramp of a training road and leaving by its exit."""


def build_training_roads(root: Path) -> list[Scenario]:
    """The family of closed multi-lane roads into root/<name>/: SUMO's cars circle them forever,
    so every episode has traffic; on the roads with ramps more of it joins and leaves."""
    built = []
    for road in TRAINING_ROADS:
        out_dir = root / road.name
        if out_dir.exists():
            shutil.rmtree(out_dir)
        ring = build_ring(
            out_dir, name=road.name, radius=road.radius, straight=600.0, lanes=road.lanes,
            lane_width=road.lane_width, ramps=road.ramps,
        )  # fmt: skip
        built.append(replace(ring, description=road.description))
    return built


MOTORWAY_NODES = (
    ("w0", 0.0, 0.0), ("w1", 1500.0, 0.0), ("w2", 2600.0, 420.0), ("w3", 4200.0, 420.0),
    ("ramp", 1050.0, -140.0), ("exit", 2900.0, 300.0),
)  # fmt: skip
MOTORWAY_EDGES = (
    # id, from, to, lanes, speed, shape (None = straight)
    ("m1", "w0", "w1", 3, 33.33, None),
    ("m2", "w1", "w2", 4, 33.33, "1500,0 1800,15 2100,80 2350,210 2600,420"),
    ("m3", "w2", "w3", 3, 33.33, "2600,420 2800,560 3100,640 3500,640 4200,420"),
    ("r0", "ramp", "w1", 1, 22.22, None),
    ("x0", "w2", "exit", 1, 22.22, None),
)
MOTORWAY_CONNECTIONS = (
    ("m1", "m2", 0, 1), ("m1", "m2", 1, 2), ("m1", "m2", 2, 3), ("r0", "m2", 0, 0),
    ("m2", "x0", 0, 0), ("m2", "m3", 1, 0), ("m2", "m3", 2, 1), ("m2", "m3", 3, 2),
)  # fmt: skip
"""A curved motorway the policies never train on: 3 lanes, an on-ramp whose acceleration lane
becomes a fourth lane and leaves again as an exit (a weave), curves of about 500-800 m, 3.75 m
lanes; demand from the main road and the ramp, some of it leaving at the exit."""


def build_motorway(out_dir: Path, name: str = "motorway") -> Scenario:
    """The evaluation motorway (see MOTORWAY_EDGES) with flows: main road through and to the exit,
    ramp through; the route `main` runs m1 m2 m3."""
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    nodes = ET.Element("nodes")
    for node, x, y in MOTORWAY_NODES:
        ET.SubElement(nodes, "node", id=node, x=fmt(x), y=fmt(y))
    write_xml(nodes, out_dir / f"{name}.nod.xml")
    edges = ET.Element("edges")
    for edge, src, dst, lanes, speed, shape in MOTORWAY_EDGES:
        attrs = {
            "id": edge,
            "from": src,
            "to": dst,
            "numLanes": str(lanes),
            "speed": fmt(speed),
            "width": "3.75",
        }
        if shape:
            attrs["shape"] = shape
        ET.SubElement(edges, "edge", attrs)
    write_xml(edges, out_dir / f"{name}.edg.xml")
    connections = ET.Element("connections")
    for src, dst, from_lane, to_lane in MOTORWAY_CONNECTIONS:
        ET.SubElement(connections, "connection", {"from": src, "to": dst, "fromLane": str(from_lane),
                                                  "toLane": str(to_lane)})  # fmt: skip
    write_xml(connections, out_dir / f"{name}.con.xml")
    net = netconvert(out_dir, name)
    routes = ET.Element("routes")
    ET.SubElement(routes, "route", id="main", edges="m1 m2 m3")
    ET.SubElement(routes, "route", id="to_exit", edges="m1 m2 x0")
    ET.SubElement(routes, "route", id="from_ramp", edges="r0 m2 m3")
    for flow, route, per_hour in (
        ("through", "main", 2400),
        ("leaving", "to_exit", 400),
        ("joining", "from_ramp", 500),
    ):
        ET.SubElement(routes, "flow", id=flow, route=route, type="behave_background", begin="0", end="100000",
                      vehsPerHour=str(per_hour), departLane="best", departSpeed="desired")  # fmt: skip
    write_xml(routes, out_dir / f"{name}.rou.xml")
    return Scenario(
        name=name,
        net=net,
        routes=out_dir / f"{name}.rou.xml",
        vtypes=shared_vtypes(out_dir),
        route_id="main",
        looping=False,
        description=DESCRIPTIONS["motorway"],
    )
