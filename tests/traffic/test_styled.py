"""The styled driver: driver styles drawn from a population, the network choosing lanes and headways
with the rules only forbidding, and the teacher that gives the network its first driving."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from helpers import behave

from behaviors.errors import BehaveError
from behaviors.fleet.drivers import STYLED_LANES, STYLED_OBS_SIZE, StyledDriver
from behaviors.learn.ddpg.checkpoint import save_checkpoint
from behaviors.learn.ddpg.networks import Actor
from behaviors.run.populate import populate
from behaviors.run.populate_config import PopulateConfig
from behaviors.traffic.actuation import actuate_lanes
from behaviors.traffic.rewards import TrafficStep, TrafficWeights, styled_rewards
from behaviors.traffic.scene import AgentStyle, LaneNeighbours, Motion, RoadPlace
from behaviors.traffic.settings import DriverSettings, LaneDriving
from behaviors.traffic.styles import (
    HEADWAY_RANGE,
    KEEPER,
    LORRY,
    OVERTAKER,
    action_of_headway,
    draw_styles,
    headway_of_action,
    read_population,
)
from tests.learn.test_traffic import NO_LEADERS, leaders_of


def lane_step(
    steer: float,
    accel: float = 0.5,
    leaders=NO_LEADERS,
    lateral: LaneDriving = STYLED_LANES,
    lane: int = 1,
    lane_leads_on=(3000.0, 3000.0, 3000.0),
    speed: float = 30.0,
    time_headway: float | None = None,
    changing: int = 0,
):
    """One actuate_lanes step of one car in lane `lane` of three 3.5 m lanes, wanting 33 m/s."""
    headway = None if time_headway is None else np.array([time_headway])
    if headway is None and lateral.network_chooses:
        headway = headway_of_action(np.array([accel]))
    return actuate_lanes(
        np.array([[steer, accel, 0.0]]),
        Motion(np.array([speed]), np.array([33.0]), np.zeros(1), np.zeros(1), np.array([changing])),
        RoadPlace(
            np.zeros(1),
            np.array([3.5]),
            np.array([2 - lane]),
            np.array([lane]),
            np.array([(lane - 1) * 3.5]),
            np.array([5.25]),
            np.array([33.3]),
            lane_leads_on=np.array([lane_leads_on]),
        ),
        LaneNeighbours(*leaders),
        DriverSettings(lateral, 0.2),
        AgentStyle(time_headway=headway),
    )


def test_styles_are_drawn_per_behaviour_reproducibly_and_within_their_ranges():
    behaviour = np.repeat([0.0, 1.0], 5000)
    styles = draw_styles(behaviour, np.random.default_rng(4))
    again = draw_styles(behaviour, np.random.default_rng(4))
    np.testing.assert_array_equal(styles.time_headway, again.time_headway)
    keepers, overtakers = behaviour == 0, behaviour == 1
    assert HEADWAY_RANGE[0] <= styles.time_headway.min() and styles.time_headway.max() <= HEADWAY_RANGE[1]
    assert np.median(styles.time_headway[keepers]) == pytest.approx(KEEPER.headway_median, abs=0.05)
    assert np.median(styles.time_headway[overtakers]) == pytest.approx(OVERTAKER.headway_median, abs=0.05)
    assert styles.eagerness[overtakers].mean() > 0.7 > 0.3 > styles.eagerness[keepers].mean()
    assert styles.desired_fraction[overtakers].mean() > styles.desired_fraction[keepers].mean() + 0.1
    assert np.std(styles.desired_fraction[keepers]) == pytest.approx(KEEPER.speed_sd, abs=0.01)


def test_a_population_file_gives_other_distributions_and_bad_ones_are_refused(tmp_path):
    fields = {
        "speed_mean": 1.0, "speed_sd": 0.1, "speed_range": [0.8, 1.2], "headway_median": 2.0,
        "headway_sigma": 0.2, "eagerness_a": 1.0, "eagerness_b": 1.0,
    }  # fmt: skip
    good = tmp_path / "calm.json"
    good.write_text(json.dumps({"keeper": fields, "overtaker": fields}))
    keeper, _, _ = read_population(str(good))
    assert keeper.headway_median == 2.0 and keeper.speed_range == (0.8, 1.2)
    assert read_population("default") == (KEEPER, OVERTAKER, LORRY)
    for dist in read_population("highd"):
        dist.check("highd")  # the fitted preset is within the ranges a file must keep
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"keeper": {**fields, "headway_median": 9.0}, "overtaker": fields}))
    with pytest.raises(BehaveError, match="out of range"):
        read_population(str(bad))
    missing = tmp_path / "missing.json"
    missing.write_text(json.dumps({"keeper": fields}))
    with pytest.raises(BehaveError, match="cannot read"):
        read_population(str(missing))
    with pytest.raises(BehaveError, match="no such preset"):
        read_population("nobody")


def test_the_accel_action_spans_the_headways_and_the_teacher_inverts_it():
    assert headway_of_action(np.array([1.0, 0.0]))[0] == HEADWAY_RANGE[0]
    assert headway_of_action(np.array([1.0, 0.0]))[1] == HEADWAY_RANGE[1]
    asked = np.array([0.5, 1.0, 1.4, 2.2, 3.0])
    np.testing.assert_allclose(headway_of_action(action_of_headway(asked)), asked)


def test_no_rule_moves_a_car_that_the_network_keeps_in_its_lane():
    # the middle lane, nobody anywhere: the rules keep right, the network's "no wish" is obeyed
    assert lane_step(0.0, lateral=LaneDriving()).changing[0] == -1
    assert lane_step(0.0).changing[0] == 0
    assert lane_step(-1.0).changing[0] == -1  # the network moves right when it wishes
    assert lane_step(1.0).changing[0] == 1  # and left, with nobody slower ahead to pass


def test_the_envelope_forbids_a_change_into_a_car_a_missing_gap_or_a_lane_that_ends():
    alongside = leaders_of(fast_lead=(2, 0.0, 30.0))
    assert lane_step(1.0, leaders=alongside).changing[0] == 0
    fast_follower = leaders_of(fast_follow=(3, 8.0, 38.0))  # closing in fast, 8 m behind
    assert lane_step(1.0, leaders=fast_follower).changing[0] == 0
    assert lane_step(-1.0, lane_leads_on=(3000.0, 3000.0, 150.0)).changing[0] == 0  # ends 150 m on
    assert lane_step(0.0, lane=0).changing[0] == 0 and lane_step(-1.0, lane=0).changing[0] == 0  # no lane
    # the own lane ends: the route's need moves the car whatever the network wishes
    assert lane_step(0.0, lane_leads_on=(300.0, 3000.0, 3000.0)).changing[0] != 0


def test_the_network_chooses_the_headway_and_the_envelope_bounds_the_closest():
    leader = leaders_of(lead=(0, 30.0, 30.0))  # 30 m ahead at the car's 30 m/s: a 1 s gap
    close = lane_step(0.0, accel=1.0, leaders=leader).actuation.speed[0]  # asks 0.5 s
    far = lane_step(0.0, accel=0.0, leaders=leader).actuation.speed[0]  # asks 3.0 s
    assert close > 30.0 > far
    # the safety headway bounds whatever the network asks: a car at 0.3 s brakes
    tailgating = leaders_of(lead=(0, 9.0, 30.0))
    assert lane_step(0.0, accel=1.0, leaders=tailgating).actuation.speed[0] < 30.0
    assert STYLED_LANES.min_time_headway < HEADWAY_RANGE[0] + 1e-9


def test_passing_on_the_slow_side_stays_forbidden():
    # the fast-side lane's leader drives at 25 m/s just ahead: the car may not pass it on its right
    beside = leaders_of(fast_lead=(2, 5.0, 25.0))
    assert lane_step(0.0, accel=1.0, leaders=beside, speed=30.0).actuation.speed[0] < 30.0


def test_the_styled_observation_ends_with_the_style():
    driver = StyledDriver()
    assert driver.obs_size(True) == STYLED_OBS_SIZE
    assert driver.observation_layout(True).endswith("time_headway+eagerness")
    rows = driver.new_rows(2, draw_styles(np.array([0.0, 1.0]), np.random.default_rng(0)))
    assert rows.time_headway.shape == (2,) and rows.eagerness.shape == (2,)
    habits = driver.teacher_habits(np.array([0.0, 1.0]))
    assert habits.overtakes.all()  # every driver keeps right
    assert habits.pass_margin[0] > habits.pass_margin[1] and habits.patience[0] > habits.patience[1]


def styled_step(**over) -> TrafficStep:
    """Two drivers at 25 m/s wanting 30, 30 m behind a leader at 25 m/s (a 1.2 s headway)."""
    gap, other = np.full((2, 6), np.inf), np.full((2, 6), np.nan)
    gap[:, 0], other[:, 0] = 30.0, 25.0
    base = dict(
        speed=np.full(2, 25.0), desired_speed=np.full(2, 30.0), acceleration=np.zeros(2),
        lateral_acceleration=np.zeros(2), lane_deviation=np.zeros(2), lane_changed=np.zeros(2, bool),
        behaviour_id=np.zeros(2), gap=gap, other_speed=other, collided=np.zeros(2, bool),
        off_track=np.zeros(2, bool), no_progress=np.zeros(2, bool), time_headway=np.full(2, 1.2),
        eagerness=np.full(2, 0.5),
    )  # fmt: skip
    base.update(over)
    return TrafficStep(**base)


def test_the_styled_reward_follows_each_drivers_style():
    weights = TrafficWeights()
    eager_or_not = styled_rewards(styled_step(eagerness=np.array([1.0, 0.0])), weights).values
    assert eager_or_not["speed"][0] < eager_or_not["speed"][1]  # the eager one is not content behind it
    headways = styled_rewards(styled_step(time_headway=np.array([1.2, 2.4])), weights).values
    assert headways["headway"][0] == 0.0 > headways["headway"][1]  # at its own headway: no cost
    changed = styled_step(lane_changed=np.ones(2, bool), eagerness=np.array([1.0, 0.0]))
    cost = styled_rewards(changed, weights).values["lane_change"]
    assert cost[1] < cost[0] < 0.0  # a change costs the reluctant driver more
    close = gap_step = styled_step(time_headway=np.array([0.6, 0.6]))
    gap_step.gap[:, 0] = [7.5, 15.0]  # 0.3 s and 0.6 s
    near = styled_rewards(close, weights).values["headway"]
    assert near[0] < near[1] == 0.0  # closer than the safety headway costs even when the style asks


def test_a_driver_holds_itself_where_its_style_puts_it_in_the_lane():
    def sideways(bias: float | None) -> float:
        out = actuate_lanes(
            np.array([[0.0, 0.6, 0.0]]),
            Motion(np.array([30.0]), np.array([33.0]), np.zeros(1), np.zeros(1), np.array([0])),
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
            DriverSettings(STYLED_LANES, 0.2),
            AgentStyle(time_headway=np.array([1.4]), lane_bias=None if bias is None else np.array([bias])),
        )
        return float(out.actuation.lateral_speed[0])

    assert sideways(None) == 0.0  # on its lane's centre line, it stays there
    assert sideways(0.4) > 0.0 > sideways(-0.4)  # drawn off it, it moves to its own place
    styles = draw_styles(np.zeros(4000), np.random.default_rng(1))
    assert 0.2 < np.abs(styles.lane_bias).mean() < 0.3 and np.abs(styles.lane_bias).max() <= 0.5


def styled_checkpoint(path: Path) -> Path:
    """An untrained styled-driver actor: which styles are drawn does not depend on how it drives."""
    meta = {
        "algorithm": "ps-ddpg", "driver": "styled", "behaviour": "multi",
        "behaviours": ["overtaking", "lanekeeping"],
        "obs_dim": STYLED_OBS_SIZE, "observation_layout": "test", "normalisation": "test", "hidden": [16, 16],
        "training_steps": 0,
    }  # fmt: skip
    save_checkpoint(path, actor_state=Actor(STYLED_OBS_SIZE, (16, 16)).state_dict(), meta=meta)
    return path


@pytest.mark.sumo
def test_populate_draws_each_agents_style_from_the_population_and_tables_it(tmp_path):
    policy = styled_checkpoint(tmp_path / "styled.pt")
    calm = dict(KEEPER.__dict__, headway_median=2.5, headway_sigma=0.0, speed_range=list(KEEPER.speed_range))
    population = tmp_path / "calm.json"
    population.write_text(json.dumps({"keeper": calm, "overtaker": calm}))
    fcd = tmp_path / "run.xml"
    populate(PopulateConfig(policy=policy, duration=10.0, background=4, fcd=fcd, population=str(population)))
    with (tmp_path / "run.agents.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 8
    assert all(float(r["style_time_headway_s"]) == 2.5 for r in rows)
    assert all(
        0.0 <= float(r["style_eagerness"]) <= 1.0 and abs(float(r["style_lane_bias_m"])) <= 0.5 for r in rows
    )
    traffic = tmp_path / "traffic.xml"
    populate(PopulateConfig(duration=5.0, background=0, fcd=traffic))
    with (tmp_path / "traffic.agents.csv").open() as f:
        unstyled = list(csv.DictReader(f))
    assert unstyled[0]["style_speed_factor"] != "" and unstyled[0]["style_time_headway_s"] == ""


@pytest.mark.sumo
def test_a_population_for_a_driver_without_styles_is_one_line(tmp_path):
    out = behave("populate", "--population", "default", "--duration", "5", "--fcd", str(tmp_path / "f.xml"))
    assert out.returncode != 0 and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1].startswith("behave: error: --population draws driver styles")
