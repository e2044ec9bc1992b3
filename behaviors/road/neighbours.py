"""Who is near whom: exact fixed-radius neighbour search over vehicle centres, on a grid when large.

Shared by both drivers (the paper's opponent rays, the traffic driver's surroundings and its limits)
and by insertion (`crowded`).
"""

from __future__ import annotations

import numpy as np

from behaviors.road.geometry import ranges

DENSE_PAIRS = 200_000
"""Below this many (query, point) combinations all distances are computed at once, without a grid."""

MAX_GRID_CELLS = 1 << 16
"""Cap on the neighbour grid's cells: on a huge map the cells grow instead (only slower, still exact)."""

Neighbours = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""(query rows, point rows, x offsets, y offsets, squared distances); offsets are point - query."""


def within(near: Neighbours, radius: float) -> Neighbours:
    """The pairs of a search with a larger radius that are closer than `radius`: the search itself
    when all of them are (the traffic sensors' usual case: no copies of some 12,000 pairs)."""
    close = near[4] < radius**2
    if close.all():
        return near
    keep = np.flatnonzero(close)
    return near[0][keep], near[1][keep], near[2][keep], near[3][keep], near[4][keep]


DISTANCE_RESOLUTION = 1e-3
"""m: neighbours whose distances differ by less than this are ranked by their order instead."""
_ENTRY_BITS = 26  # up to 67 million candidate entries per call


def nearest_per_slot(slots: int, slot: np.ndarray, distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(slots that have an entry, index of each one's nearest entry), in one pass over all entries.

    Each entry's distance (to a millimetre) and index are packed into one integer, so a single
    unbuffered minimum per slot finds the nearest: sorting the candidates costs more.
    """
    if len(slot) >= 1 << _ENTRY_BITS:
        raise ValueError("too many neighbour entries for one call")
    low = distance.min(initial=0.0)
    rank = np.rint((distance - low) / DISTANCE_RESOLUTION).astype(np.int64)  # np.round's own ufunc
    packed = (rank << _ENTRY_BITS) | np.arange(len(slot), dtype=np.int64)
    best = np.full(slots, np.iinfo(np.int64).max)
    np.minimum.at(best, slot, packed)
    found = np.flatnonzero(best != np.iinfo(np.int64).max)
    return found, best[found] & ((1 << _ENTRY_BITS) - 1)


def neighbour_pairs(query: np.ndarray, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """All (query row, point row) pairs closer than `radius`, sorted by query row."""
    q, m, _, _, _ = neighbours(query, points, radius)
    return q, m


def neighbours(
    query: np.ndarray, points: np.ndarray, radius: float, exclude: np.ndarray | None = None
) -> Neighbours:
    """Pairs closer than `radius`, without (i, exclude[i]); brute force when small, else a grid."""
    if len(query) == 0 or len(points) == 0:
        empty = np.zeros(0)
        return np.zeros(0, np.int64), np.zeros(0, np.int64), empty, empty, empty
    if len(query) * len(points) <= DENSE_PAIRS:
        dx = points[:, 0][None, :] - query[:, 0][:, None]
        dy = points[:, 1][None, :] - query[:, 1][:, None]
        square = dx * dx + dy * dy
        close = square < radius**2
        if exclude is not None:
            close[np.arange(len(query)), exclude] = False
        q, m = np.nonzero(close)
        return q, m, dx[q, m], dy[q, m], square[q, m]
    per_query, idx, order = _grid_candidates(query, points, radius)
    q = np.repeat(np.arange(len(query)), per_query)  # one repeat, then plain gathers
    # contiguous coordinates, points in grid order: the gathers below read memory nearly in sequence
    dx = points[order, 0][idx] - np.ascontiguousarray(query[:, 0])[q]
    dy = points[order, 1][idx] - np.ascontiguousarray(query[:, 1])[q]
    square = dx * dx + dy * dy
    close = square < radius**2
    if exclude is not None:
        rank = np.empty(len(order), np.int64)
        rank[order] = np.arange(len(order))
        close &= idx != rank[exclude][q]
    keep = np.flatnonzero(close)
    return q[keep], order[idx[keep]], dx[keep], dy[keep], square[keep]


CELLS_PER_RADIUS = 2
"""Neighbour-grid cells are radius / 2 wide: a 5 x 5 block spans 2.5 radii, not 3 as with 3 x 3."""


def _grid_candidates(
    query: np.ndarray, points: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points in the grid cells around each query: count per query, positions in `order`, `order`.

    Points are sorted by cell (column-major), so for each query each grid column
    of its block is one contiguous run. Dense (a count per cell over the bounding
    box), so a lookup is plain indexing, not a binary search; a margin of blocks
    keeps every run inside.
    """
    both = (points, query)
    low = np.array([min(a[:, 0].min() for a in both), min(a[:, 1].min() for a in both)])
    span = np.array([max(a[:, 0].max() for a in both), max(a[:, 1].max() for a in both)]) - low
    # a hair over radius / k, so float rounding of cell indices cannot hide a pair just inside it
    size = max(radius / CELLS_PER_RADIUS * (1 + 1e-9), float(np.sqrt(span[0] * span[1] / MAX_GRID_CELLS)))
    reach = int(np.ceil(radius / size))  # cells a neighbour can be away along each axis
    low = low - reach * size
    rows = int(span[1] // size) + 2 * reach + 1
    columns = int(span[0] // size) + 2 * reach + 1
    cell_p = _flat_cell(points, low, size, reach, rows, columns)
    order = np.argsort(cell_p, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(cell_p, minlength=rows * columns))])
    column_offsets = np.arange(-reach, reach + 1) * rows
    bottom = _flat_cell(query, low, size, reach, rows, columns)[:, None] + column_offsets - reach
    begin = start[bottom].ravel()
    count = start[bottom + 2 * reach + 1].ravel() - begin
    return count.reshape(len(query), -1).sum(axis=1), ranges(begin, count), order


def _flat_cell(
    points: np.ndarray, low: np.ndarray, size: float, reach: int, rows: int, columns: int
) -> np.ndarray:
    """Column-major index of each point's grid cell, kept off the margins.

    Every point lies at least `reach` cells above `low`, but float rounding can put the
    lowest one a hair below: clamping keeps every block around a point inside the grid.
    """
    cell = np.floor((points - low) / size).astype(np.int64)
    x = np.clip(cell[:, 0], reach, columns - reach - 1)
    y = np.clip(cell[:, 1], reach, rows - reach - 1)
    return x * rows + y


def crowded(
    position: np.ndarray, speed: np.ndarray, rows: np.ndarray, clearance: float, decel: float
) -> np.ndarray:
    """[len(rows)] bool: whether another vehicle's front lies within `clearance` of the front of each
    vehicle in `rows` (of `position` [M, 2], `speed` [M]), or within the distance in which the two
    would close up at their speed difference braking at `decel`. SUMO inserts a car where its lane is
    free but does not see a learned car moving over from the next lane, so populate puts such a car
    elsewhere (docs/history.md). Direction is not known here, so a fast car put down ahead of a slow
    one is moved too."""
    if len(rows) == 0:
        return np.zeros(0, bool)
    reach = clearance + float(np.ptp(speed)) ** 2 / (2 * decel)  # the largest distance that can matter
    q, m, _, _, square = neighbours(position[rows], position, reach, rows)
    closing = np.abs(speed[rows][q] - speed[m])
    close = np.sqrt(square) < clearance + closing**2 / (2 * decel)
    out = np.zeros(len(rows), bool)
    out[q[close]] = True
    return out
