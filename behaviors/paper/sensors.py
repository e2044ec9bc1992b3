"""The paper's 65-value TORCS-like state (66 with the behaviour id), for all agents at once.

Pure numpy: no SUMO here, so every value can be checked against geometry by hand.
See the observation table in the README for the layout, units and normalisation.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from behaviors.road.geometry import RAY_RANGE, RoadGeometry, ranges
from behaviors.road.neighbours import neighbours

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
    track = _track_rays_soon(agents.centre, agents.heading, geometry)
    obs = np.empty((n, OBS_SIZE if behaviour_id is None else OBS_SIZE_WITH_ID), np.float32)
    obs[:, SLICES["angle"]] = (agents.angle / np.pi)[:, None]
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
    obs[:, SLICES["track"]] = track() / RAY_RANGE
    if behaviour_id is not None:
        obs[:, OBS_SIZE] = behaviour_id
    return obs


PARALLEL_AGENTS = 200
"""From this many agents on, track rays run on a second thread beside the opponent rays."""

_sensor_thread: ThreadPoolExecutor | None = None


def _track_rays_soon(
    origin: np.ndarray, heading: np.ndarray, geometry: RoadGeometry
) -> Callable[[], np.ndarray]:
    """Track rays, started on a worker thread for big fleets; call the result to get them.

    numpy lets go of the GIL inside its loops, and the two ray casts are independent,
    so on a second core they overlap (docs/benchmarks.md). SUMO is
    not stepping meanwhile, so the second core is otherwise idle. Small fleets stay on
    one thread: handing work over costs more than it saves there.
    """
    global _sensor_thread
    if len(origin) < PARALLEL_AGENTS:
        rays = track_rays(origin, heading, geometry)
        return lambda: rays
    if _sensor_thread is None:
        _sensor_thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="behave-sensors")
    return _sensor_thread.submit(track_rays, origin, heading, geometry).result


def engine_rpm(speed: np.ndarray) -> np.ndarray:
    """Engine speed from a simple six-gear model: the lowest gear that stays under the shift point."""
    wheel_rpm = speed / WHEEL_RADIUS * 60.0 / (2 * np.pi)
    rpm = wheel_rpm[:, None] * GEAR_RATIOS[None, :] * FINAL_DRIVE
    # ratios fall with the gear, so the gears over the shift point are exactly the lowest ones
    gear = np.minimum(np.count_nonzero(rpm > SHIFT_UP_RPM, axis=1), len(GEAR_RATIOS) - 1)
    return np.maximum(rpm[np.arange(len(speed)), gear], IDLE_RPM)


def track_rays(origin: np.ndarray, heading: np.ndarray, geometry: RoadGeometry) -> np.ndarray:
    """[N, 19] distance along each track ray to the nearest carriageway border, capped at 200 m.

    Instead of testing every ray against every segment, each nearby segment is
    turned into the interval of bearings it covers; only rays inside that
    interval are intersected with it (usually one or none). Work happens in each
    car's own frame (x forward, y left), where the ray directions are constants
    and the rays only span the front half-plane, so segments behind are dropped
    before any trigonometry.
    """
    n = len(origin)
    out = np.full(n * len(TRACK_RAY_ANGLES), RAY_RANGE)
    agent, seg = geometry.candidates(origin, heading)
    # as complex numbers, (point - origin) * e^{-i heading} is the point in the car's frame
    z_origin = (origin[:, 0] + 1j * origin[:, 1])[agent]
    turn = np.exp(-1j * heading)[agent]
    a = (geometry.seg_za[seg] - z_origin) * turn
    b = (geometry.seg_zb[seg] - z_origin) * turn
    front = np.flatnonzero((a.real > 0) | (b.real > 0))
    agent, a, b = agent[front], a[front], b[front]
    # contiguous copies: numpy's vector loops (arctan2 above all) are several times faster on them
    ax, ay, bx, by = (np.ascontiguousarray(part) for part in (a.real, a.imag, b.real, b.imag))
    cross = ax * by - ay * bx  # a x b: its sign tells on which side the segment crosses x = 0
    # a segment half behind the car reaches round to the +-90 degree ray on the side it crosses
    ta = np.where(ax < 0, np.copysign(np.pi, -cross), np.arctan2(ay, ax))
    tb = np.where(bx < 0, np.copysign(np.pi, cross), np.arctan2(by, bx))
    step = TRACK_RAY_ANGLES[1] - TRACK_RAY_ANGLES[0]
    first = np.ceil((np.minimum(ta, tb) - TRACK_RAY_ANGLES[0]) / step)
    last = np.floor((np.maximum(ta, tb) - TRACK_RAY_ANGLES[0]) / step)
    first = np.maximum(first, 0).astype(np.int64)
    count = np.maximum(np.minimum(last, len(TRACK_RAY_ANGLES) - 1).astype(np.int64) - first + 1, 0)
    pair = np.repeat(np.arange(len(agent)), count)
    ray = ranges(first, count)
    # ray t * u meets the segment's line a + s (b - a) where t = (a x b) / (u x (b - a))
    denom = _RAY_COS[ray] * (by - ay)[pair] - _RAY_SIN[ray] * (bx - ax)[pair]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = cross[pair] / denom
    hit = (t >= 0) & (t < RAY_RANGE)
    np.minimum.at(out, agent[pair[hit]] * len(TRACK_RAY_ANGLES) + ray[hit], t[hit])
    return out.reshape(n, -1)


_RAY_COS = np.cos(TRACK_RAY_ANGLES)
_RAY_SIN = np.sin(TRACK_RAY_ANGLES)


def opponent_rays(
    origin: np.ndarray, heading: np.ndarray, others: np.ndarray, self_rows: np.ndarray
) -> np.ndarray:
    """float32 [N, 36] distance to the nearest vehicle centre in each 10-degree sector, capped at 200 m.

    Sector k covers bearings [-180 + 10k, -170 + 10k) degrees relative to the
    heading (sector 0 starts straight behind; 18 starts straight ahead, to the left).
    The pair arithmetic runs in float32 (the observation's own precision) on
    coordinates taken relative to the fleet's corner, so it stays within a millimetre
    on nets tens of kilometres wide; a vehicle within about 1e-6 rad of a sector's edge
    may land in either sector.
    """
    n = len(origin)
    if n == 0:
        return np.zeros((0, OPPONENT_SECTORS), np.float32)
    corner = origin.min(axis=0) if len(others) == 0 else np.minimum(origin.min(axis=0), others.min(axis=0))
    local_origin = (origin - corner).astype(np.float32)
    local_others = (others - corner).astype(np.float32)
    q, _, dx, dy, square = neighbours(local_origin, local_others, RAY_RANGE, self_rows)
    # each neighbour in the car's frame (x ahead, y left): one arctan2 gives the relative bearing
    cos, sin = np.cos(heading).astype(np.float32)[q], np.sin(heading).astype(np.float32)[q]
    bearing = np.arctan2(dy * cos - dx * sin, dx * cos + dy * sin)  # [-pi, pi]
    sector = ((bearing + np.float32(np.pi)) * np.float32(1 / SECTOR_WIDTH)).astype(np.int64)
    cell = q * OPPONENT_SECTORS + np.minimum(sector, OPPONENT_SECTORS - 1)
    # nearest by squared distance, rooted once per sector; empty sectors read the full range
    nearest = np.full(n * OPPONENT_SECTORS, np.float32(RAY_RANGE**2))
    np.minimum.at(nearest, cell, square)
    return np.sqrt(nearest).reshape(n, -1)
