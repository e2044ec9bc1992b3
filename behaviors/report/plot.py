"""Figures of FCD traces (see behaviors.report.fcd_read.read_fcd), drawn without pyplot.

matplotlib.figure.Figure with an Agg canvas needs no backend selection, so importing or
calling this never changes the global matplotlib state of the caller.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING, Any

from behaviors.errors import BehaveError
from behaviors.files import atomic_path
from sumo_scenarios.net import DEFAULT_LANE_WIDTH, lane_widths

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

GROUP_STYLES = {  # realism_tracks.py's vehicle group -> (legend label, colour)
    "keepers": ("keeper (learned)", "tab:blue"),
    "overtakers": ("overtaker (learned)", "tab:orange"),
}
SUMO_CAR = ("SUMO car", "tab:gray")
# Longitudinal column -> axis label. FCD `distance` is SUMO's linear referencing: a road
# position only on nets whose edges carry kilometrage (else the position on the current edge).
ALONG_LABELS = {
    "distance": "road position [m]",
    "road": "road position along the net [m]",
    "odometer": "distance driven since insertion [m]",
    "pos": "position on lane [m]",
}
DISTANCE_NOISE = 0.1  # metres a road position may step back (2-decimal rounding) and stay monotone
AGENT_STYLE = {"linewidth": 1.4, "alpha": 0.95, "zorder": 3}
SUMO_CAR_STYLE = {"linewidth": 0.8, "alpha": 0.45, "zorder": 2}


def plot_fcd(
    df: pd.DataFrame,
    out: Path,
    *,
    title: str = "",
    lane_width: float = DEFAULT_LANE_WIDTH,  # FCD does not record lane widths
    net: Path | None = None,
) -> None:
    """Time-space diagram and lateral position over time, one line per vehicle, as PNG.

    The time-space axis is the road position: FCD `distance` when it grows along every trace (a net
    whose edges carry kilometrage), else, with `net`, each edge's place along the net (`road_offsets`)
    plus the position on it; without either, the distance driven since insertion (`odometer`, where one
    jam shows at as many heights as the cars came from places). Lateral positions are in lanes:
    posLat is divided by each lane's width read from `net`, or by `lane_width` for lanes it
    does not name (or without a net).
    """
    missing = {"time", "id", "type", "lane", "posLat"} - set(df.columns)
    if missing:
        raise BehaveError(f"FCD table lacks columns for plotting: {', '.join(sorted(missing))}")
    widths = _lane_widths(Path(net)) if net is not None else {}
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(11, 8), layout="constrained")
    FigureCanvasAgg(figure)
    space, lateral = figure.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    df, along = time_space_axis(df.sort_values(["id", "time"], kind="stable"), net)
    styles = trace_styles(df)
    for vid, trace in df.groupby("id", sort=False):
        label, colour = styles[vid]
        style: dict[str, Any] = {"color": colour, "label": label}  # Line2D keywords
        style.update(AGENT_STYLE if colour != SUMO_CAR[1] else SUMO_CAR_STYLE)
        space.plot(trace["time"], trace[along], **style)
        lateral.plot(trace["time"], _lateral_lanes(trace, widths, lane_width), **style)
    index = _lane_index(df["lane"]).dropna()
    lanes = (int(index.min()), int(index.max())) if len(index) else (0, 0)
    _decorate(space, lateral, along, title, lanes)
    _save_png(figure, Path(out))


def trace_styles(df: pd.DataFrame) -> dict[str, tuple[str, str]]:
    """(legend label, colour) of each vehicle, grouped as the realism report groups it: by the
    vType of its last record, SUMO's per-vehicle copies `TYPE@id` counting as TYPE. A scenario's
    car that `populate --share` made an agent starts with the scenario's type."""
    from behaviors.report.realism_tracks import group_names  # pandas-heavy: only once a plot is drawn

    last_type = df.groupby("id", sort=False)["type"].last()
    groups = group_names(last_type.index.to_series(), last_type, "type")
    pairs = zip(last_type.index, groups, strict=True)
    return {vid: GROUP_STYLES.get(group, SUMO_CAR) for vid, group in pairs}


def _along_column(df: pd.DataFrame) -> str:
    """`distance` if it is a road position (never falls along a trace), else `odometer`."""
    present = [c for c in ALONG_LABELS if c in df.columns and df[c].notna().any()]
    if not present:
        if df.empty:  # no vehicle drove: nothing is drawn, the label is moot
            return "pos"
        raise BehaveError("FCD table has no distance, odometer or pos values to plot")
    if present[0] == "distance" and len(present) > 1:
        steps = df.groupby("id", sort=False)["distance"].diff()  # df is sorted by id, time
        if steps.min(skipna=True) < -DISTANCE_NOISE:
            return present[1]
    return present[0]


def time_space_axis(df: pd.DataFrame, net: Path | None) -> tuple[pd.DataFrame, str]:
    """The time-space diagram's column (an ALONG_LABELS key): FCD `distance` where it is a road
    position, else `road` (added: `road_positions`) with a net that places the records, else
    `odometer` (or `pos`). `df` sorted by id and time."""
    along = _along_column(df)
    if along != "distance" and net is not None:
        road = road_positions(df, Path(net))
        if road is not None:
            return df.assign(road=road), "road"
    return df, along


