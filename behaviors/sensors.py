"""The paper's 65-value TORCS-like state (66 with the behaviour id), for all agents at once.

Pure numpy: no SUMO here, so every value can be checked against geometry by hand.
See the observation table in the README for the layout, units and normalisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.geometry import RAY_RANGE, RoadGeometry

TRACK_RAY_ANGLES = np.deg2rad(np.arange(-90.0, 91.0, 10.0))
"""19 track-edge rays relative to the car's heading; positive = to the left."""

OPPONENT_SECTORS = 36
SECTOR_WIDTH = 2 * np.pi / OPPONENT_SECTORS

WHEEL_RADIUS = 0.3
GEAR_RATIOS = np.array([3.6, 2.2, 1.5, 1.1, 0.9, 0.75])
FINAL_DRIVE = 3.9
SHIFT_UP_RPM = 6500.0
IDLE_RPM = 800.0

OBS_SIZE = 65
OBS_SIZE_WITH_ID = 66
OBSERVATION_LAYOUT = (
    ("angle", 1),
    ("track", 19),
    ("trackPos", 1),
    ("speedX", 1),
    ("speedY", 1),
    ("speedZ", 1),
    ("wheelSpinVel", 4),
    ("rpm", 1),
    ("opponents", 36),
)
"""Names and sizes in order; the behaviour id, when used, follows as the 66th value."""

SLICES = {}
_start = 0
for _name, _size in OBSERVATION_LAYOUT:
    SLICES[_name] = slice(_start, _start + _size)
    _start += _size
del _start, _name, _size


@dataclass(frozen=True)
class AgentFrame:
    """Kinematic state of the controlled agents in one step (row i = agent i)."""

    centre: np.ndarray  # [N, 2] car centre, metres
    heading: np.ndarray  # [N] world heading, radians CCW from +x
    angle: np.ndarray  # [N] heading relative to the road axis, radians
    speed: np.ndarray  # [N] m/s along the heading
    track_pos: np.ndarray  # [N] lateral offset / half carriageway width (+1 = left border)


def observe(
    agents: AgentFrame,
    vehicle_centres: np.ndarray,
    agent_rows: np.ndarray,
    geometry: RoadGeometry,
    behaviour_id: np.ndarray | None = None,
) -> np.ndarray:
    """float32 [N, 65] (or [N, 66] with `behaviour_id`) observations.

    `vehicle_centres` holds every vehicle in the simulation (SUMO's own too);
    `agent_rows[i]` is agent i's row in it, so an agent does not see itself.
    """
    n = len(agents.speed)
    obs = np.empty((n, OBS_SIZE if behaviour_id is None else OBS_SIZE_WITH_ID), np.float32)
    obs[:, SLICES["angle"]] = (agents.angle / np.pi)[:, None]
    obs[:, SLICES["track"]] = track_rays(agents.centre, agents.heading, geometry) / RAY_RANGE
    obs[:, SLICES["trackPos"]] = agents.track_pos[:, None]
    kmh = agents.speed * 3.6
    obs[:, SLICES["speedX"]] = (kmh * np.cos(agents.angle) / 300.0)[:, None]
    obs[:, SLICES["speedY"]] = (kmh * np.sin(agents.angle) / 300.0)[:, None]
    obs[:, SLICES["speedZ"]] = 0.0
    obs[:, SLICES["wheelSpinVel"]] = (agents.speed / WHEEL_RADIUS / 100.0)[:, None]
    obs[:, SLICES["rpm"]] = (engine_rpm(agents.speed) / 10000.0)[:, None]
    obs[:, SLICES["opponents"]] = (
        opponent_rays(agents.centre, agents.heading, vehicle_centres, agent_rows) / RAY_RANGE
    )
    if behaviour_id is not None:
        obs[:, OBS_SIZE] = behaviour_id
    return obs


