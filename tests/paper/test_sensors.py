"""Sensors against geometry computed by hand (pure numpy, plus the shipped ring's shapes)."""

from __future__ import annotations

import numpy as np
import pytest

from behaviors.paper.sensors import (
    OBS_SIZE,
    OBS_SIZE_WITH_ID,
    PARALLEL_AGENTS,
    SLICES,
    TRACK_RAY_ANGLES,
    AgentFrame,
    engine_rpm,
    observe,
    opponent_rays,
    track_rays,
)
from behaviors.road.geometry import RAY_RANGE
from behaviors.road.geometry_build import build_geometry, load_geometry
from behaviors.road.neighbours import neighbour_pairs
from sumo_scenarios import get_scenario

LANE_WIDTH = 3.2
HALF = LANE_WIDTH  # two lanes: the carriageway spans y in [-3.2, 3.2]


@pytest.fixture(scope="module")
def straight():
    """A 1 km two-lane road along +x, centred on y = 0, in three edges."""
    edges = []
    for k, (x0, x1) in enumerate([(0, 300), (300, 700), (700, 1000)]):
        lanes = [
            (f"e{k}_{i}", [(x0, y), (x1, y)], LANE_WIDTH, 30.0, x1 - x0)
            for i, y in enumerate((-LANE_WIDTH / 2, LANE_WIDTH / 2))
        ]
        edges.append((f"e{k}", lanes, True))
    return build_geometry(edges, [("e0", "e1"), ("e1", "e2")])


def analytic_straight_rays(offset: float, heading: float) -> np.ndarray:
    s = np.sin(heading + TRACK_RAY_ANGLES)
    with np.errstate(divide="ignore"):
        d = np.where(s > 0, (HALF - offset) / s, (-HALF - offset) / s)
    return np.where((np.abs(s) < 1e-12) | (d > RAY_RANGE), RAY_RANGE, d)


@pytest.mark.parametrize("offset", [0.0, 1.1, -2.3])
@pytest.mark.parametrize("heading_deg", [0.0, 7.0, -20.0, 45.0])
def test_track_rays_match_the_analytic_distance_to_the_borders(straight, offset, heading_deg):
    heading = np.deg2rad(heading_deg)
    rays = track_rays(np.array([[420.0, offset]]), np.array([heading]), straight)[0]
    np.testing.assert_allclose(rays, analytic_straight_rays(offset, heading), atol=0.05)


def test_track_rays_are_vectorised_over_agents(straight):
    origins = np.array([[100.0, 0.5], [500.0, -1.0], [650.0, 2.0]])
    headings = np.deg2rad([3.0, -12.0, 30.0])
    together = track_rays(origins, headings, straight)
    for i in range(3):
        np.testing.assert_allclose(
            together[i], track_rays(origins[i : i + 1], headings[i : i + 1], straight)[0]
        )


def test_ray_along_a_straight_road_sees_nothing_within_range(straight):
    rays = track_rays(np.array([[300.0, 0.0]]), np.array([0.0]), straight)[0]
    assert rays[9] == RAY_RANGE  # straight ahead, parallel to both borders


def test_ring_side_rays_measure_the_distance_to_both_borders_on_curves():
    scenario = get_scenario("ring")
    geometry = load_geometry(scenario.net)
    import sumolib

    net = sumolib.net.readNet(str(scenario.net))
    checked = 0
    for edge in net.getEdges():
        lanes = edge.getLanes()
        for number, lane in enumerate(lanes):
            shape = np.asarray(lane.getShape())
            if len(shape) < 10:
                continue  # a straight edge: covered by the straight-road test
            mid = len(shape) // 2
            point = (shape[mid - 1] + shape[mid]) / 2
            pos = np.sum(np.linalg.norm(np.diff(shape[:mid], axis=0), axis=1))
            pos += np.linalg.norm(point - shape[mid - 1])
            row = geometry.lane_index[lane.getID()]
            tangent, curvature = geometry.road_axis(
                np.array([row]), np.array([pos / geometry.lane_length_scale[row]])
            )
            rays = track_rays(point[None], tangent, geometry)[0]
            width = lane.getWidth()
            right = (number + 0.5) * width
            left = (len(lanes) - number - 0.5) * width
            assert rays[0] == pytest.approx(right, abs=0.05)
            assert rays[-1] == pytest.approx(left, abs=0.05)
            assert abs(1 / curvature[0]) == pytest.approx(200.0, rel=0.05)
            checked += 1
    assert checked == 6  # two curves, three lanes each


