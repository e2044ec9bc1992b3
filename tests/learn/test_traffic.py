"""The traffic driver: lane observation, lateral-speed actuation, traffic reward, and its env."""

from __future__ import annotations

import contextlib
import subprocess
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from behaviors.car.model import CarModel
from behaviors.fleet.control import Fleet, moves_to_send
from behaviors.fleet.drivers import PaperDriver, TrafficDriver, make_driver
from behaviors.fleet.handover import HANDOVER_DISTANCE, LaneEnds, LanePlace, straddling_an_ending_lane
from behaviors.learn import traffic_env
from behaviors.learn.env import make_env
from behaviors.learn.traffic_env import CRAWL_CARS, CRAWL_GAP, CRAWL_SPEED, queue_places
from behaviors.road.geometry import RoadGeometry
from behaviors.road.geometry_build import build_geometry, load_geometry
from behaviors.road.neighbours import nearest_per_slot, neighbours
from behaviors.run.populate import populate
from behaviors.run.populate_config import config_from
from behaviors.sumo.sim import SimOptions, SumoSim
from behaviors.sumo.sumo_home import sumo_binary
from behaviors.sumo.timing import PhaseTimer
from behaviors.traffic.actuation import actuate_lanes
from behaviors.traffic.intent import lane_intent, lane_wish
from behaviors.traffic.lanes import (
    GAP_RANGE,
    TRAFFIC_OBS_SIZE,
    TRAFFIC_SLICES,
    LaneAgents,
    observe_lanes,
    road_coordinates,
    surroundings,
)
from behaviors.traffic.lateral import lateral_profile
from behaviors.traffic.law import following_accel
from behaviors.traffic.limits import gap_acceptable
from behaviors.traffic.motives.cooperative import letting_in
from behaviors.traffic.motives.keep_right import slow_side_free
from behaviors.traffic.motives.strategic import falling_in
from behaviors.traffic.motives.wishes import LaneWishes
from behaviors.traffic.rewards import TrafficStep, TrafficWeights, traffic_rewards
from behaviors.traffic.scene import AgentStyle, LaneNeighbours, Motion, RoadPlace, lane_traffic, look_ahead
from behaviors.traffic.settings import CarFollowing, DriverSettings, LaneDriving, Rules
from behaviors.traffic.shield import surroundings as shield_surroundings
from behaviors.traffic.styles import fixed_styles
from sumo_scenarios import get_scenario
from sumo_scenarios.build import AGENT_ACTION_STEP, AGENT_VTYPES
from sumo_scenarios.osm_like import build_osm_like


def lanes_along(centre_line: list[tuple[float, float]], lanes: int = 3, width: float = 3.5) -> RoadGeometry:
    """One edge of `lanes` lanes whose middle lane follows `centre_line` (lane 0 on the right)."""
    line = np.asarray(centre_line, float)
    d = np.diff(line, axis=0)
    normal = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    vertex_normal = np.concatenate([normal[:1], normal[:-1] + normal[1:], normal[-1:]])
    vertex_normal /= np.hypot(vertex_normal[:, 0], vertex_normal[:, 1])[:, None]
    length = float(np.hypot(d[:, 0], d[:, 1]).sum())
    specs = [
        (
            f"e_{k}",
            [tuple(p) for p in line + (k - (lanes - 1) / 2) * width * vertex_normal],
            width,
            33.3,
            length,
        )
        for k in range(lanes)
    ]
    return build_geometry([("e", specs, True)])


STRAIGHT = lanes_along([(-500.0, 0.0), (500.0, 0.0)])
"""Three 3.5 m lanes along +x; the middle one (lane 1) passes through the origin at 500 m."""


def one_agent(**over) -> LaneAgents:
    base = dict(
        front=np.array([[0.0, 0.0]]),
        lane_row=np.array([STRAIGHT.lane_index["e_1"]]),
        shape_pos=np.array([500.0]),
        curvature=np.array([0.0]),
        speed=np.array([30.0]),
        lateral_speed=np.array([0.0]),
        changing=np.array([0]),
        desired_speed=np.array([30.0]),
        speed_limit=np.array([33.3]),
        lane_offset=np.array([0.0]),
        lane_width=np.array([3.5]),
        lane_number=np.array([1]),
        lanes=np.array([3]),
        lane_leads_on=np.array([[1000.0, 1000.0, 1000.0]]),
        behaviour_id=np.array([1.0]),
    )
    base.update(over)
    return LaneAgents(**base)


def test_road_coordinates_on_a_circle_give_arc_length_and_lane_offset():
    radius = 200.0
    # a car 3.5 m further out (right of a left-turning road), 60 degrees round the bend
    phi = np.pi / 3
    r_other = radius + 3.5
    point = np.array([r_other * np.sin(phi), radius - r_other * np.cos(phi)])
    along, across = road_coordinates(point[:1], point[1:], np.array([0.0]), np.array([1 / radius]))
    assert along[0] == pytest.approx(radius * phi, rel=1e-9)
    assert across[0] == pytest.approx(-3.5, abs=1e-9)
    straight = road_coordinates(np.array([10.0]), np.array([2.0]), np.array([np.pi / 2]), np.array([0.0]))
    assert straight[0][0] == pytest.approx(2.0) and straight[1][0] == pytest.approx(-10.0)


def test_surroundings_find_leaders_and_followers_per_lane():
    agent = one_agent()
    # world: agent front at 0, others: own lane 40 m ahead, fast lane (left, +3.5 m) 10 m behind,
    # slow lane (right) 100 m ahead, and one far away
    positions = np.array([[0.0, 0.0], [45.0, 0.2], [-5.0, 3.5], [105.0, -3.5], [1000.0, 0.0]])
    speeds = np.array([30.0, 25.0, 35.0, 20.0, 10.0])
    around = surroundings(agent, positions, speeds, np.array([0]), STRAIGHT)
    gap, other = around.gap[0], around.other_speed[0]
    assert gap[0] == pytest.approx(40.0) and other[0] == 25.0  # leader: 45 m front to front - 5 m
    assert np.isinf(gap[1]) and np.isnan(other[1])  # nobody behind in the own lane
    assert np.isinf(gap[2])
    assert gap[3] == pytest.approx(0.0) and other[3] == 35.0  # fast-lane car alongside: gap 0
    assert gap[4] == pytest.approx(100.0) and other[4] == 20.0
    obs = observe_lanes(agent, around)
    assert obs.shape == (1, TRAFFIC_OBS_SIZE)
    assert obs[0, TRAFFIC_SLICES["gap"]][0] == pytest.approx(40.0 / GAP_RANGE)
    assert obs[0, TRAFFIC_SLICES["relative_speed"]][0] == pytest.approx(-5.0 / 15.0)


@pytest.mark.parametrize(
    "right_of_centre, other_speed, leads",
    [
        (2.5, 0.0, False),  # stands, body over the line, 0.7 m clear of ours: driven past
        (2.3, 0.0, True),  # 0.5 m clear: too close to pass
        (2.5, 3.0, True),  # moving: followed, as any car over the line
    ],
)
def test_a_car_standing_alongside_over_the_line_leads_only_without_room_to_pass(
    right_of_centre, other_speed, leads
):
    # at a lane drop's end a car waiting to merge stood with its body over the line, and the agent
    # beside it stood for it while it waited for the agent: two minutes, until the run ended
    agent = one_agent(speed=np.array([0.0]))
    positions = np.array([[0.0, 0.0], [1.5, -right_of_centre]])
    around = surroundings(agent, positions, np.array([0.0, other_speed]), np.array([0]), STRAIGHT)
    assert (around.gap[0, 0] == 0.0) == leads
    assert around.gap[0, 4] == 0.0  # its own lane's car alongside either way: no change into it


def test_nearest_per_slot_is_the_smallest_distance_of_each_slot_across_many_agents():
    rng = np.random.default_rng(3)
    slot = rng.integers(0, 60, 2_000)
    distance = np.round(rng.uniform(-5.0, 150.0, 2_000), 2)  # rounded: ties between entries occur
    found, nearest = nearest_per_slot(64, slot, distance)
    assert list(found) == sorted(set(slot.tolist()))
    for s_, k in zip(found, nearest, strict=True):
        assert slot[k] == s_ and distance[k] == distance[slot == s_].min()
    assert nearest_per_slot(6, np.zeros(0, np.int64), np.zeros(0))[0].size == 0


def test_each_of_many_agents_gets_its_own_nearest_leader_and_follower():
    # agents every 20 m in the middle lane, a SUMO car 8 m ahead of each: every agent's leader is
    # its own car (gap 3 m), its follower the car in front of the agent behind (gap 7 m)
    count = 30
    fronts = np.stack([np.arange(count) * 20.0 - 300.0, np.zeros(count)], axis=1)
    cars = fronts + np.array([8.0, 0.0])
    agents = one_agent(
        front=fronts, lane_row=np.full(count, STRAIGHT.lane_index["e_1"]), shape_pos=fronts[:, 0] + 500.0,
        **{k: np.repeat(v, count, axis=0) for k, v in vars(one_agent()).items()
           if isinstance(v, np.ndarray) and k not in ("front", "lane_row", "shape_pos")},
    )  # fmt: skip
    speeds = np.concatenate([np.full(count, 30.0), np.arange(count) + 10.0])
    around = surroundings(agents, np.concatenate([fronts, cars]), speeds, np.arange(count), STRAIGHT)
    assert around.gap[:, 0] == pytest.approx(np.full(count, 3.0))
    assert list(around.other_speed[:, 0]) == list(np.arange(count) + 10.0)
    assert around.gap[1:, 1] == pytest.approx(np.full(count - 1, 7.0))
    assert list(around.other_speed[1:, 1]) == list(np.arange(count - 1) + 10.0)


def test_one_wider_neighbour_search_serves_the_lanes_and_the_shield_as_their_own_searches_do():
    rng = np.random.default_rng(5)
    count, cars = 40, 200
    x = rng.uniform(-480.0, 480.0, count + cars)
    lane = rng.integers(0, 3, count + cars)
    fronts = np.stack([x, (lane - 1) * 3.5 + rng.normal(0.0, 0.4, count + cars)], axis=1)
    speeds = rng.uniform(15.0, 35.0, count + cars)
    agents = one_agent(
        front=fronts[:count], lane_row=np.array([STRAIGHT.lane_index[f"e_{k}"] for k in lane[:count]]),
        shape_pos=x[:count] + 500.0, lane_number=lane[:count],
        **{k: np.repeat(v, count, axis=0) for k, v in vars(one_agent()).items()
           if isinstance(v, np.ndarray) and k not in ("front", "lane_row", "shape_pos", "lane_number")},
    )  # fmt: skip
    rows = np.arange(count)
    wide = neighbours(fronts[rows], fronts, 400.0, exclude=rows)
    alone = surroundings(agents, fronts, speeds, rows, STRAIGHT)
    shared = surroundings(agents, fronts, speeds, rows, STRAIGHT, wide)
    np.testing.assert_array_equal(alone.gap, shared.gap)
    np.testing.assert_array_equal(alone.other_speed, shared.other_speed)
    assert np.isfinite(alone.gap[:, 0]).sum() > count // 2  # most agents have a leader to find
    axis = np.zeros(count)
    own = shield_surroundings(fronts[rows], axis, fronts, rows, CarModel(), 120.0)
    given = shield_surroundings(fronts[rows], axis, fronts, rows, CarModel(), 120.0, wide)
    for name in ("side_room", "leader", "leader_gap"):
        np.testing.assert_array_equal(getattr(own, name), getattr(given, name))
    assert (own.leader >= 0).sum() > count // 2


