"""The bundled SUMO scenarios: geometry read back with sumolib, behaviour checked with libsumo."""

from __future__ import annotations

import math
import subprocess
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import sumolib

from behaviors.errors import BehaveError
from behaviors.report.fcd_read import fcd_options, read_fcd
from behaviors.sumo.sumo_home import sumo_binary
from sumo_scenarios import (
    SCENARIO_NAMES,
    Scenario,
    build_ring,
    build_scenarios,
    get_scenario,
    route_edges,
    scenario_info,
    training_roads,
)
from sumo_scenarios.build import shared_vtypes
from sumo_scenarios.net import lane_widths

EXPECTED = {"ring": (3, 3.5), "highway": (3, 3.5), "tiny": (2, 3.2)}
DT = 0.1


def read_net(scenario: Scenario) -> sumolib.net.Net:
    return sumolib.net.readNet(str(scenario.net))


@contextmanager
def simulation(scenario: Scenario) -> Iterator[object]:
    """libsumo runs one simulation per process: always close it, even when a check fails."""
    import libsumo

    libsumo.start(
        ["sumo", "-n", str(scenario.net), "-r", str(scenario.routes), "-a", str(scenario.vtypes),
         "--step-length", str(DT), "--lateral-resolution", "0.4", "--no-step-log",
         "--no-warnings", "--seed", "0"]
    )  # fmt: skip
    try:
        yield libsumo
    finally:
        libsumo.close()


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_bundled_scenario_lanes_and_width(name: str) -> None:
    scenario = get_scenario(name)
    lanes, width = EXPECTED[name]
    net = read_net(scenario)
    edges = [e for e in net.getEdges() if e.getFunction() == ""]
    assert {e.getLaneNumber() for e in edges} == {lanes}
    assert {ln.getWidth() for e in edges for ln in e.getLanes()} == {width}
    info = scenario_info(scenario)
    assert (info.lanes, info.lane_width_m, info.edges) == (lanes, width, len(edges))
    assert info.looping == (name == "ring")
    assert set(route_edges(scenario)) == {e.getID() for e in edges}


@pytest.mark.parametrize(
    "scenario", [get_scenario(n) for n in SCENARIO_NAMES] + training_roads(ramps=True), ids=lambda s: s.name
)
def test_the_streaming_net_reader_agrees_with_sumolib(scenario: Scenario) -> None:
    """sumo_scenarios.net (the one reader) against sumolib's object model: every lane's width, and
    the route's length over the mean lane lengths of its edges and of the junctions between them."""
    net = sumolib.net.readNet(str(scenario.net), withInternal=True)
    assert lane_widths(scenario.net) == {
        ln.getID(): ln.getWidth() for e in net.getEdges() for ln in e.getLanes()
    }

    def mean_length(edge: sumolib.net.edge.Edge) -> float:
        return sum(ln.getLength() for ln in edge.getLanes()) / edge.getLaneNumber()

    route = [net.getEdge(e) for e in route_edges(scenario)]
    hops = zip(route, route[1:] + route[:1] if scenario.looping else route[1:], strict=False)
    vias = [c.getViaLaneID() for a, b in hops for c in a.getConnections(b)[:1]]
    length = sum(map(mean_length, route)) + sum(mean_length(net.getLane(v).getEdge()) for v in vias if v)
    assert scenario_info(scenario).length_m == length


def test_ring_is_a_closed_three_km_loop_with_lane_to_lane_connections() -> None:
    scenario = get_scenario("ring")
    net = read_net(scenario)
    route = [net.getEdge(e) for e in route_edges(scenario)]
    assert abs(scenario_info(scenario).length_m - 3000.0) < 300.0
    for edge, nxt in zip(route, route[1:] + route[:1], strict=True):
        assert edge.getToNode() == nxt.getFromNode()
        connections = edge.getOutgoing()[nxt]
        pairs = {(c.getFromLane().getIndex(), c.getToLane().getIndex()) for c in connections}
        assert pairs == {(i, i) for i in range(edge.getLaneNumber())}
    assert all(250.0 <= e.getLength() <= 350.0 for e in route if len(e.getShape()) == 2)


def max_curvature(shape: list[tuple[float, float]]) -> float:
    """Largest heading change per metre between consecutive shape segments."""
    best = 0.0
    for a, b, c in zip(shape, shape[1:], shape[2:], strict=False):
        h1 = math.atan2(b[1] - a[1], b[0] - a[0])
        h2 = math.atan2(c[1] - b[1], c[0] - b[0])
        turn = abs((h2 - h1 + math.pi) % (2 * math.pi) - math.pi)
        ds = (math.dist(a, b) + math.dist(b, c)) / 2
        best = max(best, turn / ds)
    return best


