"""A RoadGeometry from a SUMO network: the borders and lane axes built from the net's tables
(`build_geometry`), and kept beside a big net in a cache file (`load_geometry`)."""

from __future__ import annotations

import contextlib
import io
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import astuple
from pathlib import Path

import numpy as np

from behaviors.errors import BehaveError
from behaviors.files import atomic_write_bytes
from behaviors.road.geometry import EdgeInfo, RoadGeometry
from sumo_scenarios.net import LaneSpec, read_net

JUNCTION_GAP = 5.0
"""Border ends of consecutive edges closer than this (metres) are joined across the junction."""

_LANE_GAP = 1.0e6
"""Spacing between lanes in the concatenated lane-position axis (keeps lanes apart)."""


CACHE_VERSION = 3
"""Bumped whenever what the geometry cache holds changes: older caches are rebuilt."""

CACHE_MIN_BYTES = 2_000_000
"""Nets smaller than this are read in well under a second: no cache file is left beside them."""


def load_geometry(
    net_file: Path | str, cache: bool = False, on_status: Callable[[str], None] | None = None
) -> RoadGeometry:
    """The geometry of a .net.xml (or .net.xml.gz); BehaveError if it is missing, malformed or has no
    multi-lane car edge.

    With `cache`, a net of CACHE_MIN_BYTES or more keeps its geometry beside it
    (`<net>.behave-geometry.npz`, valid while the net's size and mtime and CACHE_VERSION hold),
    written atomically; a folder that cannot be written just gets no cache.
    """
    path = Path(net_file)
    if not path.is_file():
        raise BehaveError(f"network file not found: {path}")
    say = on_status or (lambda _: None)
    stat = path.stat()
    key = np.array([CACHE_VERSION, stat.st_size, stat.st_mtime_ns], np.int64)
    cached = cache_path(path)
    if cache and stat.st_size >= CACHE_MIN_BYTES:
        geometry = read_cache(cached, key)
        if geometry is not None:
            say(f"road geometry read from {cached.name}")
            return geometry
    say(f"reading network {path.name} ({stat.st_size / 1e6:.1f} MB)")
    try:
        tables = read_net(path)
    except (ET.ParseError, OSError, ValueError, EOFError) as exc:
        raise BehaveError(f"cannot read network {path}: {type(exc).__name__}: {exc}") from None
    if not any(is_normal and len(lanes) >= 2 for _, lanes, is_normal in tables.edges):
        raise BehaveError(f"network {path} has no multi-lane edge; behave needs at least one")
    say(f"building road geometry of {len(tables.edges):,} edges")
    links, car_links, lane_next = sorted(tables.links), sorted(tables.car_links), sorted(tables.lane_next)
    geometry = build_geometry(tables.edges, links, tables.lefthand, car_links, lane_next)
    if cache and stat.st_size >= CACHE_MIN_BYTES:
        with contextlib.suppress(BehaveError):
            write_cache(cached, key, geometry)
            say(f"road geometry cached in {cached.name}")
    return geometry


def cache_path(net: Path) -> Path:
    return net.with_name(f"{net.name}.behave-geometry.npz")


LANE_TABLES = (
    *("lane_number", "lane_num_lanes", "lane_normal", "lane_width", "lane_speed", "lane_length_scale"),
    *("lane_base", "axis_s", "axis_angle", "axis_curvature", "axis_xy", "lane_next", "seg_a", "seg_b"),
)


def write_cache(path: Path, key: np.ndarray, g: RoadGeometry) -> None:
    """The geometry as plain arrays (no pickles), complete or absent."""
    edge_ids = list(g.edges)
    edge_row = {e: k for k, e in enumerate(edge_ids)}
    info = np.array([astuple(g.edges[e]) for e in edge_ids], float).reshape(-1, 5)
    pairs = np.array(
        [(edge_row[a], edge_row[b]) for a, succ in g.car_successors.items() for b in succ], np.int64
    )
    out = io.BytesIO()
    np.savez(
        out, key=key, lefthand=np.array(g.lefthand), lane_ids=np.array(list(g.lane_index), str),
        lane_edge=np.array([edge_row[e] for e in g.lane_edge], np.int64), edge_ids=np.array(edge_ids, str),
        edge_info=info, successors=pairs.reshape(-1, 2), **{name: getattr(g, name) for name in LANE_TABLES},
    )  # fmt: skip
    atomic_write_bytes(path, out.getvalue())


