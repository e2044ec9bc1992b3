"""The fundamental diagram of an FCD: flow against density by Edie's generalised definitions.

The road is cut into space-time cells: each normal edge into pieces of `cell_m` metres (all its car
lanes together), time into windows of `window_s` seconds. In a cell of length L with n lanes over a
window T, with each FCD record standing for the step dt it covers:

* density k = total time spent in the cell / (L x n x T), in vehicles per lane-km;
* flow q = total distance travelled in the cell / (L x n x T), in vehicles per hour per lane;
* speed = q / k (the space-mean speed).

Per group (SUMO's cars, keepers, overtakers) k and q are that group's share of the cell (the groups'
k and q add up to the cell's); `all` is every vehicle. Junction-internal lanes are left out (their
records belong to no cell), and so are cells shorter than MIN_CELL_M and the last, incomplete window.
Pure functions of a table (`read_fcd`'s columns id, time, lane, pos, speed and optionally type):
no SUMO needed.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from behaviors.files import atomic_path, atomic_write_text, ensure_writable_dir

if TYPE_CHECKING:
    from collections.abc import Mapping

    from matplotlib.figure import Figure

CELL_M = 500.0
WINDOW_S = 60.0
MIN_CELL_M = 50.0
"""m: a cell shorter than this (an edge's short tail, a short edge) gives no point."""
DENSITY_BIN = 5.0
"""veh per lane-km: the summary's capacity is the highest mean flow over cells in bins this wide."""
MIN_CELLS_PER_BIN = 3
ALL = "all"
COLUMNS = ("group", "edge", "cell_start_m", "cell_m", "lanes", "t_start_s", "window_s",
           "vehicle_s", "vehicle_m", "density", "flow", "speed")  # fmt: skip


@dataclass(frozen=True)
class RoadEdges:
    """Per normal edge its length (m) and number of lanes cars may use."""

    length: dict[str, float]
    lanes: dict[str, int]


def road_from_net(net: Path) -> RoadEdges:
    """Lengths and car-lane counts of a net's normal edges (sumo_scenarios.net)."""
    from sumo_scenarios.net import read_net

    tables = read_net(Path(net))
    length, lanes = {}, {}
    for edge, specs, normal in tables.edges:
        if normal and specs:
            length[edge] = max(spec[4] for spec in specs)
            lanes[edge] = len(specs)
    return RoadEdges(length, lanes)


def road_from_fcd(df: pd.DataFrame) -> RoadEdges:
    """Without a net: an edge is as long as the furthest position seen on it and has as many lanes as
    its highest lane index seen + 1."""
    normal = df[~df["lane"].astype(str).str.startswith(":")]
    lane = normal["lane"].astype(str)
    parts = lane.str.rpartition("_")
    index = pd.to_numeric(parts[2], errors="coerce")
    by_edge = pd.DataFrame({"edge": parts[0], "index": index, "pos": normal["pos"].to_numpy(float)})
    grouped = by_edge.groupby("edge")
    return RoadEdges(
        {str(e): float(v) for e, v in grouped["pos"].max().items()},
        {str(e): int(v) + 1 for e, v in grouped["index"].max().items() if np.isfinite(v)},
    )


def step_of(times: pd.Series) -> float:
    """The FCD's record period: the median difference between successive record times."""
    unique = np.unique(times.to_numpy(float))
    return float(np.median(np.diff(unique))) if len(unique) > 1 else 1.0


def edie_cells(
    df: pd.DataFrame,
    road: RoadEdges,
    groups: pd.Series | None = None,
    *,
    cell_m: float = CELL_M,
    window_s: float = WINDOW_S,
    start_s: float | None = None,
    end_s: float | None = None,
    edges: set[str] | None = None,
) -> pd.DataFrame:
    """Edie's flow and density per space-time cell, per group and for `all` (COLUMNS, one row per cell
    and group; empty cells included with 0).

    `groups`: a group name per record (None: only `all`). Time runs from `start_s` (default: the
    first record) in whole windows up to `end_s` (default: the last record + one step); `edges`
    limits the cells to those edges.
    """
    if cell_m <= 0 or window_s <= 0:
        raise ValueError("cell length and window must be positive")
    dt = step_of(df["time"])
    t0 = float(df["time"].min()) if start_s is None else float(start_s)
    t1 = float(df["time"].max()) + dt if end_s is None else float(end_s)
    n_windows = int(np.floor((t1 - t0) / window_s + 1e-9))
    cells = _cells(road, cell_m, edges)
    group_names = [ALL] if groups is None else [*sorted(set(groups.astype(str))), ALL]
    if n_windows <= 0 or cells.empty:
        return pd.DataFrame(columns=list(COLUMNS))
    lane = df["lane"].astype(str)
    edge = lane.str.rpartition("_")[0]
    time = df["time"].to_numpy(float)
    pos = df["pos"].to_numpy(float)
    window = np.floor((time - t0) / window_s + 1e-9)
    piece = np.floor(pos / cell_m)
    keep = (~lane.str.startswith(":")).to_numpy() & (window >= 0) & (window < n_windows)
    keep &= edge.isin(cells["edge"].unique()).to_numpy()
    records = pd.DataFrame({
        "edge": edge.to_numpy()[keep],
        "piece": piece[keep].astype(np.int64),
        "window": window[keep].astype(np.int64),
        "vehicle_s": dt,
        "vehicle_m": df["speed"].to_numpy(float)[keep] * dt,
        "group": (ALL if groups is None else groups.astype(str).to_numpy()[keep]),
    })  # fmt: skip
    amounts = ["vehicle_s", "vehicle_m"]
    sums = [records.groupby(["group", "edge", "piece", "window"])[amounts].sum()]
    if groups is not None:
        every = records.groupby(["edge", "piece", "window"])[amounts].sum()
        sums.append(pd.concat({ALL: every}, names=["group"]))
    totals = pd.concat(sums)
    grid = pd.MultiIndex.from_product(
        [group_names, range(len(cells)), range(n_windows)], names=["group", "cell", "window"]
    ).to_frame(index=False)
    grid = grid.join(cells, on="cell")
    grid = grid.join(totals, on=["group", "edge", "piece", "window"]).fillna(
        {"vehicle_s": 0.0, "vehicle_m": 0.0}
    )
    area = grid["cell_m"] * grid["lanes"] * window_s  # lane-metre-seconds
    out = pd.DataFrame({
        "group": grid["group"],
        "edge": grid["edge"],
        "cell_start_m": grid["piece"] * cell_m,
        "cell_m": grid["cell_m"],
        "lanes": grid["lanes"],
        "t_start_s": t0 + grid["window"] * window_s,
        "window_s": window_s,
        "vehicle_s": grid["vehicle_s"],
        "vehicle_m": grid["vehicle_m"],
        "density": grid["vehicle_s"] / area * 1000.0,  # veh per lane-km
        "flow": grid["vehicle_m"] / area * 3600.0,  # veh per hour per lane
    })  # fmt: skip
    out["speed"] = (out["flow"] / out["density"].where(out["density"] > 0)) / 3.6  # m/s
    return out[list(COLUMNS)].reset_index(drop=True)


def _cells(road: RoadEdges, cell_m: float, edges: set[str] | None) -> pd.DataFrame:
    rows = []
    for edge in sorted(road.length):
        if (edges is not None and edge not in edges) or road.lanes.get(edge, 0) < 1:
            continue
        length = road.length[edge]
        for piece in range(int(np.ceil(length / cell_m - 1e-9))):
            size = min(cell_m, length - piece * cell_m)
            if size >= MIN_CELL_M:
                rows.append((edge, piece, size, road.lanes[edge]))
    return pd.DataFrame(rows, columns=["edge", "piece", "cell_m", "lanes"])


def region(cells: pd.DataFrame) -> pd.DataFrame:
    """Edie's definitions over the union of the cells (per group): density, flow and speed of the
    whole region, the cells weighted by their area."""
    area = cells["cell_m"] * cells["lanes"] * cells["window_s"]
    sums = pd.DataFrame({"vehicle_s": cells["vehicle_s"], "vehicle_m": cells["vehicle_m"], "area": area})
    total = sums.groupby(cells["group"]).sum()
    density = total["vehicle_s"] / total["area"] * 1000.0
    flow = total["vehicle_m"] / total["area"] * 3600.0
    return pd.DataFrame({"density": density, "flow": flow, "speed": flow / density.where(density > 0) / 3.6})


def summary(cells: pd.DataFrame) -> pd.DataFrame:
    """Per group: the whole region's density, flow and speed, and the capacity seen: the highest mean
    flow over the cells of a DENSITY_BIN-wide density bin (bins of MIN_CELLS_PER_BIN cells or more)
    with the bin's mean density."""
    whole = region(cells)
    rows = {}
    for group, part in cells[cells["density"] > 0].groupby("group"):
        bins = np.floor(part["density"] / DENSITY_BIN)
        binned = part.groupby(bins).agg(
            density=("density", "mean"), flow=("flow", "mean"), n=("flow", "size")
        )
        binned = binned[binned["n"] >= MIN_CELLS_PER_BIN]
        best = binned.loc[binned["flow"].idxmax()] if len(binned) else None
        rows[group] = {
            "max_flow": float(best["flow"]) if best is not None else np.nan,
            "density_at_max_flow": float(best["density"]) if best is not None else np.nan,
            "cells": int((part["vehicle_s"] > 0).sum()),
        }
    table = whole.join(pd.DataFrame.from_dict(rows, orient="index"))
    order = [g for g in table.index if g != ALL] + ([ALL] if ALL in table.index else [])
    return table.reindex(order)


def summary_markdown(table: pd.DataFrame) -> list[str]:
    """Markdown lines of `summary`'s table."""
    lines = [
        "| group | density (veh/lane-km) | flow (veh/h/lane) | speed (m/s) "
        "| max flow of a density bin (veh/h/lane) | at density (veh/lane-km) |",
        "|---|---|---|---|---|---|",
    ]
    for group, row in table.iterrows():
        cells = [
            row["density"],
            row["flow"],
            row["speed"],
            row.get("max_flow"),
            row.get("density_at_max_flow"),
        ]
        lines.append(f"| {group} | " + " | ".join(_num(v) for v in cells) + " |")
    return lines


def _num(value: float | None) -> str:
    if value is None or not np.isfinite(value):
        return "-"
    return f"{value:,.0f}" if abs(value) >= 100 else f"{value:.1f}"


def write_flow(cells: pd.DataFrame, out: Path, title: str, *, picture: bool = True) -> list[Path]:
    """flow.csv (one row per cell and group) and flow.png (flow and speed against density) in `out`,
    each complete or absent."""
    out = Path(out)
    ensure_writable_dir(out)
    buffer = io.StringIO()
    cells.to_csv(buffer, index=False, float_format="%.6g", lineterminator="\n", quoting=csv.QUOTE_MINIMAL)
    paths = [out / "flow.csv"]
    atomic_write_text(paths[0], buffer.getvalue())
    if picture:
        with atomic_path(out / "flow.png") as tmp:
            figure(cells, title).savefig(tmp, format="png", dpi=100)
        paths.append(out / "flow.png")
    return paths


COLOURS = {"keepers": "tab:blue", "overtakers": "tab:orange", "sumo": "tab:gray", ALL: "black"}


def figure(cells: pd.DataFrame, title: str, colours: Mapping[str, str] | None = None) -> Figure:
    """Flow and speed against density, one colour per group (cells with vehicles)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    colours = {**COLOURS, **(colours or {})}
    fig = Figure(figsize=(12, 5), layout="constrained")
    FigureCanvasAgg(fig)
    flow_ax, speed_ax = fig.subplots(1, 2)
    groups = [g for g in dict.fromkeys(cells["group"]) if g != ALL] + [ALL]
    for k, group in enumerate(groups):
        part = cells[(cells["group"] == group) & (cells["vehicle_s"] > 0)]
        if part.empty:
            continue
        colour = colours.get(group, f"C{k + 3}")
        flow_ax.scatter(part["density"], part["flow"], s=8, alpha=0.6, label=group, color=colour)
        speed_ax.scatter(part["density"], part["speed"], s=8, alpha=0.6, label=group, color=colour)
    flow_ax.set(xlabel="density [veh/lane-km]", ylabel="flow [veh/h/lane]", title="flow against density")
    speed_ax.set(
        xlabel="density [veh/lane-km]", ylabel="space-mean speed [m/s]", title="speed against density"
    )
    for axes in (flow_ax, speed_ax):
        axes.set_xlim(left=0)
        axes.set_ylim(bottom=0)
        axes.grid(alpha=0.3)
        if axes.get_legend_handles_labels()[0]:
            axes.legend()
    fig.suptitle(f"{title}: Edie's definitions per cell (groups: their share of each cell)")
    return fig
