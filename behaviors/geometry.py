"""Road geometry from a SUMO network, as flat numpy arrays.

Two things are derived once per network and then queried vectorised for all
agents each step:

* the carriageway borders of every normal edge (junction internals ignored) as
  line segments, indexed by a coarse grid so a ray only tests nearby segments;
* per lane, the centre-line shape with cumulative length, tangent angle and
  curvature, so a (lane, lane position) pair gives the road axis direction and
  curvature without asking SUMO (whose lane angles are piecewise constant).

Angles here are mathematical: radians, counter-clockwise from +x.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from behaviors.errors import BehaveError

RAY_RANGE = 200.0
"""Range of the track-edge and opponent sensors, metres (as in TORCS)."""

GRID_CELL = 50.0
"""Edge length of the culling grid's cells, metres."""

HEADING_SECTORS = 8
"""Candidate lists are split by heading as well: sector k holds headings within pi/8 of k pi/4."""

JUNCTION_GAP = 5.0
"""Border ends of consecutive edges closer than this (metres) are joined across the junction."""

_LANE_GAP = 1.0e6
"""Spacing between lanes in the concatenated lane-position axis (keeps lanes apart)."""


@dataclass(frozen=True)
class EdgeInfo:
    """What the controller needs to know about a normal edge's carriageway."""

    lanes: int
    lane_width: float
    speed: float
    length: float  # SUMO's length of the edge's rightmost lane, metres
    normal: bool  # False for junction-internal edges


