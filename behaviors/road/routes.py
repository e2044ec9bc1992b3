"""Where learned cars drive on any net, and how they are put down there: routes of multi-lane
edges and the check that a car SUMO placed is not too close to another.

Shared by `behave populate` and the environments on a user's road (traffic_env.py), so that
agents train where and as populate puts them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from behaviors.road.geometry import RoadGeometry
from behaviors.road.neighbours import crowded
from behaviors.sumo.sim import SumoSim, VehicleState

LANE_END_MARGIN = 20.0
"""m: a lane that ends this much short of its edge's farthest-leading lane is a lane that ends."""


def lane_leads_on(lane_ends: np.ndarray, best_end: np.ndarray, lane_pos: np.ndarray) -> np.ndarray:
    """Metres each of the own/fast/slow lanes leads on; a lane that goes as far as the edge's best
    lane (the route itself ends there, or the road goes on) counts as leading on for ever: the end
    of a route is not a lane that ends."""
    ending = lane_ends < best_end[:, None] - LANE_END_MARGIN
    return np.where(ending, lane_ends - lane_pos[:, None], np.inf)


INSERT_CLEARANCE = 6.0
"""m between a newly inserted car's front and any other's, or it is withdrawn and put elsewhere."""
INSERT_DECEL = 4.0
"""m/s^2: nor may a car be put down so close to another that, braking this hard, it would not match
speeds before the clearance is used up (SUMO's check misses a learned car crossing into the lane)."""
INSERT_LANE_RUN = 400.0
INSERT_LANE_RUN_S = 16.0
"""Nor any car in a lane that stops leading on along its route within max(this m, this s at its
speed) while another lane of its edge goes on: a car put down near a lane drop's end can stand there
and block the lane for good, since the policies merge out while moving, not from rest
(docs/flow.md, docs/history.md)."""


@dataclass(frozen=True)
class RouteGraph:
    """Normal edges with at least two car lanes, and which of them a car can drive on to."""

    edges: list[str]
    length: np.ndarray  # [E] metres
    lanes: np.ndarray  # [E] lanes a passenger car may use (not sidewalks, bus or bike lanes)
    successors: list[list[int]]
    start_cdf: np.ndarray  # [E] cumulative lane-metres: a route starts on an edge in proportion to them


def route_graph(geometry: RoadGeometry) -> RouteGraph:
    """The multi-lane car edges and the car connections between them (SUMO refuses a route whose
    consecutive edges are linked only by, say, a bus lane's connections: "No connection")."""
    edges = [e for e, info in geometry.edges.items() if info.normal and info.lanes >= 2]
    index = {e: k for k, e in enumerate(edges)}
    ahead = geometry.car_successors
    successors = [sorted(index[to] for to in ahead.get(e, ()) if to in index) for e in edges]
    length = np.array([geometry.edges[e].length for e in edges])
    lanes = np.array([geometry.edges[e].lanes for e in edges])
    return RouteGraph(
        edges=edges, length=length, lanes=lanes, successors=successors, start_cdf=np.cumsum(length * lanes)
    )


def random_start(graph: RouteGraph, rng: np.random.Generator) -> int:
    """An edge drawn in proportion to its car lane-metres."""
    return int(np.searchsorted(graph.start_cdf, rng.random() * graph.start_cdf[-1], side="right"))


def random_walk(
    graph: RouteGraph, start: int, rng: np.random.Generator, min_length: float
) -> tuple[str, ...]:
    """A walk along multi-lane edges from `start` until long enough or a dead end."""
    k = start
    route, length = [k], graph.length[k]
    while length < min_length and graph.successors[k]:
        k = graph.successors[k][int(rng.integers(len(graph.successors[k])))]
        route.append(k)
        length += graph.length[k]
    return tuple(graph.edges[i] for i in route)


ROUTE_VARIANTS = 8
"""Routes drawn per start edge, then reused. SUMO keeps every route it is given until the run
ends, so one new route per insertion (and per retry) would grow populate with simulated time
(docs/history.md)."""