def test_ring_curves_have_a_200_m_radius_and_dense_points() -> None:
    net = read_net(get_scenario("ring"))
    curves = [e for e in net.getEdges() if e.getFunction() == "" and len(e.getShape()) > 2]
    assert len(curves) == 2
    for edge in curves:
        centre = edge.getLanes()[1].getShape()  # the middle of three lanes is the centre line
        assert 1 / max_curvature(centre) == pytest.approx(200.0, rel=0.05)
        assert edge.getLength() / (len(centre) - 1) < 3.5


@pytest.mark.sumo
def test_highway_has_a_utm_projection() -> None:
    scenario = get_scenario("highway")
    net = read_net(scenario)
    assert net.hasGeoProj()
    assert net.getLocationOffset() == [-690000.0, -5336000.0]  # real UTM-32 metres
    with simulation(scenario) as sim:
        lon, lat = sim.simulation.convertGeo(0.0, 0.0)
    assert (lon, lat) == (pytest.approx(11.5545, abs=1e-3), pytest.approx(48.1488, abs=1e-3))


@pytest.mark.sumo
def test_highway_fcd_distance_is_the_road_position(tmp_path) -> None:
    """Edges carry kilometrage 0, 300, ..., so FCD `distance` runs on across edges and junctions."""
    scenario = get_scenario("highway")
    cars = tmp_path / "cars.rou.xml"
    cars.write_text(
        '<routes><vehicle id="late" route="main" depart="0" departPos="150" departSpeed="max"/>'
        '<vehicle id="early" route="main" depart="5" departLane="2" departSpeed="max"/></routes>'
    )
    fcd = tmp_path / "fcd.csv"
    sumo = [sumo_binary("sumo"), "-n", str(scenario.net), "-r", f"{scenario.routes},{cars}"]
    sumo += ["--step-length", str(DT), "--end", "120", "--no-step-log", "--no-warnings"]
    subprocess.run([*sumo, *fcd_options(fcd, geo=False)], check=True, capture_output=True)
    df = read_fcd(fcd).sort_values(["id", "time"])
    assert set(df["id"]) == {"late", "early"}
    assert set(df["lane"].str.rsplit("_", n=1).str[0]) >= set(route_edges(scenario))  # all 10 edges
    for _, trace in df.groupby("id"):
        assert (trace["distance"].diff().dropna() >= -0.01).all()
        assert trace["distance"].max() > 2900  # not the 0-300 m sawtooth of the edge positions
        start = trace["distance"].iloc[0]
        # the odometer also counts the 0.1 m junction lanes, which carry no kilometrage
        offset = (trace["distance"] - trace["odometer"]).to_numpy()
        assert offset == pytest.approx(start, abs=0.1 * 9 + 0.02)


@pytest.mark.sumo
def test_build_reproduces_the_shipped_networks(tmp_path) -> None:
    built = build_scenarios(tmp_path)
    roads = training_roads(ramps=True)
    assert [s.name for s in built] == [*SCENARIO_NAMES, *(r.name for r in roads)]
    for scenario, shipped in zip(built, [*map(get_scenario, SCENARIO_NAMES), *roads], strict=True):
        assert scenario.net.parent == tmp_path / scenario.name
        assert scenario_info(scenario) == scenario_info(shipped)


def test_the_shipped_vtypes_are_the_ones_the_build_writes(tmp_path) -> None:
    shipped = get_scenario("highway").vtypes
    assert shared_vtypes(tmp_path / "road").read_bytes() == shipped.read_bytes()


@pytest.mark.sumo
def test_the_ramp_roads_have_cars_joining_and_leaving_and_only_the_wider_family_has_them() -> None:
    plain, wide = training_roads(), training_roads(ramps=True)
    assert len(plain) == 5 and len(wide) == 7 and [r.name for r in wide[:5]] == [r.name for r in plain]
    seen: set[str] = set()
    with simulation(wide[-1]) as sumo:
        for _ in range(1500):  # 150 s: the first cars from the ramp drive 3.2 km to the exit
            sumo.simulationStep()
            seen.update(sumo.vehicle.getRoadID(v) for v in sumo.vehicle.getIDList())
    assert {"ramp_in", "ramp_out"} <= seen