@dataclass(frozen=True)
class RoadGeometry:
    """Borders (segments + culling grid) and lane axes of a network's normal edges."""

    seg_a: np.ndarray  # [M, 2] segment start points
    seg_b: np.ndarray  # [M, 2] segment end points
    seg_za: np.ndarray  # [M] complex: seg_a as x + iy (car-frame transforms are one multiply)
    seg_zb: np.ndarray  # [M] complex: seg_b as x + iy
    cell_keys: np.ndarray  # [C] sorted (grid cell, heading sector) keys that have candidates
    cell_start: np.ndarray  # [C + 1] key i's candidates are cell_segments[cell_start[i]:cell_start[i + 1]]
    cell_segments: np.ndarray  # [total] segment ids per key, key after key
    lane_index: dict[str, int]  # lane id -> row in the lane tables
    lane_edge: list[str]  # lane row -> edge id
    lane_number: np.ndarray  # [L] index of the lane within its edge (0 = rightmost)
    lane_num_lanes: np.ndarray  # [L] lanes of the lane's edge
    lane_normal: np.ndarray  # [L] bool, False for junction-internal lanes
    lane_width: np.ndarray  # [L] lane width, metres
    lane_speed: np.ndarray  # [L] speed limit, m/s
    lane_length_scale: np.ndarray  # [L] shape length / SUMO lane length
    lane_base: np.ndarray  # [L] offset of each lane on the concatenated axis
    axis_s: np.ndarray  # [P] concatenated vertex positions (lane base + arc length)
    axis_angle: np.ndarray  # [P] unwrapped tangent angle at each vertex
    axis_curvature: np.ndarray  # [P] curvature of the segment starting at vertex
    edges: dict[str, EdgeInfo]

    def road_axis(self, lane_rows: np.ndarray, lane_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tangent angle (interpolated between vertex tangents) and curvature at lane positions."""
        s = self.lane_base[lane_rows] + lane_pos * self.lane_length_scale[lane_rows]
        i = np.clip(np.searchsorted(self.axis_s, s, side="right") - 1, 0, len(self.axis_s) - 2)
        span = self.axis_s[i + 1] - self.axis_s[i]
        t = np.clip((s - self.axis_s[i]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
        angle = self.axis_angle[i] + t * (self.axis_angle[i + 1] - self.axis_angle[i])
        return angle, self.axis_curvature[i]

    def candidates(self, points: np.ndarray, heading: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(point row, segment id) pairs: the border segments a track ray from each pose may hit.

        That is every segment within RAY_RANGE that is not wholly behind the car.
        Flat pairs rather than a padded table: cells on curves list hundreds of
        segments, cells on straights a handful, and padding would cost them all the same.
        """
        keys = cell_key(points) * HEADING_SECTORS + heading_sector(heading)
        row = np.minimum(np.searchsorted(self.cell_keys, keys), len(self.cell_keys) - 1)
        start = self.cell_start[row]
        count = np.where(self.cell_keys[row] == keys, self.cell_start[row + 1] - start, 0)
        return np.repeat(np.arange(len(points)), count), self.cell_segments[ranges(start, count)]


def heading_sector(heading: np.ndarray) -> np.ndarray:
    """Index k of the heading sector [k pi/4 - pi/8, k pi/4 + pi/8) each heading lies in."""
    width = 2 * np.pi / HEADING_SECTORS
    return np.floor(heading / width + 0.5).astype(np.int64) % HEADING_SECTORS


def cell_key(points: np.ndarray) -> np.ndarray:
    """Grid cell of each point packed into one int64 (x and y cell indices, offset to positive)."""
    cells = np.floor(points / GRID_CELL).astype(np.int64) + (1 << 20)
    return cells[:, 0] * (1 << 21) + cells[:, 1]


def load_geometry(net_file: Path | str) -> RoadGeometry:
    """Read a .net.xml with sumolib; BehaveError if it is missing, malformed or has no multi-lane edge."""
    import sumolib  # imported here: sumolib is slow to import and only needed once per net

    path = Path(net_file)
    if not path.is_file():
        raise BehaveError(f"network file not found: {path}")
    try:
        net = sumolib.net.readNet(str(path), withInternal=True)
    except Exception as exc:  # sumolib raises SAX errors, KeyErrors, ... on bad files
        raise BehaveError(f"cannot read network {path}: {type(exc).__name__}: {exc}") from None
    edges = net.getEdges(withInternal=True)
    if not any(e.getFunction() == "" and e.getLaneNumber() >= 2 for e in edges):
        raise BehaveError(f"network {path} has no multi-lane edge; behave needs at least one")
    specs = [
        (
            e.getID(),
            [
                (ln.getID(), ln.getShape(), ln.getWidth(), ln.getSpeed(), ln.getLength())
                for ln in e.getLanes()
            ],
            e.getFunction() == "",
        )
        for e in edges
    ]
    links = [
        (e.getID(), succ.getID())
        for e in edges
        if e.getFunction() == ""
        for succ in e.getOutgoing()
        if succ.getFunction() == ""
    ]
    return build_geometry(specs, links)


LaneSpec = tuple[str, list[tuple[float, float]], float, float, float]
"""(lane id, centre-line shape, width, speed limit, SUMO lane length)."""


def build_geometry(
    edges: list[tuple[str, list[LaneSpec], bool]], links: list[tuple[str, str]] = ()
) -> RoadGeometry:
    """Geometry from plain edge/lane data (lanes ordered right to left, as SUMO numbers them).

    Each edge comes with a flag: True for a normal edge (its carriageway borders
    are sensed), False for a junction-internal one (only its lane axes are kept,
    so a car crossing a junction still knows the road direction). `links` joins
    the borders of consecutive normal edges across short junction gaps.
    """
    seg_a: list[np.ndarray] = []
    seg_b: list[np.ndarray] = []
    lane_index: dict[str, int] = {}
    lane_edge: list[str] = []
    numbers, counts, widths, speeds, scales, bases, normals = [], [], [], [], [], [], []
    axis_s, axis_angle, axis_curv = [], [], []
    infos: dict[str, EdgeInfo] = {}
    base = 0.0
    borders: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for edge_id, lanes, normal in edges:
        if normal:
            right = offset_polyline(np.asarray(lanes[0][1], float), -lanes[0][2] / 2)
            left = offset_polyline(np.asarray(lanes[-1][1], float), lanes[-1][2] / 2)
            borders[edge_id] = (right, left)
            for border in (right, left):
                seg_a.append(border[:-1])
                seg_b.append(border[1:])
        infos[edge_id] = EdgeInfo(
            lanes=len(lanes),
            lane_width=float(np.mean([spec[2] for spec in lanes])),
            speed=float(max(spec[3] for spec in lanes)),
            length=float(lanes[0][4]),
            normal=normal,
        )
        for number, (lane_id, shape, width, speed, length) in enumerate(lanes):
            pts = np.asarray(shape, float)
            s, angle, curvature = polyline_axis(pts)
            lane_index[lane_id] = len(lane_edge)
            lane_edge.append(edge_id)
            numbers.append(number)
            counts.append(len(lanes))
            normals.append(normal)
            widths.append(width)
            speeds.append(speed)
            scales.append(s[-1] / length if length > 0 else 1.0)
            bases.append(base)
            axis_s.append(base + s)
            axis_angle.append(angle)
            axis_curv.append(curvature)
            base += s[-1] + _LANE_GAP
    for src, dst in links:
        for end, start in zip(borders[src], borders[dst], strict=True):
            if np.linalg.norm(start[0] - end[-1]) < JUNCTION_GAP:
                seg_a.append(end[-1:])
                seg_b.append(start[:1])
    a = np.concatenate(seg_a)
    b = np.concatenate(seg_b)
    keep = np.linalg.norm(b - a, axis=1) > 1e-6
    a, b = a[keep], b[keep]
    keys, start, segments = candidate_table(a, b)
    return RoadGeometry(
        seg_a=a,
        seg_b=b,
        seg_za=a[:, 0] + 1j * a[:, 1],
        seg_zb=b[:, 0] + 1j * b[:, 1],
        cell_keys=keys,
        cell_start=start,
        cell_segments=segments,
        lane_index=lane_index,
        lane_edge=lane_edge,
        lane_number=np.asarray(numbers, np.int64),
        lane_num_lanes=np.asarray(counts, np.int64),
        lane_normal=np.asarray(normals, bool),
        lane_width=np.asarray(widths, float),
        lane_speed=np.asarray(speeds, float),
        lane_length_scale=np.asarray(scales, float),
        lane_base=np.asarray(bases, float),
        axis_s=np.concatenate(axis_s),
        axis_angle=np.concatenate(axis_angle),
        axis_curvature=np.concatenate(axis_curv),
        edges=infos,
    )


def polyline_axis(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cumulative length, vertex tangent angle (mean of adjacent segments) and segment curvature."""
    d = np.diff(points, axis=0)
    length = np.hypot(d[:, 0], d[:, 1])
    seg_angle = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    s = np.concatenate([[0.0], np.cumsum(length)])
    vertex = np.concatenate([[seg_angle[0]], (seg_angle[:-1] + seg_angle[1:]) / 2, [seg_angle[-1]]])
    curvature = np.append(np.diff(vertex) / np.maximum(length, 1e-9), 0.0)
    return s, vertex, curvature


def offset_polyline(points: np.ndarray, offset: float) -> np.ndarray:
    """The polyline shifted sideways by `offset` (positive = left), mitred at the vertices."""
    d = np.diff(points, axis=0)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    normals = np.concatenate([n[:1], n[:-1] + n[1:], n[-1:]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    # mitre: scale so each segment keeps exactly `offset` from its centre line
    cos_half = np.concatenate([[1.0], np.einsum("ij,ij->i", normals[1:-1], n[:-1]), [1.0]])
    return points + normals * (offset / np.maximum(cos_half, 0.2))[:, None]


def candidate_table(seg_a: np.ndarray, seg_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every grid cell near a border and every heading sector, the segments a track ray may hit.

    A segment qualifies for a cell when its distance to the cell's centre is at most
    RAY_RANGE plus the cell's half diagonal, and for a heading sector when one of its
    end points can lie ahead of a car somewhere in the cell with a heading in the
    sector (track rays span only the front half-plane; a segment with both ends
    behind the car is wholly behind it). Both tests are conservative, so every
    segment a ray can touch is listed. Returns the sorted keys (see `candidates`) and
    the lists in CSR form (offsets [C + 1], flat segment ids).
    """
    half_diagonal = GRID_CELL * np.sqrt(0.5)
    reach = RAY_RANGE + half_diagonal
    centres = cells_near(seg_a, seg_b, reach)
    sector_width = 2 * np.pi / HEADING_SECTORS
    keys, segments = [], []
    chunk_size = max(1, min(256, 2_000_000 // len(seg_a)))  # bounds the [cells, segments] memory
    for first in range(0, len(centres), chunk_size):
        chunk = centres[first : first + chunk_size]
        near = point_segment_distance(chunk[:, None, :], seg_a[None], seg_b[None]) <= reach
        cell, seg = np.nonzero(near)
        ends = [end[seg] - chunk[cell] for end in (seg_a, seg_b)]
        for k in range(HEADING_SECTORS):
            ahead = np.zeros(len(seg), bool)
            for v in ends:
                off = np.abs(wrap_angle(np.arctan2(v[:, 1], v[:, 0]) - k * sector_width))
                # the most ahead this end can be for headings in the sector, measured from the centre
                best = np.hypot(v[:, 0], v[:, 1]) * np.cos(np.maximum(off - sector_width / 2, 0.0))
                ahead |= best > -half_diagonal - 1e-6
            keys.append(cell_key(chunk[cell[ahead]]) * HEADING_SECTORS + k)
            segments.append(seg[ahead])
    key, segment = np.concatenate(keys), np.concatenate(segments)
    order = np.lexsort((segment, key))
    key, segment = key[order], segment[order]
    unique, start = np.unique(key, return_index=True)
    return unique, np.append(start, len(key)).astype(np.int64), segment.astype(np.int64)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles mapped to [-pi, pi)."""
    return (a + np.pi) % (2 * np.pi) - np.pi


def cells_near(seg_a: np.ndarray, seg_b: np.ndarray, reach: float) -> np.ndarray:
    """Centres of the grid cells within `reach` of some segment (sampled every cell length)."""
    length = np.linalg.norm(seg_b - seg_a, axis=1)
    steps = np.ceil(length / GRID_CELL).astype(int) + 1
    seg = np.repeat(np.arange(len(seg_a)), steps)
    t = (np.arange(steps.sum()) - np.repeat(np.cumsum(steps) - steps, steps)) / np.repeat(steps - 1, steps)
    samples = seg_a[seg] + t[:, None] * (seg_b - seg_a)[seg]
    r = int(np.ceil(reach / GRID_CELL)) + 1
    offsets = np.stack(np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij"), -1)
    offsets = offsets.reshape(-1, 2)
    base = np.unique(np.floor(samples / GRID_CELL).astype(np.int64), axis=0)
    cells = np.unique((base[:, None, :] + offsets[None]).reshape(-1, 2), axis=0)
    return (cells + 0.5) * GRID_CELL


def ranges(start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Concatenation of arange(start[i], start[i] + count[i]) over i, vectorised."""
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(count)
    return np.arange(total) + np.repeat(start - (ends - count), count)


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance from points to segments (broadcasting over leading axes)."""
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.linalg.norm(p - closest, axis=-1)
