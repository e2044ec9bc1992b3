"""A sweep run's figures and the sweep's plot: the flow, realism and fundamental-diagram figures of a
populate FCD, measured as `behave report` measures them (the row's columns), and sweep.png."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from behaviors.files import atomic_path
from behaviors.report.agents_table import agents_path
from behaviors.sumo.sim import STANDSTILL_SPEED

if TYPE_CHECKING:
    import pandas as pd

OK = "ok"
"""A finished run's status: its row has figures, the plot draws it."""
FLOW_GROUPS = {
    "sumo": ("sumo",),
    "agents": ("keepers", "overtakers"),
    "all": ("sumo", "keepers", "overtakers"),
}
"""The flow figures' groups of vehicles (realism's groups by vType: SUMO's own cars, the agents)."""
PLOTTED = (
    ("all_mean_speed", "mean speed, all cars [m/s]"),
    ("sumo_mean_speed", "mean speed, SUMO's cars [m/s]"),
    ("all_travel_time_mean_s", "travel time of cars that left [s]"),
    ("all_throughput_per_h", "cars leaving per hour"),
    ("sumo_stops_per_vehicle", "stops per SUMO car"),
    ("collisions", "agent collisions"),
)


def fcd_figures(fcd: Path, net: Path) -> dict[str, float]:
    """The flow figures (`flow_figures`) and `behave report`'s realism figures and fundamental-diagram
    summary (`edie_figures`) of a populate FCD, measured as `behave report FCD --net NET` does."""
    from behaviors.report.fcd_read import read_fcd
    from behaviors.report.realism import read_agents
    from behaviors.report.realism_tracks import Lanes, read_lanes

    df = read_fcd(fcd)
    lanes = read_lanes(net) if net.is_file() else Lanes()
    figures = flow_figures(df) | realism_figures(df, lanes, read_agents(agents_path(fcd)))
    return figures | edie_figures(df, net)


def flow_figures(df: pd.DataFrame) -> dict[str, float]:
    """Per group (SUMO's own cars, the agents, all; by each vehicle's last vType as `report` groups):
    vehicles, vehicle-km, mean speed over all records, cars that left before the end, their mean
    travel time (first to last record, plus one step), cars leaving per hour, and stops per vehicle
    (times a moving car came below STANDSTILL_SPEED)."""
    import numpy as np
    import pandas as pd

    from behaviors.report.realism_tracks import group_names

    df = df.sort_values(["id", "time"], kind="stable")
    times = np.sort(df["time"].unique())
    step = float(np.diff(times).min()) if len(times) > 1 else 0.0
    span = float(times[-1] - times[0]) + step if len(times) else 0.0
    per_car = df.groupby("id", sort=True).agg(first=("time", "first"), last=("time", "last"),
                                              type=("type", "last"))  # fmt: skip
    per_car["group"] = group_names(per_car.index.to_series(), per_car["type"], "type").to_numpy()
    halted = (df["speed"] < STANDSTILL_SPEED).to_numpy()
    same = df["id"].to_numpy()[1:] == df["id"].to_numpy()[:-1]
    stop = np.zeros(len(df), bool)
    stop[1:] = halted[1:] & ~halted[:-1] & same
    stops = pd.Series(stop).groupby(df["id"].to_numpy()).sum()
    speed_sum = df.groupby("id")["speed"].sum()
    records = df.groupby("id").size()
    end = float(times[-1]) if len(times) else 0.0
    out: dict[str, float] = {}
    for name, groups in FLOW_GROUPS.items():
        cars = per_car.index[per_car["group"].isin(groups)]
        left = per_car.loc[cars][per_car.loc[cars, "last"] < end - step / 2]
        n, n_left = len(cars), len(left)
        driven = float(speed_sum.reindex(cars).sum())
        out[f"{name}_vehicles"] = float(n)
        out[f"{name}_vehicle_km"] = driven * step / 1000
        out[f"{name}_mean_speed"] = driven / float(records.reindex(cars).sum()) if n else math.nan
        out[f"{name}_left"] = float(n_left)
        travel = (left["last"] - left["first"]).mean() + step
        out[f"{name}_travel_time_mean_s"] = float(travel) if n_left else math.nan
        out[f"{name}_throughput_per_h"] = n_left / span * 3600 if span > 0 else math.nan
        out[f"{name}_stops_per_vehicle"] = float(stops.reindex(cars).sum() / n) if n else math.nan
    out["agents_share_of_vehicles"] = (
        out["agents_vehicles"] / out["all_vehicles"] if len(per_car) else math.nan
    )
    return out