@pytest.mark.sumo
def test_the_motorway_has_a_ramp_a_weave_and_an_exit_that_cars_use() -> None:
    net = read_net(get_scenario("motorway"))
    lanes = {e.getID(): e.getLaneNumber() for e in net.getEdges() if e.getFunction() == ""}
    assert lanes == {"m1": 3, "m2": 4, "m3": 3, "r0": 1, "x0": 1}
    assert {ln.getWidth() for e in net.getEdges() for ln in e.getLanes()} == {3.75}
    m2 = net.getEdge("m2")
    assert [c.getTo().getID() for c in m2.getLanes()[0].getOutgoing()] == ["x0"]  # lane 0 leaves
    seen: set[str] = set()
    with simulation(get_scenario("motorway")) as sumo:
        for _ in range(1200):  # 120 s: the first cars from the main road reach the exit
            sumo.simulationStep()
            seen.update(sumo.vehicle.getRoadID(v) for v in sumo.vehicle.getIDList())
    assert {"m1", "m2", "m3", "r0", "x0"} <= seen


@pytest.mark.sumo
def test_build_ring_scales_for_benchmarks(tmp_path) -> None:
    scenario = build_ring(tmp_path / "big", name="big", straight=4000.0, lanes=4)
    info = scenario_info(scenario)
    assert (info.name, info.lanes, info.looping) == ("big", 4, True)
    assert info.length_m == pytest.approx(8000 + 2 * math.pi * 200, rel=0.01)


@pytest.mark.sumo
def test_ring_cars_circle_without_teleports() -> None:
    scenario = get_scenario("ring")
    lap = scenario_info(scenario).length_m
    with simulation(scenario) as sim:
        for lane in range(3):
            sim.vehicle.add(
                f"k{lane}", "loop", typeID="behave_keeper", departLane=str(lane),
                departPos=str(20.0 * lane), departSpeed="0",
            )  # fmt: skip
        teleports = 0
        for _ in range(3000):
            sim.simulationStep()
            teleports += sim.simulation.getStartingTeleportNumber()
        assert sorted(sim.vehicle.getIDList()) == ["k0", "k1", "k2"]
        assert teleports == 0
        assert min(sim.vehicle.getDistance(v) for v in sim.vehicle.getIDList()) > lap
        # speedFactor 1 with speedDev 0: Krauss drives exactly at the limit, not 1.06x it
        assert [sim.vehicle.getSpeed(v) for v in sim.vehicle.getIDList()] == pytest.approx([33.33] * 3)


@pytest.mark.sumo
def test_change_sublane_moves_exactly_the_requested_metres() -> None:
    with simulation(get_scenario("tiny")) as sim:
        sim.vehicle.add("a", "main", typeID="behave_overtaker", departLane="0", departSpeed="20")
        sim.simulationStep()
        sim.vehicle.setSpeedMode("a", 0)
        sim.vehicle.setLaneChangeMode("a", 0)
        sim.simulationStep()
        before = sim.vehicle.getLateralLanePosition("a")
        sim.vehicle.changeSublane("a", 0.3)
        sim.simulationStep()
        assert sim.vehicle.getLateralLanePosition("a") - before == pytest.approx(0.3, abs=1e-6)


def test_vtypes_define_agents_and_sumo_driven_cars() -> None:
    root = ET.parse(get_scenario("tiny").vtypes).getroot()
    types = {t.get("id"): t.attrib for t in root.iter("vType")}
    assert set(types) == {
        "behave_keeper",
        "behave_overtaker",
        "behave_lorry",
        "behave_passive",
        "behave_background",
    }
    physics = {k: v for k, v in types["behave_keeper"].items() if k not in ("id", "color")}
    assert physics == {k: v for k, v in types["behave_overtaker"].items() if k not in ("id", "color")}
    assert types["behave_keeper"]["color"] != types["behave_overtaker"]["color"]
    assert float(types["behave_passive"]["maxSpeed"]) < float(types["behave_keeper"]["maxSpeed"])
    lorry = types["behave_lorry"]
    assert lorry["vClass"] == "truck" and float(lorry["length"]) > 3 * float(types["behave_keeper"]["length"])
    assert float(lorry["accel"]) < float(types["behave_keeper"]["accel"])


def test_unknown_scenario_names_the_choices() -> None:
    with pytest.raises(
        BehaveError, match=r"unknown scenario 'nope' \(choose from ring, highway, tiny, motorway\)"
    ):
        get_scenario("nope")


@pytest.mark.sumo
def test_cli_lists_and_builds(tmp_path) -> None:
    from typer.testing import CliRunner

    from behaviors.cli.scenario import app

    listed = CliRunner().invoke(app, ["list"])
    assert listed.exit_code == 0, listed.output
    assert all(name in listed.output for name in SCENARIO_NAMES)
    built = CliRunner().invoke(app, ["build", "--out", str(tmp_path)])
    assert built.exit_code == 0, built.output
    assert (tmp_path / "ring" / "ring.net.xml").exists()


@pytest.mark.sumo
def test_netconvert_failure_is_a_behave_error(tmp_path) -> None:
    with pytest.raises(BehaveError, match="needs at least one lane"):
        build_ring(tmp_path, lanes=0)