class RoutePool:
    """Route ids for new vehicles: at most ROUTE_VARIANTS walks per start edge, each edge list
    handed to SUMO once, so the routes SUMO holds are bounded by the net, not by the run."""

    def __init__(
        self, graph: RouteGraph, min_length: float, add: Callable[[str, tuple[str, ...]], None]
    ) -> None:
        self.graph = graph
        self.min_length = min_length
        self.add = add  # hands a new route to SUMO
        self.by_start: dict[int, list[str]] = {}
        self.by_edges: dict[tuple[str, ...], str] = {}

    def draw(self, rng: np.random.Generator) -> str:
        """A route id; a start edge's first walks are kept (repeats included, so reuse keeps their odds)."""
        start = random_start(self.graph, rng)
        kept = self.by_start.setdefault(start, [])
        if len(kept) >= ROUTE_VARIANTS:
            return kept[int(rng.integers(len(kept)))]
        edges = random_walk(self.graph, start, rng, self.min_length)
        if edges not in self.by_edges:
            self.by_edges[edges] = f"behave_route_{len(self.by_edges)}"
            self.add(self.by_edges[edges], edges)
        kept.append(self.by_edges[edges])
        return kept[-1]


def lane_km(graph: RouteGraph) -> float:
    """Kilometres of car lanes on the multi-lane edges: what a traffic density is counted over."""
    return float((graph.length * graph.lanes).sum()) / 1000.0


def too_close(vehicles: VehicleState, rows: np.ndarray) -> np.ndarray:
    """Which of the cars SUMO just placed (`rows` of `vehicles`) must be withdrawn and put elsewhere:
    within INSERT_CLEARANCE of another, or too close to match its speed braking at INSERT_DECEL."""
    return crowded(vehicles.position, vehicles.speed, rows, INSERT_CLEARANCE, INSERT_DECEL)


def lane_runs_out(
    lane_end: np.ndarray, best_end: np.ndarray, lane_pos: np.ndarray, speed: np.ndarray
) -> np.ndarray:
    """[N] bool: newly placed cars whose lane (ending at `lane_end` in lane coordinates; the
    edge's farthest-leading lane at `best_end`) stops leading on within INSERT_LANE_RUN, as the
    hand-over tells a lane that ends from the end of a route (lane_leads_on)."""
    leads = lane_leads_on(lane_end[:, None], best_end, lane_pos)[:, 0]
    return leads < np.maximum(INSERT_LANE_RUN, INSERT_LANE_RUN_S * speed)


def misplaced(
    sim: SumoSim,
    vehicles: VehicleState,
    geometry: RoadGeometry,
    ids: list[str],
    keeper: np.ndarray | None = None,
) -> np.ndarray:
    """[N] bool: which of the cars SUMO just placed (`ids`) are withdrawn and put elsewhere: too
    close to another car, in a lane that runs out, or a lane keeper (`keeper` [N], None: none) in the
    fast-most of several car lanes (lanes counted as in `geometry`): a keeper keeps its lane, and
    traffic comes onto a road from its slow side, not into the lane the law leaves for passing."""
    rows = np.array([vehicles.row[v] for v in ids], np.int64)
    out = too_close(vehicles, rows)
    if not ids:
        return out
    ahead = [sim.lane_lengths_ahead(v) for v in ids]
    lanes = sim.read_lanes(ids)
    lane_end = np.array([a.get(lane, 0.0) for a, lane in zip(ahead, lanes, strict=True)])
    best_end = np.array([max(a.values(), default=0.0) for a in ahead])
    lane_pos, _ = sim.read_lane_places(ids)
    out |= lane_runs_out(lane_end, best_end, lane_pos, vehicles.speed[rows])
    if keeper is not None and keeper.any():
        lane_rows = np.array([geometry.lane_index.get(lane, -1) for lane in lanes], np.int64)
        count = np.where(lane_rows >= 0, geometry.lane_num_lanes[lane_rows], 0)
        fast_most = (count > 1) & (geometry.lane_number[lane_rows] == count - 1)
        out |= keeper & fast_most
    return out
