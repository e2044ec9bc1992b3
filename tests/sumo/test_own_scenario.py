"""A user's own scenario: --sumocfg, a share of its cars as agents, set-up that scales, traffic lights."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from behaviors.car.model import CarModel
from behaviors.errors import BehaveError
from behaviors.fleet.control import Fleet
from behaviors.fleet.drivers import make_driver
from behaviors.learn.ddpg.checkpoint import save_checkpoint
from behaviors.learn.ddpg.networks import Actor
from behaviors.learn.env import KEEPER_TYPE, OVERTAKER_TYPE
from behaviors.learn.policy import PRETRAINED
from behaviors.report.fcd_read import fcd_options, read_fcd
from behaviors.road.geometry_build import cache_path, load_geometry
from behaviors.run.populate import populate
from behaviors.run.populate_config import config_from
from behaviors.sumo.scenario_config import read_sumocfg, share_draw
from behaviors.sumo.sim import COLLISION_OPTIONS, SimOptions, SumoSim
from behaviors.sumo.sumo_home import sumo_binary
from behaviors.sumo.timing import PhaseTimer
from behaviors.traffic.lanes import TRAFFIC_OBS_SIZE
from behaviors.traffic.styles import fixed_styles
from sumo_scenarios import get_scenario

AGENT_TYPES = {KEEPER_TYPE, OVERTAKER_TYPE}


def traffic_policy(tmp: Path) -> Path:
    """An untrained traffic-driver checkpoint: which cars are agents does not depend on how they drive."""
    path = tmp / "traffic.pt"
    meta = {
        "algorithm": "ps-ddpg", "behaviour": "traffic", "behaviours": ["keeper", "overtaker"],
        "obs_dim": TRAFFIC_OBS_SIZE, "observation_layout": "test", "normalisation": "test",
        "hidden": [32, 32], "training_steps": 0,
    }  # fmt: skip
    save_checkpoint(path, actor_state=Actor(TRAFFIC_OBS_SIZE, (32, 32)).state_dict(), meta=meta)
    return path


def netconvert(tmp: Path, name: str, nodes: str, edges: str, *extra: str) -> Path:
    (tmp / f"{name}.nod.xml").write_text(f"<nodes>{nodes}</nodes>")
    (tmp / f"{name}.edg.xml").write_text(f"<edges>{edges}</edges>")
    net = tmp / f"{name}.net.xml"
    subprocess.run(
        [sumo_binary("netconvert"), "-n", str(tmp / f"{name}.nod.xml"), "-e", str(tmp / f"{name}.edg.xml"),
         "-o", str(net), "--no-turnarounds", *extra],
        check=True, capture_output=True,
    )  # fmt: skip
    return net


def roads_scenario(tmp: Path, roads: int, end: float, cars_per_hour: int = 2400) -> Path:
    """`roads` separate 3-lane 400 m roads (with relative paths, in a sub-folder) fed by flows of
    passenger cars and of lorries, and a sumocfg with its own step length and end."""
    folder = tmp / "scenario"
    folder.mkdir()
    nodes = "".join(
        f'<node id="a{k}" x="0" y="{40 * k}"/><node id="b{k}" x="400" y="{40 * k}"/>' for k in range(roads)
    )
    edges = "".join(f'<edge id="r{k}" from="a{k}" to="b{k}" numLanes="3" speed="30"/>' for k in range(roads))
    netconvert(folder, "roads", nodes, edges)
    flows = "".join(
        f'<flow id="car{k}" type="car" begin="0" end="{end}" vehsPerHour="{cars_per_hour}" '
        f'departLane="random" departSpeed="max"><route edges="r{k}"/></flow>'
        f'<flow id="lorry{k}" type="lorry" begin="0" end="{end}" vehsPerHour="300" departLane="0" '
        f'departSpeed="max"><route edges="r{k}"/></flow>'
        for k in range(roads)
    )
    (folder / "demand.rou.xml").write_text(
        '<routes><vType id="car" vClass="passenger" sigma="0.5"/>'
        f'<vType id="lorry" vClass="truck" length="12" maxSpeed="25"/>{flows}</routes>'
    )
    cfg = folder / "roads.sumocfg"
    cfg.write_text(
        '<configuration><input><net-file value="roads.net.xml"/><route-files value="demand.rou.xml"/></input>'
        f'<time><begin value="0"/><end value="{end}"/><step-length value="0.5"/></time></configuration>'
    )
    return cfg


def plain_sumo_fcd(cfg: Path, fcd: Path, seed: int, *options: str) -> pd.DataFrame:
    """The scenario run by SUMO alone with the options behave documents it forces (and `options`: what
    a run with agents changes, and says)."""
    subprocess.run(
        [sumo_binary("sumo"), "-c", str(cfg), "--seed", str(seed), *options,
         "--no-step-log", "true", *COLLISION_OPTIONS, *fcd_options(fcd, geo=False)],
        check=True, capture_output=True,
    )  # fmt: skip
    return read_fcd(fcd)


def run_share(tmp: Path, cfg: Path, share: float, seed: int = 0) -> pd.DataFrame:
    fcd = tmp / f"share{share}.xml"
    populate(config_from(cfg, share=share, seed=seed, policy=traffic_policy(tmp), fcd=fcd))
    return read_fcd(fcd)


def test_share_draws_are_uniform_and_fixed_by_seed_and_id():
    draws = np.array([share_draw(7, f"car{k}.{j}") for k in range(4) for j in range(5000)])
    assert abs((draws < 0.2).mean() - 0.2) < 0.01 and abs((draws < 0.5).mean() - 0.5) < 0.01
    assert share_draw(7, "car0.1") == share_draw(7, "car0.1") != share_draw(8, "car0.1")


@pytest.mark.sumo
def test_a_zero_share_run_is_row_identical_to_plain_sumo(tmp_path):
    cfg = roads_scenario(tmp_path, roads=2, end=60.0)
    ours = run_share(tmp_path, cfg, 0.0, seed=3)
    plain = plain_sumo_fcd(cfg, tmp_path / "plain.xml", seed=3)
    assert len(plain) > 1000 and ours["time"].diff().max() == pytest.approx(0.5)  # the sumocfg's step
    pd.testing.assert_frame_equal(ours.reset_index(drop=True), plain.reset_index(drop=True))


@pytest.fixture(scope="module")
def shared_run(tmp_path_factory) -> pd.DataFrame:
    """The FCD of a 20% share on 8 roads (~1,700 passenger cars)."""
    tmp = tmp_path_factory.mktemp("share")
    cfg = roads_scenario(tmp, roads=8, end=320.0)
    return run_share(tmp, cfg, 0.2)


@pytest.mark.sumo
def test_the_share_of_passenger_cars_that_become_agents_is_right(shared_run):
    fcd = shared_run
    agents = set(fcd.loc[fcd["type"].isin(AGENT_TYPES), "id"])
    cars = set(fcd.loc[fcd["type"] == "car", "id"])  # an agent's row of its departure step has its own type
    assert len(cars) > 1500 and agents <= cars  # no lorry became an agent
    assert abs(len(agents) / len(cars) - 0.2) <= 0.02
    assert set(fcd["type"]) >= AGENT_TYPES  # keepers and overtakers both


@pytest.mark.sumo
def test_cars_on_roads_without_agents_drive_exactly_as_in_plain_sumo(tmp_path):
    """SUMO's cars that never meet an agent keep their every row: converting other cars draws on
    no random stream they use. Sparse flows leave some roads without agents."""
    cfg = roads_scenario(tmp_path, roads=8, end=60.0, cars_per_hour=300)
    with_agents = ("--step-length", "0.2", "--lateral-resolution", "0.8")  # the policy's step, sublanes
    fcd, plain = run_share(tmp_path, cfg, 0.2), plain_sumo_fcd(cfg, tmp_path / "plain.xml", 0, *with_agents)
    agent_roads = set(fcd.loc[fcd["type"].isin(AGENT_TYPES), "lane"].str.split("_").str[0])
    road = fcd["lane"].str.split("_").str[0]
    ours = fcd[~road.isin(agent_roads)].reset_index(drop=True)
    theirs = plain[~plain["lane"].str.split("_").str[0].isin(agent_roads)].reset_index(drop=True)
    assert 0 < len(agent_roads) < 8 and len(ours) > 500
    pd.testing.assert_frame_equal(ours, theirs)


@pytest.mark.sumo
def test_a_sumocfg_asking_for_the_ballistic_update_runs_with_it(tmp_path):
    """behave states the position update on SUMO's command line (its agents' vTypes would turn SUMO
    to the ballistic one by themselves), so it must pass on the sumocfg's own choice."""
    cfg = roads_scenario(tmp_path, roads=2, end=30.0)
    cfg.write_text(
        cfg.read_text().replace(
            "</time>", '</time><processing><step-method.ballistic value="on"/></processing>'
        )
    )
    assert read_sumocfg(cfg).ballistic
    ours = run_share(tmp_path, cfg, 0.0, seed=3)
    plain = plain_sumo_fcd(cfg, tmp_path / "plain.xml", seed=3)
    pd.testing.assert_frame_equal(ours.reset_index(drop=True), plain.reset_index(drop=True))
    cfg.write_text(cfg.read_text().replace('value="on"', 'value="maybe"'))
    with pytest.raises(BehaveError, match=r"step-method\.ballistic must be true or false, got 'maybe'"):
        read_sumocfg(cfg)


