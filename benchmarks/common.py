"""Pieces the benchmark scripts share (they run as scripts: `python benchmarks/bench_*.py`)."""

from __future__ import annotations

import csv
import multiprocessing
import os
import signal
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from pathlib import Path
from types import TracebackType

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


def burn(conn: Connection) -> None:
    """Pure-Python spinning on one core: what another populate, a training or a build does beside
    a benchmark. Says so once it spins (its imports are done); never returns: CpuBurner kills it."""
    conn.send("spinning")
    x = 0
    while True:
        x = (x * 1_103_515_245 + 12_345) & 0x7FFF_FFFF


class CpuBurner:
    """A CPU-bound process beside a benchmark, spinning while switched on and stopped (SIGSTOP)
    while off; it starts off. Started on entering the `with` block and killed on leaving it,
    whatever happened inside, so it never outlives the benchmark."""

    START_TIMEOUT_S = 120.0

    def __init__(self) -> None:
        self.process: BaseProcess | None = None

    def __enter__(self) -> CpuBurner:
        context = multiprocessing.get_context("spawn")
        ours, theirs = context.Pipe()
        self.process = context.Process(target=burn, args=(theirs,), daemon=True, name="CPU burner")
        self.process.start()
        try:
            if not ours.poll(self.START_TIMEOUT_S) or ours.recv() != "spinning":
                raise RuntimeError("the CPU burner did not start")
            self.switch(False)
        except BaseException:
            self.stop()
            raise
        return self

    def switch(self, on: bool) -> None:
        """Spin (SIGCONT) or stand still (SIGSTOP)."""
        assert self.process is not None and self.process.pid is not None
        os.kill(self.process.pid, signal.SIGCONT if on else signal.SIGSTOP)

    @property
    def alive(self) -> bool:
        return self.process is not None and self.process.is_alive()

    def stop(self) -> None:
        if self.process is not None:
            self.process.kill()  # SIGKILL ends a stopped process too
            self.process.join(timeout=30)

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        self.stop()