def engine_rpm(speed: np.ndarray) -> np.ndarray:
    """Engine speed from a simple six-gear model: the lowest gear that stays under the shift point."""
    wheel_rpm = speed / WHEEL_RADIUS * 60.0 / (2 * np.pi)
    rpm = wheel_rpm[:, None] * GEAR_RATIOS[None, :] * FINAL_DRIVE
    gear = np.minimum(np.argmax(rpm <= SHIFT_UP_RPM, axis=1), len(GEAR_RATIOS) - 1)
    gear = np.where(rpm[:, -1] > SHIFT_UP_RPM, len(GEAR_RATIOS) - 1, gear)
    return np.maximum(rpm[np.arange(len(speed)), gear], IDLE_RPM)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles mapped to [-pi, pi)."""
    return (a + np.pi) % (2 * np.pi) - np.pi


def track_rays(origin: np.ndarray, heading: np.ndarray, geometry: RoadGeometry) -> np.ndarray:
    """[N, 19] distance along each track ray to the nearest carriageway border, capped at 200 m.

    Instead of testing every ray against every segment, each nearby segment is
    turned into the interval of bearings it covers; only rays inside that
    interval are intersected with it (usually one or none).
    """
    n = len(origin)
    out = np.full(n * len(TRACK_RAY_ANGLES), RAY_RANGE)
    cand = geometry.candidates(origin)
    agent, col = np.nonzero(cand >= 0)
    seg = cand[agent, col]
    a = geometry.seg_a[seg] - origin[agent]
    b = geometry.seg_b[seg] - origin[agent]
    ta = wrap_angle(np.arctan2(a[:, 1], a[:, 0]) - heading[agent])
    tb = wrap_angle(np.arctan2(b[:, 1], b[:, 0]) - heading[agent])
    lo, hi = np.minimum(ta, tb), np.maximum(ta, tb)
    wraps = hi - lo > np.pi  # the segment lies across the car's back: covers [hi, pi) and [-pi, lo]
    step = TRACK_RAY_ANGLES[1] - TRACK_RAY_ANGLES[0]
    first = TRACK_RAY_ANGLES[0]
    last_ray = len(TRACK_RAY_ANGLES) - 1
    # ray ranges [j0, j1] and [j2, j3] (inclusive) covered by each segment
    j0 = np.where(wraps, np.ceil((hi - first) / step), np.ceil((lo - first) / step))
    j1 = np.where(wraps, last_ray, np.floor((hi - first) / step))
    j2 = np.where(wraps, 0, 1)
    j3 = np.where(wraps, np.floor((lo - first) / step), 0)
    j0, j1 = np.maximum(j0, 0).astype(np.int64), np.minimum(j1, last_ray).astype(np.int64)
    j2, j3 = np.maximum(j2, 0).astype(np.int64), np.minimum(j3, last_ray).astype(np.int64)
    c1 = np.maximum(j1 - j0 + 1, 0)
    c2 = np.maximum(j3 - j2 + 1, 0)
    pair = np.concatenate([np.repeat(np.arange(len(seg)), c1), np.repeat(np.arange(len(seg)), c2)])
    ray = np.concatenate([_ranges(j0, c1), _ranges(j2, c2)])
    if len(pair) == 0:
        return out.reshape(n, -1)
    direction = heading[agent[pair]] + TRACK_RAY_ANGLES[ray]
    ux, uy = np.cos(direction), np.sin(direction)
    pa, pb = a[pair], b[pair]
    ex, ey = pb[:, 0] - pa[:, 0], pb[:, 1] - pa[:, 1]
    denom = ux * ey - uy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (pa[:, 0] * ey - pa[:, 1] * ex) / denom
    hit = np.isfinite(t) & (t >= 0) & (t < RAY_RANGE)
    np.minimum.at(out, agent[pair][hit] * len(TRACK_RAY_ANGLES) + ray[hit], t[hit])
    return out.reshape(n, -1)


def _ranges(start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Concatenation of arange(start[i], start[i] + count[i]) over i, vectorised."""
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offsets = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
    return np.repeat(start, count) + offsets


def opponent_rays(
    origin: np.ndarray, heading: np.ndarray, others: np.ndarray, self_rows: np.ndarray
) -> np.ndarray:
    """[N, 36] distance to the nearest vehicle centre in each 10-degree sector, capped at 200 m.

    Sector k covers bearings [-180 + 10k, -170 + 10k) degrees relative to the
    heading (sector 0 starts straight behind; 18 starts straight ahead, to the left).
    """
    n = len(origin)
    out = np.full(n * OPPONENT_SECTORS, RAY_RANGE)
    q, m = neighbour_pairs(origin, others, RAY_RANGE)
    keep = m != self_rows[q]
    q, m = q[keep], m[keep]
    d = others[m] - origin[q]
    dist = np.hypot(d[:, 0], d[:, 1])
    bearing = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - heading[q])
    sector = np.minimum(((bearing + np.pi) / SECTOR_WIDTH).astype(np.int64), OPPONENT_SECTORS - 1)
    np.minimum.at(out, q * OPPONENT_SECTORS + sector, dist)
    return out.reshape(n, -1)


def neighbour_pairs(query: np.ndarray, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """All (query row, point row) pairs closer than `radius`, via a grid of radius-sized cells."""
    if len(points) == 0 or len(query) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    cell_p = np.floor(points / radius).astype(np.int64)
    key_p = cell_p[:, 0] * (1 << 32) + cell_p[:, 1]
    order = np.argsort(key_p, kind="stable")
    sorted_keys = key_p[order]
    cell_q = np.floor(query / radius).astype(np.int64)
    qs, ms = [], []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            key = (cell_q[:, 0] + dx) * (1 << 32) + cell_q[:, 1] + dy
            start = np.searchsorted(sorted_keys, key, side="left")
            count = np.searchsorted(sorted_keys, key, side="right") - start
            qs.append(np.repeat(np.arange(len(query)), count))
            ms.append(order[_ranges(start, count)])
    q = np.concatenate(qs)
    m = np.concatenate(ms)
    d = points[m] - query[q]
    close = d[:, 0] ** 2 + d[:, 1] ** 2 < radius**2
    return q[close], m[close]