def test_a_car_astride_two_lanes_blocks_both_and_missing_lanes_are_walls():
    road = lanes_along([(-500.0, 1.75), (500.0, 1.75)], lanes=2)  # lane 0's centre on y = 0
    agent = one_agent(
        lane_number=np.array([0]), lanes=np.array([2]), lane_row=np.array([road.lane_index["e_0"]])
    )
    positions = np.array([[0.0, 0.0], [30.0, 1.75]])  # centred on the line to the fast lane
    around = surroundings(agent, positions, np.array([30.0, 30.0]), np.array([0]), road)
    assert around.gap[0, 0] == pytest.approx(25.0) and around.gap[0, 2] == pytest.approx(25.0)
    assert around.gap[0, 4] == 0.0 and around.gap[0, 5] == 0.0  # no lane on the slow side
    obs = observe_lanes(agent, around)
    assert obs[0, TRAFFIC_SLICES["lanes_slow_side"]][0] == 0.0


def test_a_lane_pose_without_curvature_is_the_same_pose_with_the_curvature_left_out():
    kink = np.radians(12.5)
    road = lanes_along([(0.0, 0.0), (250.0, 0.0), (250.0 + 250.0 * np.cos(kink), 250.0 * np.sin(kink))])
    rows = np.array([road.lane_index[f"e_{k}"] for k in (0, 1, 2, 1)])
    at = np.array([10.0, 249.0, 251.0, 600.0])  # before, at and beyond the vertex, past the end
    full, light = road.lane_pose(rows, at), road.lane_pose(rows, at, with_curvature=False)
    for name in ("point", "angle", "pos", "length", "segment_start", "segment_end"):
        np.testing.assert_array_equal(getattr(light, name), getattr(full, name))
    assert np.isnan(light.curvature).all()  # left out, not a silent 0
    assert np.abs(full.curvature[1:]).min() > 1e-4  # the bend is there in the full pose


def test_a_car_in_the_own_lane_beyond_a_bend_of_the_polyline_is_the_leader_not_a_neighbour():
    # the bundled motorway's lanes turn 12.5 degrees at a vertex, 250 m apart: a smoothed road
    # heading put a car 40 m ahead in the own lane 2.4 m to the side, and the agent saw no leader
    kink = np.radians(12.5)
    centre = [(0.0, 0.0), (250.0, 0.0), (250.0 + 250.0 * np.cos(kink), 250.0 * np.sin(kink))]
    road = lanes_along(centre)
    middle = road.lane_index["e_1"]
    on_lane = lambda s, lane: road.lane_pose(np.array([road.lane_index[f"e_{lane}"]]), np.array([s])).point[0]  # noqa: E731
    agent = one_agent(
        front=on_lane(220.0, 1)[None, :], lane_row=np.array([middle]), shape_pos=np.array([220.0])
    )
    positions = np.stack([on_lane(220.0, 1), on_lane(320.0, 1), on_lane(300.0, 0), on_lane(150.0, 2)])
    around = surroundings(agent, positions, np.array([30.0, 20.0, 25.0, 35.0]), np.array([0]), road)
    assert around.gap[0, 0] == pytest.approx(100.0 - 5.0, abs=0.5) and around.other_speed[0, 0] == 20.0
    # in the next lanes, lane positions differ from the own lane's by the mitre at the vertex (0.4 m)
    assert around.gap[0, 4] == pytest.approx(80.0 - 5.0, abs=1.0)  # slow lane, beyond the vertex
    assert around.gap[0, 3] == pytest.approx(70.0 - 5.0, abs=1.0)  # fast lane, behind
    assert np.isinf(around.gap[0, 2])


def test_neighbours_beyond_the_end_of_a_curved_lane_stay_in_their_lanes():
    radius, arc_end = 300.0, np.pi / 6  # a 157 m arc; the neighbours are 60 m past its end
    phi = np.linspace(0.0, arc_end, 40)
    road = lanes_along([(radius * np.sin(p), radius - radius * np.cos(p)) for p in phi])
    agent_at = road.lane_pose(np.array([road.lane_index["e_1"]]), np.array([120.0])).point[0]
    agent = one_agent(
        front=agent_at[None, :], lane_row=np.array([road.lane_index["e_1"]]), shape_pos=np.array([120.0])
    )
    ahead = arc_end + 60.0 / radius  # the road goes on on the same circle
    same = [radius * np.sin(ahead), radius - radius * np.cos(ahead)]
    outer = [(radius + 3.5) * np.sin(ahead), radius - (radius + 3.5) * np.cos(ahead)]
    around = surroundings(
        agent, np.array([agent_at, same, outer]), np.array([30.0, 20.0, 25.0]), np.array([0]), road
    )
    expected = radius * arc_end + 60.0 - 120.0 - 5.0
    assert around.gap[0, 0] == pytest.approx(expected, abs=1.0)
    assert around.gap[0, 4] == pytest.approx(expected, abs=1.5)  # the outer lane is lane 0 here


def junction_road(via: list, lanes_after: int, lane_next: list[tuple[str, str]]) -> RoadGeometry:
    """Two 3.5 m lanes along +x to x = 300 (a_0, a_1), a 20 m junction of lanes `via`, and
    `lanes_after` lanes on to x = 800 (b_k), linked lane to lane by `lane_next`."""
    a = [(f"a_{k}", [(0.0, 3.5 * k), (300.0, 3.5 * k)], 3.5, 33.3, 300.0) for k in range(2)]
    b = [(f"b_{k}", [(320.0, 3.5 * k), (800.0, 3.5 * k)], 3.5, 33.3, 480.0) for k in range(lanes_after)]
    edges = [("a", a, True), (":j", via, False), ("b", b, True)]
    return build_geometry(edges, [("a", "b")], car_links=[("a", "b")], lane_next=lane_next)


def shifting_junction(linked: bool) -> RoadGeometry:
    """Two lanes on after the junction, the lane ahead of the left one (a_1) one lane further
    right: a_1 leads into b_0, as at a lane drop's merge."""
    via = [
        (":j_0", [(300.0, 3.5), (320.0, 0.0)], 3.5, 33.3, 20.3),
        (":j_1", [(300.0, 0.0), (320.0, 0.0)], 3.5, 33.3, 20.0),
    ]
    lane_next = [("a_1", ":j_0"), (":j_0", "b_0"), ("a_0", ":j_1"), (":j_1", "b_0")] if linked else []
    return junction_road(via, 2, lane_next)


@pytest.mark.parametrize("linked", [True, False])
def test_a_car_ahead_beyond_a_junction_is_placed_in_the_lane_its_own_lane_leads_into(linked):
    """The car 60 m into b_0 is in the lane a_1 leads into: the leader, not a car one lane over on
    the slow side, which is where the straight line from a_1's end puts it (and the car in b_1
    its leader)."""
    road = shifting_junction(linked)
    agent = one_agent(
        front=np.array([[250.0, 3.5]]), lane_row=np.array([road.lane_index["a_1"]]),
        shape_pos=np.array([250.0]), lane_number=np.array([1]), lanes=np.array([2]),
    )  # fmt: skip
    positions = np.array([[250.0, 3.5], [380.0, 0.0], [380.0, 3.5]])
    around = surroundings(agent, positions, np.array([30.0, 5.0, 30.0]), np.array([0]), road)
    through_junction = 50.0 + np.hypot(20.0, 3.5) + 60.0 - 5.0
    if linked:  # a_1's continuation leaves its line; a_0's goes on along it (the line serves there)
        departs = road.lane_next_departs(np.array([road.lane_index["a_1"], road.lane_index["a_0"]]))
        assert departs.tolist() == [True, False]
        assert around.gap[0, 0] == pytest.approx(through_junction, abs=0.5)
        assert around.other_speed[0, 0] == 5.0
        inside = one_agent(
            front=np.array([[310.0, 1.75]]), lane_row=np.array([road.lane_index[":j_0"]]),
            shape_pos=np.array([np.hypot(10.0, 1.75)]), lane_number=np.array([0]), lanes=np.array([1]),
        )  # fmt: skip
        positions[0] = (310.0, 1.75)
        around = surroundings(inside, positions, np.array([30.0, 5.0, 30.0]), np.array([0]), road)
        assert around.gap[0, 0] == pytest.approx(np.hypot(10.0, 1.75) + 60.0 - 5.0, abs=0.5)
        assert around.other_speed[0, 0] == 5.0
    else:
        assert around.other_speed[0, 0] == 30.0 and around.other_speed[0, 4] == 5.0


def widening_junction(linked: bool) -> RoadGeometry:
    """Three lanes on after the junction: a ramp's lane joins on the right (b_0), so a_0 leads into
    b_1 and a_1 into b_2, each one lane further left."""
    via = [(f":j_{k}", [(300.0, 3.5 * k), (320.0, 3.5 * (k + 1))], 3.5, 33.3, 20.3) for k in range(2)]
    lane_next = [("a_0", ":j_0"), (":j_0", "b_1"), ("a_1", ":j_1"), (":j_1", "b_2")] if linked else []
    return junction_road(via, 3, lane_next)


@pytest.mark.parametrize("linked", [True, False])
def test_a_car_behind_a_junction_is_placed_in_the_lane_it_leads_into(linked):
    """An agent 10 m into b_1; a fast car 30 m before the junction in a_1, which leads into b_2, the
    agent's fast-side lane: it is that lane's follower (the gap check then keeps the agent from moving
    out in front of it), not the agent's own lane's, where the straight line back from b_1's start
    puts it (on `motorway4` an agent took it for a car two lanes over and was run into)."""
    road = widening_junction(linked)
    agent = one_agent(
        front=np.array([[330.0, 3.5]]), lane_row=np.array([road.lane_index["b_1"]]),
        shape_pos=np.array([10.0]), lane_number=np.array([1]), lanes=np.array([3]), speed=np.array([7.0]),
    )  # fmt: skip
    positions = np.array([[330.0, 3.5], [270.0, 3.5]])
    around = surroundings(agent, positions, np.array([7.0, 28.0]), np.array([0]), road)
    if linked:
        departs = road.lane_prev_departs(np.array([road.lane_index["b_1"], road.lane_index["b_0"]]))
        assert departs.tolist() == [True, False]  # b_0 comes from no lane: nothing behind to follow
        through_junction = 10.0 + np.hypot(20.0, 3.5) + 30.0 - 5.0
        assert around.gap[0, 3] == pytest.approx(through_junction, abs=0.5)
        assert around.other_speed[0, 3] == 28.0
        assert around.gap[0, 1] == np.inf  # nobody behind in the own lane
        assert around.lane_follower_gap[0, 0] == pytest.approx(through_junction, abs=0.5)
    else:
        assert around.other_speed[0, 1] == 28.0 and np.isnan(around.other_speed[0, 3])


NO_LEADERS = (np.full((1, 6), np.inf), np.full((1, 6), np.nan))


MECHANICS = LaneDriving(rules=Rules.none())
"""The execution layer without the rules of the road: the policy's lane choice alone."""

DT = 0.2
"""s: the step `drive_lanes` drives at."""


