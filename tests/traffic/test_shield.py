"""The safety shield of `behave populate`: its geometry by hand, its bounds, and in SUMO."""

from __future__ import annotations

import numpy as np
import pytest

from behaviors import make_env
from behaviors.car.model import CarModel, ShieldBounds
from behaviors.paper.heading import actuate
from behaviors.traffic.shield import (
    EMERGENCY_DECEL,
    SIDE_MARGIN,
    STANDSTILL_GAP,
    safe_speed,
    side_limits,
    surroundings,
)
from tests.learn.test_env import keep_lane

CAR = CarModel()


def scene(fronts: list[tuple[float, float]], axis: float = 0.0, shift=(0.0, 0.0)):
    """The agent's front bumper at the origin, the road along +x, other fronts at `fronts`;
    the whole scene turned by `axis` and shifted."""
    turn = np.array([[np.cos(axis), -np.sin(axis)], [np.sin(axis), np.cos(axis)]])
    pts = np.array([(0.0, 0.0), *fronts]) @ turn.T + np.array(shift)
    return surroundings(pts[:1], np.array([axis]), pts, np.array([0]), CAR, 150.0)


@pytest.mark.parametrize("axis, shift", [(0.0, (0.0, 0.0)), (2.1, (5e5, 4.2e6)), (-0.7, (-30.0, 12.0))])
def test_side_room_and_leader_are_measured_along_and_across_the_road(axis, shift):
    fronts = [
        (0.0, 3.5),  # alongside on the left: 3.5 - 1.8 = 1.7 m free
        (-5.5, -3.0),  # its front half a metre behind our rear bumper: still alongside (1 m slack)
        (20.0, 3.5),  # ahead in the next lane: neither beside nor in the way
        (20.0, 0.2),  # ahead in our way: rear bumper at 15, 15 m from our front
        (30.0, 0.0),  # further ahead in our way
        (-12.0, 0.0),  # behind: never a leader
    ]
    around = scene(fronts, axis, shift)
    np.testing.assert_allclose(around.side_room, [[1.7, 1.2]], atol=1e-6)
    assert around.leader.tolist() == [4]
    np.testing.assert_allclose(around.leader_gap, [15.0], atol=1e-6)


def test_cars_ahead_or_behind_are_not_beside():
    around = scene([(6.0, 0.5)])  # straight ahead, overlapping sideways: a leader, not a neighbour
    assert np.isinf(around.side_room).all() and around.leader.tolist() == [1]
    assert around.leader_gap[0] == pytest.approx(1.0)
    assert np.isinf(scene([(-6.5, 3.5)]).side_room[0, 0])  # 1.5 m behind our rear: not alongside
    assert np.isinf(scene([(6.5, 3.5)]).side_room[0, 0])  # its rear 1.5 m ahead of our front
    # a car slightly across our lane line but not in our way (gap over the margin) is beside us
    assert scene([(0.0, -2.2)]).side_room[0, 1] == pytest.approx(0.4)


def test_a_car_beside_with_room_to_pass_is_no_leader_however_far_ahead_it_reaches():
    # at a lane drop's end a car waiting to merge stood 1.5 m ahead, its body 0.7 m from the
    # agent's: the agent, capped to its speed (0), stood beside it for two minutes
    roomy = scene([(1.5, -2.5)])  # 2.5 - 1.8 = 0.7 m free
    assert roomy.leader.tolist() == [-1] and roomy.side_room[0, 1] == pytest.approx(0.7)
    tight = scene([(1.5, -2.3)])  # 0.5 m: under PASSING_ROOM, still in the agent's way
    assert tight.leader.tolist() == [1] and tight.side_room[0, 1] == pytest.approx(0.5)
    assert scene([(7.0, -2.5)]).leader.tolist() == [1]  # ahead, not beside: its path can still close


def test_nobody_around_leaves_every_move_and_speed_free():
    around = scene([])
    assert np.isinf(around.side_room).all() and around.leader.tolist() == [-1]
    assert np.isinf(safe_speed(around.leader_gap, np.zeros(1), np.array([30.0]), 0.2, CAR)).all()


def test_side_limits_are_half_the_room_minus_the_margin():
    room = np.array([[1.7, np.inf], [0.5, 2 * SIDE_MARGIN]])
    np.testing.assert_allclose(side_limits(room), [[0.85 - SIDE_MARGIN, np.inf], [0.0, 0.0]])


def test_the_safe_speed_can_always_stop_behind_a_leader_braking_as_hard():
    rng = np.random.default_rng(0)
    gap, leader, speed = rng.uniform(0, 120, 1000), rng.uniform(0, 40, 1000), rng.uniform(0, 50, 1000)
    dt, b = 0.2, CAR.max_brake
    v = safe_speed(gap, leader, speed, dt, CAR)
    bound = v > speed - EMERGENCY_DECEL * dt + 1e-9  # where the emergency floor did not decide
    assert bound.sum() > 500
    # one step at v, then full braking, stays behind the leader braking at b from now, keeping the
    # standstill gap (or, already closer than that, not closing in further)
    travel = v * dt + v**2 / (2 * b)
    room = np.maximum(gap - STANDSTILL_GAP, 0.0) + leader**2 / (2 * b)
    np.testing.assert_array_less(travel[bound], room[bound] + 1e-9)
    # and it is the highest such speed (the bound is tight)
    faster = v + 0.01
    assert (faster * dt + faster**2 / (2 * b) > room)[bound].all()
    # never asks for more than an emergency stop
    assert (v >= speed - EMERGENCY_DECEL * dt - 1e-9).all()