def test_opponent_rays_land_in_the_right_sector_at_the_right_distance():
    origin = np.array([[10.0, 5.0]])
    heading = np.array([np.deg2rad(30.0)])
    placed = {  # bearing relative to heading (deg) -> distance
        5.0: 12.0,  # ahead-left: sector 18
        -5.0: 20.0,  # ahead-right: sector 17
        95.0: 7.0,  # left: sector 27
        -175.0: 40.0,  # behind: sector 0
        130.0: 250.0,  # out of range: not seen
    }
    others = [origin[0]]  # the agent itself is row 0 and must not see itself
    for bearing, dist in placed.items():
        a = heading[0] + np.deg2rad(bearing)
        others.append(origin[0] + dist * np.array([np.cos(a), np.sin(a)]))
    rays = opponent_rays(origin, heading, np.array(others), np.array([0]))[0]
    expected = np.full(36, RAY_RANGE)
    expected[[18, 17, 27, 0]] = [12.0, 20.0, 7.0, 40.0]
    np.testing.assert_allclose(rays, expected, atol=1e-4)  # float32 arithmetic


def test_opponent_rays_keep_the_nearest_vehicle_per_sector():
    origin = np.zeros((1, 2))
    others = np.array([[50.0, 1.0], [30.0, 1.0], [0.0, 0.0]])
    rays = opponent_rays(origin, np.zeros(1), others, np.array([2]))[0]
    assert rays[18] == pytest.approx(np.hypot(30.0, 1.0))


def test_observation_layout_and_normalisation(straight):
    agents = AgentFrame(
        centre=np.array([[400.0, 1.6]]),
        heading=np.array([0.1]),
        angle=np.array([0.1]),
        speed=np.array([25.0]),
        track_pos=np.array([0.5]),
    )
    obs = observe(agents, np.array([[400.0, 1.6], [430.0, 1.6]]), np.array([0]), straight)
    assert obs.shape == (1, OBS_SIZE) and obs.dtype == np.float32
    assert obs[0, SLICES["angle"]][0] == pytest.approx(0.1 / np.pi)
    assert obs[0, SLICES["trackPos"]][0] == pytest.approx(0.5)
    assert obs[0, SLICES["speedX"]][0] == pytest.approx(25 * 3.6 * np.cos(0.1) / 300, rel=1e-6)
    assert obs[0, SLICES["speedY"]][0] == pytest.approx(25 * 3.6 * np.sin(0.1) / 300, rel=1e-6)
    np.testing.assert_allclose(obs[0, SLICES["wheelSpinVel"]], 25 / 0.3 / 100, rtol=1e-6)
    assert obs[0, SLICES["opponents"]][18 - 1] == pytest.approx(30.0 / RAY_RANGE)  # 0.1 rad right of heading
    with_id = observe(agents, np.array([[400.0, 1.6]]), np.array([0]), straight, np.array([1.0]))
    assert with_id.shape == (1, OBS_SIZE_WITH_ID) and with_id[0, -1] == 1.0
    np.testing.assert_allclose(with_id[0, :OBS_SIZE][:29], obs[0, :29])


def test_engine_rpm_stays_in_the_gear_model_band():
    speeds = np.linspace(0.0, 50.0, 101)
    rpm = engine_rpm(speeds)
    assert rpm.min() >= 800.0 and rpm.max() <= 10000.0
    assert rpm[-1] > rpm[50]  # top gear: rpm grows with speed