def drive_lanes(
    steers,
    speed=30.0,
    lane_offset=0.0,
    lanes=3,
    lane=1,
    width=3.5,
    leaders=NO_LEADERS,
    lateral=MECHANICS,
    behaviour=None,
    far_fast_leader=None,
):
    """Run the traffic driver's actuation alone for one agent on a straight road with `lanes` lanes,
    keeping the books SUMO would (a car whose centre crosses a line is in the next lane, its offset
    jumps by a lane width); returns per step the lane, the offset in it, lateral speed and accel.
    `behaviour` ("keeper"/"overtaker"; None: no habits) drives with TrafficDriver's habits for it.
    Steps of DT seconds."""
    car, dt = CarModel(), DT
    state = dict(
        speed=np.array([speed]), lat=np.array([0.0]), acc=np.array([0.0]), changing=np.array([0]),
        held=np.array([0.0]),
    )  # fmt: skip
    offset, rows = np.array([lane_offset]), []
    for steer in steers:
        carriageway = (lane - (lanes - 1) / 2) * width + offset
        habits = None
        if behaviour is not None:
            flag = np.array([1.0 if behaviour == "overtaker" else 0.0])
            agent = one_agent(lane_number=np.array([lane]), lanes=np.array([lanes]), behaviour_id=flag)
            habits = TrafficDriver(lateral).habits(agent)
        out = actuate_lanes(
            np.array([[steer, 0.5, 0.0]]),
            Motion(
                state["speed"],
                np.array([speed]),
                state["lat"],
                state["acc"],
                state["changing"],
                held_for=state["held"],
            ),
            RoadPlace(
                offset,
                np.array([width]),
                np.array([lanes - 1 - lane]),
                np.array([lane]),
                carriageway,
                np.array([lanes * width / 2]),
                np.array([33.3]),
            ),
            LaneNeighbours(*leaders, far_fast_leader=far_fast_leader),
            DriverSettings(lateral, dt, car),
            AgentStyle(habits=habits),
        )
        a = out.actuation
        offset = offset + a.lateral_move
        if abs(offset[0]) > width / 2:  # SUMO moves the car to the next lane
            step = int(np.sign(offset[0]))
            lane, offset = lane + step, offset - step * width
        state = dict(
            speed=a.speed,
            lat=a.lateral_speed,
            acc=out.lateral_accel,
            changing=out.changing,
            held=out.held_for,
        )
        rows.append((lane, offset[0], a.lateral_speed[0], out.lateral_accel[0], out.changing[0], a.speed[0]))
    return np.array(rows)


def test_a_lane_change_is_a_smooth_commitment_to_the_neighbour_lane_centre():
    dt = DT
    run = drive_lanes([1.0] + [0.0] * 60)  # one step of full steer, then steer 0
    lane, offset, lat_speed, lat_accel = run[:, 0], run[:, 1], run[:, 2], run[:, 3]
    assert lane[-1] == 2 and abs(offset[-1]) < 0.02  # in the new lane, at its centre
    moving = np.flatnonzero(np.abs(lat_speed) > 0.05)
    duration = (moving[-1] - moving[0] + 1) * dt
    assert 4.0 <= duration <= 8.0  # recorded drivers: 5-6 s on average
    assert np.abs(lat_accel).max() <= LaneDriving().max_lateral_accel + 1e-9
    assert np.abs(np.diff(lat_accel)).max() / dt <= LaneDriving().max_lateral_jerk + 1e-9
    assert run[-1, 4] == 0  # the change is over
    assert np.all(np.diff(lane) >= 0) and lane.max() == 2  # one lane, never two


def test_steer_zero_centres_the_car_and_a_change_once_begun_goes_on():
    centring = drive_lanes([0.0] * 40, lane_offset=0.8)
    assert centring[0, 0] == 1 and abs(centring[-1, 1]) < 0.02
    assert np.abs(centring[:, 1]).max() <= 0.8 + 1e-9  # no overshoot across the centre line's far side
    committed = drive_lanes([1.0] + [-1.0] * 10 + [0.0] * 40)  # steering back does not call it off
    assert committed[-1, 0] == 2 and abs(committed[-1, 1]) < 0.02


def test_a_change_waits_for_a_gap_a_driver_would_take():
    lateral = MECHANICS
    speed, desired = np.full(4, 30.0), np.full(4, 30.0)
    gap, other = np.full((4, 6), np.inf), np.full((4, 6), np.nan)
    gap[1, 2:4] = 0.0  # a car alongside in the fast lane
    gap[2, 3], other[2, 3] = 8.0, 40.0  # a fast car 8 m behind in the fast lane, 10 m/s faster
    gap[3, 2], other[3, 2] = 60.0, 28.0  # the fast lane's leader 60 m ahead, a little slower
    fast_ok = gap_acceptable(lane_traffic(speed, desired, gap, other, lateral.following), lateral)[:, 0]
    assert fast_ok.tolist() == [True, False, False, True]
    car = CarModel()
    waiting = actuate_lanes(
        np.array([[1.0, 0.5, 0.0]]),
        Motion(speed[:1], desired[:1], np.zeros(1), np.zeros(1), np.array([0])),
        RoadPlace(
            np.zeros(1),
            np.array([3.5]),
            np.array([1]),
            np.array([1]),
            np.zeros(1),
            np.array([5.25]),
            np.array([33.3]),
        ),
        LaneNeighbours(gap[1:2], other[1:2]),
        DriverSettings(lateral, 0.2, car),
    )
    assert waiting.changing[0] == 0 and waiting.actuation.lateral_move[0] == 0.0


def test_a_slow_car_across_the_line_behind_does_not_hide_a_fast_one_in_the_lane():
    """The follower slot holds the nearest car whose body reaches into the lane: a slow car just over
    the line 18 m back. A car at 29 m/s 55 m back in that lane would be alongside within 5 s."""
    agent = one_agent(speed=np.array([11.0]), desired_speed=np.array([30.0]))
    positions = np.array([[0.0, 0.0], [-23.0, 1.0], [-60.0, 3.5]])  # the agent, the straddler, the fast car
    around = surroundings(agent, positions, np.array([11.0, 12.0, 29.0]), np.array([0]), STRAIGHT)
    assert around.gap[0, 3] == pytest.approx(18.0) and around.other_speed[0, 3] == 12.0  # the straddler
    assert around.lane_follower_gap[0, 0] == pytest.approx(55.0) and around.lane_follower_speed[0, 0] == 29.0
    ruled = LaneDriving()
    traffic = lane_traffic(agent.speed, agent.desired_speed, around.gap, around.other_speed, ruled.following)
    assert gap_acceptable(traffic, ruled)[0, 0]  # by the slots alone: room
    followers = (around.lane_follower_gap, around.lane_follower_speed)
    assert not gap_acceptable(traffic, ruled, lane_followers=followers)[0, 0]


@pytest.mark.parametrize(
    ("offset", "lateral_speed", "brakes"), [(1.26, 1.0, True), (0.3, 1.0, False), (1.26, -0.5, False)]
)
def test_a_car_reaching_over_a_line_keeps_behind_that_lanes_leader(offset, lateral_speed, brakes):
    """A change given up 0.5 m short of the line (steer 0, changing 0) leaves the car's body over it
    while its lateral speed comes down: it brakes for a car 3 m ahead in that lane, 4 m/s slower,
    though its own lane is free. Centred (0.3 m off), or moving back out of that lane (as a car that
    has just passed into the next lane beside a slower one), it does not."""
    car, ruled = CarModel(), LaneDriving()
    gap, other = np.full((1, 6), np.inf), np.full((1, 6), np.nan)
    gap[0, 0], other[0, 0] = 17.0, 20.8  # the own lane's leader, faster
    gap[0, 2], other[0, 2] = 3.1, 15.0  # the fast-side lane's leader, just put down there
    gap[0, 4:] = 0.0  # no slow-side lane
    out = actuate_lanes(
        np.array([[0.0, 0.5, 0.0]]),
        Motion(np.array([18.8]), np.array([30.0]), np.array([lateral_speed]), np.array([0.0]), np.array([0])),
        RoadPlace(
            np.array([offset]),
            np.array([3.5]),
            np.array([2]),
            np.array([0]),
            np.array([offset - 3.5]),
            np.array([5.25]),
            np.array([33.3]),
        ),
        LaneNeighbours(gap, other),
        DriverSettings(ruled, 0.2, car),
    )
    braking = (out.actuation.speed[0] - 18.8) / 0.2
    assert braking < -3.0 if brakes else braking > 0.0


def test_no_lane_change_towards_a_side_without_a_lane():
    run = drive_lanes([1.0] * 30, lane=2)  # already in the fast lane of three
    assert set(run[:, 4]) == {0} and np.abs(run[:, 1]).max() < 1e-9


def test_lateral_motion_is_limited_at_low_speed_and_at_the_border():
    slow = drive_lanes([1.0] * 5, speed=2.0)
    assert np.abs(slow[:, 2]).max() <= LaneDriving().max_slip * 2.0 + 1e-9
    car, lateral = CarModel(), MECHANICS
    edge = actuate_lanes(
        np.array([[0.0, 0.5, 0.0]]),
        Motion(np.array([30.0]), np.array([30.0]), np.array([1.2]), np.array([0.0]), np.array([0])),
        RoadPlace(
            np.array([-0.5]),
            np.array([3.5]),
            np.array([0]),
            np.array([2]),
            np.array([4.3]),
            np.array([5.25]),
            np.array([33.3]),
        ),
        LaneNeighbours(*NO_LEADERS),
        DriverSettings(lateral, 0.2, car),
    )
    assert edge.actuation.off_track[0]


def leaders_of(**cars):
    """NO_LEADERS with cars in NEIGHBOUR_SLOTS columns: name=(column, gap m, speed m/s)."""
    gap, other = np.full((1, 6), np.inf), np.full((1, 6), np.nan)
    for column, g, v in cars.values():
        gap[0, column], other[0, column] = g, v
    return gap, other


def test_rules_of_the_road_keep_right_where_the_slow_lane_is_free():
    ruled = LaneDriving()
    back = drive_lanes([0.0] * 60, lateral=ruled)  # middle lane, nobody anywhere, no wish
    assert back[-1, 0] == 0 and abs(back[-1, 1]) < 0.05  # moved over to the rightmost lane
    queue = leaders_of(slow_lead=(4, 30.0, 20.0))  # a slower car 30 m ahead in the slow lane
    stays = drive_lanes([0.0] * 60, lateral=ruled, leaders=queue)
    assert set(stays[:, 0]) == {1}
    closing = leaders_of(slow_follow=(5, 15.0, 36.0))  # someone coming up fast behind in the slow lane
    assert set(drive_lanes([0.0] * 5, lateral=ruled, leaders=closing)[:, 4]) == {0}


def test_rules_of_the_road_the_fast_lane_is_for_passing():
    ruled = LaneDriving()
    free = drive_lanes([1.0] * 10, lateral=ruled)  # a wish for the fast lane with nobody to pass
    assert set(free[:, 4]) <= {0, -1}  # no move to the fast side (it keeps right instead)
    held = leaders_of(lead=(0, 40.0, 22.0))  # held up: a leader 40 m ahead, 8 m/s slower than wanted
    passing = drive_lanes([1.0] * 3, lateral=ruled, leaders=held)
    assert passing[-1, 4] == 1  # the change to pass begins
    assert drive_lanes([1.0] * 3, leaders=held)[-1, 4] == 1  # without the rules too


def test_rules_of_the_road_no_passing_on_the_slow_side_at_speed():
    ruled, car = LaneDriving(), CarModel()
    fast_lane_leader = leaders_of(fast_lead=(2, 10.0, 25.0))  # 10 m ahead in the fast lane, 5 m/s slower
    gap, other = fast_lane_leader
    args = (
        Motion(np.array([30.0]), np.array([30.0]), np.zeros(1), np.zeros(1), np.array([0])),
        RoadPlace(np.zeros(1), np.array([3.5]), np.array([1]), np.array([1]), np.zeros(1), np.array([5.25]),
                  np.array([33.3])),
        LaneNeighbours(gap, other),
    )  # fmt: skip
    steer_none = np.array([[0.0, 0.5, 0.0]])
    ruled_speed = actuate_lanes(steer_none, *args, DriverSettings(ruled, 0.2, car)).actuation.speed[0]
    free_speed = actuate_lanes(steer_none, *args, DriverSettings(MECHANICS, 0.2, car)).actuation.speed[0]
    assert ruled_speed < 30.0 - 0.2 and free_speed >= 30.0 - 1e-9  # it brakes not to pass on the right
    other[0, 2] = 12.0  # the fast lane crawls (below 60 km/h): passing on the right is allowed
    crawl = actuate_lanes(steer_none, *args, DriverSettings(ruled, 0.2, car)).actuation.speed[0]
    assert crawl >= 30.0 - 1e-9


