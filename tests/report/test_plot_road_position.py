"""`behave plot` draws by road position on a net without kilometrage: a jam is at
one height whichever place its cars came from. The bundled motorway's edges carry no kilometrage, so
SUMO's FCD `distance` restarts on every edge and plot fell back to the distance since insertion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import behave

from behaviors.report.plot import ALONG_LABELS, road_offsets, road_positions, time_space_axis
from sumo_scenarios import get_scenario

MOTORWAY = get_scenario("motorway").net


def test_edges_sit_where_the_road_reaches_them() -> None:
    """m1 -> m2 -> m3 (and the exit x0); the on-ramp r0 ends where it joins m2; a ring's lap runs on."""
    offsets = road_offsets(MOTORWAY)
    assert offsets["m1"] == 0.0
    assert offsets["m2"] == pytest.approx(1496, abs=1)
    assert offsets["m3"] == offsets["x0"] == pytest.approx(offsets["m2"] + 1217, abs=1)
    assert offsets["r0"] == pytest.approx(offsets["m2"] - 457, abs=1)
    ring = road_offsets(get_scenario("ring").net)
    assert ring["e0"] == 0.0 and sorted(ring.values()) == list(ring.values())


def jam() -> pd.DataFrame:
    """Two cars standing 300 m into m2: one came along m1 from the road's start, one from the
    on-ramp; one record of the first inside the junction between m1 and m2."""
    rows = [
        ("main", 0.0, "m1_1", 1400.0, 1400.0), ("main", 1.0, ":w1_0_1", 5.0, 1500.0),
        ("main", 2.0, "m2_1", 100.0, 1600.0), ("main", 3.0, "m2_1", 300.0, 1800.0),
        ("ramp", 0.0, "r0_0", 300.0, 0.0), ("ramp", 2.0, "m2_0", 290.0, 450.0),
        ("ramp", 3.0, "m2_0", 300.0, 460.0),
    ]  # fmt: skip
    df = pd.DataFrame(rows, columns=["id", "time", "lane", "pos", "odometer"])
    return df.assign(type="behave_background", posLat=0.0, distance=df["pos"])  # SUMO's, per edge


def test_a_jam_is_at_one_road_position_whatever_the_way_in() -> None:
    df = jam()
    road = road_positions(df, MOTORWAY)
    assert road is not None
    at_jam = road[df["time"] == 3.0].to_numpy()
    assert at_jam == pytest.approx([1796, 1796], abs=1)  # the odometer has them 1,340 m apart
    inside = road[df["lane"].str.startswith(":")].to_numpy()
    assert np.isfinite(inside).all() and 1400 < inside[0] < 1596  # between its neighbours
    drawn, along = time_space_axis(df, MOTORWAY)
    assert drawn["road"].equals(road)
    assert (along, ALONG_LABELS[along]) == ("road", "road position along the net [m]")
    assert time_space_axis(df, None)[1] == "odometer"  # no net: all there is


@pytest.mark.sumo
def test_plot_draws_a_csv_fcd_along_the_net(tmp_path: Path) -> None:
    """`behave plot --net` on a csv FCD of the jam: drawn (the axis chosen as time_space_axis does)."""
    fcd = tmp_path / "fcd.csv"
    jam().rename(columns={c: f"vehicle_{c}" for c in ("id", "lane", "pos", "odometer", "type", "posLat",
                                                          "distance")}).rename(
        columns={"time": "timestep_time"}).to_csv(fcd, sep=";", index=False)  # fmt: skip
    done = behave("plot", str(fcd), "--out", str(tmp_path / "p.png"), "--net", "motorway")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "p.png").stat().st_size > 10_000