@pytest.mark.sumo
def test_sumocfg_options_hold_and_paths_resolve_against_its_folder(tmp_path):
    cfg = roads_scenario(tmp_path, roads=1, end=90.0)
    scenario = read_sumocfg(cfg)
    assert scenario.net == cfg.parent / "roads.net.xml" and scenario.routes == (
        cfg.parent / "demand.rou.xml",
    )
    config = config_from(cfg, policy=traffic_policy(tmp_path))
    assert (config.step_length, config.duration, config.keepers, config.background) == (0.5, 90.0, 0, 0)
    assert config_from(cfg, step_length=0.2, duration=10.0).step_length == 0.2


@pytest.mark.sumo
def test_sumocfg_times_in_sumos_clock_format_are_read_as_sumo_reads_them(tmp_path):
    cfg = roads_scenario(tmp_path, roads=1, end=90.0)
    text = cfg.read_text()

    def times(begin: str, end: str) -> str:
        return text.replace(
            '<begin value="0"/><end value="90.0"/>', f'<begin value="{begin}"/><end value="{end}"/>'
        )

    for begin, end, expected in (
        ("0:01:00", "1:00:30.5", (60.0, 3630.5)),
        ("1:00:00:00", "9e4", (86400.0, 9e4)),
    ):
        cfg.write_text(times(begin, end))
        assert (read_sumocfg(cfg).begin, read_sumocfg(cfg).end) == expected
    cfg.write_text(times("0", "1:30"))  # SUMO refuses MM:SS too
    with pytest.raises(BehaveError, match="end must be seconds or HH:MM:SS"):
        read_sumocfg(cfg)