def test_a_change_is_given_up_for_a_car_that_comes_alongside():
    ruled = LaneDriving()
    held = leaders_of(lead=(0, 40.0, 22.0))
    start = drive_lanes([1.0] * 3, lateral=ruled, leaders=held)
    assert start[-1, 4] == 1
    gap, other = held
    gap[0, 3] = 0.0  # a car has come up alongside in the fast lane
    given_up = drive_lanes([1.0] * 3, lateral=ruled, leaders=(gap, other))
    assert set(given_up[:, 4]) == {0}


def test_a_slow_side_lane_is_free_only_where_its_leader_would_not_hold_the_car_up_again():
    ruled = LaneDriving()
    speed, desired = np.array([22.0]), np.array([27.0])  # slowed down behind a 23 m/s car

    def free(gap: float) -> bool:
        traffic = lane_traffic(speed, desired, *leaders_of(slow_lead=(4, gap, 23.0)), ruled.following)
        return bool(slow_side_free(traffic, ruled)[0])

    reach = float(look_ahead(speed, ruled)[0])
    assert not free(reach + 10.0)  # beyond the look-ahead, but caught up with at the speed it wants
    assert free(reach + ruled.keep_right_catch_up_s * (27.0 - 23.0) + 5.0)


def test_a_change_goes_on_to_the_next_lane_in_one_move_while_the_wish_holds():
    run = drive_lanes([1.0] * 60, lane=0)  # the policy's wish alone, from the rightmost of three lanes
    first, arrived = np.flatnonzero(run[:, 4] == 1)[0], np.flatnonzero(run[:, 0] == 2)[0]
    assert (run[first:arrived, 4] == 1).all()  # no step back to "no change" on the way
    assert np.abs(np.diff(run[first:arrived, 3])).max() <= LaneDriving().max_lateral_jerk * 0.2 + 1e-9


def test_a_change_leaves_the_new_follower_a_second_and_a_merging_car_half_that():
    ruled = LaneDriving()
    speed, desired = np.full(3, 25.0), np.full(3, 25.0)
    gap, other = np.full((3, 6), np.inf), np.full((3, 6), np.nan)
    gap[:, 3], other[:, 3] = [22.0, 32.0, 22.0], 25.0  # the fast lane's follower, as fast: 0.9 s, 1.3 s
    merging = np.array([[False, False], [False, False], [True, False]])
    ok = gap_acceptable(lane_traffic(speed, desired, gap, other, ruled.following), ruled, merging)[:, 0]
    assert ok.tolist() == [False, True, True]


def test_sumo_takes_a_car_over_the_line_of_an_ending_lane_unless_it_is_moving_away_from_it():
    # the slow-side lane ends 100 m on, the own and fast lanes lead on; the body 0.3 m over its line
    ends = LaneEnds(np.array([[2000.0, 2000.0, 100.0]]), np.array([2000.0]), np.array([np.inf]))

    def taken(lateral_speed: float | None) -> bool:
        speed = None if lateral_speed is None else np.array([lateral_speed])
        place = LanePlace(
            np.zeros(1), np.array([-1.15]), np.array([1]), np.array([3]), np.array([0.85]), speed
        )
        return bool(straddling_an_ending_lane(ends, place, np.array([250.0]))[0])

    assert taken(None) and taken(0.0) and taken(-0.3)  # holding there, or drifting towards it
    assert not taken(0.4)  # just out of it, on its way to the own lane's centre


def test_a_standing_car_edges_sideways_into_a_gap():
    ruled = LaneDriving()
    out = actuate_lanes(
        np.array([[0.0, 0.5, 0.0]]),
        Motion(np.zeros(1), np.array([30.0]), np.zeros(1), np.zeros(1), np.array([1])),
        RoadPlace(
            np.zeros(1),
            np.array([3.5]),
            np.array([1]),
            np.array([1]),
            np.zeros(1),
            np.array([5.25]),
            np.array([33.3]),
        ),
        LaneNeighbours(*NO_LEADERS),
        DriverSettings(ruled, 0.2),
    )
    assert 0.0 < out.actuation.lateral_speed[0] <= ruled.crawl_lateral_speed


def test_a_car_ahead_in_a_lane_that_ends_is_let_in_and_one_alongside_is_passed_unless_it_asks():
    ruled = LaneDriving()
    ends = np.array([[2000.0, 2000.0, 120.0]])  # the slow-side lane ends 120 m on, the own lane leads on
    speed, desired = np.array([20.0]), np.array([30.0])

    def let_in(leaders, lane_ends=ends) -> float:
        return float(letting_in(lane_traffic(speed, desired, *leaders, ruled.following), lane_ends, ruled)[0])

    merging = leaders_of(slow_lead=(4, 30.0, 15.0))  # 30 m ahead, slower, in the lane that ends
    assert -ruled.following.comfortable_decel <= let_in(merging) < -0.5  # it drops back, gently
    assert let_in(leaders_of(slow_lead=(4, 1.0, 20.0))) == np.inf  # alongside: too near to leave it a gap
    assert let_in(leaders_of(slow_lead=(4, 20.0, 0.0))) == np.inf  # standing 20 m on: no braking in time
    no_room = leaders_of(lead=(0, 33.0, 20.0), slow_lead=(4, 30.0, 20.0))  # it would not fit in front
    assert let_in(no_room) == np.inf
    leads_on = np.array([[2000.0, 2000.0, 2000.0]])
    assert let_in(merging, leads_on) == np.inf  # the lane leads on: nobody merges
    asks = np.array([[False, True]])  # ... unless the car there asks to come over (bound for an exit)
    asked = letting_in(lane_traffic(speed, desired, *merging, ruled.following), leads_on, ruled, asks)[0]
    assert asked == pytest.approx(let_in(merging))
    # one alongside, its front ahead, that asks: dropped back for, gently, unless the car closes on it
    alongside = leaders_of(slow_lead=(4, 0.0, 20.0))
    assert let_in(alongside) == np.inf  # its lane ends, but it does not ask: the next car back lets it in
    beside = letting_in(lane_traffic(speed, desired, *alongside, ruled.following), leads_on, ruled, asks)[0]
    assert beside == pytest.approx(-ruled.following.comfortable_decel)
    faster = lane_traffic(np.array([23.0]), desired, *alongside, ruled.following)  # it passes, 3 m/s faster,
    assert letting_in(faster, leads_on, ruled, asks)[0] == np.inf  # and the car behind lets it in
    # one standing at the end of its lane 5 m ahead with its body over the line, the same car in both
    # slots: the agent creeping up stops with the courtesy's room, more than following it leaves (at
    # the standing gap SUMO's driver found no room to finish its change, and both stood for minutes)
    creeping, over_the_line = np.array([2.0]), leaders_of(lead=(0, 5.0, 0.0), slow_lead=(4, 5.0, 0.0))
    traffic = lane_traffic(creeping, desired, *over_the_line, ruled.following)
    assert letting_in(traffic, leads_on, ruled, asks)[0] < min(traffic.lead_accel[0, 0], 0.0)
    slow_to_stop = np.array([3.0])  # at walking pace in a queue, a standing car 6 m on is let in
    standing = leaders_of(slow_lead=(4, 6.0, 0.0))
    queued = letting_in(lane_traffic(slow_to_stop, desired, *standing, ruled.following), ends, ruled)
    assert -ruled.safe_decel <= queued[0] < -0.5


def test_a_car_whose_lane_ends_falls_in_behind_the_car_beside_it_and_moves_out_600_m_ahead():
    ruled = LaneDriving()
    speed, desired = np.array([25.0]), np.array([30.0])
    beside = leaders_of(fast_lead=(2, 7.0, 25.0), fast_follow=(3, 11.0, 25.5))  # no gap: a platoon
    to_fast = np.array([1])
    brake = falling_in(lane_traffic(speed, desired, *beside, ruled.following), to_fast, ruled)
    assert -ruled.safe_decel <= brake[0] < -0.5  # drops back behind the car ahead in the target lane
    assert (
        falling_in(lane_traffic(speed, desired, *beside, ruled.following), np.array([0]), ruled)[0] == np.inf
    )  # not waiting
    assert (
        falling_in(lane_traffic(speed, desired, *NO_LEADERS, ruled.following), to_fast, ruled)[0] == np.inf
    )  # nobody there

    def change_begins(leads_on: float, leaders=NO_LEADERS) -> tuple[int, float]:
        out = actuate_lanes(
            np.array([[0.0, 0.5, 0.0]]),
            Motion(speed, desired, np.zeros(1), np.zeros(1), np.zeros(1, int)),
            RoadPlace(
                np.zeros(1),
                np.array([3.5]),
                np.array([2]),
                np.array([0]),
                np.array([-3.5]),
                np.array([5.25]),
                np.array([33.3]),
                lane_leads_on=np.array([[leads_on, np.inf, -1.0]]),
            ),
            LaneNeighbours(*leaders),
            DriverSettings(ruled, 0.2),
        )
        return int(out.changing[0]), float(out.actuation.speed[0])

    assert change_begins(550.0)[0] == 1  # the own lane ends 550 m on: over to the fast side
    assert change_begins(np.inf)[0] == 0  # it leads on: the rightmost lane is kept
    waits, slower = change_begins(500.0, beside)
    assert waits == 0 and slower < 25.0 - 0.4  # no gap yet: it waits, falling back to make one


def test_no_lane_change_begins_inside_a_junction_but_one_under_way_goes_on():
    ruled = LaneDriving()
    steer, lanes = np.array([1.0, 1.0]), np.array([1, 1])
    changing, offset, width = np.array([0, 1]), np.array([0.0, 0.5]), np.array([3.5, 3.5])
    ok = np.ones((2, 2), bool)
    free = np.zeros(2, bool)

    def heading(may_begin: np.ndarray | None) -> np.ndarray:
        place = RoadPlace(
            offset, width, lanes, lanes, offset, np.full(2, 5.25), np.full(2, 33.3), may_begin=may_begin
        )
        wish = lane_wish(LaneWishes(steer, free, np.ones(2, bool), np.zeros(2)), place, ruled, None)
        return lane_intent(wish, changing, place, ok, None, ruled)

    open_road, junction = heading(None), heading(np.zeros(2, bool))
    assert open_road.tolist() == [1, 1] and junction.tolist() == [0, 1]


def test_car_following_settles_at_a_human_headway_and_stops_behind_a_standing_car():
    law = CarFollowing()
    speed = np.array([25.0])
    gap = np.array([25.0 * law.time_headway + law.min_gap])
    at_rest = following_accel(speed, np.array([1e6]), gap, speed, law)
    assert abs(at_rest[0]) < 0.05  # following a leader at its speed and the law's headway: no pull
    v, g, dt = 20.0, 120.0, 0.1
    for _ in range(600):  # a standing car 120 m ahead
        a = following_accel(np.array([v]), np.array([30.0]), np.array([g]), np.array([0.0]), law)[0]
        a = max(a, -CarModel().max_brake)
        v = max(v + a * dt, 0.0)
        g -= v * dt
    assert v < 0.05 and law.min_gap - 0.5 < g < law.min_gap + 1.0  # stands a few metres behind it


