"""The environment on real SUMO (libsumo): actuation, terminations, API, determinism, bad input."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from behaviors import BehaveError, make_env
from behaviors.car.model import CarModel
from behaviors.learn.env import EnvConfig
from behaviors.learn.metrics import passed_fraction
from behaviors.paper.sensors import SLICES
from behaviors.sumo.sim import VehicleState
from behaviors.sumo.sumo_home import sumo_binary
from behaviors.traffic.rewards import COLLISION_PENALTY, OFF_TRACK_PENALTY

CAR = CarModel()


def keep_lane(obs: np.ndarray, speed: float = 20.0, lanes: int = 3) -> np.ndarray:
    """A scripted driver: steer to the nearest lane centre, drive at about `speed` m/s."""
    angle = obs[:, SLICES["angle"]][:, 0] * np.pi
    v = obs[:, SLICES["speedX"]][:, 0] * 300 / 3.6
    track_pos = obs[:, SLICES["trackPos"]][:, 0]
    lane = np.clip(np.floor((track_pos + 1) / 2 * lanes), 0, lanes - 1)
    target = (lane + 0.5) * 2 / lanes - 1
    steer = np.clip(-4 * angle - 1.5 * (track_pos - target), -1, 1)
    return np.stack([steer, np.clip((speed - v) * 0.3, 0, 1), np.clip((v - speed - 2) * 0.3, 0, 1)], 1)


def offset_of(env, slot: int) -> float:
    row = env.fleet.ids.index(env.possible_agents[slot])
    return float(env.fleet.frame.offset[row])


@pytest.fixture
def tiny():
    env = make_env("tiny", agents=1, seed=3, max_steps=400, start_speed=0.0)
    yield env
    env.close()


def drive(env, actions_fn, steps):
    batch = None
    for _ in range(steps):
        if not env.agents:
            break
        batch = env.step_arrays(actions_fn(env.live_obs).astype(np.float32))
    return batch


@pytest.mark.sumo
def test_a_steer_command_moves_the_car_sideways_by_the_expected_amount(tiny):
    tiny.reset_arrays(3)
    drive(tiny, lambda o: np.array([[0.0, 1.0, 0.0]]), 30)  # 30 steps at full throttle: 18 m/s
    v0 = tiny.fleet.speed[0]
    before = offset_of(tiny, 0)
    tiny.step_arrays(np.array([[0.5, 0.0, 0.0]], np.float32))
    dt = tiny.config.step_length
    yaw = 0.5 * min(v0 * np.tan(CAR.max_steer) / CAR.wheelbase, CAR.max_lateral_accel / v0)
    expected = v0 * np.sin(yaw * dt) * dt  # straight road: no curvature term
    assert offset_of(tiny, 0) - before == pytest.approx(expected, abs=1e-3)
    assert expected > 0.05  # a real move, to the left
    # the heading persists: with steer 0 the car keeps drifting by the same angle
    before = offset_of(tiny, 0)
    tiny.step_arrays(np.array([[0.0, 0.0, 0.0]], np.float32))
    assert offset_of(tiny, 0) - before == pytest.approx(v0 * np.sin(yaw * dt) * dt, abs=1e-3)


@pytest.mark.sumo
def test_brake_stops_the_car(tiny):
    tiny.reset_arrays(3)
    drive(tiny, lambda o: np.array([[0.0, 1.0, 0.0]]), 40)
    assert tiny.fleet.speed[0] > 20
    drive(tiny, lambda o: np.array([[0.0, 0.0, 1.0]]), 17)  # 24 m/s - 7.5 m/s^2 * 0.2 s * 17 < 0
    assert tiny.fleet.speed[0] == 0.0
    pos = tiny.sim.read_vehicles().position.copy()
    tiny.step_arrays(np.array([[0.0, 0.0, 1.0]], np.float32))
    np.testing.assert_allclose(tiny.sim.read_vehicles().position, pos)


@pytest.mark.sumo
def test_steering_into_the_border_is_off_track_and_removes_the_agent(tiny):
    tiny.reset_arrays(3)
    drive(tiny, lambda o: np.array([[0.0, 1.0, 0.0]]), 20)
    batch = drive(tiny, lambda o: np.array([[1.0, 0.5, 0.0]]), 100)
    assert batch.terminated[0] and batch.off_track[0] and not batch.truncated[0]
    assert batch.terms.off_track[0] == OFF_TRACK_PENALTY
    assert tiny.agents == [] and "agent_0" not in tiny.sim.vehicle_ids()


@pytest.mark.sumo
def test_a_rear_end_collision_removes_the_crashed_agents_and_the_others_drive_on():
    env = make_env("tiny", agents=3, seed=1, max_steps=300, start_speed=0.0)
    try:
        env.reset_arrays(1)
        lanes = {vid: env.sim._sumo.vehicle.getLaneIndex(vid) for vid in env.agents}
        assert lanes["agent_0"] == lanes["agent_2"] != lanes["agent_1"]  # 0 ahead of 2, 1 beside

        def crash(obs):
            act = keep_lane(obs, lanes=2)
            live = list(env.agents)
            if "agent_0" in live:
                act[live.index("agent_0")] = [0.0, 0.0, 1.0]  # the leader stands
            if "agent_2" in live:
                act[live.index("agent_2")] = [0.0, 1.0, 0.0]  # the follower floors it
            return act

        collided = set()
        for _ in range(100):
            slots = env.live_slots
            batch = env.step_arrays(crash(env.live_obs).astype(np.float32))
            collided |= {int(s) for s in slots[batch.collided]}
            if collided:
                assert (batch.terms.collision[batch.collided] == COLLISION_PENALTY).all()
                assert batch.terminated[batch.collided].all()
                break
        assert collided == {0, 2}
        assert env.agents == ["agent_1"]
        assert set(env.sim.vehicle_ids()) == {"agent_1"}
        before = env.progress[env._car_row["agent_1"]]
        drive(env, lambda o: keep_lane(o, lanes=2), 10)
        assert env.progress[env._car_row["agent_1"]] > before + 10
    finally:
        env.close()


@pytest.mark.sumo
def test_no_progress_terminates_after_five_seconds_standing(tiny):
    tiny.reset_arrays(3)
    batch = drive(tiny, lambda o: np.array([[0.0, 0.0, 1.0]]), 30)
    assert batch.terminated[0] and batch.no_progress[0]
    assert tiny.steps == 25  # 5 s at 0.2 s per step


@pytest.mark.sumo
def test_the_time_limit_truncates_and_keeps_the_last_observation():
    env = make_env("ring", agents=2, seed=0, max_steps=20)
    try:
        env.reset_arrays(0)
        batch = drive(env, keep_lane, 20)
        assert batch.truncated.all() and not batch.terminated.any()
        assert np.abs(batch.next_obs).sum() > 0
        assert env.agents == []
    finally:
        env.close()


@pytest.mark.sumo
def test_parallel_api_test_passes():
    env = make_env("tiny", agents=2, seed=0, max_steps=60)
    try:
        parallel_api_test(env, num_cycles=200)
    finally:
        env.close()


@pytest.mark.sumo
def test_same_seed_and_actions_give_identical_observations_over_200_steps():
    def run() -> np.ndarray:
        env = make_env(
            "ring", behaviour="overtaking", agents=3, opponents=3, seed=11, max_steps=200, start_speed=5.0
        )
        try:
            rng = np.random.default_rng(5)
            trace = [env.reset_arrays(11)]
            for _ in range(200):
                if not env.agents:
                    break
                act = keep_lane(env.live_obs) + rng.normal(0, 0.1, (len(env.agents), 3))
                trace.append(env.step_arrays(act.astype(np.float32)).next_obs)
            return np.concatenate(trace)
        finally:
            env.close()

    first, second = run(), run()
    assert len(first) > 3 * 150
    np.testing.assert_array_equal(first, second)


@pytest.mark.sumo
def test_multi_behaviour_placements_put_the_ids_where_asked():
    assert EnvConfig(behaviour="multi", overtakers=2, keepers=2, placement="A").behaviour_ids().tolist() == [
        1,
        1,
        0,
        0,
    ]
    assert EnvConfig(behaviour="multi", overtakers=2, keepers=2, placement="B").behaviour_ids().tolist() == [
        0,
        0,
        1,
        1,
    ]
    mixed = EnvConfig(behaviour="multi", overtakers=2, keepers=2, placement="C").behaviour_ids().tolist()
    assert sorted(mixed) == [0, 0, 1, 1] and mixed not in ([1, 1, 0, 0], [0, 0, 1, 1])
    env = make_env("ring", behaviour="multi", overtakers=2, keepers=3, placement="A", seed=2)
    try:
        obs = env.reset_arrays(2)
        assert obs.shape == (5, 66)
        assert obs[:, -1].tolist() == [1, 1, 0, 0, 0]
        types = [env.sim._sumo.vehicle.getTypeID(v) for v in env.agents]
        assert types == ["behave_overtaker"] * 2 + ["behave_keeper"] * 3
    finally:
        env.close()


@pytest.mark.sumo
def test_overtaking_puts_slower_passive_cars_ahead():
    env = make_env("ring", behaviour="overtaking", agents=3, opponents=2, seed=4)
    try:
        env.reset_arrays(4)
        passive = [v for v in env.sim.vehicle_ids() if v.startswith("passive_")]
        assert len(passive) == 2
        agent_progress = [env.progress[env._car_row[a]] for a in env.agents]
        assert min(env.progress[env._car_row[p]] for p in passive) > max(agent_progress)
    finally:
        env.close()


@pytest.mark.sumo
def test_multi_behaviour_can_have_passive_cars_to_overtake_and_passing_counts_overtakers_only():
    assert EnvConfig(behaviour="multi", overtakers=1, keepers=1).n_opponents == 0  # the paper's setting
    env = make_env("ring", behaviour="multi", overtakers=2, keepers=2, opponents=2, seed=4)
    try:
        env.reset_arrays(4)
        passive = [v for v in env.sim.vehicle_ids() if v.startswith("passive_")]
        assert len(passive) == 2 and len(env.agents) == 4
        assert passed_fraction(env) == 0.0  # everyone starts behind the passive cars
        overtakers = np.flatnonzero(env.slot_behaviour == 1) + 2  # progress rows: passive cars first
        env.progress[overtakers[0]] = env.progress[:2].max() + 1.0  # one overtaker ahead of both
        env.progress[np.flatnonzero(env.slot_behaviour == 0) + 2] = 1e9  # keepers do not count
        assert passed_fraction(env) == pytest.approx(0.5)
    finally:
        env.close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"agents": 0}, "at least one agent"),
        ({"agents": 5000}, "do not fit"),
        ({"behaviour": "drifting"}, "unknown behaviour 'drifting'"),
        ({"behaviour": "multi", "placement": "D", "overtakers": 1, "keepers": 1}, "unknown placement 'D'"),
        ({"behaviour": "multi"}, "multi needs"),
        ({"scenario": "moon"}, "unknown scenario 'moon'"),
    ],
)
def test_bad_options_raise_a_clear_error(kwargs, message):
    with pytest.raises(BehaveError, match=message):
        make_env(**kwargs)


def write_net(tmp: Path, lanes: int) -> Path:
    (tmp / "n.nod.xml").write_text('<nodes><node id="a" x="0" y="0"/><node id="b" x="200" y="0"/></nodes>')
    (tmp / "n.edg.xml").write_text(f'<edges><edge id="e" from="a" to="b" numLanes="{lanes}"/></edges>')
    net = tmp / "n.net.xml"
    subprocess.run(
        [
            sumo_binary("netconvert"),
            "-n",
            str(tmp / "n.nod.xml"),
            "-e",
            str(tmp / "n.edg.xml"),
            "-o",
            str(net),
        ],
        check=True,
        capture_output=True,
    )
    return net


@pytest.mark.sumo
def test_bad_network_files_raise_a_clear_error(tmp_path):
    from behaviors.road.geometry_build import load_geometry

    with pytest.raises(BehaveError, match="network file not found"):
        load_geometry(tmp_path / "missing.net.xml")
    broken = tmp_path / "broken.net.xml"
    broken.write_text("<net><edge id=")
    with pytest.raises(BehaveError, match="cannot read network"):
        load_geometry(broken)
    with pytest.raises(BehaveError, match="no multi-lane edge"):
        load_geometry(write_net(tmp_path, lanes=1))
    assert load_geometry(write_net(tmp_path, lanes=2)).edges["e"].lanes == 2


@pytest.mark.sumo
def test_start_speed_is_drawn_per_episode_or_fixed():
    env = make_env("ring", agents=3, seed=7, max_steps=10)
    try:
        speeds = set()
        for seed in (1, 2):
            env.reset_arrays(seed)
            assert len(set(env.fleet.speed)) == 1  # one speed for the whole formation
            speeds.add(float(env.fleet.speed[0]))
            assert 0.0 <= env.fleet.speed[0] <= 0.7 * 33.34
        assert len(speeds) == 2
    finally:
        env.close()
    fixed = make_env("ring", agents=2, seed=7, start_speed=12.0)
    try:
        fixed.reset_arrays(1)
        np.testing.assert_allclose(fixed.sim.read_speeds(fixed.agents), 12.0)
    finally:
        fixed.close()


def test_vehicle_state_without_removed_cars_drops_exactly_their_rows():
    position = np.arange(10.0).reshape(5, 2)
    ids = ("a", "b", "c", "d", "e")
    length = np.array([5.0, 16.5, 5.0, 9.0, 4.5])
    state = VehicleState(
        ids, position, np.arange(5.0) + 20.0, np.arange(5.0), {v: k for k, v in enumerate(ids)},
        length, np.full(5, 1.8),
    )  # fmt: skip
    assert state.without(["zz"]) is state  # removing nobody (or an unknown id) copies nothing
    left = state.without(["b", "e", "zz"])
    assert left.ids == ("a", "c", "d") and left.row == {"a": 0, "c": 1, "d": 2}
    np.testing.assert_array_equal(left.position, position[[0, 2, 3]])
    np.testing.assert_array_equal(left.distance, [0.0, 2.0, 3.0])
    np.testing.assert_array_equal(left.speed, [20.0, 22.0, 23.0])
    np.testing.assert_array_equal(left.length, [5.0, 5.0, 9.0])
    assert state.longest == 16.5 and left.longest == 9.0


@pytest.mark.sumo
def test_the_lane_term_measures_the_offset_from_the_lane_centre_sumo_reports():
    env = make_env("tiny", agents=1, seed=3, max_steps=400, start_speed=15.0, lane_weight=0.5)
    try:
        env.reset_arrays(3)
        batch = drive(env, lambda o: np.array([[0.3, 0.3, 0.0]]), 3)  # drift left, off the lane centre
        vid = env.agents[0]
        lateral = env.sim._sumo.vehicle.getLateralLanePosition(vid)
        width = env.sim._sumo.lane.getWidth(env.sim._sumo.vehicle.getLaneID(vid))
        assert abs(lateral) > 0.1
        expected = -0.5 * batch.speed[0] * 3.6 * abs(lateral) / (width / 2)
        assert batch.terms.lane[0] == pytest.approx(expected, rel=1e-9)
        assert batch.reward[0] == pytest.approx(sum(v[0] for v in batch.terms.as_dict().values()))
    finally:
        env.close()
