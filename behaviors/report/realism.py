"""Realism report: how human-like the traces of an FCD are, per group of vehicles (`measure`).

The measures and the naturalistic figures they are compared with are listed in docs/manual/report.md
(lane use, lane changes, lateral acceleration and jerk, lane-change peak and
duration, time headway and time-to-collision, passes and their side, speed, losses). Everything
here is vectorised numpy/pandas over the whole table: a million FCD records take seconds. The
records are read by realism_tracks.py, measured by realism_measures.py, written by
realism_output.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from behaviors.errors import BehaveError
from behaviors.report.agents_table import LONG_STANDSTILL_S, REPORTED
from behaviors.report.realism_measures import (
    headways,
    lane_changes,
    lane_offsets,
    lateral_motion,
    like_for_like,
    passes,
    trips,
)
from behaviors.report.realism_tracks import (
    ASSUMED_LANE_WIDTH,
    GROUP_BY,
    GROUPS_OF_TYPE,
    KEEPERS,
    OTHER_GROUP,
    OVERTAKERS,
    SKIP_S,
    Lanes,
    group_names,
    prepare,
)

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

LAT_ACCEL_LIMIT = 1.5  # m/s^2
THW_LIMIT = 1.0  # s
OFF_CENTRE_LIMIT = 0.5  # m from the lane centre
RUN_GAP_S = 3600.0
"""s between stacked runs (`stack_runs`): no car of one run is seen beside a car of another."""
TTC_LIMIT = 3.0  # s


class NothingToMeasure(BehaveError):
    """No car drove longer than the seconds left out at its start."""


def read_agents(path: Path) -> pd.DataFrame | None:
    """The per-agent table if the file exists (None if not): how and when each agent ended."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        agents = pd.read_csv(
            path, dtype={c: str for c in ("id", "behaviour", "vtype", "policy", "end_reason")}
        )
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise BehaveError(f"{path} is not a per-agent table ({err})") from None
    missing = [c for c in REPORTED if c not in agents.columns]
    if missing:
        raise BehaveError(f"{path} is not a per-agent table (no {', '.join(missing)} column)")
    return agents


def stack_runs(
    runs: Sequence[tuple[pd.DataFrame, pd.DataFrame | None]],
) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """Several runs (FCD, per-agent table or None) as one to measure together: ids get the run's
    number (`3:agent_0`) and each run's clock starts RUN_GAP_S after the previous run ended, so
    that no car is another run's leader or pass. The agent tables are kept only if every run has one."""
    fcds, tables, start = [], [], 0.0
    for k, (fcd, agents) in enumerate(runs):
        shift = start - float(fcd["time"].min())
        fcds.append(fcd.assign(id=f"{k}:" + fcd["id"].astype(str), time=fcd["time"] + shift))
        if agents is not None:
            moved = {"depart_s": agents["depart_s"] + shift, "end_s": agents["end_s"] + shift}
            tables.append(agents.assign(id=f"{k}:" + agents["id"].astype(str), **moved))
        start = float(fcds[-1]["time"].max()) + RUN_GAP_S
    if not fcds:
        raise BehaveError("no runs to measure")
    both = len(tables) == len(fcds)
    return pd.concat(fcds, ignore_index=True), pd.concat(tables, ignore_index=True) if both else None


def losses(agents: pd.DataFrame, group_by: str = "type") -> pd.DataFrame:
    """Per group: collisions, off-tracks and removals without progress per agent-hour (over the
    agents' whole runs), and how many agents stood still LONG_STANDSTILL_S or longer."""
    group = group_names(agents["id"], agents["vtype"], group_by)
    hours = (agents["end_s"] - agents["depart_s"]).clip(lower=0) / 3600
    table = pd.DataFrame({
        "group": group, "hours": hours,
        "collision": agents["end_reason"] == "collision", "off_track": agents["end_reason"] == "off_track",
        "no_progress": agents["end_reason"] == "no_progress",
        "standing": agents["longest_standstill_s"] >= LONG_STANDSTILL_S,
    }).groupby("group").sum()  # fmt: skip
    rate = table[["collision", "off_track", "no_progress"]].div(
        table["hours"].where(table["hours"] > 0), axis=0
    )
    rate.columns = ["collisions_per_agent_hour", "off_tracks_per_agent_hour", "no_progress_per_agent_hour"]
    return rate.assign(agents_standing=table["standing"].astype(float))


@dataclass(frozen=True)
class Metric:
    key: str
    label: str
    reference: str = "-"
    share: bool = False  # shown as a percentage


