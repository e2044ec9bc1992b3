"""The agents table: one row per learned agent's run, in the same columns whichever command drove it.

`behave populate` writes it beside its FCD and `behave evaluate --record` beside each episode's
(`<fcd stem>.agents.csv`, which `behave report` reads); `behave train` writes one row per agent and
episode into its run directory's agents.csv. The shared COLUMNS come first; a command's own columns
(EXTRA_COLUMNS) follow them.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

COLUMNS = ("id", "behaviour", "vtype", "policy", "depart_s", "end_s", "end_reason", "distance_m",
           "mean_speed_mps", "longest_standstill_s")  # fmt: skip
"""Every command's first columns: who drove, with what policy, from when to when, how far and how it ended."""
INCIDENT_COLUMNS = ("incident_side", "incident_lane", "incident_lane_offset_m", "incident_other",
                    "incident_speed_mps", "incident_other_speed_mps", "incident_headway_s",
                    "incident_lateral_gap_m")  # fmt: skip
"""populate's: how a collision or off-track looked (records.Incident); empty for the other agents."""
STYLE_COLUMNS = ("style_speed_factor", "style_time_headway_s", "style_eagerness", "style_lane_bias_m")
"""populate's: the style each agent drew (styles.Styles: desired speed as a share of the limit, the
headway it wants, its eagerness to pass, where in its lane it holds itself); a driver without styles
has only the first."""
EXTRA_COLUMNS = {
    "populate": (*INCIDENT_COLUMNS, *STYLE_COLUMNS),
    "evaluate": ("reward",),
    "train": ("episode", "reward"),
}
"""Each command's own columns, after the shared ones: an episode's agents share ids, a run's episodes
do not (train), and the episodes' reward is the driver's."""
REPORTED = ("id", "vtype", "depart_s", "end_s", "end_reason", "longest_standstill_s")
"""What `behave report` reads of a table: tables written before `policy` and `mean_speed_mps` still report."""
END_REASONS = ("arrived", "collision", "off_track", "no_progress", "still_driving")
"""How an agent's run ends: at the end of its route, crashed, off the carriageway, taken out by SUMO
without arriving (stuck, no progress; in an episode: no progress), or still on the road when the run
(or episode: its time limit or its road's end) ends."""
LONG_STANDSTILL_S = 30.0
"""Standing still this long at a time is reported (a car waiting at a light, or stuck)."""


def columns(command: str) -> tuple[str, ...]:
    """The header of `command`'s agents table."""
    return (*COLUMNS, *EXTRA_COLUMNS[command])


def agents_path(fcd: Path) -> Path:
    """Where an FCD's agents table goes: beside it, `<fcd stem>.agents.csv`."""
    fcd = Path(fcd)
    return fcd.with_name(f"{fcd.stem}.agents.csv")


@dataclass(frozen=True)
class AgentRun:
    """One learned agent's run: the shared columns of its row."""

    id: str
    behaviour: str  # "keeper" or "overtaker"
    vtype: str
    policy: str  # the policy's label (policy.Policy.label; in training, the run's directory)
    depart_s: float
    end_s: float
    end_reason: str  # one of END_REASONS
    distance_m: float  # SUMO's speed x step summed: its odometer under its Euler update
    longest_standstill_s: float

    @property
    def mean_speed_mps(self) -> float:
        driven = self.end_s - self.depart_s
        return self.distance_m / driven if driven > 0 else math.nan

    def cells(self) -> list[Any]:
        """The COLUMNS' cells, rounded (to mm and ms), nan as empty."""
        times = [cell(self.depart_s), cell(self.end_s)]
        driven = [cell(self.distance_m, 2), cell(self.mean_speed_mps), cell(self.longest_standstill_s)]
        return [self.id, self.behaviour, self.vtype, self.policy, *times, self.end_reason, *driven]


def cell(value: Any, digits: int = 3) -> Any:
    """A CSV cell: floats rounded, nan empty, anything else as it is."""
    if isinstance(value, float):
        return "" if math.isnan(value) else round(value, digits)
    return value


def table_text(command: str, rows: Iterable[Sequence[Any]]) -> str:
    """`command`'s agents table as CSV text: the header, then `rows` (cells in `columns(command)` order)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(columns(command))
    writer.writerows(rows)
    return out.getvalue()
