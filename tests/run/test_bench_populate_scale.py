"""bench_populate's options at scale: the pure parts (row and option parsing, the
alternating blocks, ratios against the bars, the table's columns, peak memory, the warm-up's wait
for every vehicle) and the CPU burner starting, pausing and never outliving its `with` block.
Nothing here times anything: the measurements are benchmarks/bench_populate.py's own."""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from bench_populate import (
    AT_ONCE,
    COLUMNS,
    IDLE,
    LOADED,
    WARMUP_STEPS,
    InsertionTimeout,
    Result,
    Row,
    all_in,
    alternating_blocks,
    columns,
    core_count,
    csv_rows,
    extra_columns,
    parse_args,
    parse_rows,
    peak_rss_mb,
    route_steps,
    row_of,
    target_lines,
    verdict,
    warm_up,
)
from common import CpuBurner


def test_rows_parse_with_and_without_background():
    assert parse_rows("10000:2000, 1000") == [Row(10000, 2000), Row(1000, 0)]


def test_the_default_options_add_nothing_at_scale():
    args = parse_args([])
    assert (args.beside_cpu_burner, args.parallel, args.memory, args.lanes) == (False, None, False, 3)
    assert args.row_list == [Row(100, 100), Row(1000, 200)]
    assert columns() == COLUMNS and extra_columns() == ()


def test_parallel_defaults_to_the_core_count_and_excludes_the_burner():
    assert parse_args(["--parallel"]).parallel == core_count()
    assert parse_args(["--parallel", "3"]).parallel == 3
    with pytest.raises(SystemExit):
        parse_args(["--parallel", "2", "--beside-cpu-burner"])
    with pytest.raises(SystemExit):
        parse_args(["--parallel", "0"])


def test_blocks_take_turns_and_give_each_label_its_steps():
    schedule = alternating_blocks(25, 10, (IDLE, LOADED))
    assert schedule == [(IDLE, 10), (LOADED, 10), (IDLE, 10), (LOADED, 10), (IDLE, 5), (LOADED, 5)]
    flipped = alternating_blocks(25, 10, (IDLE, LOADED), flip=True)
    assert flipped[0] == (LOADED, 10)
    for labels in (schedule, flipped):
        assert sum(n for label, n in labels if label == IDLE) == 25
        assert sum(n for label, n in labels if label == LOADED) == 25
    assert alternating_blocks(200, 200, (IDLE,)) == [(IDLE, 200)]  # the default schedule


def test_routes_are_drawn_for_the_default_steps_at_least():
    assert route_steps(200) == 200  # the default rows: as before
    assert route_steps(10) == 200  # a smoke run's cars do not arrive and come back all warm-up long
    assert route_steps(400) == 400  # idle + loaded steps


def test_a_bar_is_met_at_the_bar_and_missed_without_a_measurement():
    assert verdict(1.2, 1.2) == "met"
    assert verdict(1.21, 1.2) == "MISSED"
    assert verdict(float("nan"), 1.2) == "MISSED"


def test_peak_rss_is_read_from_vmhwm():
    status = "Name:\tpython\nVmPeak:\t 999999 kB\nVmHWM:\t  204800 kB\nVmRSS:\t  102400 kB\n"
    assert peak_rss_mb(status) == 200.0
    assert math.isnan(peak_rss_mb("Name:\tpython\n"))


