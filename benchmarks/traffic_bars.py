"""The bars for a traffic-driver policy, measured on populate's FCD with the realism report.

For each net (the bundled highway with 20 SUMO cars, and the motorway the policies never train
on, with its own flows from the main road and an on-ramp) and each seed: `behave populate` with
4 keepers + 4 overtakers (re-inserted as they leave), shield OFF, then `behave report`'s
measures per group; one more run per net with the shield ON counts how often it set the speed.
Prints one row per bar with the threshold, every run's value and whether all runs meet it, and
writes the table to docs/realism.md (and the raw reports under --out).

    python benchmarks/traffic_bars.py --policy behaviors/pretrained/traffic.pt --seeds 0,1,2
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from common import write_measured_doc

from behaviors.report.agents_table import agents_path
from behaviors.report.fcd_read import read_fcd
from behaviors.report.realism import measure, read_agents
from behaviors.report.realism_output import write_report
from behaviors.report.realism_tracks import KEEPERS, OTHER_GROUP, OVERTAKERS, read_lanes
from behaviors.run.populate import populate
from behaviors.run.populate_config import PopulateConfig
from sumo_scenarios import get_scenario


@dataclass(frozen=True)
class Bar:
    name: str
    threshold: str
    value: Callable[[pd.DataFrame, dict], float]  # (report table, run facts) -> value
    ok: Callable[[float], bool] | None  # None: a row shown beside the bars, not one


def cell(table: pd.DataFrame, key: str, group: str) -> float:
    if group not in table.columns or key not in table.index:
        return math.nan
    value = pd.to_numeric(table.loc[key, group], errors="coerce")
    return float(value)


def ratio(over: float, under: float) -> float:
    """over / under; inf when only `over` is positive (keepers that passed nobody)."""
    if under > 0:
        return over / under
    return math.inf if over > 0 else math.nan


def worst(table: pd.DataFrame, key: str) -> float:
    """The larger of the two groups' values (nan where neither group has one)."""
    known = [v for v in (cell(table, key, g) for g in (KEEPERS, OVERTAKERS)) if not math.isnan(v)]
    return max(known) if known else math.nan


RUN_BARS = (
    Bar("collisions + off-tracks per agent-hour (shield off)", "<= 0.5",
        lambda t, f: f["losses_per_hour"], lambda v: v <= 0.5),
    Bar("agent-steps whose speed the shield set (shield on)", "<= 5%",
        lambda t, f: f.get("shield_speed_share", math.nan), lambda v: v <= 0.05),
)  # fmt: skip
"""Bars on a run's summary."""

DRIVING_BARS = (
    Bar("keepers: lane changes per vehicle-km", "<= 0.15",
        lambda t, f: cell(t, "lane_changes_per_km", KEEPERS), lambda v: v <= 0.15),
    Bar("... of them the route did not ask for (`behave report`; not a bar)", "",
        lambda t, f: cell(t, "discretionary_lane_changes_per_km", KEEPERS), None),
    Bar("SUMO's vehicles: lane changes per vehicle-km (reference, not a bar)", "",
        lambda t, f: cell(t, "lane_changes_per_km", OTHER_GROUP), None),
    Bar("keepers: share of time in the rightmost lane", "<= 75%",
        lambda t, f: cell(t, "lane_0_share", KEEPERS), lambda v: v <= 0.75),
    Bar("overtakers: lane changes per vehicle-km", "<= 1",
        lambda t, f: cell(t, "lane_changes_per_km", OVERTAKERS), lambda v: v <= 1.0),
    Bar("overtakers: passes made on the left", ">= 90%",
        lambda t, f: cell(t, "passes_overtaking_side", OVERTAKERS), lambda v: v >= 0.9),
    Bar("overtakers / keepers: passes per km, on the trips both made", ">= 2",
        lambda t, f: f.get("like_for_like", {}).get("passes_per_km", math.nan), lambda v: v >= 2.0),
    Bar("... all trips pooled (not a bar: the share's draw of routes weighs in)", "",
        lambda t, f: ratio(cell(t, "passes_per_km", OVERTAKERS), cell(t, "passes_per_km", KEEPERS)), None),
    Bar("overtakers / keepers: mean speed, on the trips both made", ">= 1.05",
        lambda t, f: f.get("like_for_like", {}).get("mean_speed", math.nan), lambda v: v >= 1.05),
    Bar("... all trips pooled (not a bar)", "",
        lambda t, f: cell(t, "mean_speed", OVERTAKERS) / cell(t, "mean_speed", KEEPERS), None),
    Bar("time with |lateral accel| > 1.5 m/s^2 (worse group)", "<= 5%",
        lambda t, f: worst(t, "lat_accel_over_limit"), lambda v: v <= 0.05),
    Bar("median peak lateral accel of a lane change (worse group)", "<= 2 m/s^2",
        lambda t, f: worst(t, "lc_peak_accel_median"), lambda v: v <= 2.0),
    Bar("following time with headway < 1 s (worse group)", "<= 10%",
        lambda t, f: worst(t, "thw_below_limit"), lambda v: v <= 0.10),
)  # fmt: skip
"""Bars on the realism report of a run's FCD (the run's facts are not needed)."""
BARS = RUN_BARS + DRIVING_BARS