def bad_scenario_input(tmp: Path) -> list[tuple[dict, str]]:
    cfg = roads_scenario(tmp, roads=1, end=30.0)
    broken = tmp / "broken.sumocfg"
    broken.write_text('<configuration><input><net-file value="nowhere.net.xml"/></input></configuration>')
    fcd = tmp / "o.xml"
    return [
        ({"sumocfg": tmp / "missing.sumocfg"}, "sumocfg not found"),
        ({"sumocfg": broken}, "names a file that does not exist"),
        ({"sumocfg": None, "share": 0.2, "fcd": fcd}, "needs --sumocfg"),
        ({"sumocfg": cfg, "net": get_scenario("highway").net}, "--net and --sumocfg"),
        (
            {"sumocfg": cfg, "share": 1.5, "policy": traffic_policy(tmp), "fcd": fcd},
            "share must be in [0, 1]",
        ),
        (
            {"sumocfg": cfg, "share": 0.2, "policy": PRETRAINED / "multi.pt", "fcd": fcd},
            "needs a traffic-driver policy",
        ),
    ]


@pytest.mark.sumo
def test_bad_scenario_input_is_refused_before_anything_runs(tmp_path):
    for given, message in bad_scenario_input(tmp_path):
        with pytest.raises(BehaveError, match=re.escape(message)):
            populate(config_from(**given))
        assert not (tmp_path / "o.xml").exists()


