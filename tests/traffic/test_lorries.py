"""Learned lorries: a third kind the styled network drives through its style (their limiter's top
speed, long headways, hardly any wish to pass), as long as they are, in SUMO as a lorry's vType."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import behave

from behaviors.errors import BehaveError
from behaviors.fleet.traffic_rows import TrafficRows, desired_speed
from behaviors.report.export import read_fcd
from behaviors.traffic.bodies import Bodies
from behaviors.traffic.lanes import surroundings
from behaviors.traffic.styles import KEEPER, KINDS, LORRY, OVERTAKER, PRESETS, draw_styles, read_population
from sumo_scenarios.build import LORRY_SIZE, LORRY_TOP_SPEED
from tests.learn.test_traffic import STRAIGHT, one_agent
from tests.run.test_populate_truth import netconvert, read_agents


def test_lorries_draw_their_limiters_speed_long_headways_and_little_eagerness():
    kind = np.repeat([0.0, 1.0, 2.0], 2000)
    style = draw_styles(kind, np.random.default_rng(0), PRESETS["default"])
    lorry, cars = kind == 2.0, kind < 2.0
    assert KINDS.index("lorry") == 2
    assert (style.top_speed[lorry] >= 80 / 3.6).all() and (style.top_speed[lorry] <= 90 / 3.6).all()
    assert np.isinf(style.top_speed[cars]).all()
    assert np.median(style.time_headway[lorry]) > np.median(style.time_headway[kind == 0.0])
    assert style.eagerness[lorry].mean() < 0.15 < style.eagerness[kind == 0.0].mean()
    assert np.abs(style.lane_bias[lorry]).mean() < np.abs(style.lane_bias[cars]).mean()


def test_a_lorry_wants_the_limit_only_up_to_its_top_speed():
    own = TrafficRows(desired_fraction=np.array([1.0, 1.0, 1.07]), top_speed=np.array([24.0, 24.0, np.inf]))
    limit = np.array([36.1, 22.2, 36.1])
    assert desired_speed(own, limit).tolist() == [24.0, 22.2, pytest.approx(1.07 * 36.1)]


def test_the_same_seed_draws_the_same_cars_with_lorries_in_the_population():
    """Lorries draw their top speed only for themselves: cars' styles do not move when a population
    has lorries."""
    kind = np.array([0.0, 1.0, 1.0, 0.0])
    two = draw_styles(kind, np.random.default_rng(3), (KEEPER, OVERTAKER))
    three = draw_styles(kind, np.random.default_rng(3), (KEEPER, OVERTAKER, LORRY))
    for field in ("desired_fraction", "time_headway", "eagerness", "lane_bias"):
        assert getattr(two, field).tolist() == getattr(three, field).tolist()


def test_a_population_file_may_leave_lorries_out_or_give_them(tmp_path):
    base = {
        "speed_mean": 1.0, "speed_sd": 0.05, "speed_range": [0.9, 1.1], "headway_median": 1.4,
        "headway_sigma": 0.3, "eagerness_a": 2.0, "eagerness_b": 2.0,
    }  # fmt: skip
    path = tmp_path / "people.json"
    path.write_text(json.dumps({"keeper": base, "overtaker": base}))
    assert read_population(str(path))[2] == LORRY
    slow = {**base, "speed_range": [1.0, 1.0], "speed_sd": 0.0, "top_speed_range": [20.0, 22.0]}
    path.write_text(json.dumps({"keeper": base, "overtaker": base, "lorry": slow}))
    assert read_population(str(path))[2].top_speed_range == (20.0, 22.0)
    path.write_text(
        json.dumps({"keeper": base, "overtaker": base, "lorry": {**slow, "top_speed_range": [3, 4]}})
    )
    with pytest.raises(BehaveError, match="out of range"):
        read_population(str(path))


def test_a_learned_lorry_measures_its_follower_from_its_own_rear():
    """A car 25 m behind a lorry agent's front is 8.5 m behind its rear, not the 20 m a car's body leaves."""
    agent = one_agent()
    positions = np.array([[0.0, 0.0], [-25.0, 3.5]])  # the agent; a car in the fast-side lane behind it
    speeds = np.array([25.0, 30.0])
    as_car = surroundings(agent, positions, speeds, np.array([0]), STRAIGHT, bodies=Bodies.cars(2))
    lorry = Bodies(
        np.array([*LORRY_SIZE[:1], 5.0]), np.array([LORRY_SIZE[1], 1.8]), *np.array([LORRY_SIZE]).T
    )
    as_lorry = surroundings(agent, positions, speeds, np.array([0]), STRAIGHT, bodies=lorry)
    assert as_car.gap[0, 3] == pytest.approx(20.0)  # fast-side follower
    assert as_lorry.gap[0, 3] == pytest.approx(25.0 - LORRY_SIZE[0])


def lane_changes_per_km(fcd: pd.DataFrame) -> pd.Series:
    """Per vehicle kind: lane changes on one edge per km driven."""
    df = fcd.sort_values(["id", "time"])
    df["edge"] = df["lane"].str.rsplit("_", n=1).str[0]
    same = (df["id"] == df["id"].shift()) & (df["edge"] == df["edge"].shift())
    df["change"] = same & (df["lane"] != df["lane"].shift())
    df["kind"] = df["type"].str.split("@").str[0]
    km = df.groupby("kind")["speed"].sum() * 0.2 / 1000
    return df.groupby("kind")["change"].sum() / km


@pytest.mark.sumo
def test_learned_lorries_drive_at_their_limiter_keep_right_and_seldom_change_lane(tmp_path):
    fcd = tmp_path / "run.xml"
    done = behave(
        "populate", "--policy", "styled", "--keepers", "6", "--overtakers", "6", "--lorries", "8",
        "--background", "10", "--duration", "300", "--keep-count", "--seed", "1", "--fcd", str(fcd),
        "--json", "-q",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["collisions"] == 0 and summary["off_tracks"] == 0
    assert summary["lorry_mean_speed"] < summary["keeper_mean_speed"] < summary["overtaker_mean_speed"]
    _, agents = read_agents(tmp_path / "run.agents.csv")
    lorries = [a for a in agents if a["behaviour"] == "lorry"]
    assert len(lorries) >= 8 and {a["vtype"] for a in lorries} == {"behave_lorry"}
    trace = read_fcd(fcd)
    lorry = trace["type"].str.startswith("behave_lorry")
    assert trace.loc[lorry, "speed"].max() <= LORRY_TOP_SPEED + 0.01
    changes = lane_changes_per_km(trace)
    assert changes["behave_lorry"] < 0.5 * changes["behave_keeper"]
    lane = trace.loc[lorry, "lane"].str.rsplit("_", n=1).str[1].astype(int)
    assert (lane == 0).mean() > 0.6  # mostly in the rightmost lane


def lorry_scenario(tmp: Path) -> Path:
    """A 2 km 3-lane motorway with cars and 12 m lorries of the scenario's own type, as a sumocfg."""
    net = netconvert(
        tmp,
        '<node id="a" x="0" y="0"/><node id="b" x="2000" y="0"/>',
        '<edge id="road" from="a" to="b" numLanes="3" width="3.5" speed="33.3"/>',
    )
    (tmp / "traffic.rou.xml").write_text(
        '<routes><vType id="truck12" vClass="truck" length="12" width="2.5" maxSpeed="25"/>'
        '<route id="r" edges="road"/>'
        '<flow id="car" begin="0" end="200" vehsPerHour="1500" route="r" departLane="random"'
        ' departSpeed="max"/>'
        '<flow id="truck" type="truck12" begin="0" end="200" vehsPerHour="500" route="r" departLane="0"'
        ' departSpeed="max"/></routes>'
    )
    cfg = tmp / "lorries.sumocfg"
    cfg.write_text(
        f'<configuration><input><net-file value="{net.name}"/><route-files value="traffic.rou.xml"/></input>'
        '<time><end value="240"/></time></configuration>'
    )
    return cfg


