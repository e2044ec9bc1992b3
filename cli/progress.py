"""Progress of a long command: a bar in a terminal, a line now and then in a log, nothing with -q.

A batch job's log gets no bar (rich draws one only on a terminal), so there a line is printed
each time another PROGRESS_FRACTION of the work is done or PROGRESS_SECONDS of wall time have
passed, whichever comes first.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Annotated, TextIO

import typer

from behaviors.errors import BehaveError

PROGRESS_FRACTION = 0.1
PROGRESS_SECONDS = 30.0

QUIET = Annotated[
    bool, typer.Option("--quiet", "-q", help="no progress and no summary text, only errors (and --json)")
]
VERBOSE = Annotated[bool, typer.Option("--verbose", "-v", help="more detail: set-up steps, phase timings")]


def verbosity(quiet: bool, verbose: bool) -> int:
    """-1 quiet, 0 normal, 1 verbose; both flags at once is a usage error."""
    if quiet and verbose:
        raise BehaveError("-q/--quiet and -v/--verbose exclude each other: give one")
    return -1 if quiet else int(verbose)


def line_due(done: float, total: float, last_done: float, now: float, last_time: float) -> bool:
    """Whether another progress line is due: the end reached, another PROGRESS_FRACTION of `total`
    done since the last line, or PROGRESS_SECONDS of wall time passed since it."""
    if done >= total:
        return done > last_done
    more = done - last_done >= PROGRESS_FRACTION * total * (1 - 1e-9)
    return more or now - last_time >= PROGRESS_SECONDS


def progress_line(what: str, done: float, total: float, unit: str, elapsed: float) -> str:
    percent = 100 * done / total if total > 0 else 100.0
    amount = f"{round(done, 1):,g}/{round(total, 1):,g} {unit}"  # 0.6/5 s, 360/3,600 s
    return f"{what}: {amount} ({percent:.0f}%), {elapsed:,.0f} s elapsed"


class ProgressLines:
    """Progress as occasional lines (see line_due) written to `stream`."""

    def __init__(
        self,
        what: str,
        total: float,
        unit: str,
        stream: TextIO,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.what, self.total, self.unit, self.stream, self.clock = what, total, unit, stream, clock
        self.start = self.last_time = clock()
        self.last_done = 0.0

    def update(self, done: float, detail: str = "") -> None:
        now = self.clock()
        if line_due(done, self.total, self.last_done, now, self.last_time):
            line = progress_line(self.what, done, self.total, self.unit, now - self.start)
            print(f"{line}; {detail}" if detail else line, file=self.stream, flush=True)
            self.last_done, self.last_time = done, now

    def close(self) -> None:
        pass


class ProgressBar:
    """rich's transient bar, started at the first update (after the set-up passed its checks)."""

    def __init__(self, what: str, total: float, unit: str, stderr: bool) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        count = TextColumn(f"{{task.completed:.0f}}/{{task.total:.0f}} {unit}")
        detail = TextColumn("{task.fields[detail]}")
        columns = (TextColumn(what), BarColumn(), count, TimeElapsedColumn(), detail)
        self.progress = Progress(*columns, transient=True, console=Console(stderr=stderr))
        self.task = self.progress.add_task(what, total=total, detail="")

    def update(self, done: float, detail: str = "") -> None:
        if not self.progress.live.is_started:
            self.progress.start()
        self.progress.update(self.task, completed=done, detail=detail)

    def close(self) -> None:
        if self.progress.live.is_started:
            self.progress.stop()


class NoProgress:
    def update(self, done: float, detail: str = "") -> None:
        pass

    def close(self) -> None:
        pass


Progress = ProgressLines | ProgressBar | NoProgress


def make_progress(what: str, total: float, unit: str, *, level: int, stderr: bool) -> Progress:
    """A bar where the stream it goes to (stderr, or stdout) is a terminal, else occasional lines on
    stderr; nothing at all when quiet (level -1)."""
    if level < 0:
        return NoProgress()
    stream = sys.stderr if stderr else sys.stdout
    if stream.isatty():
        return ProgressBar(what, total, unit, stderr)
    return ProgressLines(what, total, unit, sys.stderr)
