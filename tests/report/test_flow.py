"""The fundamental diagram: Edie's definitions on trajectories with known flow and density, and
`behave report` writing flow.csv/flow.png for a real populate FCD."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from behaviors.report.fcd_read import read_fcd
from behaviors.report.flow import ALL, RoadEdges, edie_cells, region, road_from_fcd, summary
from sumo_scenarios import get_scenario
from tests.report.test_realism import populated, report

EDGE_M = 1000.0
STEP = 0.5


def circulating(per_lane: int, lanes: int, speed: float, duration: float, vtype: str = "car") -> pd.DataFrame:
    """`per_lane` cars evenly spaced on each lane of one edge, all at `speed`, wrapping at its end
    (a ring cut open): the density and flow are known exactly."""
    rows = []
    times = np.arange(0.0, duration, STEP)
    for lane in range(lanes):
        for k in range(per_lane):
            start = k * EDGE_M / per_lane
            pos = (start + speed * times) % EDGE_M
            rows.append(pd.DataFrame({"id": f"{vtype}{lane}.{k}", "time": times, "lane": f"e_{lane}",
                                      "pos": pos, "speed": speed, "type": vtype}))  # fmt: skip
    return pd.concat(rows, ignore_index=True)


def test_steady_traffic_has_the_known_flow_and_density() -> None:
    # 5 cars per lane on 1 km, 2 lanes, 20 m/s: k = 5 veh/lane-km, q = k * 72 km/h = 360 veh/h/lane
    df = circulating(per_lane=5, lanes=2, speed=20.0, duration=120.0)
    road = RoadEdges({"e": EDGE_M}, {"e": 2})
    cells = edie_cells(df, road, cell_m=250.0, window_s=60.0)
    assert len(cells) == 4 * 2  # 4 pieces x 2 windows, group `all` only
    whole = region(cells).loc[ALL]
    assert whole["density"] == pytest.approx(5.0, rel=1e-6)
    assert whole["flow"] == pytest.approx(360.0, rel=1e-6)
    assert whole["speed"] == pytest.approx(20.0, rel=1e-6)
    # every cell sees the same: uniform spacing, uniform speed
    assert cells["density"].to_numpy() == pytest.approx(np.full(8, 5.0), rel=0.05)
    assert cells["flow"].to_numpy() == pytest.approx(np.full(8, 360.0), rel=0.05)


def test_flow_and_density_are_not_swapped_and_lanes_count() -> None:
    """Slow dense traffic and fast light traffic: density is time spent, flow distance travelled,
    both per lane (the 3-lane road holds the same cars per lane-km as the 1-lane one)."""
    slow = circulating(per_lane=30, lanes=3, speed=5.0, duration=60.0)  # k 30, q 30 * 18 = 540
    fast = circulating(per_lane=6, lanes=1, speed=30.0, duration=60.0)  # k 6, q 6 * 108 = 648
    slow_cells = edie_cells(slow, RoadEdges({"e": EDGE_M}, {"e": 3}), cell_m=EDGE_M, window_s=60.0)
    fast_cells = edie_cells(fast, RoadEdges({"e": EDGE_M}, {"e": 1}), cell_m=EDGE_M, window_s=60.0)
    assert region(slow_cells).loc[ALL, "density"] == pytest.approx(30.0)
    assert region(slow_cells).loc[ALL, "flow"] == pytest.approx(540.0)
    assert region(fast_cells).loc[ALL, "density"] == pytest.approx(6.0)
    assert region(fast_cells).loc[ALL, "flow"] == pytest.approx(648.0)
    # lanes read from the FCD: the highest index seen + 1
    assert road_from_fcd(slow).lanes == {"e": 3}


def test_groups_add_up_to_all_and_summary_per_group() -> None:
    cars = circulating(per_lane=4, lanes=2, speed=30.0, duration=240.0, vtype="sumo")
    agents = circulating(per_lane=2, lanes=2, speed=15.0, duration=240.0, vtype="keepers")
    df = pd.concat([cars, agents], ignore_index=True)
    cells = edie_cells(df, RoadEdges({"e": EDGE_M}, {"e": 2}), df["type"], cell_m=200.0, window_s=60.0)
    whole = region(cells)
    assert set(whole.index) == {"sumo", "keepers", ALL}
    assert whole.loc["sumo", "density"] == pytest.approx(4.0)
    assert whole.loc["keepers", "density"] == pytest.approx(2.0)
    assert whole.loc[ALL, "density"] == pytest.approx(6.0)
    assert whole.loc[ALL, "flow"] == pytest.approx(4 * 108 + 2 * 54)
    assert whole.loc["keepers", "speed"] == pytest.approx(15.0)
    table = summary(cells)
    assert list(table.index) == ["keepers", "sumo", ALL]
    assert table.loc[ALL, "max_flow"] == pytest.approx(540.0, rel=0.05)
    assert table.loc[ALL, "density_at_max_flow"] == pytest.approx(6.0, rel=0.05)


def test_internal_lanes_and_partial_windows_are_left_out() -> None:
    df = circulating(per_lane=5, lanes=1, speed=20.0, duration=90.0)  # one whole 60 s window
    junction = df.head(50).assign(lane=":j_0_0")
    cells = edie_cells(
        pd.concat([df, junction]), RoadEdges({"e": EDGE_M}, {"e": 1}), cell_m=EDGE_M, window_s=60.0
    )
    assert len(cells) == 1
    assert cells.loc[0, "density"] == pytest.approx(5.0)


@pytest.mark.sumo
def test_report_draws_the_fundamental_diagram_of_a_real_populate_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    fcd = populated(tmp_path)
    out = tmp_path / "report"
    net = get_scenario("highway").net
    args = [str(fcd), "--net", str(net), "--out", str(out), "--window-s", "20", "--cell-m", "300"]
    code, stdout, stderr = report(args, monkeypatch, capsys)
    assert code == 0, stderr
    assert "Flow against density" in stdout
    cells = pd.read_csv(out / "flow.csv")
    assert set(cells["group"]) == {"keepers", "overtakers", "sumo", ALL}
    assert set(cells["lanes"]) == {3} and set(cells["cell_m"]) == {300.0}
    assert len(cells) == 4 * 10 * 2  # 4 groups x 10 edges of 300 m x 2 windows of 20 s
    # the groups add up to `all` in every cell
    parts = cells[cells["group"] != ALL].groupby(["edge", "t_start_s"])[["density", "flow"]].sum()
    every = cells[cells["group"] == ALL].set_index(["edge", "t_start_s"])[["density", "flow"]]
    assert np.allclose(parts.loc[every.index].to_numpy(), every.to_numpy())
    # Edie's density over the whole road = the mean number of cars on its normal lanes / 9 lane-km
    df = read_fcd(fcd)
    on_road = df[~df["lane"].astype(str).str.startswith(":") & (df["time"] < 40.0)]
    expected = on_road.groupby("time").size().reindex(np.unique(df["time"]), fill_value=0).mean() / 9.0
    assert region(cells).loc[ALL, "density"] == pytest.approx(expected, rel=0.02)
    assert 10 < region(cells).loc[ALL, "speed"] < 40  # m/s, on a 120 km/h road
    assert (out / "flow.png").read_bytes()[:4] == b"\x89PNG"
    text = (out / "realism.md").read_text()
    assert "## Flow against density" in text and "| all |" in text


def test_report_refuses_bad_cells(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "fcd.xml").write_text("<fcd-export/>")
    code, _, stderr = report([str(tmp_path / "fcd.xml"), "--cell-m", "0"], monkeypatch, capsys)
    assert code == 2 and "--cell-m must be a positive number" in stderr