@pytest.mark.sumo
def test_share_lorries_turns_a_scenarios_lorries_into_learned_ones_of_their_own_size(tmp_path):
    cfg = lorry_scenario(tmp_path)
    fcd = tmp_path / "out.xml"
    done = behave(
        "populate", "--sumocfg", str(cfg), "--share", "1", "--share-lorries", "--policy", "styled",
        "--fcd", str(fcd), "--json", "-q",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["collisions"] == 0
    _, agents = read_agents(tmp_path / "out.agents.csv")
    lorries = [a for a in agents if a["behaviour"] == "lorry"]
    assert len(lorries) >= 20 and all(a["id"].startswith("truck") for a in lorries)
    types = set(read_fcd(fcd)["type"])
    assert any(t.startswith("behave_lorry@truck") for t in types)  # their own 12 m, in a copy of the type
    without = behave("populate", "--sumocfg", str(cfg), "--share", "1", "--policy", "styled",
                     "--fcd", str(tmp_path / "cars.xml"), "--json", "-q")  # fmt: skip
    _, agents = read_agents(tmp_path / "cars.agents.csv")
    assert without.returncode == 0 and not [a for a in agents if a["behaviour"] == "lorry"]


@pytest.mark.sumo
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--lorries", "4"), "learned lorries drive through their style"),
        (("--share-lorries", "--policy", "styled"), "--share-lorries draws a scenario's lorries"),
    ],
)
def test_lorries_without_a_styled_policy_or_a_scenario_are_one_line(tmp_path, args, message):
    done = behave("populate", *args, "--duration", "5", "--fcd", str(tmp_path / "f.xml"))
    assert done.returncode == 2
    assert message in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "f.xml").exists()
