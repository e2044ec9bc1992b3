"""Bars on safety, lane keeping, lane changes, headways and keeping right, over large samples.

Runs `behave populate` (through the library) in light and dense traffic on the bundled highway and on
the curved motorway no policy trains on, with the shield on (as users run it) and off (the bare
policy), sums the agent-hours per shield setting, and measures every run's FCD with `behave report`'s
realism measures plus two of its own: the share of time a car's body straddles a lane line, and the
overtakers' share of time in the rightmost through lane while that lane is free beside them (a
weave's auxiliary lane from an on-ramp to an exit is not a through lane).

    python benchmarks/dense_bars.py [--policy P] [--seed 0] [--quick]

Prints one table of runs and one of bars, and writes docs/dense.md.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from common import write_measured_doc

from behaviors.report.agents_table import agents_path
from behaviors.report.fcd_read import read_fcd
from behaviors.report.realism import measure, read_agents
from behaviors.report.realism_tracks import Lanes, group_names, read_lanes
from behaviors.run.populate import populate
from behaviors.run.populate_config import DEFAULT_POLICY, PopulateConfig
from sumo_scenarios import get_scenario
from sumo_scenarios.net import read_net

CAR_WIDTH = 1.8
"""m: the behave vTypes' width; a body wider than its lane's room less this touches a line."""
FREE_AHEAD = 100.0
FREE_BEHIND = 30.0
"""m: the rightmost lane counts as free beside a car when nobody in it is this far ahead or behind."""
SKIP_S = 10.0
KEEPERS, OVERTAKERS, SUMO = "keepers", "overtakers", "sumo"


@dataclass(frozen=True)
class Setting:
    """One populate run: a net (with its own flows or behave's background cars) and the agents."""

    name: str
    net: str  # a bundled scenario name
    overtakers: int
    keepers: int
    background: int
    duration: float
    own_routes: bool = False  # the scenario's own flows instead of background cars

    def config(self, policy: Path, seed: int, shield: bool, fcd: Path) -> PopulateConfig:
        scenario = get_scenario(self.net)
        return PopulateConfig(
            net=scenario.net,
            routes=scenario.routes if self.own_routes else None,
            overtakers=self.overtakers,
            keepers=self.keepers,
            background=self.background,
            duration=self.duration,
            policy=policy,
            seed=seed,
            fcd=fcd,
            keep_count=True,
            shield=shield,
        )


SETTINGS = (
    Setting("highway light", "highway", 30, 30, 20, 1200.0),  # 80 cars on 9 lane-km: 9 per lane-km
    Setting("highway dense", "highway", 100, 100, 60, 600.0),  # 260 cars: 29 per lane-km
    Setting("motorway dense", "motorway", 100, 100, 0, 600.0, own_routes=True),
)
QUICK = (Setting("highway quick", "highway", 4, 4, 10, 60.0),)


def straddling(df: pd.DataFrame, lanes: Lanes) -> pd.Series:
    """Per group, the share of settled records on normal lanes whose body reaches over a lane line."""
    settled = df["time"] - df.groupby("id")["time"].transform("min") >= SKIP_S
    normal = ~df["lane"].astype(str).str.startswith(":")
    width = df["lane"].map(lanes.width).astype(float).fillna(3.2)
    over = df["posLat"].abs() > (width - CAR_WIDTH) / 2
    keep = settled & normal & df["posLat"].notna()
    groups = group_names(df["id"], df["type"], "type")
    return over[keep].groupby(groups[keep]).mean()


def through_ranks(net: Path, lanes: Lanes) -> dict[str, int]:
    """Each car lane's rank from the outer side among its edge's through lanes, -1 for the others: a
    through lane goes on into a road of two lanes or more (or its edge leads nowhere: the road's
    end). An auxiliary lane from an on-ramp to an exit, a lane into an exit and a dropped lane are
    not through lanes, and keeping right does not mean moving into them."""
    tables = read_net(net)
    lanes_of = {edge: len(specs) for edge, specs, normal in tables.edges if normal}
    onward = {src for src, _ in tables.car_links}
    through = {a for a, b in tables.lane_links if lanes_of.get(b.rpartition("_")[0], 0) >= 2}
    out: dict[str, int] = {}
    for edge, specs, normal in tables.edges:
        if not normal:
            continue
        ids = sorted((spec[0] for spec in specs), key=lambda lane: lanes.rank.get(lane, 0))
        kept = [lane for lane in ids if lane in through or edge not in onward]
        out.update(dict.fromkeys(ids, -1))
        out.update({lane: k for k, lane in enumerate(kept)})
    return out


def rightmost_while_free(df: pd.DataFrame, ranks: dict[str, int], group: str) -> float:
    """Share of a group's settled records in the rightmost through lane (`through_ranks`), among
    those where that lane of the same edge holds nobody else from FREE_BEHIND behind to FREE_AHEAD
    ahead of the car."""
    lane = df["lane"].astype(str)
    rank = lane.map(ranks).astype(float)
    edge = lane.str.rpartition("_")[0]
    settled = df["time"] - df.groupby("id")["time"].transform("min") >= SKIP_S
    mine = (group_names(df["id"], df["type"], "type") == group) & settled & ~lane.str.startswith(":")
    if not mine.any():
        return math.nan
    step = pd.factorize(df["time"])[0].astype(np.int64)
    edge_code = pd.factorize(edge)[0].astype(np.int64)
    key = (step * (edge_code.max() + 1) + edge_code) * 1e6 + df["pos"].to_numpy(float)
    right = np.sort(key[(rank == 0).to_numpy()])
    ask = key[mine.to_numpy()]
    near = np.searchsorted(right, ask + FREE_AHEAD, "right") - np.searchsorted(
        right, ask - FREE_BEHIND, "left"
    )
    in_right = (rank[mine] == 0).to_numpy()
    free = near - in_right == 0  # itself excluded
    return float(in_right[free].mean()) if free.any() else math.nan


def cell(table: pd.DataFrame, key: str, group: str) -> float:
    return float(table.loc[key, group]) if key in table.index and group in table.columns else math.nan


def run(setting: Setting, policy: Path, seed: int, shield: bool, out: Path) -> dict:
    fcd = out / setting.name.replace(" ", "_") / ("shield" if shield else "bare") / "fcd.parquet"
    config = setting.config(policy, seed, shield, fcd)
    summary = populate(config)
    hours = summary.agent_steps * config.step_length / 3600
    df = read_fcd(fcd)
    lanes = read_lanes(config.net)
    report = measure(df, lanes, agents=read_agents(agents_path(fcd)))
    row = {
        "setting": setting.name,
        "shield": "on" if shield else "off",
        "agent_hours": hours,
        "collisions": summary.collisions,
        "off_tracks": summary.off_tracks,
        "losses_per_hour": (summary.collisions + summary.off_tracks) / max(hours, 1e-9),
        "standing_30s": summary.long_standstills,
        "agents_speed": df.loc[df["type"].isin(["behave_keeper", "behave_overtaker"]), "speed"].mean(),
        "sumo_speed": df.loc[~df["type"].astype(str).str.startswith("behave_k")
                             & ~df["type"].astype(str).str.startswith("behave_o"), "speed"].mean(),
        "overtakers_right_free": rightmost_while_free(df, through_ranks(config.net, lanes), OVERTAKERS),
    }  # fmt: skip
    table, strad = report.table, straddling(df, lanes)
    for group in (KEEPERS, OVERTAKERS, SUMO):
        row[f"{group}_offset"] = cell(table, "lane_offset_mean", group)
        row[f"{group}_straddle"] = float(strad.get(group, math.nan))
        row[f"{group}_lc_peak"] = cell(table, "lc_peak_accel_median", group)
        row[f"{group}_lc_duration"] = cell(table, "lc_duration_median", group)
        row[f"{group}_thw_median"] = cell(table, "thw_median", group)
        row[f"{group}_thw_below_1s"] = cell(table, "thw_below_limit", group)
        row[f"{group}_left_passes"] = cell(table, "passes_overtaking_side", group)
        row[f"{group}_rightmost"] = cell(table, "lane_0_share", group)
    return row


@dataclass(frozen=True)
class Bar:
    name: str
    threshold: str
    value: object  # (runs DataFrame) -> float
    ok: object  # (float) -> bool


def pooled_losses(runs: pd.DataFrame, shield: str) -> float:
    chosen = runs[runs["shield"] == shield]
    return float((chosen["collisions"] + chosen["off_tracks"]).sum() / chosen["agent_hours"].sum())


def worst(runs: pd.DataFrame, column: str, high: bool = True) -> float:
    values = runs[column].dropna()
    return float(values.max() if high else values.min()) if len(values) else math.nan


BARS = (
    Bar("losses per agent-hour, shield off (all runs pooled)", "<= 0.1",
        lambda r: pooled_losses(r, "off"), lambda v: v <= 0.1),
    Bar("losses per agent-hour, shield on (all runs pooled)", "<= 0.01",
        lambda r: pooled_losses(r, "on"), lambda v: v <= 0.01),
    Bar("keepers: mean distance from the lane centre outside lane changes, m (worst run)", "<= 0.25",
        lambda r: worst(r, "keepers_offset"), lambda v: v <= 0.25),
    Bar("straddling a line: agents' share minus SUMO's, points (worst run)", "<= 5",
        lambda r: 100 * float((r[["keepers_straddle", "overtakers_straddle"]].max(axis=1)
                               - r["sumo_straddle"]).max()), lambda v: v <= 5),
    Bar("median peak lateral accel of a lane change, m/s^2 (worst group and run)", "<= 1.2",
        lambda r: max(worst(r, "keepers_lc_peak"), worst(r, "overtakers_lc_peak")), lambda v: v <= 1.2),
    Bar("median lane-change duration, s (shortest group and run)", ">= 4",
        lambda r: min(worst(r, "keepers_lc_duration", False), worst(r, "overtakers_lc_duration", False)),
        lambda v: v >= 4),
    Bar("median lane-change duration, s (longest group and run)", "<= 8",
        lambda r: max(worst(r, "keepers_lc_duration"), worst(r, "overtakers_lc_duration")),
        lambda v: v <= 8),
    Bar("overtakers: time in the rightmost lane while it is free (lowest run)", ">= 25%",
        lambda r: worst(r, "overtakers_right_free", False), lambda v: v >= 0.25),
    Bar("overtakers: passes made on the left (lowest run)", ">= 90%",
        lambda r: worst(r, "overtakers_left_passes", False), lambda v: v >= 0.9),
    Bar("agents' median time headway in dense traffic, s (lowest)", ">= 1.2",
        lambda r: min(worst(r[r.setting.str.contains("dense")], f"{g}_thw_median", False)
                      for g in (KEEPERS, OVERTAKERS)), lambda v: v >= 1.2),
    Bar("agents' median time headway in dense traffic, s (highest)", "<= 2.2",
        lambda r: max(worst(r[r.setting.str.contains("dense")], f"{g}_thw_median")
                      for g in (KEEPERS, OVERTAKERS)), lambda v: v <= 2.2),
    Bar("agents' following time below 1 s in dense traffic (highest)", "< 15%",
        lambda r: max(worst(r[r.setting.str.contains("dense")], f"{g}_thw_below_1s")
                      for g in (KEEPERS, OVERTAKERS)), lambda v: v < 0.15),
)  # fmt: skip


def fmt(value: float, percent: bool) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{100 * value:.1f}%" if percent else f"{value:.2f}"


def bars_markdown(runs: pd.DataFrame) -> str:
    lines = ["| bar | threshold | measured | met |", "|---|---|---|---|"]
    for bar in BARS:
        value = bar.value(runs)  # type: ignore[operator]
        met = "-" if math.isnan(value) else ("yes" if bar.ok(value) else "no")  # type: ignore[operator]
        lines.append(f"| {bar.name} | {bar.threshold} | {fmt(value, bar.threshold.endswith('%'))} | {met} |")
    return "\n".join(lines)


RUN_COLUMNS = {
    "agent_hours": "agent-h", "collisions": "collisions", "off_tracks": "off-tracks",
    "losses_per_hour": "losses/agent-h", "standing_30s": "stood 30 s", "agents_speed": "agents m/s",
    "sumo_speed": "SUMO m/s", "keepers_offset": "keepers offset m", "keepers_straddle": "keepers straddle",
    "overtakers_straddle": "overtakers straddle", "sumo_straddle": "SUMO straddle",
    "overtakers_lc_peak": "overtakers LC peak m/s^2", "overtakers_lc_duration": "overtakers LC s",
    "overtakers_right_free": "overtakers right while free", "overtakers_rightmost": "overtakers rightmost",
    "sumo_rightmost": "SUMO rightmost", "overtakers_left_passes": "overtakers left passes",
    "keepers_thw_median": "keepers THW s", "overtakers_thw_median": "overtakers THW s",
    "sumo_thw_median": "SUMO THW s",
}  # fmt: skip
PERCENT = {"keepers_straddle", "overtakers_straddle", "sumo_straddle", "overtakers_right_free",
           "overtakers_rightmost", "sumo_rightmost", "overtakers_left_passes"}  # fmt: skip


def runs_markdown(runs: pd.DataFrame) -> str:
    header = ["run", *RUN_COLUMNS.values()]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for _, row in runs.iterrows():
        cells = [f"{row['setting']}, shield {row['shield']}"]
        cells += [fmt(float(row[k]), k in PERCENT) for k in RUN_COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, default=DEFAULT_POLICY)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/dense_bars"))
    parser.add_argument("--doc", type=Path, default=Path("docs/dense.md"))
    parser.add_argument(
        "--quick", action="store_true", help="one short run per shield setting (a smoke test)"
    )
    args = parser.parse_args()
    settings = QUICK if args.quick else SETTINGS
    rows = []
    for setting in settings:
        for shield in (True, False):
            rows.append(run(setting, args.policy, args.seed, shield, args.out))
            r = rows[-1]
            print(f"{setting.name}, shield {r['shield']}: {r['agent_hours']:.1f} agent-hours, "
                  f"{r['collisions']} collisions, {r['off_tracks']} off-tracks", flush=True)  # fmt: skip
    runs = pd.DataFrame(rows)
    runs.to_csv(args.out / "runs.csv", index=False)
    text = runs_markdown(runs) + "\n\n" + bars_markdown(runs)
    print(text)
    if not args.quick:
        doc = (
            "# Dense traffic, large samples: the bars on safety, lanes and headways\n\n"
            f"`python benchmarks/dense_bars.py --policy {args.policy} --seed {args.seed}` (`make dense`): "
            "each setting once with the shield on and once off, agents re-inserted as they leave "
            "(`--keep-count`); measured on populate's FCD by `behave report`'s realism measures "
            "(each car's first 10 s left out), plus the share of time a body reaches over a lane line "
            "and the overtakers' share of time in the rightmost through lane (an auxiliary lane from "
            "an on-ramp to an exit, a lane into an exit or a dropped lane is none) among the moments "
            f"that lane is free beside them (nobody from {FREE_BEHIND:.0f} m behind to "
            f"{FREE_AHEAD:.0f} m ahead). "
            "highway: the bundled 3-lane, 3 km straight (9 lane-km) with behave's background cars; "
            "motorway: the curved 3-lane motorway with an on-ramp, a weave and an exit that no "
            "policy trains on, with its own flows.\n\n" + text + "\n"
        )
        write_measured_doc(args.doc, doc)


if __name__ == "__main__":
    main()
