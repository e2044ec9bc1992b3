"""populate tells the truth: SUMO speeds, how agents ended, standstills, car-only routes, bounded routes."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from behaviors.report.agents_table import columns as agent_columns
from behaviors.report.fcd_read import read_fcd
from behaviors.road.geometry_build import load_geometry
from behaviors.road.routes import ROUTE_VARIANTS, route_graph
from behaviors.run.fcd_sealing import partial_path
from behaviors.run.populate import populate
from behaviors.run.populate_config import DEFAULT_POLICY, PopulateConfig
from behaviors.run.population import Population
from behaviors.run.records import end_reasons
from behaviors.sumo.sumo_home import sumo_binary


def netconvert(tmp: Path, nodes: str, edges: str, connections: str = "") -> Path:
    """A net built by netconvert from plain XML, as a user would build one."""
    (tmp / "n.nod.xml").write_text(f"<nodes>{nodes}</nodes>")
    (tmp / "n.edg.xml").write_text(f"<edges>{edges}</edges>")
    (tmp / "n.con.xml").write_text(f"<connections>{connections}</connections>")
    net = tmp / "n.net.xml"
    subprocess.run(
        [sumo_binary("netconvert"), "-n", str(tmp / "n.nod.xml"), "-e", str(tmp / "n.edg.xml"),
         "-x", str(tmp / "n.con.xml"), "-o", str(net), "--no-turnarounds"],
        check=True, capture_output=True,
    )  # fmt: skip
    return net


def blocked_road(tmp: Path) -> tuple[Path, Path]:
    """A 1 km three-lane road whose three lanes SUMO cars block, stopped at 900 m for the whole run."""
    net = netconvert(
        tmp,
        '<node id="a" x="0" y="0"/><node id="b" x="1000" y="0"/>',
        '<edge id="road" from="a" to="b" numLanes="3" width="3.75" speed="25"/>',
    )
    blockers = "".join(
        f'<vehicle id="block{k}" type="blocker" route="r" depart="0" departLane="{k}" departPos="900" '
        f'departSpeed="0"><stop lane="road_{k}" endPos="905" duration="1000"/></vehicle>'
        for k in range(3)
    )
    routes = tmp / "blockers.rou.xml"
    routes.write_text(
        f'<routes><vType id="blocker" vClass="passenger" length="5" width="1.8"/>'
        f'<route id="r" edges="road"/>{blockers}</routes>'
    )
    return net, routes


def bus_town(tmp: Path) -> Path:
    """'main': sidewalk, bus lane, two car lanes. Straight on to 'onward' only from the bus lane;
    right into 'street' (sidewalk, bus lane, one car lane) from a car lane."""
    return netconvert(
        tmp,
        '<node id="a" x="0" y="0"/><node id="b" x="400" y="0"/><node id="c" x="800" y="0"/>'
        '<node id="d" x="400" y="-400"/>',
        '<edge id="main" from="a" to="b" numLanes="4" speed="25">'
        '<lane index="0" allow="pedestrian" width="2.0"/><lane index="1" allow="bus"/></edge>'
        '<edge id="onward" from="b" to="c" numLanes="3" speed="25"><lane index="0" allow="bus"/></edge>'
        '<edge id="street" from="b" to="d" numLanes="3" speed="14">'
        '<lane index="0" allow="pedestrian" width="2.0"/><lane index="1" allow="bus"/></edge>',
        '<connection from="main" to="onward" fromLane="1" toLane="0"/>'
        '<connection from="main" to="onward" fromLane="1" toLane="1"/>'
        '<connection from="main" to="street" fromLane="2" toLane="2"/>',
    )


def read_agents(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), list(reader)


@pytest.mark.sumo
def test_agents_stuck_behind_stopped_cars_are_reported_with_sumos_speeds(tmp_path):
    net, routes = blocked_road(tmp_path)
    fcd = tmp_path / "out" / "run.xml"
    summary = populate(PopulateConfig(net=net, routes=routes, policy=DEFAULT_POLICY, overtakers=0, keepers=6,
                                      background=0, duration=70.0, fcd=fcd, seed=0))  # fmt: skip
    columns, agents = read_agents(tmp_path / "out" / "run.agents.csv")
    assert columns == list(agent_columns("populate"))
    assert len(agents) == summary.vehicles == 6
    out = summary.as_dict()
    for reason in ("arrived", "collision", "off_track", "no_progress", "still_driving"):
        assert out[f"agents_{reason}"] == sum(a["end_reason"] == reason for a in agents)
    standing = [float(a["longest_standstill_s"]) for a in agents]
    assert out["agents_standing_30s"] == sum(t >= 30 for t in standing) >= 1  # they wait behind the blockers
    assert out["longest_standstill_s"] == max(standing) >= 30
    for a in agents:
        assert (a["behaviour"], a["vtype"]) == ("keeper", "behave_keeper")
        assert float(a["depart_s"]) <= float(a["end_s"]) <= 70.0 + 1e-6
        assert 0.0 <= float(a["distance_m"]) <= 1000.0
        if a["end_reason"] == "still_driving":
            assert float(a["end_s"]) == pytest.approx(70.0)
    # the mean speed is SUMO's: the FCD's keeper rows, without each agent's insertion step
    df = read_fcd(fcd)
    keepers = df[df["type"] == "behave_keeper"].sort_values("time")
    after_insertion = keepers[keepers.duplicated("id")]
    assert out["keeper_mean_speed"] == pytest.approx(after_insertion["speed"].mean(), abs=0.01)
    assert out["keeper_mean_speed"] < 15.0  # commanded speeds would look like a free road


def test_an_agent_ends_by_the_first_thing_that_happened_to_it():
    crashed = np.array([True, False, False, False, False, True])
    off_track = np.array([True, True, False, False, False, False])
    gone = np.array([False, False, True, True, False, False])
    arrived = np.array([False, False, True, False, False, False])
    reasons = end_reasons(crashed, off_track, gone, arrived)
    assert reasons.tolist() == ["collision", "off_track", "arrived", "no_progress", "", "collision"]


@pytest.mark.sumo
def test_routes_use_only_car_lanes_and_the_connections_cars_may_take(tmp_path):
    net = bus_town(tmp_path)
    graph = route_graph(load_geometry(net))
    assert "street" not in graph.edges  # one car lane beside a bus lane and a sidewalk: single-lane
    main, onward = graph.edges.index("main"), graph.edges.index("onward")
    assert graph.lanes[main] == graph.lanes[onward] == 2
    assert onward not in graph.successors[main]  # only the bus lane goes straight on
    # the crash this was: libsumo "has no valid route. No connection between edge 'main' and edge 'onward'"
    summary = populate(PopulateConfig(net=net, policy=DEFAULT_POLICY, overtakers=4, keepers=4, background=4,
                                      duration=10.0, fcd=tmp_path / "fcd.xml", seed=0))  # fmt: skip
    assert summary.vehicles == 12


@pytest.mark.sumo
def test_repeated_insertions_reuse_sumos_routes(tmp_path):
    import libsumo

    config = PopulateConfig(policy=DEFAULT_POLICY, overtakers=0, keepers=0, background=20, duration=60.0,
                            fcd=tmp_path / "fcd.xml", seed=0)  # fmt: skip
    population = Population(config)
    population.start(partial_path(config.fcd))
    try:
        counts = []
        for _ in range(30):
            population.step()
            population.sim.remove(sorted(population.background_ids))  # everyone leaves ...
            population.background_ids.clear()
            population.insert("background", 20)  # ... and comes back on a new route draw
            counts.append(len(libsumo.route.getIDList()))
    finally:
        population.close()
    assert counts[-1] == counts[9]  # no new routes once the draws repeat
    assert counts[-1] <= ROUTE_VARIANTS * len(population.graph.edges)


@pytest.mark.sumo
def test_cli_prints_how_the_agents_ended(tmp_path):
    fcd = tmp_path / "fcd.xml"
    result = subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "populate", "--overtakers", "1", "--keepers", "1",
         "--background", "0", "--duration", "5", "--fcd", str(fcd)],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    for line in ("agents arrived", "agents off track", "agents still driving", "agents standing 30s",
                 "longest standstill"):  # fmt: skip
        assert line in result.stdout
    assert f"per-agent table written to {tmp_path / 'fcd.agents.csv'}" in " ".join(result.stdout.split())
    assert (tmp_path / "fcd.agents.csv").is_file()
