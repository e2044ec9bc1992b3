"""populate's own structures stay bounded on long runs: the rows of agents whose run
ended go to a temporary file, not a list that grows with the run. Long runs: benchmarks/soak.py."""

from __future__ import annotations

import csv
import gc
import io
import tracemalloc
from pathlib import Path

import numpy as np

from behaviors.report.agents_table import columns
from behaviors.run.records import AgentLog, AgentRow, Incident, PopulateSummary, write_agents_csv
from behaviors.traffic.styles import unstyled


def end_agents(log: AgentLog, first: int, count: int, time: float) -> None:
    """`count` agents join, drive a step and end: every third by a collision with an incident."""
    ids = [f"keeper_{k}" for k in range(first, first + count)]
    log.join(ids, ["keeper"] * count, time, unstyled(np.full(count, 0.9)))
    driving = len(log.ids) - count  # agents already on the road drive on
    log.observe(np.ones(len(log.ids), bool), np.full(len(log.ids), 20.0))
    reasons = np.array([""] * driving + ["collision" if k % 3 == 0 else "arrived" for k in range(count)])
    incident = Incident("left", "e0_1", 0.4, "background_1", 20.0, 18.5, np.nan, 0.31)
    log.end(reasons, time + 1.0, {driving + k: incident for k in range(0, count, 3)})


def test_ended_agents_do_not_stay_in_memory() -> None:
    log = AgentLog(0.2, "traffic")
    end_agents(log, 0, 100, 0.0)  # warm up whatever is allocated once
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for batch in range(1, 51):
            end_agents(log, batch * 100, 100, batch * 10.0)
        gc.collect()  # dataclasses.astuple leaves cycles behind until the next collection
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert len(log.ended) == 5100
    # as a list of AgentRow they held 1.9 MB (tracemalloc); in the file, only its write buffer
    assert grown < 200_000, f"{grown:,} bytes held for 5,000 ended agents"


def test_the_agents_table_holds_the_ended_rows_in_order_then_those_driving(tmp_path: Path) -> None:
    log = AgentLog(0.2, "traffic")
    end_agents(log, 0, 4, 0.0)
    log.join(["overtaker_9"], ["overtaker"], 3.0, unstyled(np.full(1, 1.05)))
    end_agents(log, 4, 2, 5.0)
    driving = log.driving(7.0)
    path = tmp_path / "fcd.agents.csv"
    write_agents_csv(path, log.ended, driving)
    rows = list(csv.reader(io.StringIO(path.read_text())))
    assert rows[0] == list(columns("populate"))
    assert [r[0] for r in rows[1:]] == [f"keeper_{k}" for k in range(6)] + ["overtaker_9"]
    reasons = ["collision", "arrived", "arrived", "collision", "collision", "arrived", "still_driving"]
    assert [r[6] for r in rows[1:]] == reasons
    assert rows[1][10:18] == ["left", "e0_1", "0.4", "background_1", "20.0", "18.5", "", "0.31"]
    assert rows[1][18:] == ["0.9", "", "", ""]  # the style drawn: a speed factor alone (no styles)
    # the same bytes as writing the rows straight from memory
    expected = io.StringIO()
    writer = csv.writer(expected, lineterminator="\n")
    writer.writerow(columns("populate"))
    writer.writerows(row.cells() for row in read_back(rows[1:-1]) + driving)
    assert path.read_text() == expected.getvalue()
    # and a second table of the same log (a later write) holds the same rows
    write_agents_csv(tmp_path / "again.csv", log.ended, driving)
    assert (tmp_path / "again.csv").read_text() == path.read_text()

    summary = PopulateSummary()
    summary.count_agents(log.ended, driving)
    ended = {"arrived": 3, "collision": 3, "off_track": 0, "no_progress": 0, "still_driving": 1}
    assert summary.ended == ended


def read_back(rows: list[list[str]]) -> list[AgentRow]:
    """AgentRows from CSV cells (mean speed derived; the incident and style as text: cells() writes text
    as it is)."""
    return [
        AgentRow(r[0], r[1], r[2], r[3], float(r[4]), float(r[5]), r[6], float(r[7]), float(r[9]),
                 Incident(*r[10:18]), tuple(r[18:]))  # type: ignore[arg-type]
        for r in rows
    ]  # fmt: skip