def traffic_step(**over) -> TrafficStep:
    n = 2
    base = dict(
        speed=np.full(n, 30.0),
        desired_speed=np.full(n, 30.0),
        acceleration=np.zeros(n),
        lateral_acceleration=np.zeros(n),
        lane_deviation=np.zeros(n),
        lane_changed=np.zeros(n, bool),
        behaviour_id=np.array([0.0, 1.0]),
        gap=np.full((n, 6), np.inf),
        other_speed=np.full((n, 6), np.nan),
        collided=np.zeros(n, bool),
        off_track=np.zeros(n, bool),
        no_progress=np.zeros(n, bool),
    )
    base.update(over)
    return TrafficStep(**base)


def test_free_road_at_the_desired_speed_is_the_best_step():
    gap = np.full((2, 6), np.inf)
    gap[:, 4:6] = 0.0  # in the slowest lane
    terms = traffic_rewards(traffic_step(gap=gap), TrafficWeights())
    assert terms.total == pytest.approx([1.0, 1.0])


def test_keeping_up_with_a_slower_car_costs_nothing_and_hanging_back_costs_both_behaviours():
    """The leader's speed is the target while it is nearer than 3 m + 1.3 s x speed (the law keeps
    2.5 m + 1.2 s): following it there costs neither behaviour (passing is the lane habits'); hanging
    back costs as much as driving slower than wanted on a free road (fine-tunes learnt to hang back
    when it cost nothing)."""
    gap = np.full((2, 6), np.inf)
    gap[:, 0] = 28.0  # 1.4 s behind a car at 20 m/s: within 3 m + 1.3 s x 20 m/s = 29 m
    other = np.full((2, 6), np.nan)
    other[:, 0] = 20.0
    terms = traffic_rewards(
        traffic_step(speed=np.full(2, 20.0), gap=gap, other_speed=other), TrafficWeights()
    ).as_dict()
    assert terms["speed"] == pytest.approx([1.0, 1.0])  # keeper, overtaker: the lane allows 20 m/s
    assert terms["headway"] == pytest.approx([0.0, 0.0]) and terms["closing"] == pytest.approx([0.0, 0.0])
    gap[:, 0] = 60.0  # 3 s behind it: both are asked to close up to a human headway
    far = traffic_rewards(traffic_step(speed=np.full(2, 20.0), gap=gap, other_speed=other), TrafficWeights())
    assert far.as_dict()["speed"] == pytest.approx([1 - 10 / 30, 1 - 10 / 30])  # both want 30 m/s


def test_short_headway_closing_in_lane_changes_and_passing_on_the_slow_side_cost():
    w = TrafficWeights()
    gap = np.full((2, 6), np.inf)
    other = np.full((2, 6), np.nan)
    gap[:, 0], other[:, 0] = 15.0, 25.0  # 0.5 s behind, closing at 5 m/s: TTC 3 s
    gap[:, 2], other[:, 2] = 5.0, 20.0  # a slower car just ahead in the fast-side lane
    terms = traffic_rewards(
        traffic_step(gap=gap, other_speed=other, lane_changed=np.array([True, True])), w
    ).as_dict()
    safe_gap = w.standstill_gap + w.safe_headway * 30.0
    assert terms["headway"] == pytest.approx(-w.headway * (1 - 15.0 / safe_gap))
    queue = np.full((2, 6), np.inf)
    queue[:, 0] = 3.0  # standing 3 m behind a standing car: a queue, not tailgating
    still = traffic_step(speed=np.zeros(2), gap=queue, other_speed=np.where(np.isinf(queue), np.nan, 0.0))
    assert traffic_rewards(still, w).as_dict()["headway"] == pytest.approx([0.0, 0.0])
    assert terms["closing"] == pytest.approx(-w.closing * (4 - 3) / 4)
    assert terms["lane_change"] == pytest.approx([-w.lane_change_keeper, -w.lane_change_overtaker])
    assert terms["pass_slow_side"] == pytest.approx(-w.pass_slow_side * 10 / 5 / 2)


def test_an_overtaker_with_a_free_slow_lane_is_asked_to_keep_to_it():
    gap = np.full((2, 6), np.inf)
    terms = traffic_rewards(traffic_step(gap=gap), TrafficWeights()).as_dict()
    assert terms["keep_slow_side"] == pytest.approx([0.0, -TrafficWeights().keep_slow_side])
    walled = gap.copy()
    walled[:, 4:6] = 0.0  # already in the slowest lane
    terms = traffic_rewards(traffic_step(gap=walled), TrafficWeights()).as_dict()
    assert terms["keep_slow_side"] == pytest.approx([0.0, 0.0])


@pytest.mark.sumo
def test_traffic_env_runs_an_episode_among_sumo_cars():
    env = make_env("ring", behaviour="multi", overtakers=2, keepers=2, driver="traffic", seed=3, max_steps=40)
    try:
        obs = env.reset_arrays(seed=3)
        assert obs.shape[1] == TRAFFIC_OBS_SIZE and 1 <= len(obs) <= 4
        assert len(env.sim.vehicle_ids()) > len(obs)  # SUMO's own cars are on the road
        steps = 0
        while env.agents:
            batch = env.step_arrays(np.tile([0.0, 0.3, 0.0], (len(env.agents), 1)).astype(np.float32))
            assert np.isfinite(batch.reward).all() and np.isfinite(batch.next_obs).all()
            steps += 1
        assert steps == 40 or batch.terminated.any()
        first = env.reset_arrays(seed=3)
        np.testing.assert_array_equal(first, obs)  # one seed, one episode
    finally:
        env.close()


def test_queue_places_fit_the_edge_head_first_with_at_least_sumos_gap_between_cars():
    rng = np.random.default_rng(0)
    car, min_gap = 5.0, 2.5
    for length in (30.0, 120.0, 600.0):
        for _ in range(50):
            fronts = queue_places(length, car, min_gap, rng)
            assert (fronts >= car + 0.5).all() and (fronts <= length - 1.0).all()
            gaps = -np.diff(fronts) - car  # rear of one car to the front of the next behind it
            assert (gaps >= min_gap + CRAWL_GAP[0]).all() and (gaps <= min_gap + CRAWL_GAP[1]).all()
            assert len(fronts) <= CRAWL_CARS[1]
    assert max(len(queue_places(600.0, car, min_gap, rng)) for _ in range(50)) == CRAWL_CARS[1]


@pytest.mark.sumo
def test_roads_with_queues_have_a_queue_crawling_in_the_slow_lane_while_the_others_flow(monkeypatch):
    monkeypatch.setattr(traffic_env, "CRAWL_EPISODES", 1.0)  # a queue in every episode
    env = make_env("roads+queues", behaviour="multi", overtakers=2, keepers=2, driver="traffic", seed=1,
                   max_steps=25)  # fmt: skip
    try:
        env.reset_arrays(seed=1)
        sim = env.sim
        for _ in range(25):
            if not env.agents:
                break
            env.step_arrays(np.tile([0.0, 0.3, 0.0], (len(env.agents), 1)).astype(np.float32))
        vehicles = sim.read_vehicles()
        queue = np.array([vid.startswith("queue_") for vid in vehicles.ids])
        limit = max(edge.speed for edge in env.geometry.edges.values())
        assert queue.sum() >= CRAWL_CARS[0] - 1  # all but perhaps one behind a SUMO car
        assert (vehicles.speed[queue] <= CRAWL_SPEED[1] * limit + 1.0).all()
        assert {sim._sumo.vehicle.getLaneIndex(vid) for vid in np.array(vehicles.ids)[queue]} == {0}
        assert np.median(vehicles.speed[~queue]) > 2 * CRAWL_SPEED[1] * limit  # the other lanes flow
    finally:
        env.close()


def test_the_cars_stopped_are_the_nearest_ahead_in_each_lane_of_the_own_edge():
    lanes = ["e1_0", "e1_1", "e1_1", "e1_2", "e2_0", "e1_0", "e1_2"]
    pos = np.array([150.0, 140.0, 120.0, 90.0, 130.0, 300.0, 105.0])
    # own place e1 at 100 m: e1_0's car at 150, e1_1's nearer one at 120; e1_2's at 105 is too near,
    # the one at 90 behind; e2 is another edge and e1_0's car at 300 beyond reach
    assert traffic_env.cars_ahead_per_lane(lanes, pos, "e1_1", 100.0, (10.0, 150.0)) == [0, 2]


@pytest.mark.sumo
def test_stop_and_go_episodes_stop_the_traffic_ahead_of_an_agent_and_let_it_move_on(monkeypatch):
    monkeypatch.setattr(traffic_env, "STOP_EPISODES", 1.0)
    monkeypatch.setattr(traffic_env, "STOP_AFTER_S", (1.0, 1.0))
    monkeypatch.setattr(traffic_env, "STOP_FOR_S", (12.0, 12.0))
    env = make_env("ring", behaviour="multi", overtakers=2, keepers=2, driver="traffic", seed=2,
                   max_steps=120, traffic_density=(25.0, 25.0))  # fmt: skip
    try:
        env.reset_arrays(seed=2)
        event = env.stop_and_go
        assert event is not None and (event.stop, event.go) == (5, 65)
        stopped, speeds = [], {}
        for step in range(1, 100):
            if not env.agents:
                break
            env.step_arrays(np.tile([0.0, 0.5, 0.0], (len(env.agents), 1)).astype(np.float32))
            stopped = stopped or list(env.stopped)
            if step in (60, 99):
                vehicles = env.sim.read_vehicles()
                speeds[step] = [vehicles.speed[vehicles.row[v]] for v in stopped if v in vehicles.row]
        assert len(speeds[60]) >= 2 and max(speeds[60]) < 0.1  # the traffic ahead stands
        assert min(speeds[99]) > 3.0 and env.stopped == []  # and has moved on
    finally:
        env.close()


@pytest.mark.sumo
@pytest.mark.parametrize("name", ["motorway3_lefthand", "carriageway2"])
def test_lanes_and_lane_places_derived_from_positions_are_sumos_own(tmp_path, monkeypatch, name):
    """Agents still well inside last step's lane get their lane, lane position and lateral offset
    by projection, not from SUMO: on a curved left-hand net and on 3.2 m lanes the lane is SUMO's
    in every step and the places equal SUMO's to the millimetre."""
    derive = Fleet._read_lanes
    worst, asked = [0.0, 0.0], []

    def checked(self, sim, vehicles, rows):
        lanes, places = [], []
        read_lanes, read_places = sim.read_lanes, sim.read_lane_places
        monkeypatch.setattr(sim, "read_lanes", lambda ids: lanes.append(len(ids)) or read_lanes(ids))
        monkeypatch.setattr(sim, "read_lane_places", lambda ids: places.append(len(ids)) or read_places(ids))
        readings, lane_rows, entered = derive(self, sim, vehicles, rows)
        monkeypatch.setattr(sim, "read_lanes", read_lanes)
        monkeypatch.setattr(sim, "read_lane_places", read_places)
        truth = sim.read_agents(self.rows.ids)
        assert readings.lane_id == truth.lane_id
        worst[0] = max(worst[0], float(np.abs(truth.lane_pos - readings.lane_pos).max(initial=0.0)))
        worst[1] = max(worst[1], float(np.abs(truth.lateral_pos - readings.lateral_pos).max(initial=0.0)))
        asked.append((sum(lanes), sum(places), len(rows)))
        return readings, lane_rows, entered

    monkeypatch.setattr(Fleet, "_read_lanes", checked)
    net = build_osm_like(name, tmp_path / name)
    populate(config_from(net.sumocfg, share=0.5, seed=1, duration=40.0, fcd=tmp_path / "f.xml"))
    assert worst[0] < 0.01 and worst[1] < 0.001, worst
    lanes_read, places_read, agent_steps = np.sum(asked, axis=0)
    assert agent_steps > 1000  # SUMO asked for a few, not all:
    assert lanes_read < 0.1 * agent_steps and places_read < 0.1 * agent_steps, (lanes_read, places_read)


