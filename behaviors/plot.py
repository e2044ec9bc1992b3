"""Figures of FCD traces (see behaviors.export.read_fcd), drawn without pyplot.

matplotlib.figure.Figure with an Agg canvas needs no backend selection, so importing or
calling this never changes the global matplotlib state of the caller.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from behaviors.errors import BehaveError

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

BEHAVIOURS = {  # vType id -> (legend label, colour)
    "behave_keeper": ("keeper (learned)", "tab:blue"),
    "behave_overtaker": ("overtaker (learned)", "tab:orange"),
}
SUMO_CAR = ("SUMO car", "tab:gray")
SUMO_LANE_WIDTH = 3.2  # SUMO's default; FCD does not record lane widths


def plot_fcd(df: pd.DataFrame, out: Path, *, title: str = "", lane_width: float = SUMO_LANE_WIDTH) -> None:
    """Time-space diagram and lateral position over time, one line per vehicle, as PNG."""
    missing = {"time", "id", "type", "lane", "posLat"} - set(df.columns)
    if missing:
        raise BehaveError(f"FCD table lacks columns for plotting: {', '.join(sorted(missing))}")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(10, 7), layout="constrained")
    FigureCanvasAgg(figure)
    space, lateral = figure.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    has_distance = "distance" in df.columns and df["distance"].notna().any()
    along = "distance" if has_distance else "pos"
    for _, trace in df.sort_values("time").groupby("id", sort=False):
        label, colour = BEHAVIOURS.get(str(trace["type"].iloc[0]), SUMO_CAR)
        style = {"color": colour, "label": label, "linewidth": 1.2}
        space.plot(trace["time"], trace[along], **style)
        lateral.plot(trace["time"], _lateral_lanes(trace, lane_width), **style)
    _decorate(space, lateral, along, title)
    _save_png(figure, Path(out))


def _lateral_lanes(trace: pd.DataFrame, lane_width: float) -> pd.Series:
    """Lateral position in lanes: index of the lane (its id ends in _<index>) + posLat."""
    index = trace["lane"].str.rsplit("_", n=1).str[-1].astype("float64")
    return index + trace["posLat"] / lane_width


def _decorate(space: Axes, lateral: Axes, along: str, title: str) -> None:
    space.set_ylabel("distance travelled [m]" if along == "distance" else "position on lane [m]")
    space.set_title(title or "FCD trace")
    lateral.set_ylabel("lateral position [lanes]")
    lateral.set_xlabel("time [s]")
    low, high = lateral.get_ylim()
    low, high = min(low, round(low) - 0.5), max(high, round(high) + 0.5)  # outer lane edges
    for line in range(round(low), round(high) + 1):  # lane lines lie half a lane off centre
        lateral.axhline(line - 0.5, color="black", linewidth=0.6, linestyle="--", alpha=0.5)
    lateral.set_ylim(low - 0.1, high + 0.1)
    lateral.yaxis.get_major_locator().set_params(integer=True)
    for axes in (space, lateral):
        axes.grid(alpha=0.3)
    handles, labels = space.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))  # one entry per behaviour, not per car
    space.legend(unique.values(), unique.keys(), loc="upper left")


def _save_png(figure: Figure, out: Path) -> None:
    """Render to a temp file beside `out`, then rename: no half-written PNG on failure."""
    if not out.parent.is_dir():
        raise BehaveError(f"output directory does not exist: {out.parent}")
    try:
        fd, tmp = tempfile.mkstemp(prefix=".behave-plot-", suffix=".png", dir=out.parent)
    except OSError as err:
        why = f"output directory is not writable: {out.parent} ({err.strerror})"
        raise BehaveError(why) from None
    try:
        with os.fdopen(fd, "wb") as f:
            figure.savefig(f, format="png", dpi=110)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
