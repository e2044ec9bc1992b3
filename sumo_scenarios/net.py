"""The one SUMO net reader: one streaming pass of the standard library's C parser over a .net.xml
(or .net.xml.gz). sumolib's object model takes minutes on region nets; this keeps memory flat.

`net_elements` is the parse; `read_net` (road geometry, scenario facts) and `lane_widths`
(plots) are built on it, and nothing else in behave reads a net.
"""

from __future__ import annotations

import gzip
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

CAR_CLASS = "passenger"
"""The SUMO vehicle class of behave's cars: only lanes (and connections) it may use are road."""

DEFAULT_LANE_WIDTH = 3.2
"""SUMO's lane width where the net does not name one."""

LaneSpec = tuple[str, list[tuple[float, float]], float, float, float]
"""(lane id, centre-line shape, width, speed limit, SUMO lane length)."""


@dataclass
class NetTables:
    """What behave reads of a .net.xml: every edge's car lanes and the car connections."""

    edges: list[tuple[str, list[LaneSpec], bool]] = field(default_factory=list)  # id, car lanes, normal?
    links: dict[tuple[str, str], str] = field(default_factory=dict)  # normal -> normal: first via lane
    car_links: set[tuple[str, str]] = field(default_factory=set)  # ... that a passenger car may take
    lane_links: set[tuple[str, str]] = field(default_factory=set)  # lane -> lane of those car links
    lane_next: set[tuple[str, str]] = field(default_factory=set)  # car lane -> the car lane a car drives
    # on to: a connection's via lane (the junction's), or from a via lane to its normal lane
    lefthand: bool = False


def net_elements(path: Path) -> Iterator[ET.Element]:
    """The <net> element as it opens (attributes only), then each <edge> and <connection> as it
    closes, cleared once the caller moves on."""
    with open(path, "rb") as head:
        opener = gzip.open if head.read(2) == b"\x1f\x8b" else open
    with opener(path, "rb") as stream:
        for event, elem in ET.iterparse(stream, events=("start", "end")):
            if event == "start":
                if elem.tag == "net":
                    yield elem
            elif elem.tag in ("edge", "connection"):
                yield elem
                elem.clear()


def read_net(path: Path) -> NetTables:
    """Edges (normal and junction-internal) with their car lanes, and the connections."""
    out = NetTables()
    car_lane: set[str] = set()
    normal: set[str] = set()
    for elem in net_elements(path):
        if elem.tag == "net":
            out.lefthand = elem.get("lefthand") == "true"
        elif elem.tag == "edge":
            function = elem.get("function", "normal")
            if function in ("normal", "internal"):
                lanes = [
                    lane_spec(lane)
                    for lane in elem.iter("lane")
                    if allows_car(lane.get("allow"), lane.get("disallow"))
                ]
                car_lane.update(spec[0] for spec in lanes)
                if function == "normal":
                    normal.add(elem.get("id", ""))
                if lanes:
                    out.edges.append((elem.get("id", ""), lanes, function == "normal"))
        else:
            add_connection(out, elem, normal, car_lane)
    return out


def add_connection(out: NetTables, elem: ET.Element, normal: set[str], car_lane: set[str]) -> None:
    """A connection between normal edges joins them (its via lane is the junction's length), and
    joins them for cars if both its lanes and the connection itself allow a car."""
    src, dst = elem.get("from", ""), elem.get("to", "")
    here, there = f"{src}_{elem.get('fromLane')}", elem.get("via") or f"{dst}_{elem.get('toLane')}"
    if here in car_lane and there in car_lane and allows_car(elem.get("allow"), elem.get("disallow")):
        out.lane_next.add((here, there))
    if src not in normal or dst not in normal:
        return
    out.links.setdefault((src, dst), elem.get("via", ""))
    ends = (f"{src}_{elem.get('fromLane')}", f"{dst}_{elem.get('toLane')}")
    if all(lane in car_lane for lane in ends) and allows_car(elem.get("allow"), elem.get("disallow")):
        out.car_links.add((src, dst))
        out.lane_links.add(ends)


def lane_widths(path: Path) -> dict[str, float]:
    """Lane id -> width of every lane, junction-internal and non-car lanes included."""
    return {
        lane.get("id", ""): float(lane.get("width", DEFAULT_LANE_WIDTH))
        for elem in net_elements(path)
        if elem.tag == "edge"
        for lane in elem.iter("lane")
    }


def allows_car(allow: str | None, disallow: str | None) -> bool:
    """Whether SUMO's allow/disallow lists (a lane's or a connection's) let a passenger car pass."""
    if allow is not None:
        return bool({CAR_CLASS, "all"} & set(allow.split()))
    return disallow is None or not {CAR_CLASS, "all"} & set(disallow.split())


def lane_spec(lane: ET.Element) -> LaneSpec:
    points = [tuple(map(float, point.split(",")[:2])) for point in lane.get("shape", "").split()]
    shape = cast("list[tuple[float, float]]", points)  # x,y of every point
    width = float(lane.get("width", DEFAULT_LANE_WIDTH))
    return (lane.get("id", ""), shape, width, float(lane.get("speed", 13.89)), float(lane.get("length", 0.0)))
