"""Pieces the benchmark scripts share (they run as scripts: `python benchmarks/bench_*.py`)."""

from __future__ import annotations

import csv
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from rich.console import Console
from rich.table import Table

from behaviors.files import atomic_write_text


@contextmanager
def progress(console: Console, label: str) -> Iterator[None]:
    """Print what runs, then how long it took, on one line."""
    start = time.perf_counter()
    console.print(f"[dim]{label} ...[/dim]", end=" ")
    yield
    console.print(f"[dim]{time.perf_counter() - start:.1f} s[/dim]")


def write_csv(path: Path, header: Sequence[str], rows: Iterable[Sequence[str]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)


def print_table(console: Console, title: str, header: Sequence[str], rows: Iterable[Sequence[str]]) -> None:
    """Rich table: first column left-aligned (a label), numbers right-aligned."""
    table = Table(title=title)
    for k, name in enumerate(header):
        table.add_column(name, justify="left" if k == 0 else "right")
    for row in rows:
        table.add_row(*row)
    console.print(table)


def numbered_checkpoints(run: Path) -> list[tuple[int, Path]]:
    """(episodes trained, path) of a run's `episode_*.pt` checkpoints, in training order."""
    found = [(int(p.stem.split("_")[1]), p) for p in (run / "checkpoints").glob("episode_*.pt")]
    return sorted(found)


def meets_lanekeeping_bar(mean: dict[str, float]) -> bool:
    """The project's lane-keeping bar: <= 1% colliding steps, no off-track, >= 80% of the limit."""
    return mean["colliding_steps_pct"] <= 1.0 and mean["off_tracks"] == 0 and mean["mean_speed_frac"] >= 0.8


def write_measured_doc(path: Path, measured: str) -> None:
    """Write a benchmark's doc: `measured` (title, command, table), then whatever the existing doc
    holds from its first `## ` section on: notes written by hand about a measurement survive a re-run."""
    kept = ""
    if path.is_file():
        old = path.read_text()
        start = old.find("\n## ")
        kept = old[start:] if start >= 0 else ""
    atomic_write_text(path, measured.rstrip("\n") + "\n" + kept)
