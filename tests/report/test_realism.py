"""Realism measures on hand-made traces with known answers, and `behave report` on a real populate run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import behave

from behaviors.cli.main import main
from behaviors.errors import BehaveError
from behaviors.report.realism import losses, measure
from behaviors.report.realism_measures import headways, lane_changes, lateral_motion, passes
from behaviors.report.realism_tracks import Lanes, group_names, prepare, read_lanes
from behaviors.sumo.sumo_home import sumo_binary
from sumo_scenarios import get_scenario

WIDTH = 3.2  # the width realism assumes without a net
STEP = 0.2


def drive(
    vid: str, vtype: str, t: np.ndarray, pos: np.ndarray, lat: np.ndarray, speed: float, edge: str = "e"
):
    """FCD records of one car; `lat` is metres from the outer border of `edge` (lanes 3.2 m wide)."""
    index = np.floor(lat / WIDTH).astype(int)
    return pd.DataFrame({
        "id": vid, "time": t, "type": vtype, "lane": [f"{edge}_{k}" for k in index],
        "pos": pos, "posLat": lat - (index + 0.5) * WIDTH, "speed": speed,
    })  # fmt: skip


def lane_change_car(rounded: bool = False) -> pd.DataFrame:
    """One car at 30 m/s changing from lane 0 to lane 1 between 15 and 20 s, with the smooth
    textbook profile: lateral acceleration a sine, peak 2*pi*3.2/5^2 = 0.80 m/s^2."""
    t = np.arange(0, 30, STEP)
    s = np.clip((t - 15) / 5, 0, 1)
    lat = WIDTH / 2 + WIDTH * (s - np.sin(2 * np.pi * s) / (2 * np.pi))
    car = drive("c", "behave_overtaker", t, 30 * t, lat, 30.0)
    return car.assign(posLat=car["posLat"].round(2)) if rounded else car


def test_one_sinusoidal_lane_change_has_its_duration_and_peak() -> None:
    tr = prepare(lane_change_car(), Lanes(), skip_s=10)
    changes = lane_changes(tr, lateral_motion(tr)["accel"].to_numpy())
    assert len(changes) == 1
    # sideways faster than 5 cm/s: all but the first and last 0.4 s of the 5 s move
    assert 4.0 <= changes["duration"].iloc[0] <= 5.0
    assert changes["peak_accel"].iloc[0] == pytest.approx(2 * np.pi * WIDTH / 25, rel=0.05)


def test_lane_change_rates_and_rounding_noise() -> None:
    table = measure(lane_change_car(rounded=True), Lanes(), skip_s=10).table["overtakers"]
    assert table["lane_changes_per_km"] == pytest.approx(1 / 0.6, rel=0.02)  # 20 s at 30 m/s
    assert table["lane_changes_per_min"] == pytest.approx(3.0, rel=0.02)
    assert table["lat_accel_over_limit"] == 0  # FCD's 1 cm rounding does not look like swerving
    assert 0.5 < table["lc_peak_accel_median"] < 1.0
    assert table["lane_0_share"] == pytest.approx(7.5 / 20, abs=0.02)  # crosses the line at 17.5 s


def test_headway_to_the_leader_in_the_same_lane_only() -> None:
    t = np.arange(0, 20, STEP)
    cars = pd.concat([
        drive("follower", "behave_keeper", t, 30 * t, np.full(len(t), 1.6), 30.0),
        drive("leader", "car", t, 30 * t + 60, np.full(len(t), 1.6), 30.0),
        drive("beside", "car", t, 30 * t + 10, np.full(len(t), 4.8), 30.0),  # closer, other lane
    ])  # fmt: skip
    table = measure(cars, Lanes(), skip_s=0).table["keepers"]
    assert table["thw_median"] == pytest.approx(55 / 30)  # gap = 60 - a 5 m car length
    assert table["thw_p5"] == pytest.approx(55 / 30)
    assert table["thw_below_limit"] == 0
    close = pd.concat([cars[cars["id"] == "follower"], cars[cars["id"] == "leader"].assign(pos=30 * t + 30)])
    assert measure(close, Lanes(), skip_s=0).table.loc["thw_below_limit", "keepers"] == 1.0  # 25/30 s


def test_time_to_collision_when_closing_in() -> None:
    t = np.arange(0, 9.6, STEP)
    cars = pd.concat([
        drive("f", "car", t, 30 * t, np.full(len(t), 1.6), 30.0),
        drive("l", "car", t, 20 * t + 105, np.full(len(t), 1.6), 20.0),
    ])  # fmt: skip
    follow = headways(prepare(cars, Lanes(), skip_s=0))
    # gap 100 - 10 t closing at 10 m/s: TTC = 10 - t, below 3 s after t = 7 s
    assert (follow["ttc"] < 3).sum() == np.sum(10 - t < 3 - 1e-9)
    assert np.isinf(follow.loc[follow.index[0], "ttc"]) is np.False_


@pytest.mark.parametrize(
    ("passer_lat", "passed_lat", "on_overtaking_side"), [(4.8, 1.6, True), (1.6, 4.8, False)]
)
def test_a_pass_and_its_side(passer_lat: float, passed_lat: float, on_overtaking_side: bool) -> None:
    t = np.arange(0, 20, STEP)
    n = len(t)
    cars = pd.concat([
        drive("fast", "behave_overtaker", t, 35 * t, np.full(n, passer_lat), 35.0),
        drive("slow", "car", t, 25 * t + 50, np.full(n, passed_lat), 25.0),
        drive("tail", "car", t, 25 * t + 30, np.full(n, passed_lat), 25.0),  # passed too, passes nobody
    ])  # fmt: skip
    made = passes(prepare(cars, Lanes(), skip_s=0))
    assert list(made["group"]) == ["overtakers", "overtakers"]
    assert list(made["overtaking_side"]) == [on_overtaking_side] * 2
    table = measure(cars, Lanes(), skip_s=0).table
    assert table.loc["passes_overtaking_side", "overtakers"] == float(on_overtaking_side)
    assert table.loc["passes_per_km", "sumo"] == 0


def test_approach_without_pass_is_no_pass() -> None:
    t = np.arange(0, 20, STEP)
    lat = np.full(len(t), 1.6)
    closing = np.minimum(35 * t, 25 * t + 42)  # catches up and follows 2 m behind the front
    cars = pd.concat(
        [drive("a", "car", t, closing, lat + 3.2, 30.0), drive("b", "car", t, 25 * t + 50, lat, 25.0)]
    )
    assert passes(prepare(cars, Lanes(), skip_s=0)).empty


@pytest.mark.parametrize(
    ("lane_0_leads_into", "asked_by_route"), [(frozenset(), True), (frozenset({"f_0"}), False)]
)
def test_a_lane_change_out_of_a_lane_that_does_not_lead_on_is_the_routes(
    lane_0_leads_into: frozenset[str], asked_by_route: bool
) -> None:
    """A car moves from lane 0 to lane 1 of edge e, then drives on through f and g: if lane 0 does
    not lead on (an acceleration lane, a dropped lane) the route asked for the change."""
    car = lane_change_car()
    car = car.assign(lane=np.where(car["time"] < 25, car["lane"], np.where(car["time"] < 27, "f_1", "g_1")))
    next_lanes = {"e_0": lane_0_leads_into, "e_1": frozenset({"f_1"}), "f_0": frozenset({"g_0"}),
                  "f_1": frozenset({"g_1"}), "g_1": frozenset()}  # fmt: skip
    table = measure(car, Lanes(next_lanes=next_lanes), skip_s=10).table["overtakers"]
    assert table["lane_changes_per_km"] == pytest.approx(1 / 0.6, rel=0.02)
    chosen = table["discretionary_lane_changes_per_km"]
    assert chosen == (0 if asked_by_route else pytest.approx(1 / 0.6, rel=0.02))
    without_net = measure(car, Lanes(), skip_s=10)
    assert np.isnan(without_net.table.loc["discretionary_lane_changes_per_km", "overtakers"])
    assert any("connections" in note for note in without_net.notes)


def test_behaviours_compared_on_the_trips_both_made() -> None:
    """Keepers drive 30 m/s on trip b and 20 on a; overtakers 10% faster on each, but three of four
    on the slow trip: pooled they look slower (0.9x), trip for trip they are 1.1x as fast."""
    t = np.arange(0, 20, STEP)
    cars = []
    for k, (vtype, edge, speed) in enumerate(
        [("behave_keeper", "b", 30.0)] * 3 + [("behave_keeper", "a", 20.0)]
        + [("behave_overtaker", "a", 22.0)] * 3 + [("behave_overtaker", "b", 33.0)]
    ):  # fmt: skip
        cars.append(drive(f"c{k}", vtype, t, 2000.0 * k + speed * t, np.full(len(t), 1.6), speed, edge))
    report = measure(pd.concat(cars), Lanes(), skip_s=0)
    pooled = report.table.loc["mean_speed"]
    assert pooled["overtakers"] / pooled["keepers"] == pytest.approx(0.9)
    assert report.like_for_like["trips"] == 2 and report.like_for_like["km_share"] == 1
    assert report.like_for_like["mean_speed"] == pytest.approx(1.1)
    assert np.isnan(report.like_for_like["passes_per_km"])  # nobody passed anybody
    assert any("trips both made" in note for note in report.notes)


def test_junction_lane_counts_as_the_lane_it_comes_from() -> None:
    """e_0 -> junction lane :J_0_0 -> f_1 (f gains a lane on the right): lane 0, then lane 1,
    no lane change, and the lateral track stays smooth although the offset jumps by a lane."""
    t = np.arange(0, 30, STEP)
    lanes = np.where(t < 10, "e_0", np.where(t < 11, ":J_0_0", "f_1"))
    cars = pd.DataFrame({"id": "c", "time": t, "type": "car", "lane": lanes, "pos": 30 * t, "posLat": 0.0})
    report = measure(cars.assign(speed=30.0), Lanes(), skip_s=0)
    table = report.table["sumo"]
    assert table["lane_0_share"] == pytest.approx(11 / 30, abs=0.01)
    assert table["lane_changes_per_km"] == 0
    assert table["lat_accel_over_limit"] == 0
    assert np.nanmax(report.samples["accel"]["sumo"]) == 0


def build_net(root: Path, lefthand: bool) -> Path:
    """A straight 3-lane edge whose lane 0 is a sidewalk, with or without left-hand traffic."""
    (root / "n.nod.xml").write_text('<nodes><node id="a" x="0" y="0"/><node id="b" x="500" y="0"/></nodes>')
    (root / "n.edg.xml").write_text(
        '<edges><edge id="e" from="a" to="b" numLanes="3" speed="30" width="3.5">'
        '<lane index="0" allow="pedestrian" width="2"/></edge></edges>'
    )
    net = root / ("lh.net.xml" if lefthand else "rh.net.xml")
    cmd = [sumo_binary("netconvert"), "-n", "n.nod.xml", "-e", "n.edg.xml", "-o", net.name]
    subprocess.run([*cmd, *(["--lefthand"] if lefthand else [])], cwd=root, check=True, capture_output=True)
    return net


@pytest.mark.sumo
def test_net_lanes_widths_car_ranks_and_handedness(tmp_path: Path) -> None:
    for lefthand in (False, True):
        lanes = read_lanes(build_net(tmp_path, lefthand))
        assert lanes.lefthand is lefthand
        assert lanes.rank["e_1"] == 0 and lanes.rank["e_2"] == 1  # the sidewalk is no car lane
        assert lanes.centre["e_1"] == pytest.approx(2 + 3.5 / 2)
    label = measure(lane_change_car(), lanes, skip_s=0).metrics
    assert "passes made on the right (left-hand net)" in [m.label for m in label]
    (tmp_path / "routes.xml").write_text("<routes/>")
    with pytest.raises(BehaveError, match="is not a SUMO net"):
        read_lanes(tmp_path / "routes.xml")


def test_groups_by_type_or_id_prefix() -> None:
    ids = pd.Series(["keeper_3", "overtaker_0", "flow.12", "bg7"])
    types = pd.Series(["behave_keeper", "behave_overtaker", "DEFAULT_VEHTYPE", "behave_background"])
    assert list(group_names(ids, types, "type")) == ["keepers", "overtakers", "sumo", "sumo"]
    assert list(group_names(ids, types, "id-prefix")) == ["keeper", "overtaker", "flow", "bg"]
    with pytest.raises(BehaveError, match="unknown grouping"):
        group_names(ids, types, "colour")


def test_a_scenario_car_made_an_agent_after_its_first_record_is_in_the_agents_group() -> None:
    t = np.arange(0, 30, STEP)
    agent = drive("flow.3", "behave_keeper@flow.3", t, 30 * t, np.full(len(t), 1.6), 30.0)
    agent.loc[0, "type"] = "car"  # SUMO wrote the scenario's type before populate converted it
    other = drive("flow.4", "car", t, 30 * t + 100, np.full(len(t), 1.6), 30.0)
    table = measure(pd.concat([agent, other]), Lanes()).table
    assert table.loc["vehicles", "keepers"] == 1 and table.loc["vehicles", "sumo"] == 1


def test_losses_per_agent_hour() -> None:
    agents = pd.DataFrame({
        "id": ["k0", "k1", "o0"], "vtype": ["behave_keeper", "behave_keeper", "behave_overtaker"],
        "depart_s": [0.0, 0.0, 0.0], "end_s": [1800.0, 1800.0, 3600.0],
        "end_reason": ["collision", "still_driving", "off_track"], "longest_standstill_s": [0.0, 31.0, 0.0],
    })  # fmt: skip
    table = losses(agents)
    assert table.loc["keepers", "collisions_per_agent_hour"] == 1.0  # 1 in 2 x 0.5 h
    assert table.loc["overtakers", "off_tracks_per_agent_hour"] == 1.0
    assert table.loc["keepers", "agents_standing"] == 1


def report(
    args: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> tuple[int, str, str]:
    """`behave report ARGS` in this process (a fresh interpreter costs seconds of imports)."""
    monkeypatch.setattr(sys, "argv", ["behave", "report", *args])
    with pytest.raises(SystemExit) as stop:
        main()
    out = capsys.readouterr()
    return stop.value.code, out.out, out.err


def populated(folder: Path) -> Path:
    """The FCD of a short populate run on the bundled highway (2 + 2 agents, 8 SUMO cars, 40 s)."""
    fcd = folder / "fcd.xml"
    run = behave("populate", "--duration", "40", "--keepers", "2", "--overtakers", "2", "--background", "8",
                 "--keep-count", "--fcd", str(fcd))  # fmt: skip
    assert run.returncode == 0, run.stderr
    return fcd


@pytest.mark.sumo
def test_report_on_a_real_populate_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    fcd = populated(tmp_path)
    net = get_scenario("highway").net
    out = tmp_path / "report"
    code, stdout, stderr = report([str(fcd), "--net", str(net), "--out", str(out)], monkeypatch, capsys)
    assert code == 0, stderr
    assert "time headway, median" in stdout
    table = pd.read_csv(out / "realism.csv", index_col="metric")
    assert list(table.columns) == ["description", "keepers", "overtakers", "sumo", "naturalistic"]
    assert table.loc["vehicles", "sumo"] >= 8  # --keep-count replaces those that leave
    assert table.loc["collisions_per_agent_hour", "keepers"] >= 0  # the per-agent table was read
    assert (out / "realism.png").read_bytes()[:4] == b"\x89PNG"
    assert "| metric | keepers | overtakers | sumo | naturalistic |" in (out / "realism.md").read_text()


def test_report_bad_input_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "other.xml").write_text("<routes/>")
    cases = [
        ([str(tmp_path / "missing.xml")], "FCD file not found"),
        ([str(tmp_path / "other.xml")], "is not an FCD file"),
        ([str(tmp_path / "other.xml"), "--net", str(tmp_path / "other.xml")], "is not a SUMO net"),
        ([str(tmp_path / "other.xml"), "--group-by", "colour"], "unknown grouping"),
    ]
    for args, message in cases:
        code, _, stderr = report(args, monkeypatch, capsys)
        assert code == 2
        assert stderr.count("\n") == 1 and message in stderr and stderr.startswith("behave: error:")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.xml"]