@pytest.mark.sumo
def test_the_cli_says_one_line_after_its_set_up_lines_without_traceback(tmp_path):
    cfg = roads_scenario(tmp_path, roads=1, end=30.0)
    out = subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "populate", "--sumocfg", str(cfg), "--share", "0.2",
         "--policy", str(PRETRAINED / "multi.pt"), "--fcd", str(tmp_path / "o.xml")],
        capture_output=True, text=True,
    )  # fmt: skip
    lines = out.stderr.strip().splitlines()
    assert out.returncode != 0 and "Traceback" not in out.stderr and len(lines) == 1
    assert lines[0].startswith("behave: error:") and "traffic-driver policy" in lines[0]


def test_geometry_is_cached_beside_a_big_net_and_rebuilt_when_the_net_changes(tmp_path, monkeypatch):
    monkeypatch.setattr("behaviors.road.geometry_build.CACHE_MIN_BYTES", 0)
    net = tmp_path / "h.net.xml"
    net.write_bytes(get_scenario("highway").net.read_bytes())
    said: list[str] = []
    built = load_geometry(net, cache=True, on_status=said.append)
    assert cache_path(net).is_file() and any("reading network" in s for s in said)
    said.clear()
    cached = load_geometry(net, cache=True, on_status=said.append)
    assert said == ["road geometry read from h.net.xml.behave-geometry.npz"]
    assert cached.lane_index == built.lane_index and cached.edges == built.edges
    assert cached.car_successors == built.car_successors
    np.testing.assert_array_equal(cached.axis_angle, built.axis_angle)
    np.testing.assert_array_equal(cached.cell_segments, built.cell_segments)
    os.utime(net, ns=(1, 1))  # the net changed (its mtime): the cache no longer holds
    said.clear()
    load_geometry(net, cache=True, on_status=said.append)
    assert any("reading network" in s for s in said)


@pytest.mark.sumo
def test_only_car_lanes_count_and_borders_only_along_multi_lane_car_edges(tmp_path):
    """A street with one car lane and a sidewalk is a one-lane road; the sidewalk is no lane."""
    nodes = '<node id="a" x="0" y="0"/><node id="b" x="300" y="0"/><node id="c" x="600" y="0"/>'
    edges = (
        '<edge id="main" from="a" to="b" numLanes="2" speed="30"/>'
        '<edge id="street" from="b" to="c" numLanes="1" speed="14" sidewalkWidth="2.0"/>'
    )
    geometry = load_geometry(netconvert(tmp_path, "s", nodes, edges))
    assert geometry.edges["street"].lanes == 1 and "street_0" not in geometry.lane_index
    assert geometry.lane_number[geometry.lane_index["street_1"]] == 0
    assert len(geometry.seg_a) and geometry.seg_a[:, 0].max() <= 300.0 + 1e-6  # no border along the street


