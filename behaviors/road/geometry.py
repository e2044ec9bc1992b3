"""Road geometry from a SUMO network, as flat numpy arrays.

Two things are derived once per network and then queried vectorised for all
agents each step:

* the carriageway borders of every normal edge with two or more car lanes (junction
  internals ignored) as line segments, indexed by a coarse grid (built on first use) so a
  ray only tests nearby segments;
* per car lane (normal and junction-internal), the centre-line shape with cumulative length, tangent angle and
  curvature, so a (lane, lane position) pair gives the road axis direction and
  curvature without asking SUMO (whose lane angles are piecewise constant).

Angles here are mathematical: radians, counter-clockwise from +x.

Built from a net by geometry_build.py.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from sumo_scenarios.net import CAR_CLASS as CAR_CLASS  # behave's vehicle class, for geometry's users

RAY_RANGE = 200.0
"""Range of the track-edge and opponent sensors, metres (as in TORCS)."""

GRID_CELL = 50.0
"""Edge length of the culling grid's cells, metres."""

HEADING_SECTORS = 8
"""Candidate lists are split by heading as well: sector k holds headings within pi/8 of k pi/4."""


NEXT_LANES_SEEN = 3
"""Lanes sensing follows beyond a car's own lane's end (`RoadGeometry.lane_next`): an edge's end, a
junction's lane and the next edge cover the sensors' range but on the shortest edges."""
NEXT_LANES_REACH = 160.0
"""m beyond a lane's end within which its continuation is compared with the line its end points along
(the lane sensors' reach)."""
NEXT_LANE_TOLERANCE = 0.2
"""m: a continuation that leaves that line by more is followed lane by lane (`lane_next_departs`)."""


@dataclass(frozen=True)
class EdgeInfo:
    """What the controller needs to know about a normal edge's carriageway (its car lanes)."""

    lanes: int  # lanes a passenger car may use
    lane_width: float
    speed: float
    length: float  # SUMO's length of the edge's rightmost car lane, metres
    normal: bool  # False for junction-internal edges


class LanePose(NamedTuple):
    """Points on lane centre lines (see `RoadGeometry.lane_pose`); lengths in metres along the shape."""

    point: np.ndarray  # [K, 2]
    angle: np.ndarray  # [K] direction of the segment there
    curvature: np.ndarray  # [K] turn per metre into that segment (from the one before, else the
    # one after): what the lane does beyond its ends
    pos: np.ndarray  # [K] the position, clamped to the lane
    length: np.ndarray  # [K] the lane shape's length
    segment_start: np.ndarray  # [K] where the segment holding the point begins
    segment_end: np.ndarray  # [K] and ends