def exit_net(tmp: Path) -> Path:
    """A 3-lane motorway whose rightmost lane becomes an exit: the main road goes on with 2 lanes."""
    (tmp / "x.nod.xml").write_text(
        '<nodes><node id="n0" x="0" y="0"/><node id="n1" x="800" y="0"/>'
        '<node id="n2" x="1600" y="0"/><node id="n3" x="1000" y="-80"/></nodes>'
    )
    (tmp / "x.edg.xml").write_text(
        '<edges><edge id="A" from="n0" to="n1" numLanes="3" speed="33.33" width="3.5"/>'
        '<edge id="B" from="n1" to="n2" numLanes="2" speed="33.33" width="3.5"/>'
        '<edge id="X" from="n1" to="n3" numLanes="1" speed="22.22" width="3.5"/></edges>'
    )
    (tmp / "x.con.xml").write_text(
        '<connections><connection from="A" to="X" fromLane="0" toLane="0"/>'
        '<connection from="A" to="B" fromLane="1" toLane="0"/>'
        '<connection from="A" to="B" fromLane="2" toLane="1"/></connections>'
    )
    net = tmp / "x.net.xml"
    subprocess.run(
        [sumo_binary("netconvert"), "-n", str(tmp / "x.nod.xml"), "-e", str(tmp / "x.edg.xml"),
         "-x", str(tmp / "x.con.xml"), "-o", str(net), "--no-turnarounds"],
        check=True, capture_output=True,
    )  # fmt: skip
    return net


@contextlib.contextmanager
def keeper_on(
    net: Path, edges: list[str], *, lane: int, pos: float, speed: float, rules: bool = True
) -> Iterator[tuple[SumoSim, Fleet]]:
    """SUMO on `net` with one keeper, "agent", on the route `edges`, driven by a traffic-driver Fleet
    (`rules`: with the rules of the road, or the policy's lane choice alone)."""
    driver = make_driver("traffic") if rules else TrafficDriver(MECHANICS)
    fleet = Fleet(load_geometry(net), CarModel(), 0.2, PhaseTimer(), driver)
    options = SimOptions(net=net, additional=(get_scenario("tiny").vtypes,), step_length=0.2)
    with SumoSim(options) as sim:
        sim.add_route("route", edges)
        sim.add_vehicle("agent", "route", "behave_keeper", lane=lane, pos=pos, speed=speed)
        sim.step()
        sim.take_control(["agent"])
        fleet.add(["agent"], np.array([speed]), np.array([0.0]), fixed_styles(np.array([0.8])))
        yield sim, fleet


def drive_on(sim: SumoSim, fleet: Fleet, steps: int = 600) -> tuple[list[str], float]:
    """Drive the keeper with steer 0 and the law's speed until it leaves (or `steps`): the lanes it
    was in, step by step, and its lowest speed."""
    lanes, lowest_speed = [], 99.0
    while "agent" in sim.vehicle_ids() and len(lanes) < steps:
        lanes.append(sim.read_agents(["agent"]).lane_id[0])
        fleet.sense(sim, sim.read_vehicles(), True)
        fleet.act(sim, np.array([[0.0, 0.5, 0.0]], np.float32))
        sim.step()
        if "agent" in sim.vehicle_ids():
            lowest_speed = min(lowest_speed, float(sim.read_speeds(["agent"])[0]))
    return lanes, lowest_speed


@pytest.mark.sumo
def test_sumo_takes_an_agent_whose_lane_becomes_an_exit_and_hands_it_back(tmp_path):
    """Without the handover SUMO stops the agent dead where lane 0 turns off its route."""
    net = exit_net(tmp_path)
    with keeper_on(net, ["A", "B"], lane=0, pos=50.0, speed=25.0, rules=False) as (sim, fleet):
        handed_at_some_point, lowest_speed, steps = False, 99.0, 0
        while "agent" in sim.vehicle_ids() and steps < 600:
            fleet.sense(sim, sim.read_vehicles(), True)
            handed_at_some_point |= bool(fleet.rows.handed[0])
            fleet.act(sim, np.array([[0.0, 0.5, 0.0]], np.float32))
            sim.step()
            steps += 1
            if "agent" in sim.vehicle_ids():
                lowest_speed = min(lowest_speed, float(sim.read_speeds(["agent"])[0]))
        assert handed_at_some_point and fleet.handovers == 1
        assert "agent" not in sim.vehicle_ids()  # it reached the end of B
        assert lowest_speed > 15.0  # never stopped at the end of the exit lane


@pytest.mark.sumo
def test_with_the_rules_of_the_road_an_agent_leaves_a_lane_that_ends_by_itself(tmp_path):
    with keeper_on(exit_net(tmp_path), ["A", "B"], lane=0, pos=50.0, speed=25.0) as (sim, fleet):
        lanes, lowest_speed = drive_on(sim, fleet)
        assert fleet.handovers == 0 and "A_1" in lanes  # moved over before SUMO had to take it
        assert "agent" not in sim.vehicle_ids() and lowest_speed > 15.0


@pytest.mark.sumo
def test_sumo_chooses_the_speed_of_an_agent_it_took(tmp_path):
    """The agent's last commanded speed must not stick: SUMO drives a handed-over car as its own."""
    net = exit_net(tmp_path)
    with keeper_on(net, ["A", "B"], lane=0, pos=50.0, speed=12.0, rules=False) as (sim, fleet):
        speeds_while_handed = []
        while "agent" in sim.vehicle_ids() and len(speeds_while_handed) < 50:
            fleet.sense(sim, sim.read_vehicles(), True)
            fleet.act(sim, np.array([[0.0, 0.0, 0.0]], np.float32))  # hold 12 m/s while it drives
            sim.step()
            if fleet.rows.handed[0]:
                speeds_while_handed.append(float(sim.read_speeds(["agent"])[0]))
        assert speeds_while_handed and max(speeds_while_handed) > 15.0


@pytest.mark.sumo
def test_an_agent_leaving_by_a_one_lane_ramp_is_handed_over_before_it_and_not_given_back(tmp_path):
    """Its lane leads on to the ramp, so only the ramp's single lane told SUMO to take it, at the
    junction; and a car given back on a lane that soon leaves the carriageway drifted off it."""
    net = exit_net(tmp_path)
    with keeper_on(net, ["A", "X"], lane=0, pos=50.0, speed=25.0) as (sim, fleet):
        handed_on = []
        while "agent" in sim.vehicle_ids() and len(handed_on) < 400:
            lane = sim.read_agents(["agent"]).lane_id[0]
            fleet.sense(sim, sim.read_vehicles(), True)
            handed_on.append((lane, bool(fleet.rows.handed[0])))
            fleet.act(sim, np.array([[0.0, 0.5, 0.0]], np.float32))
            sim.step()
        first = next(k for k, (_, handed) in enumerate(handed_on) if handed)
        assert handed_on[first][0] == "A_0"  # before the ramp
        assert all(handed for _, handed in handed_on[first:])  # and SUMO keeps it to the end
        assert fleet.handovers == 1


@pytest.mark.sumo
def test_an_agent_reaching_over_a_lane_that_drops_is_centred_by_sumo_and_stays_on_the_road(tmp_path):
    """On a 3 -> 2 lane drop a keeper held its centre 1 m towards the ending lane; where the lane
    dropped the road narrowed under it and it was off-track (the losses of the OSM-like nets)."""
    built = build_osm_like("lanedrop", tmp_path)  # m0's lane 0 ends where m1 begins
    with keeper_on(built.net, ["m0", "m1", "m2"], lane=1, pos=700.0, speed=25.0, rules=False) as (sim, fleet):
        handed, off_track, lanes = False, False, set()
        for _ in range(150):  # 30 s: through the drop at 1096 m
            readings = sim.read_agents(["agent"])
            lanes.add(readings.lane_id[0])
            fleet.sense(sim, sim.read_vehicles(), True)
            handed |= bool(fleet.rows.handed[0])
            leaning = readings.lane_id[0] == "m0_1" and readings.lateral_pos[0] > -1.0
            steer = -1.0 if leaning else 0.0  # change into the ending lane whenever in the other
            off_track |= bool(fleet.act(sim, np.array([[steer, 0.5, 0.0]], np.float32)).off_track[0])
            sim.step()
        assert "m1_0" in lanes or "m1_1" in lanes  # it got through the drop
        assert handed and not off_track


@pytest.mark.sumo
@pytest.mark.parametrize("lefthand", [False, True])
def test_the_fast_side_is_the_higher_lane_index_in_right_and_left_hand_nets(tmp_path, lefthand):
    """A car in lane 2 beside an agent in lane 1 is on the agent's fast side in both kinds of net."""
    net = tmp_path / "h.net.xml"
    cmd = [sumo_binary("netconvert"), "-s", str(get_scenario("highway").net), "-o", str(net)]
    subprocess.run(cmd + (["--lefthand"] if lefthand else []), check=True, capture_output=True)
    geometry = load_geometry(net)
    assert geometry.lefthand == lefthand
    fleet = Fleet(geometry, CarModel(), 0.2, PhaseTimer(), make_driver("traffic"))
    options = SimOptions(net=net, additional=(get_scenario("highway").vtypes,), step_length=0.2)
    with SumoSim(options) as sim:
        sim.add_route("main", ["e0", "e1"])
        sim.add_vehicle("agent", "main", "behave_keeper", lane=1, pos=100.0, speed=20.0)
        sim.add_vehicle("beside", "main", "behave_passive", lane=2, pos=102.0, speed=20.0)
        sim.step()
        sim.take_control(["agent"])
        fleet.add(["agent"], np.array([20.0]), np.array([1.0]), fixed_styles(np.array([0.9])))
        obs = fleet.sense(sim, sim.read_vehicles(), True)
    gap = obs[0, TRAFFIC_SLICES["gap"]]
    assert gap[2] == 0.0  # fast-side leader alongside
    assert gap[4] == 1.0 and gap[5] == 1.0  # nobody in the slow-side lane


def test_the_end_of_a_route_is_not_a_lane_that_ends():
    from behaviors.road.routes import lane_leads_on

    # own lane ends 300 m before the edge's best lane (an exit); the fast lane goes as far as the best
    ends = np.array([[400.0, 700.0, 0.0], [700.0, 700.0, 700.0]])
    out = lane_leads_on(ends, np.array([700.0, 700.0]), np.array([100.0, 100.0]))
    assert out[0, 0] == 300.0 and np.isinf(out[0, 1]) and out[0, 2] < 0  # missing lane: none
    assert np.isinf(out[1]).all()  # every lane stops where the route stops: nothing ends


@pytest.mark.sumo
def test_leaving_a_junctions_internal_lane_sideways_is_not_off_the_road(tmp_path):
    """Internal edges hold some connections' lanes, not the carriageway (the motorway's lane drop
    counted agents off-track there)."""
    net = exit_net(tmp_path)
    with keeper_on(net, ["A", "B"], lane=2, pos=770.0, speed=20.0) as (sim, fleet):
        inside = []
        for _ in range(20):
            fleet.sense(sim, sim.read_vehicles(), True)
            frame = fleet.rows.frame
            result = fleet.act(sim, np.array([[1.0, 0.3, 0.0]], np.float32))  # hard towards the edge
            if not frame.on_normal_edge[0]:
                inside.append(bool(result.off_track[0]))
            sim.step()
    assert inside and not any(inside)


