"""Each rule of the traffic driver does its one thing, and switching it off alone (settings.Rules)
takes exactly that away: one test per rule, every other rule on."""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest

from behaviors.traffic.actuation import LaneCommand, actuate_lanes
from behaviors.traffic.limits import LANE_VETOES, LIMIT_NAMES, SPEED_BOUNDS
from behaviors.traffic.scene import AgentStyle, LaneNeighbours, Motion, RoadPlace
from behaviors.traffic.settings import DriverSettings, LaneDriving, LaneHabits, Rules
from tests.learn.test_traffic import NO_LEADERS, leaders_of

ALL = Rules()


def step(
    rules: Rules = ALL,
    steer: float = 0.0,
    accel: float = 0.5,
    leaders=NO_LEADERS,
    lane: int = 1,
    leads_on=(3000.0, 3000.0, 3000.0),
    speed: float = 30.0,
    changing: int = 0,
    lane_offset: float = 0.0,
    habits: LaneHabits | None = None,
) -> LaneCommand:
    """One actuate_lanes step of one car wanting 33 m/s in lane `lane` of three 3.5 m lanes."""
    return actuate_lanes(
        np.array([[steer, accel, 0.0]]),
        Motion(np.array([speed]), np.array([33.0]), np.zeros(1), np.zeros(1), np.array([changing])),
        RoadPlace(
            np.array([lane_offset]),
            np.array([3.5]),
            np.array([2 - lane]),
            np.array([lane]),
            np.array([(lane - 1) * 3.5 + lane_offset]),
            np.array([5.25]),
            np.array([33.3]),
            lane_leads_on=np.array([leads_on]),
        ),
        LaneNeighbours(*leaders),
        DriverSettings(LaneDriving(rules=rules), 0.2),
        AgentStyle(habits=habits),
    )


def without(name: str) -> Rules:
    return replace(ALL, **{name: False})


def heading(command: LaneCommand) -> int:
    return int(command.changing[0])


def speed_after(command: LaneCommand) -> float:
    return float(command.actuation.speed[0])


PASSER = LaneHabits(np.array([True]), np.array([2.0]), np.array([0.0]))
"""An overtaker with no patience to wait out."""


def test_every_rule_has_a_test_here():
    tested = {name.removeprefix("test_").split("__")[0] for name in globals() if name.startswith("test_")}
    assert {f.name for f in fields(Rules)} <= tested


def test_leave_ending_lane__moves_out_of_a_lane_that_stops_leading_on():
    ending = (300.0, 3000.0, -1.0)  # the rightmost lane ends 300 m on (keeping right moves nobody)
    assert heading(step(lane=0, leads_on=ending)) == 1
    assert heading(step(without("leave_ending_lane"), lane=0, leads_on=ending)) == 0


def test_avoid_ending_lanes__forbids_a_change_into_a_lane_that_ends_soon():
    slow_ends = (3000.0, 3000.0, 150.0)
    assert heading(step(steer=-1.0, leads_on=slow_ends)) == 0
    assert heading(step(without("avoid_ending_lanes"), steer=-1.0, leads_on=slow_ends)) == -1


def test_speed_gain__passes_a_slower_leader():
    slow_leader = leaders_of(lead=(0, 40.0, 20.0))  # in the rightmost lane: keeping right moves nobody
    assert heading(step(leaders=slow_leader, habits=PASSER, lane=0)) == 1
    assert heading(step(without("speed_gain"), leaders=slow_leader, habits=PASSER, lane=0)) == 0


def test_keep_right__moves_back_to_a_free_slow_side_lane():
    assert heading(step()) == -1
    assert heading(step(without("keep_right"))) == 0


def test_give_up_lost_gap__gives_up_a_change_whose_gap_closes_before_the_line():
    # on its way to the fast side, 0.3 m over from its lane's centre; a car has come up alongside there
    alongside = leaders_of(fast_lead=(2, 0.0, 30.0))
    on = step(leaders=alongside, steer=1.0, changing=1, lane_offset=0.3)
    off = step(without("give_up_lost_gap"), leaders=alongside, steer=1.0, changing=1, lane_offset=0.3)
    assert heading(on) == 0 and heading(off) == 1