METRICS = (
    Metric("vehicles", "vehicles"),
    Metric("vehicle_km", "vehicle-km (after each car's first seconds)"),
    Metric("mean_speed", "mean speed [m/s]"),
    Metric("lane_changes_per_km", "lane changes per vehicle-km", "0.12 (highD) - 0.22 (VTTI)"),
    Metric("discretionary_lane_changes_per_km", "lane changes per vehicle-km the route did not ask for"),
    Metric("lane_changes_per_min", "lane changes per vehicle-minute"),
    Metric("lat_accel_over_limit", f"time with |lateral accel| > {LAT_ACCEL_LIMIT} m/s^2", "~0", share=True),
    Metric("lat_accel_p95", "|lateral accel| p95 [m/s^2]"),
    Metric("lat_jerk_p95", "|lateral jerk| p95 [m/s^3]"),
    Metric("lc_peak_accel_median", "peak |lateral accel| per lane change, median [m/s^2]", "0.5-1"),
    Metric("lc_duration_median", "lane-change duration, median [s]", "5-6 (VTTI mean 6.28)"),
    Metric("lane_offset_mean", "|offset from the lane centre| outside lane changes, mean [m]"),
    Metric(
        "off_centre_share",
        f"time > {OFF_CENTRE_LIMIT:g} m off the lane centre (outside lane changes)",
        share=True,
    ),
    Metric("thw_median", "time headway, median [s]", "1-2 (freeway rush hour)"),
    Metric("thw_p5", "time headway, 5th percentile [s]", "~1 (lower limit)"),
    Metric(
        "thw_below_limit", f"following time with headway < {THW_LIMIT:g} s", "small (< 0.9 s fined, DE)", True
    ),
    Metric("ttc_below_limit", f"following time with time-to-collision < {TTC_LIMIT:g} s", share=True),
    Metric("passes_per_km", "passes made per vehicle-km"),
    Metric("passes_overtaking_side", "passes made on the left", "~100% (right: illegal, StVO 5)", True),
    Metric("collisions_per_agent_hour", "collisions per agent-hour", "0"),
    Metric("off_tracks_per_agent_hour", "off-tracks per agent-hour", "0"),
    Metric("no_progress_per_agent_hour", "agents removed without progress per agent-hour", "0"),
    Metric("agents_standing", f"agents that stood still >= {LONG_STANDSTILL_S:.0f} s"),
)
LOSS_KEYS: tuple[str, ...] = (
    "collisions_per_agent_hour",
    "off_tracks_per_agent_hour",
    "no_progress_per_agent_hour",
)
LOSS_KEYS += ("agents_standing",)


@dataclass(frozen=True)
class Report:
    """The realism measures per group, and the samples the picture is drawn from."""

    table: pd.DataFrame  # rows: metric keys (METRICS, lane shares after mean_speed); columns: groups
    metrics: tuple[Metric, ...]
    samples: dict[str, dict[str, np.ndarray]]  # "thw", "accel", "speed" -> group -> values
    notes: tuple[str, ...]
    losses_known: bool  # a per-agent table was read: no figure means the group had no agents
    like_for_like: dict[str, float] = field(default_factory=dict)
    """overtakers / keepers on the trips both made (`like_for_like`); empty without both groups."""


def check_options(skip_s: float, group_by: str) -> None:
    """Refuse bad options before a long FCD is read."""
    if not skip_s >= 0:
        raise BehaveError(f"--skip-s must be >= 0, got {skip_s}")
    if group_by not in GROUP_BY:
        raise BehaveError(f"unknown grouping {group_by!r}: choose one of {', '.join(GROUP_BY)}")


def _ordered_groups(groups: pd.Index) -> list[str]:
    known = [g for g in (*GROUPS_OF_TYPE.values(), OTHER_GROUP) if g in groups]
    return known + sorted(g for g in groups if g not in known)