@pytest.mark.sumo
def test_an_agent_in_the_fast_lane_is_handed_over_on_a_long_edge_well_before_its_exit_ramp(tmp_path):
    """carriageway2's main edge is 1.2 km long, longer than the look-ahead for a one-lane ramp: an
    agent leaving from the fast lane was handed over only on the 250 m deceleration section, where
    SUMO's driver stopped it dead in the fast lane to wait for a gap, a queue forming behind it."""
    built = build_osm_like("carriageway2", tmp_path)
    route = ["m0", "m1", built.exit_edge]
    with keeper_on(built.net, route, lane=1, pos=100.0, speed=30.0, rules=False) as (sim, fleet):
        first_handed_on, lowest_speed, lanes = None, 99.0, []
        while "agent" in sim.vehicle_ids() and len(lanes) < 600:
            readings = sim.read_agents(["agent"])
            lanes.append(readings.lane_id[0])
            fleet.sense(sim, sim.read_vehicles(), True)
            if fleet.rows.handed[0] and first_handed_on is None:
                first_handed_on = (readings.lane_id[0], float(readings.lane_pos[0]))
            fleet.act(sim, np.array([[0.0, 0.5, 0.0]], np.float32))
            sim.step()
            if "agent" in sim.vehicle_ids():
                lowest_speed = min(lowest_speed, float(sim.read_speeds(["agent"])[0]))
        assert first_handed_on is not None and first_handed_on[0] == "m0_1"
        edges = fleet.geometry.edges
        ramp_ahead = edges["m0"].length + edges["m1"].length - first_handed_on[1]
        assert ramp_ahead > 2 * HANDOVER_DISTANCE  # SUMO has the reach once per lane to cross
        assert any(lane.startswith(built.exit_edge) for lane in lanes)
        assert lowest_speed > 15.0
    with keeper_on(built.net, route, lane=1, pos=100.0, speed=30.0) as (sim, fleet):  # keeping right
        lanes, lowest_speed = drive_on(sim, fleet)
        assert "m0_0" in lanes and any(lane.startswith(built.exit_edge) for lane in lanes)
        assert lowest_speed > 15.0


@pytest.mark.sumo
def test_sumo_gives_an_agent_back_only_once_it_is_inside_its_lane(tmp_path):
    """SUMO carried a keeper it had taken over the line into a dropping lane and, where the lane
    dropped, left it on the carriageway's edge; given back there, its next step was off the road."""
    net = exit_net(tmp_path)
    with keeper_on(net, ["A", "B"], lane=1, pos=50.0, speed=25.0) as (sim, fleet):
        sim.command_agents(["agent"], np.array([25.0]), np.array([-0.85]))  # on the line to lane 0
        sim.step()
        sim.hand_to_sumo(["agent"])
        fleet.rows.handed[0] = True
        given_back_at = None
        for _ in range(100):
            lateral = float(sim.read_agents(["agent"]).lateral_pos[0])
            fleet.sense(sim, sim.read_vehicles(), True)
            if not fleet.rows.handed[0]:
                given_back_at = lateral
                break
            sim.step()
        room = (3.5 - CarModel().width) / 2
        assert given_back_at is not None and abs(given_back_at) <= room - 0.2


@pytest.mark.sumo
def test_sumo_changes_lanes_for_an_agent_whose_last_sideways_move_was_too_small_to_complete(tmp_path):
    """SUMO keeps a `changeSublane` of less than ~0.5 mm pending for good, and a pending request
    overrules every lane change SUMO's driver wants: handed over after such a move, an agent stood
    at the end of its exit lane, or 60 s on a lane line it never left."""
    with keeper_on(exit_net(tmp_path), ["A", "X"], lane=2, pos=50.0, speed=25.0) as (sim, _):
        sim.command_agents(["agent"], np.array([25.0]), np.array([1e-5]))
        sim.step()
        sim.hand_to_sumo(["agent"])
        lanes = set()
        for _ in range(300):
            if "agent" not in sim.vehicle_ids():
                break
            lanes.add(sim.read_lanes(["agent"])[0])
            sim.step()
        assert "X_0" in lanes


@pytest.mark.sumo
def test_an_agent_lets_in_a_car_of_sumo_that_must_cross_its_lane_for_an_exit(tmp_path):
    """SUMO's drivers make room for a car whose route needs their lane (its lane-change model asks
    them); nobody asks an agent, so the driver reads the wish from SUMO and drops back as it does for
    a car whose lane ends. Without it, on the dense motorway's weave, cars bound for the exit and
    cars from the on-ramp stood at its end beside agents, and the road broke down in half the seeds."""
    with keeper_on(exit_net(tmp_path), ["A", "B"], lane=1, pos=200.0, speed=22.0) as (sim, fleet):
        sim.add_route("to_exit", ["A", "X"])
        sim.add_route("through", ["A", "B"])
        sim.add_vehicle("exiting", "to_exit", "behave_passive", lane=2, pos=212.0, speed=20.0)
        sim.add_vehicle("going_on", "through", "behave_passive", lane=2, pos=240.0, speed=20.0)
        sim.step()
        asked, slowest, lanes = [], 99.0, set()
        while "exiting" in sim.vehicle_ids() and "agent" in sim.vehicle_ids():
            fleet.sense(sim, sim.read_vehicles(), True)
            asked.append(fleet.rows.own.asking[0].copy())
            fleet.act(sim, np.array([[0.0, 0.5, 0.0]], np.float32))
            sim.step()
            slowest = min(slowest, float(sim.read_speeds(["agent"])[0]))
            if "exiting" in sim.vehicle_ids():
                lanes.add(sim.read_lanes(["exiting"])[0])
                assert not sim.wants_to_change(["going_on"], np.array([-1]))[0]  # its route goes on
        assert np.array(asked)[:, 0].any() and not np.array(asked)[:, 1].any()  # from the fast side only
        assert slowest < 15.0  # it dropped back from 20 m/s to open the gap
        assert {"A_1", "A_0"} <= lanes and "agent" in sim.vehicle_ids()  # through its lane to the exit


@pytest.mark.sumo
def test_a_repeated_sideways_move_of_0_left_out_moves_the_car_as_sending_it(tmp_path):
    """`Fleet.act` leaves out a 0 to an agent whose last move was 0 (`moves_to_send`): after a 0,
    SUMO holds 0 whatever it was carrying on (a move too small to complete, one longer than a
    step), so the car goes where it went with every move sent, in every step."""
    net = exit_net(tmp_path)
    moves = [1e-5, 0.0, 0.0, 0.4, 0.0, 0.0, 1.5, 0.0, 0.0, -0.3, 0.0, 0.0, 0.0]
    runs = []
    for leave_out in (False, True):
        with keeper_on(net, ["A", "B"], lane=1, pos=50.0, speed=25.0) as (sim, _):
            last, places = np.full(1, np.nan), []
            for move in moves:
                send = moves_to_send(np.array([move]), last) if leave_out else None
                sim.command_agents(["agent"], np.array([25.0]), np.array([move]), send)
                last = np.array([move])
                sim.step()
                readings = sim.read_agents(["agent"])
                places.append((readings.lane_id[0], float(readings.lateral_pos[0])))
        runs.append(places)
    assert runs[0] == runs[1]
    assert len({lateral for _, lateral in runs[0]}) > 3  # the moves did move the car


@pytest.mark.sumo
def test_an_agent_given_back_has_its_own_vtype_and_exact_sideways_moves_again(tmp_path):
    """While SUMO drives an agent, SUMO's copy of its type (`behave_keeper@agent`) holds the
    handover's lateral limits and FCD shows it; kept after the hand-back, it read as SUMO driving
    in every later row (a loss was blamed on SUMO that way)."""
    with keeper_on(exit_net(tmp_path), ["A", "B"], lane=0, pos=50.0, speed=25.0, rules=False) as (sim, fleet):
        types_while_handed, back = set(), False
        for _ in range(600):
            fleet.sense(sim, sim.read_vehicles(), True)
            if fleet.rows.handed[0]:
                types_while_handed.add(sim._sumo.vehicle.getTypeID("agent"))
            elif types_while_handed:
                back = True
                break
            fleet.act(sim, np.array([[0.0, 0.5, 0.0]], np.float32))
            sim.step()
        assert back and types_while_handed == {"behave_keeper@agent"}
        assert sim._sumo.vehicle.getTypeID("agent") == "behave_keeper"
        before = float(sim.read_agents(["agent"]).lateral_pos[0])
        sim.command_agents(["agent"], np.array([25.0]), np.array([0.3]))
        sim.step()
        assert float(sim.read_agents(["agent"]).lateral_pos[0]) - before == pytest.approx(0.3, abs=1e-6)


@pytest.mark.sumo
def test_every_step_takes_the_commanded_speed_and_sideways_move_between_sumos_action_points_too(tmp_path):
    """SUMO works out its own plans for an agent once a second (`AGENT_ACTION_STEP`, five steps),
    but the policy's speed and sideways move must take effect at every step: the speed exactly,
    the move to a micrometre, in the steps between SUMO's action points as in those on them."""
    speeds = [25.0, 26.5, 24.0, 24.0, 27.25, 20.0, 21.5, 23.0, 22.0, 19.5, 25.0, 26.0]
    moves = [0.0, 0.3, -0.2, 0.0, 0.45, 0.0, -0.4, 0.1, 0.0, 0.25, -0.15, 0.0]
    with keeper_on(exit_net(tmp_path), ["A", "B"], lane=1, pos=50.0, speed=25.0) as (sim, _):
        assert sim._sumo.vehicle.getActionStepLength("agent") == AGENT_ACTION_STEP
        for speed, move in zip(speeds, moves, strict=True):
            before = sim.read_agents(["agent"])
            sim.command_agents(["agent"], np.array([speed]), np.array([move]))
            sim.step()
            after = sim.read_agents(["agent"])
            assert after.lane_id == before.lane_id
            assert float(sim.read_speeds(["agent"])[0]) == speed
            assert float(after.lateral_pos[0] - before.lateral_pos[0]) == pytest.approx(move, abs=1e-6)


@pytest.mark.sumo
def test_sumo_is_told_the_traffic_drivers_top_sideways_speed_and_carries_its_fastest_move_out_whole(tmp_path):
    """SUMO's cars judge a lane-changing agent's reach by its vType's maxSpeedLat: the traffic
    driver's 1.2 m/s, not the vTypes' 5 (the paper driver's), after a restart too; and the driver's
    fastest move, 0.24 m in a 0.2 s step, still happens whole in that step."""
    speed_lat = TrafficDriver().max_lateral_speed
    options = SimOptions(net=exit_net(tmp_path), additional=(get_scenario("tiny").vtypes,), step_length=0.2,
                         agent_max_speed_lat=speed_lat)  # fmt: skip
    with SumoSim(options) as sim:
        for restart in (False, True):
            if restart:
                sim.restart(options)
            assert [sim._sumo.vehicletype.getMaxSpeedLat(t) for t in AGENT_VTYPES] == [speed_lat] * len(
                AGENT_VTYPES
            )
        sim.add_route("route", ["A", "B"])
        sim.add_vehicle("agent", "route", "behave_keeper", lane=1, pos=50.0, speed=25.0)
        sim.step()
        sim.take_control(["agent"])
        for move in (speed_lat * 0.2, -speed_lat * 0.2):
            before = float(sim.read_agents(["agent"]).lateral_pos[0])
            sim.command_agents(["agent"], np.array([25.0]), np.array([move]))
            sim.step()
            assert float(sim.read_agents(["agent"]).lateral_pos[0]) - before == pytest.approx(move, abs=1e-6)
    with SumoSim(replace(options, agent_max_speed_lat=None)) as sim:
        assert sim._sumo.vehicletype.getMaxSpeedLat(AGENT_VTYPES[0]) == PaperDriver.max_lateral_speed == 5.0


