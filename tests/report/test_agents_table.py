"""One agents table: train, evaluate and populate write the same first columns, and `behave report`
reads every command's table (and tables written before `policy` and `mean_speed_mps`)."""

from __future__ import annotations

import numpy as np
import pytest

from behaviors.learn.env import EnvConfig
from behaviors.report.agents_table import COLUMNS, EXTRA_COLUMNS, REPORTED, agents_path, columns, table_text
from behaviors.report.realism import read_agents
from behaviors.run.evaluate import episode_fcd, evaluate

OLD_POPULATE_HEADER = ("id,behaviour,vtype,depart_s,end_s,end_reason,distance_m,longest_standstill_s,"
                       "incident_side,incident_lane,incident_lane_offset_m,incident_other,incident_speed_mps,"
                       "incident_other_speed_mps,incident_headway_s,incident_lateral_gap_m")  # fmt: skip


@pytest.mark.parametrize("command", sorted(EXTRA_COLUMNS))
def test_every_command_starts_with_the_shared_columns_and_report_reads_its_table(tmp_path, command):
    assert columns(command)[: len(COLUMNS)] == COLUMNS and set(REPORTED) <= set(COLUMNS)
    row = ["agent_0", "keeper", "behave_keeper", "lk", 0.0, 10.0, "collision", 150.0, 15.0, 0.0]
    path = tmp_path / f"{command}.agents.csv"
    path.write_text(table_text(command, [row + [""] * len(EXTRA_COLUMNS[command])]))
    table = read_agents(path)
    assert table is not None and list(table["end_reason"]) == ["collision"]


def test_report_reads_a_table_written_before_the_shared_schema(tmp_path):
    path = tmp_path / "old.agents.csv"
    path.write_text(
        OLD_POPULATE_HEADER + "\nkeeper_0,keeper,behave_keeper,0.0,9.0,arrived,200.0,0.0" + "," * 8 + "\n"
    )
    table = read_agents(path)
    assert table is not None and list(table["id"]) == ["keeper_0"]


@pytest.mark.sumo
def test_evaluate_records_its_episodes_agents_in_the_shared_table(tmp_path):
    config = EnvConfig(scenario="tiny", agents=2, max_steps=20)
    hold = lambda obs, slots: np.tile(np.float32([0.0, 0.3, 0.0]), (len(obs), 1))  # noqa: E731
    evaluate(config, hold, episodes=1, seed=0, record=tmp_path, label="hold")
    table = read_agents(agents_path(episode_fcd(tmp_path, 0)))
    assert table is not None and tuple(table.columns) == columns("evaluate")
    assert list(table["id"]) == ["agent_0", "agent_1"] and set(table["policy"]) == {"hold"}
    assert (table["end_s"] > table["depart_s"]).all() and (table["distance_m"] > 0).all()
    assert table["mean_speed_mps"].to_numpy() == pytest.approx(
        (table["distance_m"] / (table["end_s"] - table["depart_s"])).to_numpy(), rel=1e-3
    )