def brute_force_track_rays(origin: np.ndarray, heading: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray):
    """Every ray against every segment, no culling: the reference for the optimised sensor."""
    out = np.full((len(origin), len(TRACK_RAY_ANGLES)), RAY_RANGE)
    e = seg_b - seg_a
    for i, (p, h) in enumerate(zip(origin, heading, strict=True)):
        u = np.stack([np.cos(h + TRACK_RAY_ANGLES), np.sin(h + TRACK_RAY_ANGLES)], axis=1)[:, None, :]
        w = seg_a - p  # ray p + t u meets segment a + s e where both cross products agree
        denom = u[..., 0] * e[:, 1] - u[..., 1] * e[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / denom
            s = (w[:, 0] * u[..., 1] - w[:, 1] * u[..., 0]) / denom
        hit = (t >= 0) & (t < RAY_RANGE) & (s >= 0) & (s <= 1)
        out[i] = np.where(hit, t, RAY_RANGE).min(axis=1)
    return out


def random_ring_poses(geometry, rng: np.random.Generator, count: int):
    """Poses on the ring's carriageway (heading near the road's) and anywhere around it (any heading)."""
    import sumolib

    net = sumolib.net.readNet(str(get_scenario("ring").net))
    shapes = [np.asarray(lane.getShape()) for edge in net.getEdges() for lane in edge.getLanes()]
    origins, headings = [], []
    for shape in (shapes[k] for k in rng.integers(len(shapes), size=count)):
        i = rng.integers(len(shape) - 1)
        d = shape[i + 1] - shape[i]
        normal = np.array([-d[1], d[0]]) / np.hypot(*d)
        origins.append(shape[i] + rng.uniform() * d + rng.uniform(-1.5, 1.5) * normal)
        headings.append(np.arctan2(d[1], d[0]) + rng.normal(0.0, 0.4))
    low, high = geometry.seg_a.min(axis=0) - 50, geometry.seg_a.max(axis=0) + 50
    anywhere = rng.uniform(low, high, size=(count // 4, 2))
    return np.concatenate([origins, anywhere]), np.concatenate([headings, rng.uniform(-9, 9, count // 4)])


def test_track_rays_match_brute_force_on_the_ring():
    geometry = load_geometry(get_scenario("ring").net)
    origin, heading = random_ring_poses(geometry, np.random.default_rng(3), 400)
    expected = brute_force_track_rays(origin, heading, geometry.seg_a, geometry.seg_b)
    assert (expected < RAY_RANGE).mean() > 0.5  # the poses do see borders
    np.testing.assert_allclose(track_rays(origin, heading, geometry), expected, atol=0.02)


def test_a_big_fleet_gets_the_same_observations_as_the_ray_casts_alone():
    """From PARALLEL_AGENTS on, track rays run on a worker thread: same numbers, same rows."""
    geometry = load_geometry(get_scenario("ring").net)
    rng = np.random.default_rng(5)
    origin, heading = random_ring_poses(geometry, rng, 320)
    n = len(origin)
    assert n >= PARALLEL_AGENTS
    agents = AgentFrame(origin, heading, rng.normal(0, 0.1, n), rng.uniform(0, 30, n), rng.uniform(-1, 1, n))
    obs = observe(agents, origin, np.arange(n), geometry)
    expected_track = (track_rays(origin, heading, geometry) / RAY_RANGE).astype(np.float32)
    np.testing.assert_array_equal(obs[:, SLICES["track"]], expected_track)
    expected_opponents = (opponent_rays(origin, heading, origin, np.arange(n)) / RAY_RANGE).astype(np.float32)
    np.testing.assert_array_equal(obs[:, SLICES["opponents"]], expected_opponents)


def brute_force_opponent_rays(origin, heading, others, self_rows, edge_margin=1e-5):
    """Per agent, per vehicle: the sector formula written out plainly, in float64.

    Also returns which (agent, sector) cells a vehicle lying within `edge_margin` rad
    of a sector edge could fall into either way: float32 may round it across the edge.
    """
    out = np.full((len(origin), 36), RAY_RANGE)
    ambiguous = np.zeros((len(origin), 36), bool)
    width = 2 * np.pi / 36
    for i in range(len(origin)):
        for j in range(len(others)):
            d = others[j] - origin[i]
            dist = np.sqrt(d[0] * d[0] + d[1] * d[1])
            if j == self_rows[i] or not dist < RAY_RANGE:
                continue
            bearing = (np.arctan2(d[1], d[0]) - heading[i] + np.pi) % (2 * np.pi) - np.pi
            sector = min(int((bearing + np.pi) / width), 35)
            out[i, sector] = min(out[i, sector], dist)
            edge = (bearing + np.pi) / width
            if abs(edge - round(edge)) * width < edge_margin:
                ambiguous[i, [(round(edge) - 1) % 36, round(edge) % 36]] = True
    return out, ambiguous


@pytest.mark.parametrize("agents", [5, 500])  # brute force over all pairs, and the neighbour grid
def test_opponent_rays_match_the_brute_force_ones(agents):
    rng = np.random.default_rng(agents)
    # UTM-sized coordinates: float32 must not lose the metres there
    others = rng.uniform([350_000.0, 5_600_000.0], [353_000.0, 5_600_600.0], size=(agents + 40, 2))
    rows = rng.permutation(len(others))[:agents]
    heading = rng.uniform(-7, 7, agents)
    heading[:2] = [8.0, -20.0]  # far outside [-pi, pi): unwrapped road angles can be
    heading[2] = 0.0
    others[len(others) - 1] = others[rows[2]] + [50.0, 0.0]  # exactly on the edge between sectors 17 and 18
    expected, ambiguous = brute_force_opponent_rays(others[rows], heading, others, rows)
    rays = opponent_rays(others[rows], heading, others, rows)
    assert rays.dtype == np.float32 and ambiguous.mean() < 0.02  # nearly every cell is checked
    assert rays[2, 18] == pytest.approx(50.0, abs=1e-3)
    np.testing.assert_allclose(rays[~ambiguous], expected[~ambiguous], atol=2e-3, rtol=0)


@pytest.mark.parametrize("extent", [5000.0, 3.0e6])  # cells of radius / 2, and cells capped in number
def test_neighbour_pairs_are_the_same_with_and_without_the_grid(extent):
    rng = np.random.default_rng(7)
    points = rng.uniform(-extent, extent, size=(800, 2))
    query = rng.uniform(-extent, extent, size=(400, 2))
    query[:200] = points[:200] + rng.normal(0.0, 150.0, size=(200, 2))  # pairs even on the huge map
    q, m = neighbour_pairs(query, points, 300.0)  # 320k combinations: the grid
    d = np.linalg.norm(points[None] - query[:, None], axis=2)
    eq, em = np.nonzero(d < 300.0)
    assert len(eq) > 150 and len(q) == len(eq)
    assert set(zip(q.tolist(), m.tolist(), strict=True)) == set(zip(eq.tolist(), em.tolist(), strict=True))


def test_opponent_grid_handles_points_on_the_bounding_box_edge():
    """Regression: float rounding once put the lowest point's cell at -1 (negative index)."""
    rng = np.random.default_rng(1)
    points = rng.uniform(0, 20000, (1200, 2))
    points[0] = [points[:, 0].min() - 1e-9, points[:, 1].min()]
    heading = rng.uniform(-np.pi, np.pi, 1000)
    rays = opponent_rays(points[:1000], heading, points, np.arange(1000))
    assert rays.shape == (1000, 36) and np.all(rays <= RAY_RANGE)


def test_a_car_put_down_beside_another_is_crowded():
    from behaviors.road.neighbours import crowded

    position = np.array([[0.0, 0.0], [3.0, 2.0], [40.0, 0.0], [43.0, 3.5], [100.0, 0.0]])
    # new cars: row 1 (3.6 m from row 0's front), row 3 (4.6 m from row 2's), row 4 (alone)
    same = np.full(5, 20.0)
    assert crowded(position, same, np.array([1, 3, 4]), 6.0, 4.0).tolist() == [True, True, False]
    assert crowded(position, same, np.array([1, 3, 4]), 4.0, 4.0).tolist() == [True, False, False]
    assert crowded(position, same, np.array([], np.int64), 6.0, 4.0).tolist() == []


def test_a_car_put_down_fast_behind_a_slow_one_in_the_next_lane_is_crowded():
    """Measured on a curved motorway: an agent put down at 22.7 m/s 7 m behind one crossing into its
    lane at 14 m/s hit it 2 s later. Closing 8.7 m/s at 4 m/s^2 takes 9.5 m on top of the 6 m."""
    from behaviors.road.neighbours import crowded

    position = np.array([[0.0, 0.0], [-5.0, 3.75], [-40.0, 3.75]])
    fast = np.array([14.0, 22.7, 22.7])
    assert crowded(position, fast, np.array([1, 2]), 6.0, 4.0).tolist() == [True, False]
    assert crowded(position, np.array([14.0, 15.0, 22.7]), np.array([1]), 6.0, 4.0).tolist() == [False]