@pytest.mark.sumo
def test_sumo_reacts_at_every_step_for_an_agent_it_drives_and_once_a_second_once_given_back(tmp_path):
    """Handed to SUMO, an agent reacts as SUMO's own cars do, at every step; given back, its
    vType's action step is its own again."""
    with keeper_on(exit_net(tmp_path), ["A", "B"], lane=1, pos=50.0, speed=25.0) as (sim, _):
        sim.hand_to_sumo(["agent"])
        assert sim._sumo.vehicle.getActionStepLength("agent") == pytest.approx(0.2)
        sim.step()
        sim.take_back(["agent"])
        assert sim._sumo.vehicle.getActionStepLength("agent") == AGENT_ACTION_STEP


@pytest.mark.sumo
def test_a_car_sumo_was_moving_sideways_takes_the_policys_first_move_exactly_once_it_is_an_agent(tmp_path):
    """A scenario's car becomes an agent in the middle of SUMO's own sideways move: the policy's
    first move must be all the car does, not SUMO's move carried on to its next action point."""
    options = SimOptions(net=exit_net(tmp_path), additional=(get_scenario("tiny").vtypes,), step_length=0.2)
    with SumoSim(options) as sim:
        sim.add_route("route", ["A", "B"])
        sim.add_vehicle("car", "route", "behave_background", lane=1, pos=50.0, speed=25.0)
        sim.step()
        sim._sumo.vehicle.changeSublane("car", 1.5)  # SUMO's lcAccelLat of 1: over several steps
        sim.step()
        sim.set_agent_type("car", "behave_keeper")
        sim.take_control(["car"])
        assert sim._sumo.vehicle.getTypeID("car") == "behave_keeper"
        for move in (0.3, 0.0, -0.2):
            before = float(sim.read_agents(["car"]).lateral_pos[0])
            sim.command_agents(["car"], np.array([25.0]), np.array([move]))
            sim.step()
            assert float(sim.read_agents(["car"]).lateral_pos[0]) - before == pytest.approx(move, abs=1e-6)


def test_a_car_given_back_crawling_at_sumos_sideways_speed_goes_on_to_its_lane_centre_without_swinging_back():
    """SUMO gave a keeper back at 1.2 m/s moving over at 0.9 m/s, 0.65 m right of its lane's centre,
    where the driver's reach is 0.3 m/s: the cut from 0.9 to 0.3 carried on as -3 m/s^2 turned the
    car the other way, to 0.8 m right of the centre, and off the road at the carriageway's edge."""
    lateral = LaneDriving()
    offset, speed, accel, places = np.array([-0.65]), np.array([0.9]), np.zeros(1), []
    for _ in range(40):
        speed, accel = lateral_profile(-offset, speed, accel, np.array([1.2]), 0.2, lateral)
        offset = offset + speed * 0.2
        places.append(float(offset[0]))
    assert min(places) > -0.65 and max(places) < 0.05  # never further right than given back, no swing past
    assert abs(places[-1]) < 0.01
    assert np.all(np.abs(accel) <= lateral.max_lateral_accel)


def test_the_policy_cannot_push_a_car_closer_than_the_minimum_headway():
    car, v = CarModel(), 25.0
    gap, other = leaders_of(lead=(0, 2.0 + 1.0 * v, v))  # 1 s behind a leader at the same speed
    args = (
        Motion(np.array([v]), np.array([30.0]), np.zeros(1), np.zeros(1), np.array([0])),
        RoadPlace(np.zeros(1), np.array([3.5]), np.array([1]), np.array([1]), np.zeros(1), np.array([5.25]),
                  np.array([33.3])),
        LaneNeighbours(gap, other),
    )  # fmt: skip
    full_throttle = np.array([[0.0, 1.0, 0.0]])
    ruled, bare = DriverSettings(LaneDriving(), 0.2, car), DriverSettings(MECHANICS, 0.2, car)
    assert actuate_lanes(full_throttle, *args, ruled).actuation.speed[0] <= v
    assert actuate_lanes(full_throttle, *args, bare).actuation.speed[0] > v  # the rules off: it may
    gap[0, 0] = 2.0 + 2.0 * v  # 2 s behind: the push is the policy's
    assert actuate_lanes(full_throttle, *args, ruled).actuation.speed[0] > v


def test_overtakers_pass_a_slower_leader_unasked_and_keepers_only_a_much_slower_one_when_they_ask():
    ruled = LaneDriving()
    slower = leaders_of(lead=(0, 40.0, 27.0))  # 3 m/s slower than the 30 m/s wanted; the fast lane free
    waits = drive_lanes([0.0] * 8, lateral=ruled, leaders=slower, behaviour="overtaker")[:, 4]
    assert not waits[:4].any() and waits[-1] == 1  # after its patience (1 s), and not to the right first
    assert set(drive_lanes([1.0] * 10, lateral=ruled, leaders=slower, behaviour="keeper")[:, 4]) == {0}
    truck = leaders_of(lead=(0, 30.0, 20.0))  # 10 m/s slower
    assert set(drive_lanes([0.0] * 10, lateral=ruled, leaders=truck, behaviour="keeper")[:, 4]) == {0}
    asked = drive_lanes([1.0] * 100, lateral=ruled, leaders=truck, behaviour="keeper")
    slowed = np.flatnonzero(asked[:, 5] < 30.0 - ruled.keeper_pass_margin)[0]
    waited = slowed + round(ruled.keeper_patience / 0.2) - 1
    assert not asked[:waited, 4].any() and asked[:, 4].max() == 1  # asked: once slowed down, and after 10 s
    gap, other = leaders_of(lead=(0, 40.0, 27.0), fast_lead=(2, 90.0, 27.0))  # the fast lane no better
    no_better = drive_lanes([0.0] * 10, lateral=ruled, leaders=(gap, other), behaviour="overtaker")
    assert no_better[:, 4].max() <= 0  # no move to the fast side (it keeps right into the free lane)


def test_keepers_keep_their_lane_even_the_fast_most_one_and_only_the_rules_move_a_car_right():
    ruled = LaneDriving()
    for behaviour, lane, wish, moves in [
        ("keeper", 1, 0.0, False), ("keeper", 1, -1.0, False), ("keeper", 2, 0.0, False),
        ("overtaker", 1, 0.0, True), ("overtaker", 2, 0.0, True),
    ]:  # fmt: skip
        run = drive_lanes([wish] * 40, lateral=ruled, lane=lane, behaviour=behaviour)
        assert (run[-1, 0] < lane) == moves, (behaviour, lane, wish)
    queue = leaders_of(slow_lead=(4, 150.0, 22.0))  # 150 m ahead, 8 m/s slower: caught within 20 s
    run = drive_lanes([-1.0] * 40, lateral=ruled, leaders=queue, behaviour="overtaker")
    assert set(run[:, 0]) == {1}  # not moved right only to be held up again


def test_no_passing_on_the_slow_side_of_a_car_two_lanes_over():
    ruled = LaneDriving()
    two_over = (np.array([10.0]), np.array([25.0]))  # 10 m ahead two lanes over, 5 m/s slower
    run = drive_lanes([0.0] * 5, lateral=ruled, lane=0, behaviour="overtaker", far_fast_leader=two_over)
    assert run[-1, 5] < 30.0 - 0.5  # it brakes to stay behind
    crawling = (np.array([10.0]), np.array([12.0]))  # below 60 km/h: passing on the right is allowed
    run = drive_lanes([0.0] * 5, lateral=ruled, lane=0, behaviour="overtaker", far_fast_leader=crawling)
    assert run[-1, 5] >= 30.0 - 1e-9


def test_an_overtaker_may_drive_above_the_limit_it_wants_to_exceed():
    car, limit = CarModel(), np.array([30.0])
    out = actuate_lanes(
        np.array([[0.0, 1.0, 0.0]]),
        Motion(np.array([30.0]), np.array([33.0]), np.zeros(1), np.zeros(1), np.array([0])),
        RoadPlace(
            np.zeros(1), np.array([3.5]), np.array([0]), np.array([0]), np.zeros(1), np.array([1.75]), limit
        ),
        LaneNeighbours(*NO_LEADERS),
        DriverSettings(MECHANICS, 0.2, car),
    )
    assert 30.0 < out.actuation.speed[0] <= 33.0


def test_a_car_leaving_its_lane_takes_the_gap_it_falls_in_to_and_no_lane_ending_before_its_own():
    ruled = LaneDriving()
    speed, desired = np.array([29.0]), np.array([30.0])
    gap, other = leaders_of(fast_lead=(2, 17.0, 29.0), fast_follow=(3, 40.0, 29.0))  # 0.5 s behind one
    traffic = lane_traffic(speed, desired, gap, other, ruled.following)
    assert not gap_acceptable(traffic, ruled)[0, 0]  # too short to pass into
    assert gap_acceptable(traffic, ruled, np.array([[True, False]]))[0, 0]  # to merge into

    def heading(leads_on: list[float]) -> int:
        out = actuate_lanes(
            np.array([[0.0, 0.5, 0.0]]),
            Motion(speed, desired, np.zeros(1), np.zeros(1), np.zeros(1, int)),
            RoadPlace(
                np.zeros(1),
                np.array([3.5]),
                np.array([2]),
                np.array([0]),
                np.array([-3.5]),
                np.array([5.25]),
                np.array([33.3]),
                lane_leads_on=np.array([leads_on]),
            ),
            LaneNeighbours(gap, other),
            DriverSettings(ruled, 0.2),
        )
        return int(out.changing[0])

    assert heading([500.0, np.inf, -1.0]) == 1  # its lane ends: it merges into the gap beside
    held = leaders_of(lead=(0, 40.0, 22.0))
    ends_first = np.array([[np.inf, 1000.0, -1.0]])  # the fast-side lane ends 1 km on, the own goes on
    out = actuate_lanes(
        np.array([[1.0, 0.5, 0.0]]),
        Motion(speed, desired, np.zeros(1), np.zeros(1), np.zeros(1, int)),
        RoadPlace(
            np.zeros(1),
            np.array([3.5]),
            np.array([2]),
            np.array([0]),
            np.array([-3.5]),
            np.array([5.25]),
            np.array([33.3]),
            lane_leads_on=ends_first,
        ),
        LaneNeighbours(*held),
        DriverSettings(ruled, 0.2),
    )
    assert out.changing[0] == 0  # not into a weave's or an exit's lane to pass


def test_surroundings_find_the_nearest_leader_beyond_the_fast_side_lane():
    slow_lane = np.array([STRAIGHT.lane_index["e_0"]])
    agent = one_agent(lane_row=slow_lane, lane_number=np.array([0]), front=np.array([[0.0, -3.5]]))
    others = np.array([[40.0, 3.5], [25.0, 0.0], [-10.0, 3.5]])  # two lanes over ahead, one over, behind
    positions = np.vstack([agent.front, others])
    speeds = np.array([30.0, 27.0, 26.0, 31.0])
    around = surroundings(agent, positions, speeds, np.array([0]), STRAIGHT)
    assert around.far_fast_gap[0] == pytest.approx(35.0) and around.far_fast_speed[0] == 27.0
    assert around.gap[0, 2] == pytest.approx(20.0) and around.other_speed[0, 2] == 26.0
    alone = surroundings(agent, positions[:1], speeds[:1], np.array([0]), STRAIGHT)
    assert np.isinf(alone.far_fast_gap[0]) and np.isnan(alone.far_fast_speed[0])