def test_actuate_cuts_the_move_and_turns_the_heading_to_match_it():
    n = 3
    out = actuate(
        np.array([[1.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
        np.full(n, 20.0), np.array([0.05, -0.05, 0.0]), np.zeros(n), np.full(n, 5.25), np.zeros(n),
        np.full(n, 33.0), 0.2, CAR,
        ShieldBounds(
            side_limit=np.array([[0.05, np.inf], [np.inf, 0.0], [np.inf, np.inf]]),
            speed_cap=np.array([np.inf, np.inf, 18.0]),
        ),
    )  # fmt: skip
    assert out.side_cut.tolist() == [True, True, False]
    np.testing.assert_allclose(out.lateral_move[:2], [0.05, 0.0])
    np.testing.assert_allclose(out.speed * np.sin(out.angle) * 0.2, out.lateral_move, atol=1e-12)
    assert out.speed_cut.tolist() == [False, False, True] and out.speed[2] == 18.0


def crash_course(shield: bool, steps: int = 100) -> tuple[set[str], float]:
    """The tiny net: agent_0 stands, agent_2 floors it behind it, agent_1 (beside) steers into them.

    Returns who collided and the smallest bumper-to-bumper gap seen between agent_2 and agent_0.
    """
    env = make_env("tiny", agents=3, seed=1, max_steps=300, start_speed=0.0, shield=shield)
    try:
        env.reset_arrays(1)
        lanes = {vid: env.sim._sumo.vehicle.getLaneIndex(vid) for vid in env.agents}
        assert lanes["agent_0"] == lanes["agent_2"] != lanes["agent_1"]
        toward = 1.0 if lanes["agent_1"] < lanes["agent_0"] else -1.0
        collided: set[str] = set()
        smallest = np.inf
        for _ in range(steps):
            if not env.agents:
                break
            live = list(env.agents)
            act = keep_lane(env.live_obs, lanes=2)
            scripted = {"agent_0": [0, 0, 1], "agent_2": [0, 1, 0], "agent_1": [toward, 0.6, 0]}
            for vid, action in scripted.items():
                if vid in live:
                    act[live.index(vid)] = action
            slots = env.live_slots
            batch = env.step_arrays(act.astype(np.float32))
            collided |= {f"agent_{s}" for s in slots[batch.collided]}
            vehicles = env.sim.read_vehicles()
            if {"agent_0", "agent_2"} <= set(vehicles.row):
                gap = np.linalg.norm(vehicles.position[vehicles.row["agent_0"]]
                                     - vehicles.position[vehicles.row["agent_2"]]) - CAR.length  # fmt: skip
                smallest = min(smallest, gap)
        return collided, smallest
    finally:
        env.close()


@pytest.mark.sumo
def test_in_sumo_the_shield_prevents_the_crashes_the_bare_policy_makes():
    crashed, _ = crash_course(shield=False)
    assert "agent_2" in crashed  # without the shield the follower runs into the standing car
    crashed, smallest = crash_course(shield=True)
    assert crashed == set()
    assert smallest >= STANDSTILL_GAP - 0.5


def squeeze(shield: bool, steps: int = 60) -> tuple[set[str], float]:
    """Two agents in neighbouring lanes; agent_1 catches up with agent_0 and then steers into it.

    Returns who collided and the smallest lateral distance between their centres while alongside.
    """
    env = make_env("tiny", agents=2, seed=1, max_steps=300, start_speed=10.0, shield=shield)
    try:
        env.reset_arrays(1)
        vehicle = env.sim._sumo.vehicle
        toward = 1.0 if vehicle.getLaneIndex("agent_1") < vehicle.getLaneIndex("agent_0") else -1.0
        collided: set[str] = set()
        closest = np.inf
        for _ in range(steps):
            if len(env.agents) < 2:
                break
            behind = vehicle.getLanePosition("agent_0") - vehicle.getLanePosition("agent_1")
            act = keep_lane(env.live_obs, speed=10.0, lanes=2)
            act[1] = [0.0, 1.0, 0.0] if behind > 1.0 else [toward, 0.0, 0.0]
            slots = env.live_slots
            batch = env.step_arrays(act.astype(np.float32))
            collided |= {f"agent_{s}" for s in slots[batch.collided]}
            if len(env.agents) == 2 and abs(behind) < CAR.length:
                offsets = env.fleet.frame.offset
                closest = min(closest, abs(offsets[0] - offsets[1]))
        return collided, closest
    finally:
        env.close()


@pytest.mark.sumo
def test_in_sumo_the_shield_keeps_an_agent_from_steering_into_the_car_beside_it():
    crashed, _ = squeeze(shield=False)
    assert crashed == {"agent_0", "agent_1"}  # the bare command side-swipes
    crashed, closest = squeeze(shield=True)
    assert crashed == set()
    assert closest >= CAR.width + 2 * SIDE_MARGIN - 1e-6
