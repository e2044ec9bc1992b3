"""The realism report's files: realism.csv (raw numbers), realism.md and the picture realism.png."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from behaviors.files import atomic_path, atomic_write_text, ensure_writable_dir
from behaviors.report.realism import LAT_ACCEL_LIMIT, LOSS_KEYS, THW_LIMIT, Metric, Report
from behaviors.report.realism_tracks import OTHER_GROUP

if TYPE_CHECKING:
    from collections.abc import Sequence

    from matplotlib.figure import Figure


def format_value(value: float, metric: Metric, *, losses_known: bool = True) -> str:
    if np.isnan(value):
        return "unknown" if metric.key in LOSS_KEYS and not losses_known else "-"
    if metric.share:
        return f"{100 * value:.1f}%"
    if metric.key in ("vehicles", "agents_standing"):
        return f"{value:.0f}"
    return f"{value:.2f}" if abs(value) < 100 else f"{value:,.0f}"


def rows(report: Report) -> list[list[str]]:
    """Table rows of formatted values: description, one column per group, naturalistic reference."""
    return [
        [
            m.label,
            *(format_value(v, m, losses_known=report.losses_known) for v in report.table.loc[m.key]),
            m.reference,
        ]
        for m in report.metrics
    ]


def write_report(
    report: Report, out: Path, title: str, *, picture: bool = True, extra: Sequence[str] = ()
) -> list[Path]:
    """realism.csv (raw numbers), realism.md (with the `extra` lines at its end) and (if `picture`:
    it takes ~2 s) realism.png in `out`, each complete or absent."""
    out = Path(out)
    ensure_writable_dir(out)
    groups = list(report.table.columns)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["metric", "description", *groups, "naturalistic"])
    for m in report.metrics:
        values = ["" if np.isnan(v) else f"{v:.6g}" for v in report.table.loc[m.key]]
        writer.writerow([m.key, m.label, *values, m.reference])
    header = ["metric", *groups, "naturalistic"]
    lines = [f"# Realism report: {title}", "", *(f"- {note}" for note in report.notes), ""]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows(report)]
    lines += ["", *extra] if extra else []
    paths = [out / "realism.csv", out / "realism.md"]
    atomic_write_text(paths[0], buffer.getvalue())
    atomic_write_text(paths[1], "\n".join(lines) + "\n")
    if not picture:
        return paths
    with atomic_path(out / "realism.png") as tmp:
        _figure(report, title).savefig(tmp, format="png", dpi=100)
    return [*paths, out / "realism.png"]


def _finite(values: np.ndarray | None) -> np.ndarray:
    return np.zeros(0) if values is None else values[np.isfinite(values)]


COLOURS = {"keepers": "tab:blue", "overtakers": "tab:orange", OTHER_GROUP: "tab:gray"}


def _figure(report: Report, title: str) -> Figure:
    """Lane use per group, and the distributions of time headway, |lateral accel| and speed."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 8), layout="constrained")
    FigureCanvasAgg(figure)
    (lanes, thw), (accel, speed) = figure.subplots(2, 2)
    groups = list(report.table.columns)
    colour = {g: COLOURS.get(g, f"C{k + 3}") for k, g in enumerate(groups)}
    lane_rows = [m.key for m in report.metrics if m.key.startswith("lane_") and m.share]
    bar = 0.8 / max(len(groups), 1)
    for k, g in enumerate(groups):
        shares = report.table.loc[lane_rows, g].fillna(0).to_numpy()
        lanes.bar(np.arange(len(lane_rows)) + k * bar, 100 * shares, bar, label=g, color=colour[g])
    lanes.set_xticks(
        np.arange(len(lane_rows)) + bar * (len(groups) - 1) / 2,
        [f"lane {r.split('_')[1]}" for r in lane_rows],
    )
    lanes.set_ylabel("share of time [%]")
    lanes.set_title("lane use (lane 0 = outermost)")
    accel_bins = np.linspace(0, 3, 31)
    for g in groups:
        for axes, key in ((thw, "thw"), (speed, "speed")):
            values = np.sort(_finite(report.samples[key].get(g)))
            if len(values):
                axes.step(
                    values,
                    np.arange(1, len(values) + 1) / len(values),
                    where="post",
                    label=g,
                    color=colour[g],
                )
        values = _finite(report.samples["accel"].get(g))
        if len(values):
            accel.hist(values, bins=accel_bins, density=True, histtype="step", label=g, color=colour[g])
    thw.set(xlim=(0, 4), xlabel="time headway [s]", ylabel="share of following time below")
    speed.set(xlabel="speed [m/s]", ylabel="share of time below")
    accel.set(xlabel="|lateral acceleration| [m/s^2]", ylabel="density")
    thw.axvline(THW_LIMIT, color="red", linestyle="--", linewidth=0.8)
    accel.axvline(LAT_ACCEL_LIMIT, color="red", linestyle="--", linewidth=0.8)
    accel.set_yscale("log")
    for axes in (lanes, thw, accel, speed):
        axes.grid(alpha=0.3)
        if axes.get_legend_handles_labels()[0]:
            axes.legend()
    figure.suptitle(title)
    return figure