def road_offsets(net: Path) -> dict[str, float]:
    """Normal edge -> metres from the road's start to the edge's start, along the car connections: an
    edge starts where the longest way onto it ends (loops are cut where first met, a ring's lap starts
    again at 0), and an edge nothing leads onto ends where it joins (an on-ramp sits just before its
    merge, not at 0). {} for a net with no car edge (geometry_build.load_geometry refuses it)."""
    from behaviors.road.geometry_build import load_geometry

    try:
        geometry = load_geometry(net, cache=True)
    except BehaveError:
        return {}
    length = {e: info.length for e, info in geometry.edges.items() if info.normal}
    ahead = {e: [s for s in geometry.car_successors.get(e, ()) if s in length] for e in length}
    behind: dict[str, list[str]] = {e: [] for e in length}
    for edge, successors in ahead.items():
        for successor in successors:
            behind[successor].append(edge)
    offset: dict[str, float] = {}
    waiting = {e: len(behind[e]) for e in length}
    order = [e for e in length if not waiting[e]]
    for edge in order:  # Kahn's order: every way onto an edge is known before it
        offset.setdefault(edge, 0.0)
        for successor in ahead[edge]:
            offset[successor] = max(offset.get(successor, 0.0), offset[edge] + length[edge])
            waiting[successor] -= 1
            if not waiting[successor]:
                order.append(successor)
    for start in length:  # loops: on from where they are first met
        if start in offset and all(s in offset for s in ahead[start]):
            continue
        queue = [start]
        offset.setdefault(start, 0.0)
        while queue:
            edge = queue.pop(0)
            for successor in ahead[edge]:
                if successor not in offset:
                    offset[successor] = offset[edge] + length[edge]
                    queue.append(successor)
    for edge in length:
        if not behind[edge] and ahead[edge]:  # an entry: it ends where it joins
            offset[edge] = max(offset[edge], min(offset[s] for s in ahead[edge]) - length[edge])
    return offset


def road_positions(df: pd.DataFrame, net: Path) -> pd.Series | None:
    """Each record's place along the net (`road_offsets` of its edge + its position on the lane);
    records inside a junction are interpolated along their vehicle's trace (df sorted by id, time).
    None if the net places none of the records."""
    offsets = road_offsets(net)
    if not offsets or "pos" not in df.columns:
        return None
    edge = df["lane"].astype(str).str.rpartition("_")[0]
    road = (edge.map(offsets).astype("float64") + df["pos"]).astype("float64")
    if road.isna().all():
        return None
    return road.groupby(df["id"], sort=False).transform(lambda trace: trace.interpolate(limit_area="inside"))


def _lane_widths(net: Path) -> dict[str, float]:
    """Lane id -> width of every lane in a SUMO net, internal (junction) lanes included."""
    if not net.is_file():
        raise BehaveError(f"net file not found: {net}")
    try:
        widths = lane_widths(net)
    except (ET.ParseError, OSError, ValueError, EOFError) as err:
        raise BehaveError(f"{net} is not a SUMO net ({err})") from None
    if not widths:
        raise BehaveError(f"{net} is not a SUMO net (no lanes)")
    return widths


def _lateral_lanes(trace: pd.DataFrame, widths: dict[str, float], lane_width: float) -> pd.Series:
    """Lateral position in lanes: index of the lane (its id ends in _<index>) + posLat / width."""
    index = _lane_index(trace["lane"])
    width = trace["lane"].map(widths).astype("float64").fillna(lane_width)
    return index + trace["posLat"] / width


def _lane_index(lanes: pd.Series) -> pd.Series:
    """Index of each lane within its edge: SUMO lane ids end in _<index>."""
    return lanes.str.rsplit("_", n=1).str[-1].astype("float64")


def _decorate(space: Axes, lateral: Axes, along: str, title: str, lanes: tuple[int, int]) -> None:
    """Labels, lane markings (dashed between lanes, solid at the road's edges), one legend."""
    space.set_ylabel(ALONG_LABELS[along])
    space.set_title(title or "FCD trace")
    lateral.set_ylabel("lateral position [lanes]")
    lateral.set_xlabel("time [s]")
    first, last = lanes
    edges = [index - 0.5 for index in range(first, last + 2)]  # half a lane off each centre
    for edge in edges:
        outer = edge in (edges[0], edges[-1])
        linestyle, alpha = ("-", 0.8) if outer else ("--", 0.5)
        lateral.axhline(edge, color="black", linewidth=0.8, zorder=1, linestyle=linestyle, alpha=alpha)
    low, high = lateral.get_ylim()
    lateral.set_ylim(min(low, edges[0] - 0.15), max(high, edges[-1] + 0.15))
    lateral.set_yticks(range(first, last + 1), [f"lane {index}" for index in range(first, last + 1)])
    space.grid(alpha=0.3)
    lateral.grid(alpha=0.3, axis="x")
    handles, labels = space.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))  # one entry per behaviour, not per car
    space.legend(unique.values(), unique.keys(), loc="upper left", framealpha=0.9)


def _save_png(figure: Figure, out: Path) -> None:
    """Render to a temp file beside `out`, then rename: no half-written PNG on failure."""
    with atomic_path(Path(out)) as tmp:
        figure.savefig(tmp, format="png", dpi=110)
