"""Agents sense every vehicle at its own size: a lorry ahead is as long as its vType says, in the
traffic driver's gaps, the shield's leader and side room, and the incident table; and in SUMO an
agent stops behind a standing lorry instead of running into its back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from behaviors.car.model import CarModel
from behaviors.run.populate import populate
from behaviors.run.populate_config import DEFAULT_POLICY, PopulateConfig
from behaviors.run.records import collision_incident
from behaviors.traffic.bodies import Bodies
from behaviors.traffic.lanes import GAP_RANGE, search_radius, surroundings
from behaviors.traffic.shield import search_reach
from behaviors.traffic.shield import surroundings as shield_surroundings
from tests.learn.test_traffic import STRAIGHT, one_agent
from tests.run.test_populate_truth import netconvert, read_agents

CAR = CarModel()
LORRY = (16.5, 2.55)


def test_a_lorry_ahead_is_sensed_to_its_rear_and_a_follower_from_the_agents_rear():
    agent = one_agent()
    # own lane: a lorry whose front is 40 m ahead; fast lane: a car 20 m behind; slow lane: a car 30 m ahead
    positions = np.array([[0.0, 0.0], [40.0, 0.0], [-20.0, 3.5], [30.0, -3.5]])
    speeds = np.array([30.0, 20.0, 30.0, 25.0])
    bodies = Bodies(np.array([5.0, 16.5, 9.0, 5.0]), np.array([1.8, 2.55, 2.0, 1.8]))
    around = surroundings(agent, positions, speeds, np.array([0]), STRAIGHT, bodies=bodies)
    assert around.gap[0, 0] == pytest.approx(40.0 - 16.5)  # to the lorry's rear bumper
    assert around.gap[0, 3] == pytest.approx(20.0 - 5.0)  # from the van's front to the agent's rear
    assert around.gap[0, 4] == pytest.approx(25.0)
    as_cars = surroundings(agent, positions, speeds, np.array([0]), STRAIGHT)
    assert as_cars.gap[0, 0] == pytest.approx(35.0)  # the old assumption: every vehicle 5 m long


def test_a_lorry_whose_front_is_beyond_the_gap_range_but_whose_rear_is_within_is_seen():
    agent = one_agent()
    front = GAP_RANGE + 10.0  # a car there is out of sight, a 16.5 m lorry's rear is 143.5 m ahead
    positions = np.array([[0.0, 0.0], [front, 0.0]])
    lorry = Bodies(np.array([5.0, 16.5]), np.array([1.8, 2.55]))
    seen = surroundings(agent, positions, np.array([30.0, 20.0]), np.array([0]), STRAIGHT, bodies=lorry)
    assert seen.gap[0, 0] == pytest.approx(front - 16.5)
    car = surroundings(agent, positions, np.array([30.0, 20.0]), np.array([0]), STRAIGHT)
    assert np.isinf(car.gap[0, 0])
    assert search_radius(lorry.longest) == GAP_RANGE + 16.5


def test_a_wide_vehicle_in_the_next_lane_reaches_over_into_the_agents_lane():
    agent = one_agent()
    # its centre 2.9 m to the left: a 1.8 m car's side is 2.0 m from the agent's lane centre (in the
    # next lane only, the line is at 1.75), a 3.0 m wide load's side 1.4 m (over the line)
    positions = np.array([[0.0, 0.0], [30.0, 2.9]])
    speeds = np.array([30.0, 20.0])
    wide = Bodies(np.array([5.0, 12.0]), np.array([1.8, 3.0]))
    over = surroundings(agent, positions, speeds, np.array([0]), STRAIGHT, bodies=wide)
    assert over.gap[0, 0] == pytest.approx(18.0) and over.gap[0, 2] == pytest.approx(18.0)
    narrow = surroundings(agent, positions, speeds, np.array([0]), STRAIGHT)
    assert np.isinf(narrow.gap[0, 0]) and narrow.gap[0, 2] == pytest.approx(25.0)


def test_the_shield_measures_its_leader_to_the_lorrys_rear_and_its_side_room_to_its_side():
    # a lorry ahead in the agent's way, 30 m front to front; a wide one alongside on the right
    points = np.array([[0.0, 0.0], [30.0, 0.2], [8.0, -3.5]])
    bodies = Bodies(np.array([5.0, 16.5, 16.5]), np.array([1.8, 2.55, 2.55]))
    around = shield_surroundings(
        points[:1], np.array([0.0]), points, np.array([0]), CAR, 150.0, bodies=bodies
    )
    assert around.leader[0] == 1 and around.leader_gap[0] == pytest.approx(30.0 - 16.5)
    # the lorry on the right reaches 8.5 m behind the agent's front: alongside, 3.5 - (1.8 + 2.55) / 2 free
    assert around.side_room[0, 1] == pytest.approx(3.5 - (1.8 + 2.55) / 2)
    as_cars = shield_surroundings(points[:1], np.array([0.0]), points, np.array([0]), CAR, 150.0)
    assert as_cars.leader_gap[0] == pytest.approx(25.0) and np.isinf(as_cars.side_room[0, 1])
    assert search_reach(30.0, 0.2, CAR, 16.5) == pytest.approx(search_reach(30.0, 0.2, CAR) + 11.5)


def test_the_incident_table_measures_a_rear_end_into_a_lorry_to_its_rear():
    front = np.array([0.0, 0.0])
    side, headway, _ = collision_incident(front, 0.0, 10.0, np.array([20.0, 0.0]), 0.0, CAR, LORRY)
    assert side == "front" and headway == pytest.approx((20.0 - 16.5) / 10.0)
    side, headway, lateral = collision_incident(front, 0.0, 10.0, np.array([12.0, -2.5]), 0.0, CAR, LORRY)
    assert side == "right" and np.isnan(headway)  # alongside: the lorry's body reaches back past the front
    assert lateral == pytest.approx(2.5 - (1.8 + 2.55) / 2)


def standing_lorries(tmp: Path) -> tuple[Path, Path]:
    """A 1 km two-lane road whose both lanes are blocked at 700 m by 16.5 m lorries standing for good."""
    net = netconvert(
        tmp,
        '<node id="a" x="0" y="0"/><node id="b" x="1000" y="0"/>',
        '<edge id="road" from="a" to="b" numLanes="2" width="3.5" speed="30"/>',
    )
    lorries = "".join(
        f'<vehicle id="lorry{k}" type="lorry" route="r" depart="0" departLane="{k}" departPos="700" '
        f'departSpeed="0"><stop lane="road_{k}" endPos="705" duration="1000"/></vehicle>'
        for k in range(2)
    )
    routes = tmp / "lorries.rou.xml"
    routes.write_text(
        f'<routes><vType id="lorry" vClass="truck" length="{LORRY[0]}" width="{LORRY[1]}"/>'
        f'<route id="r" edges="road"/>{lorries}</routes>'
    )
    return net, routes


@pytest.mark.sumo
def test_agents_stop_behind_standing_lorries_without_running_into_them(tmp_path):
    """With every vehicle taken for 5 m, an agent took a standing 16.5 m lorry's rear for 11.5 m
    further away than it is, and ran into it."""
    net, routes = standing_lorries(tmp_path)
    fcd = tmp_path / "out" / "run.xml"
    for shield in (False, True):
        summary = populate(
            PopulateConfig(net=net, routes=routes, policy=DEFAULT_POLICY, overtakers=3, keepers=3,
                           background=0, duration=80.0, fcd=fcd, seed=0, shield=shield)
        )  # fmt: skip
        out = summary.as_dict()
        _, agents = read_agents(tmp_path / "out" / "run.agents.csv")
        assert len(agents) == 6
        assert out["agents_collision"] == 0, shield
        assert out["agents_standing_30s"] >= 2  # they did reach the lorries and wait behind them
