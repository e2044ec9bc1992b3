"""The shipped policy drives OSM-like nets built here with netconvert: left-hand, and 2 lanes of 3.2 m.

Each net has its own demand (through, off at the exit, on from the ramp) and runs as a user's
scenario with half its passenger cars as agents (`--sumocfg --share 0.5`, the shield on as
populate's default): no agent may leave the road, crash or stand still, and agents whose route
ends on the exit ramp get there, SUMO's driver taking them across the lane change the policy
never learnt.
"""

from __future__ import annotations

import pandas as pd
import pytest

from behaviors.report.agents_table import agents_path
from behaviors.report.fcd_read import read_fcd
from behaviors.report.realism import measure
from behaviors.report.realism_tracks import read_lanes
from behaviors.road.geometry_build import load_geometry
from behaviors.run.populate import populate
from behaviors.run.populate_config import config_from
from sumo_scenarios.osm_like import build_osm_like

pytestmark = pytest.mark.sumo

DURATION = 100.0  # s: cars leaving in the first ~20 s reach the end of the exit ramp


@pytest.mark.parametrize("name", ["motorway3_lefthand", "carriageway2"])
def test_agents_drive_an_osm_like_net_and_leave_it_by_the_exit(tmp_path, name):
    net = build_osm_like(name, tmp_path / name)
    fcd = tmp_path / "fcd.parquet"
    summary = populate(config_from(net.sumocfg, share=0.5, seed=1, duration=DURATION, fcd=fcd))
    agents = pd.read_csv(agents_path(fcd))
    ended = agents["end_reason"].value_counts().to_dict()
    assert len(agents) >= 20 and summary.collisions == summary.off_tracks == 0, ended
    assert set(ended) <= {"arrived", "still_driving"}, ended
    assert summary.handovers > 0 and agents["longest_standstill_s"].max() < 5.0
    last_lane = read_fcd(fcd).groupby("id")["lane"].last()
    leaving = agents[agents["id"].str.startswith("leaving.")]
    out = leaving.loc[leaving["end_reason"] == "arrived", "id"]
    assert len(out) >= 1 and (last_lane[out].str.rpartition("_")[0] == net.exit_edge).all()
    joined = agents.loc[agents["id"].str.startswith("joining."), "id"]
    assert (last_lane[joined].str.rpartition("_")[0] != net.ramp_edge).any()  # onto the motorway
    # the report tells the lane changes a route asks for from the others: on carriageway2 cars come
    # on through an acceleration lane that ends (on motorway3 every car departs in a lane that
    # leads where it goes: the exit's cars stay in the lane that becomes the exit)
    table = measure(read_fcd(fcd), read_lanes(net.net), skip_s=0).table
    every, chosen = table.loc["lane_changes_per_km"], table.loc["discretionary_lane_changes_per_km"]
    assert (chosen <= every).all() and (chosen < every).any() == (name == "carriageway2"), table


def test_the_geometry_knows_the_lane_each_lane_leads_into(tmp_path):
    """Sensing follows a lane through a junction into the lane it leads into (lanes.lane_coordinates);
    where a lane ends, or parts (to the exit or on), there is no one such lane."""
    built = build_osm_like("lanedrop", tmp_path)
    geometry = load_geometry(built.net)

    def leads_into(lane: str) -> str | None:
        row = geometry.lane_next[geometry.lane_index[lane]]
        return geometry.lane_names[row] if row >= 0 else None

    assert leads_into("m0_1") == ":n1_0_0" and leads_into(":n1_0_0") == "m1_0"  # on past the dropped lane
    assert leads_into("m0_0") is None  # the dropped lane
    assert leads_into("m2_0") is None  # to the exit or on: the route's choice
    assert leads_into("m2_1") == ":n3_1_1" and leads_into(":n3_1_1") == "m3_1"
    next_lanes = read_lanes(built.net).next_lanes  # the realism report's: normal lane -> normal lanes
    assert next_lanes["m0_0"] == frozenset() and next_lanes["m0_1"] == {"m1_0"}
    assert next_lanes["m2_0"] == {f"{built.exit_edge}_0", "m3_0"} and next_lanes["m2_1"] == {"m3_1"}