def net_setups() -> dict[str, dict]:
    highway, motorway = get_scenario("highway"), get_scenario("motorway")
    return {
        "highway": {"net": highway.net, "background": 20},
        "motorway": {"net": motorway.net, "routes": motorway.routes, "background": 0},
    }


def run(policy: Path, setup: dict, seed: int, duration: float, fcd: Path, shield: bool) -> dict:
    config = PopulateConfig(policy=policy, seed=seed, duration=duration, fcd=fcd, keep_count=True,
                            shield=shield, **setup)  # fmt: skip
    summary = populate(config)
    hours = summary.agent_steps * config.step_length / 3600
    return {
        "losses_per_hour": (summary.collisions + summary.off_tracks) / max(hours, 1e-9),
        "shield_speed_share": summary.speed_cuts / max(summary.agent_steps, 1),
        "summary": summary,
    }


def fmt(value: float, threshold: str) -> str:
    if math.isnan(value):
        return "-"
    if math.isinf(value):
        return "inf"
    return f"{100 * value:.1f}%" if threshold.endswith("%") else f"{value:.2f}"


def bars_table(bars: tuple[Bar, ...], columns: dict[str, tuple[pd.DataFrame, dict]]) -> str:
    """One row per bar, a column per run (its report table and facts); met = every run meets it."""
    header = ["bar", "threshold", *columns, "met"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for bar in bars:
        values = [bar.value(table, facts) for table, facts in columns.values()]
        known = [v for v in values if not math.isnan(v)]
        if bar.ok is None:
            met = ""
        else:
            met = "yes" if known and all(bar.ok(v) for v in known) else ("-" if not known else "no")
        lines.append(
            "| " + " | ".join([bar.name, bar.threshold, *(fmt(v, bar.threshold) for v in values), met]) + " |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, default=Path("behaviors/pretrained/traffic.pt"))
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--out", type=Path, default=Path("runs/traffic_bars"))
    parser.add_argument("--doc", type=Path, default=Path("docs/realism.md"))
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    columns: dict[str, tuple[pd.DataFrame, dict]] = {}
    for name, setup in net_setups().items():
        lanes = read_lanes(setup["net"])
        shielded = run(
            args.policy, setup, seeds[0], args.duration, args.out / name / "shield" / "fcd.xml", True
        )
        for seed in seeds:
            fcd = args.out / name / f"s{seed}" / "fcd.xml"
            facts = run(args.policy, setup, seed, args.duration, fcd, False)
            facts["shield_speed_share"] = shielded["shield_speed_share"] if seed == seeds[0] else math.nan
            report = measure(read_fcd(fcd), lanes, agents=read_agents(agents_path(fcd)))
            write_report(report, fcd.parent, title=f"{name} seed {seed}")
            columns[f"{name} s{seed}"] = (report.table, {**facts, "like_for_like": report.like_for_like})
            print(f"{name} seed {seed}: {facts['summary'].agent_steps} agent-steps, "
                  f"{facts['losses_per_hour']:.2f} losses per agent-hour")  # fmt: skip
    text = bars_table(BARS, columns)
    print(text)
    doc = (
        "# Traffic-driver policy against the driving bars\n\n"
        f"`python benchmarks/traffic_bars.py --policy {args.policy} --seeds {args.seeds} "
        f"--duration {args.duration:g}`: 4 keepers + 4 overtakers re-inserted as they leave, shield off "
        "(the shield row: one run per net with it on), measured by `behave report` on populate's FCD "
        "(each car's first 10 s left out). highway: the bundled 3-lane straight with 20 SUMO cars; "
        "motorway: the curved 3-lane motorway with an on-ramp, weave and exit that no policy trains on, "
        "with its own flows (3,300 veh/h).\n\n" + text + "\n"
    )
    write_measured_doc(args.doc, doc)


if __name__ == "__main__":
    main()