def measure(
    df: pd.DataFrame,
    lanes: Lanes,
    *,
    agents: pd.DataFrame | None = None,
    skip_s: float = SKIP_S,
    group_by: str = "type",
    lengths: Mapping[str, float] | None = None,
) -> Report:
    """Every realism measure of an FCD table (from `read_fcd`), per group of vehicles."""
    check_options(skip_s, group_by)
    tr = prepare(df, lanes, skip_s=skip_s, group_by=group_by, lengths=lengths)
    motion = lateral_motion(tr)
    settled = tr["settled"].to_numpy()
    if not settled.any():
        raise NothingToMeasure(
            f"no vehicle drove longer than {skip_s:g} s: nothing to measure (try a smaller --skip-s)"
        )
    live = tr[settled].assign(accel=motion["accel"].abs()[settled], jerk=motion["jerk"].abs()[settled])
    by = live.groupby("group")
    km = (live["speed"] * live["dt"].fillna(0)).groupby(live["group"]).sum() / 1000
    minutes = live["dt"].fillna(0).groupby(live["group"]).sum() / 60
    changes = lane_changes(tr, motion["accel"].to_numpy(), lanes.next_lanes)
    follow = headways(tr)
    made = passes(tr)
    offsets = lane_offsets(tr, changes)
    n_changes = changes.groupby("group").size().reindex(km.index, fill_value=0)
    rows = {
        "vehicles": by["vehicle"].nunique(),
        "vehicle_km": km,
        "mean_speed": by["speed"].mean(),
        "lane_changes_per_km": n_changes / km.where(km > 0),
        "discretionary_lane_changes_per_km": (
            (~changes["route"]).groupby(changes["group"]).sum().reindex(km.index, fill_value=0)
            / km.where((km > 0) & bool(lanes.next_lanes))
        ),
        "lane_changes_per_min": n_changes / minutes.where(minutes > 0),
        "lat_accel_over_limit": by["accel"].apply(lambda a: (a.dropna() > LAT_ACCEL_LIMIT).mean()),
        "lat_accel_p95": by["accel"].quantile(0.95),
        "lat_jerk_p95": by["jerk"].quantile(0.95),
        "lc_peak_accel_median": changes.groupby("group")["peak_accel"].median(),
        "lc_duration_median": changes.groupby("group")["duration"].median(),
        "lane_offset_mean": offsets.groupby("group")["offset"].mean(),
        "off_centre_share": (offsets["offset"] > OFF_CENTRE_LIMIT).groupby(offsets["group"]).mean(),
        "thw_median": follow.groupby("group")["thw"].median(),
        "thw_p5": follow.groupby("group")["thw"].quantile(0.05),
        "thw_below_limit": (follow["thw"] < THW_LIMIT).groupby(follow["group"]).mean(),
        "ttc_below_limit": (follow["ttc"] < TTC_LIMIT).groupby(follow["group"]).mean(),
        "passes_per_km": made.groupby("group").size().reindex(km.index, fill_value=0) / km.where(km > 0),
        "passes_overtaking_side": made.groupby("group")["overtaking_side"].mean(),
    }
    groups = _ordered_groups(km.index)
    table = pd.DataFrame({key: values.reindex(groups) for key, values in rows.items()}).T
    lane_use = live.groupby(["group", "road_rank"]).size().unstack(fill_value=0)
    lane_use = lane_use.div(lane_use.sum(axis=1), axis=0).reindex(groups).T
    lane_use.index = [f"lane_{int(rank)}_share" for rank in lane_use.index]
    notes = [_lane_note(lanes), f"each car's first {skip_s:g} s left out"]
    if not lanes.next_lanes:
        notes.append("which lane changes the route asked for is unknown without the net's connections")
    if tr["pos_lat"].isna().all():
        notes.append("lane centring unknown: the FCD has no posLat")
    if agents is not None:
        loss = losses(agents, group_by).reindex(groups).T
    else:
        loss = pd.DataFrame(np.nan, index=list(LOSS_KEYS), columns=groups)
        notes.append("losses unknown: no per-agent table (<fcd stem>.agents.csv) beside the FCD")
    at = list(table.index).index("mean_speed") + 1
    table = pd.concat([table.iloc[:at], lane_use, table.iloc[at:], loss])
    metrics = _metrics(lane_use.index, lanes.lefthand)
    samples = {
        "thw": _by_group(follow, "thw"),
        "accel": _by_group(live.dropna(subset=["accel"]), "accel"),
        "speed": _by_group(live, "speed"),
    }
    ratios = {}
    if {OVERTAKERS, KEEPERS} <= set(groups):
        ratios = like_for_like(live, made, trips(tr), OVERTAKERS, KEEPERS)
        notes.append(like_for_like_note(ratios))
    return Report(table.astype(float), metrics, samples, tuple(notes), agents is not None, ratios)


def like_for_like_note(ratios: dict[str, float]) -> str:
    """`like_for_like`'s ratios in words: `1.23x`, or what an infinite or undefined ratio means."""
    if not ratios["trips"]:
        return "overtakers / keepers: no trip both made (first to last edge), so no like-for-like ratios"

    def times(value: float, what: str) -> str:
        if math.isfinite(value):
            return f"{value:.2f}x"
        if math.isinf(value):
            return f"only the overtakers had any {what}"
        return f"neither had any {what}"

    return (
        f"overtakers / keepers on the trips both made ({ratios['trips']:.0f}, first to last edge; "
        f"{100 * ratios['km_share']:.0f}% of their km): mean speed {times(ratios['mean_speed'], 'speed')}, "
        f"passes per km {times(ratios['passes_per_km'], 'passes')}"
    )


def _lane_note(lanes: Lanes) -> str:
    if not lanes.from_net:
        return f"no net: every lane assumed {ASSUMED_LANE_WIDTH} m wide, lanes counted by their index"
    side = "left (left-hand net)" if lanes.lefthand else "right"
    return f"lane widths from the net; lanes counted from the {side} among lanes cars may use"


def _metrics(lane_rows: pd.Index, lefthand: bool) -> tuple[Metric, ...]:
    outer = "left" if lefthand else "right"
    lanes = [
        Metric(row, f"time in lane {row.split('_')[1]} (from the {outer})", "-", True) for row in lane_rows
    ]  # fmt: skip
    if lanes:
        lanes[0] = Metric(lanes[0].key, lanes[0].label, "most at low density", True)
    out: list[Metric] = []
    for metric in METRICS:
        if metric.key == "passes_overtaking_side" and lefthand:
            metric = Metric(metric.key, "passes made on the right (left-hand net)", metric.reference, True)
        out.append(metric)
        if metric.key == "mean_speed":
            out += lanes
    return tuple(out)


def _by_group(frame: pd.DataFrame, column: str) -> dict[str, np.ndarray]:
    return {str(g): part[column].to_numpy(float) for g, part in frame.groupby("group")}