def test_letting_in__drops_back_for_a_car_whose_lane_ends():
    merging = leaders_of(slow_lead=(4, 30.0, 15.0))  # 30 m ahead in the slow-side lane, which ends
    ends = (3000.0, 3000.0, 120.0)
    on = speed_after(step(leaders=merging, leads_on=ends, speed=20.0))
    off = speed_after(step(without("letting_in"), leaders=merging, leads_on=ends, speed=20.0))
    assert on < off - 0.05


def test_falling_in__drops_back_behind_the_car_beside_to_merge():
    # the own lane (the rightmost) ends 500 m on; a platoon beside leaves no gap
    platoon = leaders_of(fast_lead=(2, 7.0, 25.0), fast_follow=(3, 11.0, 25.5))
    ends = (500.0, 3000.0, -1.0)
    on = step(leaders=platoon, lane=0, leads_on=ends, speed=25.0)
    off = step(without("falling_in"), leaders=platoon, lane=0, leads_on=ends, speed=25.0)
    assert heading(on) == heading(off) == 0  # no gap: it waits either way
    assert speed_after(on) < speed_after(off) - 0.05


def test_target_leader__follows_the_leader_of_the_lane_it_heads_for():
    slower_there = leaders_of(fast_lead=(2, 60.0, 27.0))  # nobody ahead in its own lane
    on = step(leaders=slower_there, changing=1, lane_offset=0.5, steer=1.0)
    off = step(without("target_leader"), leaders=slower_there, changing=1, lane_offset=0.5, steer=1.0)
    assert heading(on) == heading(off) == 1
    assert speed_after(on) < speed_after(off) - 0.05


def test_reaching_over__follows_the_leader_of_a_lane_its_body_reaches_into():
    # 1.0 m towards the fast side, more than the 0.85 m of room its lane leaves; a slow car ahead there
    rules = replace(ALL, target_leader=False, give_up_lost_gap=False)
    slower_there = leaders_of(fast_lead=(2, 20.0, 15.0))
    on = speed_after(step(rules, leaders=slower_there, lane_offset=1.0))
    off = speed_after(step(replace(rules, reaching_over=False), leaders=slower_there, lane_offset=1.0))
    assert on < off - 0.05


def test_no_undertaking__passes_no_fast_lane_car_on_its_slow_side():
    beside_ahead = leaders_of(fast_lead=(2, 5.0, 25.0))
    on = speed_after(step(leaders=beside_ahead, accel=1.0))
    off = speed_after(step(without("no_undertaking"), leaders=beside_ahead, accel=1.0))
    assert on < 30.0 <= off


@pytest.mark.parametrize("gap", [25.0, 30.0])
def test_no_tailgating__stops_a_push_closer_than_the_minimum_headway(gap):
    leader = leaders_of(lead=(0, gap, 30.0))  # 0.8-1.0 s behind a car at its own speed
    on = speed_after(step(leaders=leader, accel=1.0))
    off = speed_after(step(without("no_tailgating"), leaders=leader, accel=1.0))
    assert on < off - 0.05


def test_each_limit_keeps_its_rules_name_and_a_step_says_whom_each_one_held():
    rules = {f.name for f in fields(Rules)}
    assert all(limit.rule in rules | {None} for limit in (*LANE_VETOES, *SPEED_BOUNDS))
    into_ending = step(steer=-1.0, leads_on=(3000.0, 3000.0, 150.0))  # asks for a lane that ends soon
    assert list(into_ending.limited) == list(LIMIT_NAMES)
    assert [name for name, held in into_ending.limited.items() if held[0]] == ["avoid_ending_lanes"]
    pushing = step(leaders=leaders_of(lead=(0, 25.0, 30.0)), accel=1.0)  # 0.8 s behind, full throttle
    assert [name for name, held in pushing.limited.items() if held[0]] == ["no_tailgating"]
