"""`behave evaluate` writes the realism report of real SUMO runs; lane centring on hand-built traces."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from behaviors.cli.main import app
from behaviors.report.realism import measure, stack_runs
from behaviors.report.realism_tracks import Lanes
from behaviors.run.evaluate import REALISM_COLUMNS

PRETRAINED = Path(__file__).resolve().parents[2] / "behaviors" / "pretrained"
WIDTH = 3.2  # the lane width realism assumes without a net
STEP = 0.2


def car(vid: str, vtype: str, pos_lat: np.ndarray, lane: np.ndarray | int = 0, start: float = 0.0):
    """FCD records of one car at 30 m/s, one record per STEP: posLat and lane index per record."""
    t = np.arange(len(pos_lat)) * STEP
    lanes = np.broadcast_to(lane, len(t))
    return pd.DataFrame({
        "id": vid, "time": t, "type": vtype, "lane": [f"e_{k}" for k in lanes],
        "pos": start + 30 * t, "posLat": pos_lat, "speed": 30.0,
    })  # fmt: skip


def test_lane_centring_outside_lane_changes() -> None:
    # a keeper 0.3 m off centre from 10 to 20 s, then 0.8 m: mean 0.55, half the time beyond 0.5 m
    keeper = car("k", "behave_keeper", np.where(np.arange(150) * STEP < 20, 0.3, 0.8))
    # an overtaker on the centre but for one smooth change from lane 0 to lane 1 at 15-20 s
    s = np.clip((np.arange(150) * STEP - 15) / 5, 0, 1)
    lat = WIDTH / 2 + WIDTH * (s - np.sin(2 * np.pi * s) / (2 * np.pi))
    index = np.floor(lat / WIDTH).astype(int)
    overtaker = car("o", "behave_overtaker", lat - (index + 0.5) * WIDTH, index, start=500.0)
    report = measure(pd.concat([keeper, overtaker], ignore_index=True), Lanes())
    table = report.table
    assert table.loc["lane_offset_mean", "keepers"] == pytest.approx(0.55)
    assert table.loc["off_centre_share", "keepers"] == pytest.approx(0.5)
    assert table.loc["lane_changes_per_km", "overtakers"] > 0  # the change is seen, and left out:
    assert table.loc["lane_offset_mean", "overtakers"] < 0.02
    assert table.loc["off_centre_share", "overtakers"] == 0.0
    assert "lane centring unknown" not in " ".join(report.notes)


def test_lane_centring_unknown_without_pos_lat() -> None:
    report = measure(car("k", "behave_keeper", np.full(100, 0.3)).drop(columns="posLat"), Lanes())
    assert np.isnan(report.table.loc["lane_offset_mean", "keepers"])
    assert np.isnan(report.table.loc["off_centre_share", "keepers"])
    assert any("no posLat" in note for note in report.notes)


def test_stacked_runs_never_meet() -> None:
    """Two episodes with the same ids and clock: stacked, the car of one is no leader of the other."""
    first = (car("agent_0", "behave_keeper", np.zeros(100)), None)
    second = (car("agent_0", "behave_keeper", np.zeros(100), start=20.0), None)
    fcd, agents = stack_runs([first, second])
    report = measure(fcd, Lanes())
    assert agents is None and report.table.loc["vehicles", "keepers"] == 2
    assert np.isnan(report.table.loc["thw_median", "keepers"])
    overlaid = pd.concat([first[0], second[0].assign(id="other")], ignore_index=True)
    assert measure(overlaid, Lanes()).table.loc["thw_median", "keepers"] == pytest.approx(
        0.5
    )  # 15 m at 30 m/s


@pytest.mark.sumo
def test_evaluate_writes_the_realism_report_of_real_runs(tmp_path: Path) -> None:
    """One network for keepers and overtakers among slower SUMO cars on the ring, and SUMO's drivers."""
    out = tmp_path / "eval"
    result = CliRunner().invoke(app, [
        "evaluate", str(PRETRAINED / "multi.pt"), "--overtakers", "1", "--keepers", "1", "--placement", "C",
        "--opponents", "2", "--episodes", "1", "--scenario", "ring", "--max-steps", "60",
        "--baseline", "sumo", "--out", str(out),
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    summary = pd.read_csv(out / "realism_summary.csv")
    policies = {"multi": "multi", "sumo (Krauss + SL2015)": "sumo-krauss-sl2015"}
    assert set(summary["policy"]) == set(policies)
    for policy in policies:
        assert list(summary[summary["policy"] == policy]["group"]) == ["keepers", "overtakers", "sumo"]
    assert {key for key, _, _ in REALISM_COLUMNS} <= set(summary.columns)
    agents = summary[summary["group"] != "sumo"]
    assert agents["losses_per_agent_hour"].notna().all()  # the agents' ends were recorded
    sumo = summary[summary["policy"] != "multi"]
    assert (sumo["lane_offset_mean"] < 0.05).all()  # SUMO's drivers hold the lane centre
    for name in policies.values():
        report = out / "realism" / name / "case-c"
        assert sorted(p.name for p in report.iterdir()) == ["realism.csv", "realism.md", "realism.png"]
        full = pd.read_csv(report / "realism.csv").set_index("metric")
        assert full.loc["vehicles", ["keepers", "overtakers", "sumo"]].tolist() == [1, 1, 2]
    markdown = (out / "results.md").read_text()
    assert "## Realism" in markdown and "| multi | case C | overtakers |" in markdown
    assert not list((out / "realism").glob(".*"))  # the episodes' FCDs are gone


@pytest.mark.sumo
def test_no_realism_records_nothing(tmp_path: Path) -> None:
    out = tmp_path / "eval"
    result = CliRunner().invoke(app, [
        "evaluate", str(PRETRAINED / "lanekeeping.pt"), "--agents", "1", "--episodes", "1", "--scenario",
        "ring", "--max-steps", "60", "--no-realism", "--out", str(out),
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == ["metrics.png", "results.csv", "results.md"]
    assert "Realism" not in (out / "results.md").read_text()