@dataclass(frozen=True)
class RoadGeometry:
    """Borders (segments + culling grid) of the multi-lane car edges, and lane axes of every car lane.

    Lane rows number car lanes only: `lane_number` counts from the rightmost car lane (a
    sidewalk or bus lane beside it is no lane of the carriageway), `lane_num_lanes` is the
    edge's number of car lanes.
    """

    seg_a: np.ndarray  # [M, 2] segment start points
    seg_b: np.ndarray  # [M, 2] segment end points
    lane_index: dict[str, int]  # lane id -> row in the lane tables
    lane_edge: list[str]  # lane row -> edge id
    lane_number: np.ndarray  # [L] index of the lane among its edge's car lanes (0 = rightmost)
    lane_num_lanes: np.ndarray  # [L] car lanes of the lane's edge
    lane_normal: np.ndarray  # [L] bool, False for junction-internal lanes
    lane_width: np.ndarray  # [L] lane width, metres
    lane_speed: np.ndarray  # [L] speed limit, m/s
    lane_length_scale: np.ndarray  # [L] shape length / SUMO lane length
    lane_base: np.ndarray  # [L] offset of each lane on the concatenated axis
    axis_s: np.ndarray  # [P] concatenated vertex positions (lane base + arc length)
    axis_angle: np.ndarray  # [P] unwrapped tangent angle at each vertex
    axis_curvature: np.ndarray  # [P] curvature of the segment starting at vertex
    axis_xy: np.ndarray  # [P, 2] the vertices themselves
    lane_next: np.ndarray  # [L] row of the one car lane a car drives on to from each lane's end (a
    # junction's lane, or the lane after it), -1 where none or several
    edges: dict[str, EdgeInfo]
    car_successors: dict[str, tuple[str, ...]] = field(default_factory=dict)
    """Normal edge -> the normal edges a passenger car may drive on to (car lanes, car connections)."""
    lefthand: bool = False

    @functools.cached_property
    def lane_on_entry(self) -> np.ndarray:
        """[L] bool: lanes of the normal edges no car connection leads onto, where SUMO puts a
        scenario's cars down."""
        entered = {to for ahead in self.car_successors.values() for to in ahead}
        entry = {e for e, info in self.edges.items() if info.normal and e not in entered}
        return np.array([edge in entry for edge in self.lane_edge], bool)

    @functools.cached_property
    def seg_za(self) -> np.ndarray:
        """seg_a as x + iy (car-frame transforms are one multiply)."""
        return self.seg_a[:, 0] + 1j * self.seg_a[:, 1]

    @functools.cached_property
    def seg_zb(self) -> np.ndarray:
        return self.seg_b[:, 0] + 1j * self.seg_b[:, 1]

    @functools.cached_property
    def _table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ray culling table, built on first use: only the paper driver's track rays need it."""
        return candidate_table(self.seg_a, self.seg_b)

    cell_keys = property(lambda self: self._table[0])  # sorted (grid cell, heading sector) keys
    cell_start = property(lambda self: self._table[1])  # [C + 1] offsets into cell_segments
    cell_segments = property(lambda self: self._table[2])  # segment ids per key, key after key

    def road_axis(self, lane_rows: np.ndarray, lane_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tangent angle (interpolated between vertex tangents) and curvature at lane positions."""
        s = self.lane_base[lane_rows] + lane_pos * self.lane_length_scale[lane_rows]
        i = np.clip(np.searchsorted(self.axis_s, s, side="right") - 1, 0, len(self.axis_s) - 2)
        span = self.axis_s[i + 1] - self.axis_s[i]
        t = np.clip((s - self.axis_s[i]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
        angle = self.axis_angle[i] + t * (self.axis_angle[i + 1] - self.axis_angle[i])
        return angle, self.axis_curvature[i]

    @functools.cached_property
    def _lane_vertices(self) -> tuple[np.ndarray, np.ndarray]:
        """First and last vertex of each lane on the concatenated axis."""
        first = np.searchsorted(self.axis_s, self.lane_base, side="left")
        return first, np.append(first[1:], len(self.axis_s)) - 1

    @functools.cached_property
    def lane_shape_length(self) -> np.ndarray:
        """[L] length of each lane's shape (SUMO's lane length times `lane_length_scale`)."""
        first, last = self._lane_vertices
        return self.axis_s[last] - self.axis_s[first]

    @functools.cached_property
    def lane_names(self) -> list[str]:
        """[L] SUMO's id of each lane row (`lane_index` inverted)."""
        names = [""] * len(self.lane_index)
        for lane, row in self.lane_index.items():
            names[row] = lane
        return names

    @functools.cached_property
    def lane_name_array(self) -> np.ndarray:
        """`lane_names` as an object array: a fleet's lane names are one gather, not a Python loop."""
        return np.array(self.lane_names, object)

    @functools.cached_property
    def lane_segments(self) -> np.ndarray:
        """[L] straight segments of each lane's shape (1 for a straight lane)."""
        first, last = self._lane_vertices
        return np.maximum(last - first, 1)

    def lane_pose(
        self, lane_rows: np.ndarray, shape_pos: np.ndarray, with_curvature: bool = True
    ) -> LanePose:
        """Where a lane's own centre line is at `shape_pos` metres along its shape, clamped to the lane.

        SUMO places cars on the lane polyline itself, whose direction jumps at each vertex;
        `road_axis` smooths those jumps (a heading for the paper's driver), which on a coarse
        polyline is several degrees off the segment a car is on. `with_curvature=False` leaves the
        curvature out (NaN), a third of the work, for callers that only need the point and angle.
        """
        first, last = self._lane_vertices
        lo, hi = first[lane_rows], last[lane_rows]
        length = self.lane_shape_length[lane_rows]
        pos = np.clip(shape_pos, 0.0, length)
        s = self.axis_s[lo] + pos
        i = lo  # a lane of one segment (most of a motorway's) is posed from its segment's constants
        a, d, span, angle = (value[lane_rows] for value in self._first_segments)
        bent = np.flatnonzero(self.lane_segments[lane_rows] > 1)
        if len(bent):
            i = lo.copy()
            i[bent] = np.clip(np.searchsorted(self.axis_s, s[bent], side="right") - 1, lo[bent], hi[bent] - 1)
            a[bent], d[bent], span[bent], angle[bent] = self._segments(i[bent], hi[bent])
        t = np.clip((s - self.axis_s[i]) / np.maximum(span, 1e-9), 0.0, 1.0)
        curvature = (
            self._segment_curvature(lo, hi, i, angle, span) if with_curvature else np.full(len(i), np.nan)
        )
        start = self.axis_s[i] - self.axis_s[lo]
        return LanePose(a + t[:, None] * d, angle, curvature, pos, length, start, start + span)

    def lane_next_departs(self, rows: np.ndarray) -> np.ndarray:
        """[K] bool for lane `rows`: within NEXT_LANES_REACH of the lane's end, the lanes it leads into
        (`lane_next`, up to NEXT_LANES_SEEN of them) leave the line its end points along, bending
        with its end's curvature, by more than NEXT_LANE_TOLERANCE: a lane shifted sideways through a
        junction. Sensing follows the lanes only there; elsewhere (most edges' ends) that line places
        the cars ahead as well, and following the lanes everywhere costs a step's sensing more
        (docs/benchmarks.md). Worked out for a lane the first time it is asked for: a region's net has
        tens of thousands of junction lanes, too many to work out at set-up."""
        return self._departing(rows, ahead=True)

    @functools.cached_property
    def lane_prev(self) -> np.ndarray:
        """[L] row of the one lane whose `lane_next` each lane is (the lane a car came on from), -1
        where there is none or several (where lanes merge, which one a car came from is its own)."""
        out = np.full(len(self.lane_next), -1, np.int64)
        source = np.flatnonzero(self.lane_next >= 0)
        target = self.lane_next[source]
        out[target] = source
        out[np.bincount(target, minlength=len(out)) > 1] = -1
        return out

    def lane_prev_departs(self, rows: np.ndarray) -> np.ndarray:
        """[K] bool for lane `rows`: the same behind the lane's start, along the lanes a car came on
        from (`lane_prev`): the lanes behind shift sideways through the junction."""
        return self._departing(rows, ahead=False)

    @functools.cached_property
    def _departs_known(self) -> dict[bool, np.ndarray]:
        """[L] per direction (True: ahead, False: behind) `_departs` as far as worked out: 1 yes, 0 no
        (also where no lane goes on that way), -1 not yet."""
        return {ahead: np.where(chain >= 0, -1, 0).astype(np.int8)
                for ahead, chain in ((True, self.lane_next), (False, self.lane_prev))}  # fmt: skip

    def _departing(self, rows: np.ndarray, ahead: bool) -> np.ndarray:
        known = self._departs_known[ahead]
        flags = known[rows]
        unknown = flags < 0
        if unknown.any():  # lanes not asked for before: in a few steps of a run; then one gather
            for row in np.unique(rows[unknown]).tolist():
                known[row] = self._departs(row, ahead)
            flags = known[rows]
        return flags == 1

    def _departs(self, row: int, ahead: bool) -> bool:
        """Whether the lanes after one lane's end (`ahead`) or before its start leave the line that
        end points along by more than NEXT_LANE_TOLERANCE within NEXT_LANES_REACH."""
        chain, sign = (self.lane_next, 1.0) if ahead else (self.lane_prev, -1.0)
        origin = self.lane_pose(np.array([row]), self.lane_shape_length[[row]] if ahead else np.zeros(1))
        points, reached, lane = [], 0.0, row
        for _ in range(NEXT_LANES_SEEN):
            lane = int(chain[lane])
            if lane < 0 or reached >= NEXT_LANES_REACH:
                break
            length = float(self.lane_shape_length[lane])
            # every 5 m from the end nearest the origin, and the far end
            from_near = np.append(np.arange(0.0, min(length, NEXT_LANES_REACH - reached), 5.0), length)
            at = from_near if ahead else length - from_near
            points.append(self.lane_pose(np.full(len(at), lane), at, with_curvature=False).point)
            reached += length
        offset = np.concatenate(points) - origin.point[0]
        heading, curvature = np.full(len(offset), origin.angle[0]), np.full(len(offset), origin.curvature[0])
        along, across = road_coordinates(offset[:, 0], offset[:, 1], heading, curvature)
        near = sign * along <= NEXT_LANES_REACH
        return bool(near.any() and np.abs(across[near]).max() > NEXT_LANE_TOLERANCE)

    def _segments(
        self, i: np.ndarray, last: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Start point, direction vector, length and angle of the segments starting at vertices `i`
        of lanes whose last vertex is `last` (none beyond it: a lane of one vertex has a point)."""
        a = self.axis_xy[i]
        d = self.axis_xy[np.minimum(i + 1, last)] - a
        return a, d, np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0])

    @functools.cached_property
    def _first_segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """[L] `_segments` of each lane's first segment, worked out once: `lane_pose` gathers them
        for lanes of one segment instead of searching the axis for the segment and working it out
        again for every car in every step."""
        return self._segments(*self._lane_vertices)

    def _segment_curvature(
        self, lo: np.ndarray, hi: np.ndarray, i: np.ndarray, angle: np.ndarray, span: np.ndarray
    ) -> np.ndarray:
        """The turn between segment `i` (direction `angle`, length `span`) and its neighbour on the
        lane (the one before, else the one after), over the distance between their middles."""
        j = np.where(i > lo, i - 1, np.minimum(i + 1, np.maximum(hi - 1, lo)))
        e = self.axis_xy[np.minimum(j + 1, hi)] - self.axis_xy[j]
        other = np.arctan2(e[:, 1], e[:, 0])
        turn = np.where(j < i, wrap_angle(angle - other), wrap_angle(other - angle))
        middles = (span + np.hypot(e[:, 0], e[:, 1])) / 2
        return np.where(j != i, turn / np.maximum(middles, 1e-9), 0.0)

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


def road_coordinates(
    dx: np.ndarray, dy: np.ndarray, heading: np.ndarray, curvature: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(along, across) of world offsets in a road frame that bends with constant curvature.

    `across` is + to the geometric left. On a straight road this is a rotation; on a curve
    the offsets are taken about the curve's centre, so a car in the next lane 100 m round a
    200 m-radius bend is still one lane over, not 25 m to the side.
    """
    c, s = np.cos(heading), np.sin(heading)
    a = dx * c + dy * s  # ahead
    b = -dx * s + dy * c  # left
    bent = np.abs(curvature) > 1e-6
    k = np.where(bent, curvature, 1.0)
    radius = 1.0 / k  # signed: + = centre on the left
    sign = np.sign(radius)
    r = np.hypot(a, b - radius)
    along = np.where(bent, np.arctan2(a, sign * (radius - b)) * np.abs(radius), a)
    across = np.where(bent, radius - sign * r, b)
    return along, across


def heading_sector(heading: np.ndarray) -> np.ndarray:
    """Index k of the heading sector [k pi/4 - pi/8, k pi/4 + pi/8) each heading lies in."""
    width = 2 * np.pi / HEADING_SECTORS
    return np.floor(heading / width + 0.5).astype(np.int64) % HEADING_SECTORS


def cell_key(points: np.ndarray) -> np.ndarray:
    """Grid cell of each point packed into one int64 (x and y cell indices, offset to positive)."""
    cells = np.floor(points / GRID_CELL).astype(np.int64) + (1 << 20)
    return cells[:, 0] * (1 << 21) + cells[:, 1]


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