def edie_figures(df: pd.DataFrame, net: Path) -> dict[str, float]:
    """`behave report`'s fundamental-diagram summary (behaviors.report.flow: Edie's density, flow and speed
    of the whole road, the highest flow of a density bin and its density, per group and `all`) as
    columns `edie_<group>_<figure>`, with report's cells; nothing if the run holds no whole window."""
    from behaviors.report.flow import CELL_M, WINDOW_S, edie_cells, road_from_fcd, road_from_net, summary
    from behaviors.report.realism_tracks import group_names

    road = road_from_net(net) if net.is_file() else road_from_fcd(df)
    groups = group_names(df["id"], df.get("type"), "type")
    cells = edie_cells(df, road, groups, cell_m=CELL_M, window_s=WINDOW_S)
    if cells.empty:
        return {}
    return {
        f"edie_{group}_{figure}": float(value)
        for group, row in summary(cells).iterrows()
        for figure, value in row.items()
    }


def realism_figures(df: pd.DataFrame, lanes: Any, agents: pd.DataFrame | None) -> dict[str, float]:
    """`behave report`'s table as columns `realism_<group>_<metric>` (nothing if no car drove long
    enough to be measured)."""
    from behaviors.report.realism import NothingToMeasure, measure

    try:
        report = measure(df, lanes, agents=agents)
    except NothingToMeasure:
        return {}
    table = report.table
    return {
        f"realism_{group}_{metric}": float(table.loc[metric, group])
        for group in table.columns
        for metric in table.index
    }


LINE_SETTINGS = ("background", "overtaker_fraction", "duration_s", "step_length_s", "shield")
"""Settings that make a line of their own in the plot when the table holds more than one value (on a
net the counts are the x axis)."""


def plot_table(table: pd.DataFrame, path: Path) -> Path | None:
    """The main figures against the share (on a net: agents / (agents + background cars)), per scenario
    and policy: the mean over seeds as a line, the range as a band, each run as a dot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = table[table["status"] == OK].copy()
    if ok.empty:
        return None
    agents = ok["overtakers"] + ok["keepers"]
    ok["x"] = ok["share"].where(ok["kind"] == "sumocfg", agents / (agents + ok["background"]))
    lines = ["scenario", "policy", *(c for c in LINE_SETTINGS if ok[c].nunique(dropna=False) > 1)]
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), squeeze=False)
    for ax, (column, title) in zip(axes.flat, PLOTTED, strict=True):
        for key, runs in ok.groupby(lines, sort=True, dropna=False):
            if column not in runs:
                continue
            spread = runs.groupby("x")[column].agg(["mean", "min", "max"]).sort_index()
            label = ", ".join(short(k, v) for k, v in zip(lines, key, strict=True))
            line = ax.plot(spread.index, spread["mean"], marker="o", label=label)
            ax.fill_between(spread.index, spread["min"], spread["max"], alpha=0.2, color=line[0].get_color())
            ax.scatter(runs["x"], runs[column], s=8, color=line[0].get_color(), alpha=0.6)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("share of learned drivers")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    seeds = ok["seed"].nunique()
    fig.suptitle(f"behave sweep: {len(ok)} runs, {seeds} seed{'s' * (seeds != 1)} per point (band: range)")
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)
    return Path(path)


def short(setting: str, value: Any) -> str:
    """A plot label's part: a scenario's or policy's file name without suffixes, else `setting=value`."""
    return Path(str(value)).name.split(".")[0] if setting in ("scenario", "policy") else f"{setting}={value}"