def result(condition: str, ms: float, alone_ms: float = 0.0, agents: int = 1000) -> Result:
    """A measured row: 100 steps at `ms` per step, SUMO alone at `alone_ms` (none if 0)."""
    r = Result(
        Row(agents, agents // 5), "traffic.pt", agents // 2, agents - agents // 2, condition, phase_s={}
    )
    r.steps, r.total_s = 100, ms / 10.0
    if alone_ms:
        r.alone_steps, r.alone_s = 100, alone_ms / 10.0
        r.no_fcd_steps, r.no_fcd_s = 100, alone_ms / 20.0
    return r


def test_slowdowns_and_their_targets():
    idle, loaded = result(IDLE, 40.0, 32.0), result(LOADED, 46.0, 33.6)
    loaded.reference = idle
    loaded.round_slowdowns, loaded.alone_round_slowdowns = [1.1, 1.2], [1.0, 1.1]
    assert loaded.slowdown == pytest.approx(1.15) and loaded.alone_slowdown == pytest.approx(1.05)
    assert math.isnan(idle.slowdown)
    lines = list(target_lines([idle, loaded]))
    assert lines[0].startswith("target: 1,000 agents <= 1.3x SUMO alone -> 1.25x (met")
    assert "CPU-bound process beside <= 1.2x idle -> 1.15x (met; each round: 1.10, 1.20)" in lines[1]
    alone = [result(f"#{k} alone", 40.0) for k in (1, 2)]
    at_once = [result(f"#{k}, 2 {AT_ONCE}", ms) for k, ms in ((1, 48.0), (2, 56.0))]
    for solo, together in zip(alone, at_once, strict=True):
        together.reference = solo
    (line,) = target_lines(alone + at_once)
    assert "each of 2 populates at once <= 1.3x itself alone -> worst 1.40x (MISSED)" in line


def test_the_scale_row_says_it_completed_with_its_memory():
    r = result(IDLE, 500.0, 400.0, agents=10_000)
    r.on_road, r.peak_rss_mb, r.alone_peak_rss_mb = 12_000, 2048.0, 1024.0
    (line,) = target_lines([r])
    assert line.startswith("scale: 10,000 agents + 2,000 background completed 100 timed steps")
    assert "1.25x SUMO alone (aim <= 1.3x: met" in line and "populate 2048 MB, SUMO alone 1024 MB" in line


def test_every_row_has_a_cell_per_column():
    rows = [result(IDLE, 40.0, 32.0), result("#1 alone", 40.0)]
    for condition in (False, True):
        assert len(row_of(rows[0], condition=condition)) == len(columns(condition))
        for memory in (False, True):
            header = columns(condition) + extra_columns(condition, memory)
            assert all(len(cells) == len(header) for cells in csv_rows(rows, condition, memory))
    assert row_of(rows[1])[COLUMNS.index("ratio")] == "-"  # no SUMO alone in a parallel row


@dataclass
class Summary:
    collisions: int = 0


@dataclass
class Timer:
    resets: int = 0

    def reset(self) -> None:
        self.resets += 1


@dataclass
class Config:
    overtakers: int = 5
    keepers: int = 5
    background: int = 2
    net: Path = Path("long_highway.net.xml")


@dataclass
class FakePopulation:
    """Inserts every vehicle at step `all_in` (never if None)."""

    all_in: int | None
    steps: int = 0
    pending: dict[str, str] = field(default_factory=lambda: {f"keeper_{k}": "keeper" for k in range(12)})
    config: Config = field(default_factory=Config)
    summary: Summary = field(default_factory=Summary)
    timer: Timer = field(default_factory=Timer)

    def step(self) -> None:
        self.steps += 1
        if self.steps == self.all_in:
            self.pending = {}


def test_warm_up_waits_for_every_vehicle():
    early, late = FakePopulation(all_in=3), FakePopulation(all_in=WARMUP_STEPS + 7)
    warm_up(early)  # type: ignore[arg-type]
    warm_up(late)  # type: ignore[arg-type]
    assert (early.steps, late.steps) == (WARMUP_STEPS, WARMUP_STEPS + 7)
    assert late.timer.resets == 1


def test_a_few_cars_being_placed_again_count_as_all_in():
    assert all_in(0, 50) and not all_in(1, 50)
    assert all_in(120, 12_000) and not all_in(121, 12_000)


def test_warm_up_gives_up_with_a_clear_message():
    stuck = FakePopulation(all_in=None)
    with pytest.raises(
        InsertionTimeout, match=r"only 0 of 12 vehicles inserted .* longer --length or more --lanes"
    ):
        warm_up(stuck, timeout_s=0.0)  # type: ignore[arg-type]
    assert stuck.steps == WARMUP_STEPS


def process_state(pid: int) -> str:
    """The kernel's one-letter state of a process: R running, S sleeping, T stopped, ..."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]


def wait_for_state(pid: int, wanted: set[str], tries: int = 200) -> str:
    """Signals arrive asynchronously: look again until the state is one of `wanted` (or give up)."""
    for _ in range(tries):
        state = process_state(pid)
        if state in wanted:
            return state
        time.sleep(0.01)
    return state


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc (Linux)")
def test_the_cpu_burner_starts_paused_spins_when_on_and_never_outlives_its_block():
    with CpuBurner() as burner:
        assert burner.alive and burner.process is not None and burner.process.pid is not None
        pid = burner.process.pid
        assert wait_for_state(pid, {"T"}) == "T"  # off until switched on
        burner.switch(True)
        assert wait_for_state(pid, {"R"}) == "R"
        burner.switch(False)
        assert wait_for_state(pid, {"T"}) == "T"
    assert not burner.alive
    with pytest.raises(KeyboardInterrupt), CpuBurner() as burner:
        burner.switch(True)
        raise KeyboardInterrupt  # an interrupted benchmark
    assert not burner.alive