def read_cache(path: Path, key: np.ndarray) -> RoadGeometry | None:
    """The cached geometry if the cache is there, readable and made from this very net file."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if not np.array_equal(data["key"], key):
                return None
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):
        return None
    edge_ids = arrays["edge_ids"].tolist()
    edges = {
        e: EdgeInfo(int(row[0]), float(row[1]), float(row[2]), float(row[3]), bool(row[4]))
        for e, row in zip(edge_ids, arrays["edge_info"].tolist(), strict=True)
    }
    successors: dict[str, list[str]] = {}
    for a, b in arrays["successors"].tolist():
        successors.setdefault(edge_ids[a], []).append(edge_ids[b])
    lane_ids = arrays["lane_ids"].tolist()
    return RoadGeometry(
        lane_index={lane: k for k, lane in enumerate(lane_ids)},
        lane_edge=[edge_ids[k] for k in arrays["lane_edge"].tolist()],
        edges=edges,
        car_successors={e: tuple(succ) for e, succ in successors.items()},
        lefthand=bool(arrays["lefthand"]),
        **{name: arrays[name] for name in LANE_TABLES},
    )


def build_geometry(
    edges: list[tuple[str, list[LaneSpec], bool]],
    links: Sequence[tuple[str, str]] = (),
    lefthand: bool = False,
    car_links: Sequence[tuple[str, str]] = (),
    lane_next: Sequence[tuple[str, str]] = (),
) -> RoadGeometry:
    """Geometry from plain edge/lane data (car lanes ordered as SUMO numbers them, lane 0 outermost).

    Each edge comes with a flag: True for a normal edge, False for a junction-internal one
    (only its lane axes are kept, so a car crossing a junction still knows the road
    direction). Borders are sensed only along normal edges with two or more car lanes, the
    roads agents drive themselves; `links` joins the borders of consecutive such edges across
    short junction gaps. In left-hand nets lane 0 is the leftmost lane, so the outer border is
    on its left.
    """
    borders = edge_borders(edges, lefthand)
    seg_a: list[np.ndarray] = [np.zeros((0, 2))]
    seg_b: list[np.ndarray] = [np.zeros((0, 2))]
    for pair in borders.values():
        for border in pair:
            seg_a.append(border[:-1])
            seg_b.append(border[1:])
    for src, dst in links:
        if src in borders and dst in borders:
            for end, start in zip(borders[src], borders[dst], strict=True):
                if np.linalg.norm(start[0] - end[-1]) < JUNCTION_GAP:
                    seg_a.append(end[-1:])
                    seg_b.append(start[:1])
    a = np.concatenate(seg_a)
    b = np.concatenate(seg_b)
    keep = np.linalg.norm(b - a, axis=1) > 1e-6
    specs = [spec for _, lanes, _ in edges for spec in lanes]
    axes = lane_axes([spec[1] for spec in specs], np.array([spec[4] for spec in specs], float))
    successors: dict[str, list[str]] = {}
    for src, dst in car_links:
        successors.setdefault(src, []).append(dst)
    lane_index = {spec[0]: k for k, spec in enumerate(specs)}
    return RoadGeometry(
        seg_a=a[keep],
        seg_b=b[keep],
        lane_index=lane_index,
        lane_next=next_lanes(lane_index, lane_next),
        lane_edge=[edge_id for edge_id, lanes, _ in edges for _ in lanes],
        lane_number=np.concatenate([np.arange(len(lanes)) for _, lanes, _ in edges]).astype(np.int64),
        lane_num_lanes=np.repeat(
            [len(lanes) for _, lanes, _ in edges], [len(lanes) for _, lanes, _ in edges]
        ).astype(np.int64),
        lane_normal=np.repeat(
            [normal for _, _, normal in edges], [len(lanes) for _, lanes, _ in edges]
        ).astype(bool),
        lane_width=np.array([spec[2] for spec in specs], float),
        lane_speed=np.array([spec[3] for spec in specs], float),
        edges={edge_id: edge_info(lanes, normal) for edge_id, lanes, normal in edges},
        car_successors={e: tuple(succ) for e, succ in successors.items()},
        lefthand=lefthand,
        **axes,
    )


def next_lanes(lane_index: dict[str, int], lane_next: Sequence[tuple[str, str]]) -> np.ndarray:
    """[L] the row of each lane's one successor among `lane_next` (lane id pairs, `NetTables.lane_next`),
    -1 where it has none or several (where lanes part, which one a car takes is its route's)."""
    out = np.full(len(lane_index), -1, np.int64)
    count = np.zeros(len(lane_index), np.int64)
    for src, dst in lane_next:
        if src in lane_index and dst in lane_index:
            out[lane_index[src]] = lane_index[dst]
            count[lane_index[src]] += 1
    out[count > 1] = -1
    return out


def edge_info(lanes: list[LaneSpec], normal: bool) -> EdgeInfo:
    return EdgeInfo(
        lanes=len(lanes),
        lane_width=float(np.mean([spec[2] for spec in lanes])),
        speed=float(max(spec[3] for spec in lanes)),
        length=float(lanes[0][4]),
        normal=normal,
    )


def edge_borders(
    edges: list[tuple[str, list[LaneSpec], bool]], lefthand: bool
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Outer (lane 0 side) and inner border of each normal edge with two or more car lanes."""
    outward = 1.0 if lefthand else -1.0  # lane 0 lies on the right of keep-right carriageways
    return {
        edge_id: (
            offset_polyline(np.asarray(lanes[0][1], float), outward * lanes[0][2] / 2),
            offset_polyline(np.asarray(lanes[-1][1], float), -outward * lanes[-1][2] / 2),
        )
        for edge_id, lanes, normal in edges
        if normal and len(lanes) >= 2
    }


def lane_axes(shapes: list[list[tuple[float, float]]], lengths: np.ndarray) -> dict[str, np.ndarray]:
    """Every lane's axis on one concatenated position axis, vectorised over all lanes at once
    (a Python loop per lane would take most of the set-up of a region net).

    Per vertex: position (lane base + arc length), tangent (mean of the adjacent segments'
    unwrapped angles) and the curvature of the segment starting there (0 at a lane's end).
    """
    counts = np.array([len(shape) for shape in shapes], np.int64)
    points = np.array([point for shape in shapes for point in shape], float).reshape(-1, 2)
    lane = np.repeat(np.arange(len(shapes)), counts)
    first = np.cumsum(counts) - counts
    last = first + counts - 1
    inner = np.ones(len(points), bool)
    inner[last] = False  # a segment starts at every vertex but the lane's last
    d = np.diff(points, axis=0, append=points[-1:])
    length = np.where(inner, np.hypot(d[:, 0], d[:, 1]), 0.0)
    raw = np.arctan2(d[:, 1], d[:, 0])
    step = np.diff(raw, prepend=raw[:1])
    wrapped = (step + np.pi) % (2 * np.pi) - np.pi
    wrapped[(wrapped == -np.pi) & (step > 0)] = np.pi  # as np.unwrap does
    wrapped[first] = 0.0
    turned = np.cumsum(wrapped)
    seg_angle = raw[first][lane] + turned - turned[first][lane]  # valid where `inner`
    starts = np.zeros(len(points), bool)
    starts[first] = True
    index = np.arange(len(points))
    before = np.where(starts, index, index - 1)
    vertex = np.where(inner, seg_angle, seg_angle[before])
    middle = inner & ~starts
    vertex = np.where(middle, (seg_angle[before] + seg_angle) / 2, vertex)
    vertex[first] = seg_angle[first]
    run = np.cumsum(length) - length  # arc length before each vertex, over all lanes
    arc = run - run[first][lane]
    total = arc[last]
    base = np.cumsum(total + _LANE_GAP) - (total + _LANE_GAP)
    after = np.append(vertex[1:], 0.0)
    curvature = np.where(inner, (after - vertex) / np.maximum(length, 1e-9), 0.0)
    return {
        "lane_length_scale": np.where(lengths > 0, total / np.where(lengths > 0, lengths, 1.0), 1.0),
        "lane_base": base,
        "axis_s": base[lane] + arc,
        "axis_angle": vertex,
        "axis_curvature": curvature,
        "axis_xy": points,
    }


def offset_polyline(points: np.ndarray, offset: float) -> np.ndarray:
    """The polyline shifted sideways by `offset` (positive = left), mitred at the vertices."""
    d = np.diff(points, axis=0)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    normals = np.concatenate([n[:1], n[:-1] + n[1:], n[-1:]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    # mitre: scale so each segment keeps exactly `offset` from its centre line
    cos_half = np.concatenate([[1.0], np.einsum("ij,ij->i", normals[1:-1], n[:-1]), [1.0]])
    return points + normals * (offset / np.maximum(cos_half, 0.2))[:, None]