def signal_net(tmp: Path) -> Path:
    """Two 2-lane roads meeting at a signal that stays red for 1,000 s."""
    nodes = (
        '<node id="a" x="0" y="0"/><node id="j" x="400" y="0" type="traffic_light"/>'
        '<node id="b" x="800" y="0"/>'
    )
    edges = (
        '<edge id="in" from="a" to="j" numLanes="2" speed="25"/>'
        '<edge id="out" from="j" to="b" numLanes="2" speed="25"/>'
    )
    (tmp / "red.tll.xml").write_text(
        '<tlLogics><tlLogic id="j" type="static" programID="0" offset="0">'
        '<phase duration="1000" state="rr"/><phase duration="10" state="GG"/></tlLogic></tlLogics>'
    )
    return netconvert(tmp, "sig", nodes, edges, "--tllogic-files", str(tmp / "red.tll.xml"))


@pytest.mark.sumo
def test_an_agent_stops_at_a_red_light_instead_of_entering_the_junction(tmp_path):
    """Without the handover the policy (here: full throttle) drives through the red at speed."""
    net = signal_net(tmp_path)
    fleet = Fleet(load_geometry(net), CarModel(), 0.2, PhaseTimer(), make_driver("traffic"))
    options = SimOptions(net=net, additional=(get_scenario("tiny").vtypes,), step_length=0.2)
    with SumoSim(options) as sim:
        sim.add_route("through", ["in", "out"])
        sim.add_vehicle("agent", "through", "behave_keeper", lane=0, pos=20.0, speed=20.0)
        sim.step()
        sim.take_control(["agent"])
        fleet.add(["agent"], np.array([20.0]), np.array([0.0]), fixed_styles(np.array([0.9])))
        lanes = set()
        for _ in range(300):  # 60 s
            fleet.sense(sim, sim.read_vehicles(), True)
            fleet.act(sim, np.array([[0.0, 1.0, 0.0]], np.float32))
            sim.step()
            lanes.add(sim.read_agents(["agent"]).lane_id[0])
        assert lanes <= {"in_0", "in_1"} and fleet.rows.handed[0] and fleet.handovers == 1
        assert float(sim.read_speeds(["agent"])[0]) < 0.1  # waiting at the line


@pytest.mark.sumo
def test_routes_add_to_the_scenarios_own_demand(tmp_path):
    cfg = roads_scenario(tmp_path, roads=1, end=20.0)
    extra = tmp_path / "extra.rou.xml"
    extra.write_text(
        '<routes><vehicle id="guest" depart="1" departLane="1"><route edges="r0"/></vehicle></routes>'
    )
    fcd = tmp_path / "o.xml"
    populate(config_from(cfg, routes=extra, policy=traffic_policy(tmp_path), fcd=fcd))
    ids = set(read_fcd(fcd)["id"])
    assert (
        "guest" in ids
        and any(v.startswith("car0.") for v in ids)
        and any(v.startswith("lorry0.") for v in ids)
    )


@pytest.mark.sumo
def test_a_scenario_car_made_an_agent_moves_sideways_exactly_as_asked(tmp_path):
    """SUMO keeps the lane-change model a car departed with (the scenario's lcAccelLat 1, which
    smooths a sideways request); made an agent, the car moves as far as asked in one step."""
    cfg = roads_scenario(tmp_path, roads=1, end=30.0)
    scenario = read_sumocfg(cfg)
    options = SimOptions(net=scenario.net, routes=scenario.routes, additional=(get_scenario("tiny").vtypes,),
                         step_length=0.5)  # fmt: skip
    with SumoSim(options) as sim:
        for _ in range(10):
            sim.step()
        cars = [v for v in sim.vehicle_ids() if v.startswith("car")][:3]
        assert len(cars) == 3
        for vid in cars:
            sim.set_agent_type(vid, KEEPER_TYPE)
        sim.take_control(cars)
        for _ in range(4):
            before = sim.read_lane_places(cars)[1]
            asked = np.where(before > 0, -0.3, 0.3)
            sim.command_agents(cars, sim.read_speeds(cars), asked)
            sim.step()
            assert np.allclose(sim.read_lane_places(cars)[1] - before, asked, atol=1e-6)
            assert np.allclose(sim.read_lateral_speeds(cars), asked / 0.5, atol=1e-6)  # signed as posLat
