"""Per-step cost of `behave populate` against SUMO alone with the same number of vehicles.

Each round runs three simulations, each in a fresh process, stepped in turn one step at a time
(the machine's speed drifts within minutes: runs timed one after the other measured the drift as
much as the code):
1. populate: `Population(config)` with learned agents (half overtakers, half keepers with the
   multi-behaviour policy; keepers only with the lane-keeping one) among `behave_background` cars,
   FCD on (the real use); whole `Population.step()` timed, split into the population timer's
   phases (read, sensors, shield, policy, actuation, sumo) plus "other" (bookkeeping, insertion);
2. SUMO alone: the same net, seed, FCD settings and vehicle count, every car `behave_background`
   and driven by SUMO; only the SUMO step (the "sumo" phase) is timed;
3. SUMO alone without FCD: as 2 without `--fcd-output`, so the FCD column is what writing FCD
   costs SUMO per step for that many vehicles.
Each run warms up (at least 20 steps, then on until every vehicle is in, within --insert-timeout)
before timing. The network is a long straight highway (3 lanes unless --lanes) built into a temp
dir with the project's own builder (the bundled one holds ~600 cars).

Rows at scale (none of them runs by default):
- `--beside-cpu-burner`: the same three runs, with a process spinning on one core beside them; it
  runs in blocks of --block steps taking turns with blocks where it is paused (SIGSTOP), so idle
  and loaded steps alternate within the same runs and the machine's drift cannot bias their ratio
  (bar: populate loaded <= 1.2x idle). The burner starts before the runs and is killed after them.
- `--parallel [N]` (N: the core count unless given): N populates (seeds seed .. seed+N-1, each its
  own process and SUMO), in blocks that take turns: each populate stepping while the others wait
  ("alone"), then all N stepping at once; each one's ms/step at once against its own alone
  (bar: <= 1.3x). No SUMO-alone runs.
- `--memory`: the peak resident memory (VmHWM) of the populate and SUMO-alone processes as columns;
  with `--rows 10000:2000 --length 300000` the 10,000-agent row (the same 13 vehicles per lane-km
  as the 1,000:200 row on 30 km).

Usage: python benchmarks/bench_populate.py [--rows 100:100,1000:200] [--steps 200] [--seed 0]
                                           [--rounds 3] [--length 30000] [--lanes 3] [--policy CKPT]
                                           [--csv PATH] [--profile] [--memory]
                                           [--beside-cpu-burner | --parallel [N]] [--block 10]
                                           [--insert-timeout 900]
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import math
import multiprocessing
import os
import pstats
import tempfile
import time
from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass, field, replace
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from pathlib import Path

import torch
from common import CpuBurner, print_table, progress, write_csv
from rich.console import Console

from behaviors.learn.ddpg.checkpoint import load_checkpoint
from behaviors.paper.sensors import OBS_SIZE_WITH_ID
from behaviors.run.fcd_sealing import partial_path
from behaviors.run.populate_config import DEFAULT_POLICY, PopulateConfig
from behaviors.run.population import Population
from behaviors.run.precision import POLICY_THREADS
from behaviors.traffic.lanes import TRAFFIC_OBS_SIZE
from sumo_scenarios.build import build_straight

WARMUP_STEPS = 20
STEP_LENGTH = 0.2
PHASES = ("read", "sensors", "shield", "policy", "actuation", "sumo")
TARGET_RATIO_1000 = 1.3
SCALE_AGENTS = 10_000
TARGET_RATIO_SCALE = 1.3  # an aim, not a bar: if missed, the doc says what bounds it
TARGET_BURNER = 1.2  # populate's ms/step with a CPU-bound process beside it / idle
TARGET_PARALLEL = 1.3  # each of N populates at once / the same populate alone
IDLE = "idle"
LOADED = "CPU burner beside"
ALONE = "alone"
AT_ONCE = "at once"
BLOCK_STEPS = 10
INSERT_TIMEOUT_S = 900.0
ROUTE_STEPS = 200
"""Steps the routes are drawn for at least (populate draws them for its duration): with a few timed
steps only (smoke runs), routes of a few hundred metres made cars arrive and come back as new
insertions so often that the warm-up never saw every vehicle in."""


@dataclass(frozen=True)
class Row:
    agents: int
    background: int


@dataclass
class Result:
    row: Row
    policy: str
    overtakers: int
    keepers: int
    condition: str = IDLE  # IDLE, LOADED, or a parallel populate's "alone"/"at once" label
    steps: int = 0
    total_s: float = 0.0
    phase_s: dict[str, float] | None = None
    collisions: int = 0
    off_tracks: int = 0
    retries: int = 0
    on_road: int = 0  # vehicles in SUMO at the end of the timed steps (worst round)
    alone_s: float = 0.0
    alone_steps: int = 0
    alone_on_road: int = 0
    no_fcd_s: float = 0.0
    no_fcd_steps: int = 0
    round_ratios: list[float] = field(default_factory=list)  # ratio of each round's lockstep runs
    peak_rss_mb: float = 0.0  # the populate process's VmHWM, largest over the rounds
    alone_peak_rss_mb: float = 0.0  # SUMO alone's (with FCD)
    reference: Result | None = None  # what `slowdown` compares with: the idle or alone row
    round_slowdowns: list[float] = field(default_factory=list)  # ms/step / reference's, per round
    alone_round_slowdowns: list[float] = field(default_factory=list)  # SUMO alone's, likewise

    def per_step_ms(self, seconds: float, steps: int | None = None) -> float:
        return 1000.0 * seconds / max(self.steps if steps is None else steps, 1)

    @property
    def ms_per_step(self) -> float:
        return self.per_step_ms(self.total_s)

    def phase_ms(self, name: str) -> float:
        phases = self.phase_s or {}
        if name == "other":
            return self.per_step_ms(self.total_s - sum(phases.get(p, 0.0) for p in PHASES))
        return self.per_step_ms(phases.get(name, 0.0))

    @property
    def real_time_factor(self) -> float:
        return self.steps * STEP_LENGTH / self.total_s if self.total_s > 0 else float("nan")

    @property
    def alone_ms(self) -> float:
        return self.per_step_ms(self.alone_s, self.alone_steps)

    @property
    def fcd_ms(self) -> float:
        """SUMO alone with FCD minus without: what writing FCD costs per step."""
        return self.alone_ms - self.per_step_ms(self.no_fcd_s, self.no_fcd_steps)

    @property
    def ratio(self) -> float:
        return ratio(self.ms_per_step, self.alone_ms)

    @property
    def slowdown(self) -> float:
        """ms/step against the reference row's (idle, or the same populate alone); nan without one."""
        return float("nan") if self.reference is None else ratio(self.ms_per_step, self.reference.ms_per_step)

    @property
    def alone_slowdown(self) -> float:
        return float("nan") if self.reference is None else ratio(self.alone_ms, self.reference.alone_ms)


def ratio(value: float, reference: float) -> float:
    """value / reference; nan when there is no reference (nothing measured)."""
    return value / reference if reference > 0 else float("nan")


def verdict(value: float, bar: float) -> str:
    """'met' or 'MISSED' (nan, nothing measured, misses)."""
    return "met" if value <= bar else "MISSED"


def pick_policy(agents: int, policy: Path | None) -> tuple[Path, int, int]:
    """(checkpoint, overtakers, keepers): half and half with a multi-behaviour policy, else all of
    the policy's own behaviour. Default: populate's default (the bundled traffic.pt)."""
    if policy is None:
        policy = DEFAULT_POLICY
    meta = load_checkpoint(policy).meta
    if int(meta["obs_dim"]) in (OBS_SIZE_WITH_ID, TRAFFIC_OBS_SIZE):  # one network, both behaviours
        return policy, agents // 2, agents - agents // 2
    if meta.get("behaviour") == "overtaking":
        return policy, agents, 0
    return policy, 0, agents


def build_highway(out_dir: Path, length: float, lanes: int = 3) -> Path:
    scenario = build_straight(
        out_dir / "long_highway",
        name="long_highway",
        length=length,
        edge_length=300.0,
        lanes=lanes,
        lane_width=3.5,
        kilometrage=True,
        description=f"straight {lanes}-lane motorway, {length / 1000:.0f} km (benchmark)",
    )
    return scenario.net


RunOutput = tuple[int, float, dict[str, float], dict[str, int]]
"""(timed steps, seconds, seconds per phase, counters)."""


def run_population(
    population: Population, fcd: Path | None, steps: int, profiler: cProfile.Profile | None = None
) -> RunOutput:
    """Warm up, then time `steps` whole steps (FCD to `fcd`, or none); steps, seconds, phases, counters."""
    population.start(None if fcd is None else partial_path(fcd))
    try:
        before = warm_up(population)
        total = 0.0
        if profiler is not None:
            profiler.enable()
        for _ in range(steps):
            start = time.perf_counter()
            population.step()
            total += time.perf_counter() - start
        if profiler is not None:
            profiler.disable()
        return steps, total, dict(population.timer.seconds), counters(population, before)
    finally:
        population.close()


class InsertionTimeout(RuntimeError):
    """SUMO did not place every vehicle within the warm-up's time limit."""


def vehicles_wanted(config: PopulateConfig) -> int:
    return config.overtakers + config.keepers + config.background


def insertion_message(inserted: int, wanted: int, steps: int, seconds: float, net: Path) -> str:
    return (
        f"only {inserted:,} of {wanted:,} vehicles inserted after {steps} warm-up steps ({seconds:.0f} s) "
        f"on {net.name}: the road is too full for SUMO to place them all; use a longer --length or more "
        f"--lanes, or a larger --insert-timeout"
    )


def all_in(pending: int, wanted: int) -> bool:
    """Every vehicle placed, but for 1% still being placed: a car that reached the end of its route
    comes back as a new insertion (`--keep-count`), so a road with a few arrivals per step is never
    without any pending."""
    return pending <= wanted // 100


def warm_up(population: Population, timeout_s: float = INSERT_TIMEOUT_S) -> dict[str, int]:
    """WARMUP_STEPS steps, then on until every vehicle is in (10,000 take SUMO a while to place),
    then a clean timer; the summary's counts at that point. Raises InsertionTimeout after `timeout_s`."""
    wanted = vehicles_wanted(population.config)
    start = time.perf_counter()
    steps = 0
    while steps < WARMUP_STEPS or not all_in(len(population.pending), wanted):
        seconds = time.perf_counter() - start
        if steps >= WARMUP_STEPS and seconds > timeout_s:
            inserted = wanted - len(population.pending)
            raise InsertionTimeout(insertion_message(inserted, wanted, steps, seconds, population.config.net))
        population.step()
        steps += 1
    population.timer.reset()
    return dict(population.summary.__dict__)


def counters(population: Population, before: dict[str, int]) -> dict[str, int]:
    s = population.summary
    return {
        "collisions": s.collisions - before["collisions"],
        "off_tracks": s.off_tracks - before["off_tracks"],
        "retries": s.insert_retries - before["insert_retries"],
        "on_road": len(population.sim.vehicle_ids()) if population.sim else 0,
    }


def config_for(
    row: Row, net: Path, fcd: Path, steps: int, seed: int, policy: Path | None = None
) -> PopulateConfig:
    policy, overtakers, keepers = pick_policy(row.agents, policy)
    return PopulateConfig(
        net=net,
        overtakers=overtakers,
        keepers=keepers,
        policy=policy,
        background=row.background,
        duration=(WARMUP_STEPS + steps) * STEP_LENGTH,
        step_length=STEP_LENGTH,
        seed=seed,
        fcd=fcd,
        keep_count=True,
    )


def route_steps(timed_steps: int) -> int:
    """The steps a run's routes are drawn for: its timed steps, at least ROUTE_STEPS (the default
    --steps, so the default rows are as before)."""
    return max(timed_steps, ROUTE_STEPS)


def sumo_alone_config(config: PopulateConfig) -> PopulateConfig:
    return replace(config, overtakers=0, keepers=0, background=config.overtakers + config.keepers
                   + config.background)  # fmt: skip


def peak_rss_mb(status: str) -> float:
    """The peak resident set size (VmHWM) in MB from the text of /proc/<pid>/status; nan if absent."""
    for line in status.splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def own_peak_rss_mb() -> float:
    try:
        return peak_rss_mb(Path("/proc/self/status").read_text())
    except OSError:  # not Linux
        return float("nan")


@dataclass
class Bucket:
    """A child's timed steps under one label (idle or loaded, alone or at once)."""

    steps: int = 0
    seconds: float = 0.0
    phases: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)

    def add(self, seconds: float, phases: dict[str, float], counts: dict[str, int]) -> None:
        self.steps += 1
        self.seconds += seconds
        for name, value in phases.items():
            self.phases[name] = self.phases.get(name, 0.0) + value
        for name, value in counts.items():
            self.counts[name] = self.counts.get(name, 0) + value

    @property
    def ms_per_step(self) -> float:
        return 1000.0 * self.seconds / max(self.steps, 1)


@dataclass
class ChildReport:
    buckets: dict[str, Bucket]
    on_road: int
    peak_rss_mb: float


def _difference(after: dict[str, float], before: dict[str, float]) -> dict[str, float]:
    return {name: value - before.get(name, 0.0) for name, value in after.items()}


def _loss_counts(population: Population) -> dict[str, int]:
    s = population.summary
    return {"collisions": s.collisions, "off_tracks": s.off_tracks, "retries": s.insert_retries}


def _next_label(conn: Connection) -> str | None:
    """The label of the parent's next ("step", label); None on "stop" or if the parent is gone (it
    gave up on another run)."""
    try:
        message = conn.recv()
    except EOFError:
        return None
    return None if message == "stop" else str(message[1])


def _stepper(config: PopulateConfig, fcd: Path | None, conn: Connection, insert_timeout_s: float) -> None:
    """A child process: one run, warmed up, then one timed step per ("step", label) message from
    the parent, each step's time, phases and losses kept under its label; on "stop" it sends back
    a ChildReport."""
    torch.set_num_threads(POLICY_THREADS)  # as `behave populate` does
    population = Population(config)
    population.start(None if fcd is None else partial_path(fcd))
    try:
        try:
            warm_up(population, insert_timeout_s)
        except InsertionTimeout as error:
            conn.send(("error", str(error)))
            return
        conn.send("ready")
        buckets: dict[str, Bucket] = {}
        while (label := _next_label(conn)) is not None:
            phases, losses = dict(population.timer.seconds), _loss_counts(population)
            start = time.perf_counter()
            population.step()
            seconds = time.perf_counter() - start
            bucket = buckets.setdefault(label, Bucket())
            bucket.add(seconds, _difference(population.timer.seconds, phases),
                       {k: v - losses[k] for k, v in _loss_counts(population).items()})  # fmt: skip
            conn.send(None)
        on_road = len(population.sim.vehicle_ids()) if population.sim else 0
        with contextlib.suppress(OSError):  # the parent is gone
            conn.send(ChildReport(buckets, on_road, own_peak_rss_mb()))
    finally:
        population.close()


Schedule = list[tuple[str, int]]
"""(label, steps) blocks, in the order they run."""


def alternating_blocks(steps: int, block: int, labels: Sequence[str], flip: bool = False) -> Schedule:
    """`steps` steps under each label, in blocks of at most `block` that take turns (in reverse
    order when `flip`, so that over rounds no label always goes first)."""
    order = list(reversed(labels)) if flip else list(labels)
    schedule: Schedule = []
    done = 0
    while done < steps:
        n = min(block, steps - done)
        schedule += [(label, n) for label in order]
        done += n
    return schedule


def run_in_lockstep(
    runs: list[tuple[PopulateConfig, Path | None]],
    schedule: Schedule,
    together: Collection[str] = (),
    on_block: Callable[[str], None] | None = None,
    insert_timeout_s: float = INSERT_TIMEOUT_S,
) -> list[ChildReport]:
    """Each run in a process of its own, stepped block by block as `schedule` says: one step of
    each in turn, or, for labels in `together`, one step of all at once (the parent waits for all).

    This machine's speed drifts by tens of percent within minutes, so runs timed one after
    the other measure the drift as much as the code; stepped in turn, every run meets the
    same machine within a fraction of a second (only one steps at a time). A fresh process per
    run also gives each the same start: SUMO's step time depends on what its process ran before.
    `on_block(label)` runs before each block (the CPU burner pauses or resumes there).
    """
    context = multiprocessing.get_context("spawn")
    children: list[tuple[BaseProcess, Connection]] = []
    try:
        for config, fcd in runs:
            ours, theirs = context.Pipe()
            process = context.Process(
                target=_stepper, args=(config, fcd, theirs, insert_timeout_s), daemon=True
            )
            process.start()
            children.append((process, ours))
        for _, conn in children:
            _expect(conn, "ready")
        for label, steps in schedule:
            if on_block is not None:
                on_block(label)
            for _ in range(steps):
                if label in together:
                    for _, conn in children:
                        conn.send(("step", label))
                    for _, conn in children:
                        conn.recv()
                else:
                    for _, conn in children:
                        conn.send(("step", label))
                        conn.recv()
        if on_block is not None:
            on_block("")  # between blocks: nothing beside
        reports = []
        for _, conn in children:
            conn.send("stop")
            reports.append(conn.recv())
        return reports
    except EOFError:
        raise SystemExit("bench_populate: a benchmark run stopped (its error is printed above)") from None
    finally:
        for child, conn in children:
            conn.close()  # a child still waiting for a step (another stopped) ends on EOFError
            child.join(timeout=60)
            if child.is_alive():
                child.kill()


def _expect(conn: Connection, message: str) -> None:
    got = conn.recv()
    if isinstance(got, tuple) and got[:1] == ("error",):
        raise SystemExit(f"bench_populate: {got[1]}")
    if got != message:
        raise RuntimeError(f"benchmark child sent {got!r}, expected {message!r}")


def add_round(
    result: Result, label: str, ours: ChildReport, by_sumo: ChildReport | None, no_fcd: ChildReport | None
) -> None:
    """Add one round's steps under `label` of the populate run and, if any, its SUMO-alone runs."""
    mine = ours.buckets[label]
    result.steps += mine.steps
    result.total_s += mine.seconds
    phase_s = result.phase_s if result.phase_s is not None else {}
    for name, seconds in mine.phases.items():
        phase_s[name] = phase_s.get(name, 0.0) + seconds
    result.phase_s = phase_s
    result.collisions += mine.counts.get("collisions", 0)
    result.off_tracks += mine.counts.get("off_tracks", 0)
    result.retries += mine.counts.get("retries", 0)
    result.on_road = ours.on_road if result.on_road == 0 else min(result.on_road, ours.on_road)
    result.peak_rss_mb = max(result.peak_rss_mb, ours.peak_rss_mb)
    if by_sumo is not None:
        theirs = by_sumo.buckets[label]
        result.alone_s += theirs.phases.get("sumo", 0.0)
        result.alone_steps += theirs.steps
        result.alone_on_road = by_sumo.on_road
        result.alone_peak_rss_mb = max(result.alone_peak_rss_mb, by_sumo.peak_rss_mb)
        result.round_ratios.append(
            ratio(mine.ms_per_step, 1000.0 * theirs.phases.get("sumo", 0.0) / theirs.steps)
        )
    if no_fcd is not None:
        bare = no_fcd.buckets[label]
        result.no_fcd_s += bare.phases.get("sumo", 0.0)
        result.no_fcd_steps += bare.steps


def round_slowdown(report: ChildReport, label: str, reference: str, phase: str | None = None) -> float:
    """One round's ms/step under `label` against under `reference` (of one phase, e.g. "sumo" for
    SUMO alone, whose other phases are no SUMO work)."""
    a, b = report.buckets[label], report.buckets[reference]
    if phase is None:
        return ratio(a.ms_per_step, b.ms_per_step)
    return ratio(a.phases.get(phase, 0.0) / max(a.steps, 1), b.phases.get(phase, 0.0) / max(b.steps, 1))


@dataclass(frozen=True)
class Plan:
    """How the rows run: the fixed settings of one benchmark invocation."""

    net: Path
    tmp: Path
    steps: int
    seed: int
    rounds: int
    policy: Path | None
    block: int = BLOCK_STEPS
    insert_timeout_s: float = INSERT_TIMEOUT_S


def new_result(row: Row, config: PopulateConfig, condition: str = IDLE) -> Result:
    return Result(row, config.policy.name, config.overtakers, config.keepers, condition, phase_s={})


def run_row(
    row: Row, net: Path, tmp: Path, steps: int, seed: int, rounds: int, policy: Path | None,
    burner: CpuBurner | None = None, block: int = BLOCK_STEPS, insert_timeout_s: float = INSERT_TIMEOUT_S,
) -> list[Result]:  # fmt: skip
    """The row's populate, SUMO alone and SUMO alone without FCD in lockstep, `rounds` times; with
    a burner, `steps` idle and `steps` loaded steps per round, in alternating blocks."""
    labels = (IDLE, LOADED) if burner is not None else (IDLE,)
    config = config_for(row, net, tmp / "populate.fcd.xml", route_steps(steps * len(labels)), seed, policy)
    alone = sumo_alone_config(replace(config, fcd=tmp / "alone.fcd.xml"))
    results = {label: new_result(row, config, label) for label in labels}
    for k in range(rounds):
        schedule = alternating_blocks(steps, block, labels, flip=k % 2 == 1) if burner else [(IDLE, steps)]
        runs = [(config, config.fcd), (alone, alone.fcd), (alone, None)]
        ours, by_sumo, no_fcd = run_in_lockstep(
            runs,
            schedule,
            on_block=(lambda label: burner.switch(label == LOADED)) if burner else None,
            insert_timeout_s=insert_timeout_s,
        )
        for label in labels:
            add_round(results[label], label, ours, by_sumo, no_fcd)
        if burner is not None:
            results[LOADED].round_slowdowns.append(round_slowdown(ours, LOADED, IDLE))
            results[LOADED].alone_round_slowdowns.append(round_slowdown(by_sumo, LOADED, IDLE, "sumo"))
    if burner is not None:
        results[LOADED].reference = results[IDLE]
    return list(results.values())


def run_parallel_row(row: Row, plan: Plan, n: int) -> list[Result]:
    """`n` populates (seeds seed .. seed+n-1), `steps` steps each alone (the others waiting) and
    `steps` all at once per round, in alternating blocks; each at once against itself alone."""
    configs = [
        config_for(
            row,
            plan.net,
            plan.tmp / f"parallel_{k}.fcd.xml",
            route_steps(2 * plan.steps),
            plan.seed + k,
            plan.policy,
        )
        for k in range(n)
    ]
    alone = [new_result(row, c, f"#{k + 1} {ALONE}") for k, c in enumerate(configs)]
    at_once = [new_result(row, c, f"#{k + 1}, {n} {AT_ONCE}") for k, c in enumerate(configs)]
    for k in range(plan.rounds):
        schedule = alternating_blocks(plan.steps, plan.block, (ALONE, AT_ONCE), flip=k % 2 == 1)
        reports = run_in_lockstep([(c, c.fcd) for c in configs], schedule, together=(AT_ONCE,),
                                  insert_timeout_s=plan.insert_timeout_s)  # fmt: skip
        for report, solo, together in zip(reports, alone, at_once, strict=True):
            add_round(solo, ALONE, report, None, None)
            add_round(together, AT_ONCE, report, None, None)
            together.round_slowdowns.append(round_slowdown(report, AT_ONCE, ALONE))
    for solo, together in zip(alone, at_once, strict=True):
        together.reference = solo
    return alone + at_once


def profile_row(
    row: Row, net: Path, tmp: Path, steps: int, seed: int, policy: Path | None, top: int = 10
) -> str:
    """cProfile of the timed populate steps (a separate run: profiling slows it down)."""
    fcd = tmp / "fcd.xml"
    profiler = cProfile.Profile()
    run_population(Population(config_for(row, net, fcd, steps, seed, policy)), fcd, steps, profiler)
    out = io.StringIO()
    pstats.Stats(profiler, stream=out).sort_stats("tottime").print_stats(top)
    return out.getvalue()


COLUMNS = (
    "agents",
    "policy",
    "ot/kp",
    "background",
    "on road",
    "steps",
    "ms/step",
    "RTF",
    *PHASES,
    "other",
    "SUMO alone",
    "ratio",
    "FCD",
    "collisions",
    "off-tracks",
    "retries",
)
SLOWDOWN_COLUMNS = ("slow-down", "SUMO alone slow-down")
MEMORY_COLUMNS = ("peak RSS MB", "SUMO alone peak RSS MB")


def columns(condition: bool = False) -> tuple[str, ...]:
    """The main table's columns: the default ones, with "condition" after "agents" when the rows
    are measured under more than one (CPU burner, parallel)."""
    return COLUMNS[:1] + (("condition",) if condition else ()) + COLUMNS[1:]


def extra_columns(condition: bool = False, memory: bool = False) -> tuple[str, ...]:
    """Columns of the options at scale: printed as a table of their own (the main one is wide
    already), appended to the main ones in the CSV."""
    return (SLOWDOWN_COLUMNS if condition else ()) + (MEMORY_COLUMNS if memory else ())


def number(value: float, digits: int = 2) -> str:
    """A figure, or '-' where nothing was measured (nan)."""
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def row_of(r: Result, for_csv: bool = False, condition: bool = False) -> list[str]:
    agents = f"{r.row.agents}" if for_csv else f"{r.row.agents:,}"
    has_alone = r.alone_steps > 0
    return [
        agents,
        *([r.condition] if condition else []),
        r.policy.removesuffix(".pt"),
        f"{r.overtakers}/{r.keepers}",
        str(r.row.background),
        str(r.on_road),
        str(r.steps),
        f"{r.ms_per_step:.2f}",
        f"{r.real_time_factor:.1f}",
        *(f"{r.phase_ms(p):.2f}" for p in (*PHASES, "other")),
        f"{r.alone_ms:.2f}" if has_alone else "-",
        f"{r.ratio:.2f}" if has_alone else "-",
        f"{r.fcd_ms:.2f}" if r.no_fcd_steps > 0 else "-",
        str(r.collisions),
        str(r.off_tracks),
        str(r.retries),
    ]


def extra_cells(r: Result, condition: bool = False, memory: bool = False) -> list[str]:
    cells = [number(r.slowdown), number(r.alone_slowdown)] if condition else []
    if memory:
        cells += [number(r.peak_rss_mb, 0), number(r.alone_peak_rss_mb, 0) if r.alone_steps > 0 else "-"]
    return cells


def csv_rows(results: list[Result], condition: bool = False, memory: bool = False) -> Iterator[list[str]]:
    for r in results:
        yield row_of(r, True, condition) + extra_cells(r, condition, memory)


def title_of(args: argparse.Namespace) -> str:
    runs = f"{args.rounds} x {args.steps} timed steps of {STEP_LENGTH} s"
    blocks = f"alternating in blocks of {args.block}"
    if args.beside_cpu_burner:
        runs = f"{args.rounds} x ({args.steps} idle + {args.steps} loaded steps, {blocks})"
    elif args.parallel:
        each = f"{args.steps} steps alone + {args.steps} at once"
        runs = f"{args.parallel} populates, {args.rounds} x ({each}, {blocks})"
    return (
        f"behave populate step cost, ms/step, FCD on: {runs} (after at least {WARMUP_STEPS} warm-up), "
        f"{args.length / 1000:.0f} km {args.lanes}-lane highway, seed {args.seed}"
    )


def scale_row(r: Result, condition: bool, memory: bool) -> list[str]:
    """A row of the table of the options at scale: what it is, its ms/step, the new figures."""
    label = [f"{r.row.agents:,}", *([r.condition] if condition else [])]
    alone = [number(r.alone_ms), number(r.ratio)] if r.alone_steps else ["-", "-"]
    return [*label, f"{r.ms_per_step:.2f}", *alone, *extra_cells(r, condition, memory)]


def has_conditions(args: argparse.Namespace) -> bool:
    return bool(args.beside_cpu_burner or args.parallel)


def print_results(results: list[Result], args: argparse.Namespace, console: Console) -> None:
    condition = has_conditions(args)
    print_table(
        console, title_of(args), columns(condition), (row_of(r, condition=condition) for r in results)
    )
    console.print(
        "RTF = real-time factor; ot/kp = overtakers/keepers; SUMO alone = ms/step of the SUMO step with "
        "the same vehicle count, all behave_background, FCD on; ratio = ms/step / SUMO alone;\n"
        "FCD = SUMO alone with FCD minus without (ms/step); collisions, off-tracks and insert retries of "
        "the agents during the timed steps"
    )
    extra = extra_columns(condition, args.memory)
    if not extra:
        return
    header = ("agents", *(("condition",) if condition else ()), "ms/step", "SUMO alone", "ratio", *extra)
    rows = (scale_row(r, condition, args.memory) for r in results)
    print_table(console, "at scale: slow-down under load and peak memory", header, rows)
    if condition:
        console.print(
            "slow-down = ms/step / the same run's idle steps (CPU burner) or the same populate's steps "
            "alone (parallel); SUMO alone slow-down likewise for SUMO alone's step"
        )
    if args.memory:
        console.print("peak RSS = the process's VmHWM (each run is a process of its own; both hold Python, "
                      "torch and the net)")  # fmt: skip


def rounds_text(values: list[float]) -> str:
    return ", ".join(number(x) for x in values)


def target_lines(results: list[Result]) -> Iterator[str]:
    for r in results:
        if r.condition == IDLE and r.row.agents == 1000:
            ok = verdict(r.ratio, TARGET_RATIO_1000)
            yield (
                f"target: 1,000 agents <= {TARGET_RATIO_1000}x SUMO alone -> {r.ratio:.2f}x ({ok}; "
                f"each round: {rounds_text(r.round_ratios)})"
            )
        if r.condition == IDLE and r.row.agents >= SCALE_AGENTS:
            yield (
                f"scale: {r.row.agents:,} agents + {r.row.background:,} background completed "
                f"{r.steps} timed steps ({r.on_road:,} vehicles on the road at the end); "
                f"{number(r.ratio)}x SUMO alone (aim <= {TARGET_RATIO_SCALE}x: "
                f"{verdict(r.ratio, TARGET_RATIO_SCALE)}; each round: {rounds_text(r.round_ratios)}); "
                f"peak RSS populate {number(r.peak_rss_mb, 0)} MB, "
                f"SUMO alone {number(r.alone_peak_rss_mb, 0)} MB"
            )
        if r.condition == LOADED:
            yield (
                f"target: {r.row.agents:,} agents with a CPU-bound process beside <= {TARGET_BURNER}x "
                f"idle -> "
                f"{number(r.slowdown)}x ({verdict(r.slowdown, TARGET_BURNER)}; each round: "
                f"{rounds_text(r.round_slowdowns)}); SUMO alone {number(r.alone_slowdown)}x its idle "
                f"(each round: {rounds_text(r.alone_round_slowdowns)})"
            )
    at_once = [r for r in results if AT_ONCE in r.condition]
    if at_once:
        worst = max(r.slowdown for r in at_once)
        each = "; ".join(f"{r.condition}: {number(r.slowdown)}x (rounds {rounds_text(r.round_slowdowns)})"
                         for r in at_once)  # fmt: skip
        yield (
            f"target: each of {len(at_once)} populates at once <= {TARGET_PARALLEL}x itself alone -> worst "
            f"{number(worst)}x ({verdict(worst, TARGET_PARALLEL)}); {each}"
        )


def parse_rows(text: str) -> list[Row]:
    rows = []
    for item in text.split(","):
        agents, _, background = item.strip().partition(":")
        rows.append(Row(int(agents), int(background or 0)))
    return rows


def core_count() -> int:
    """Cores this process may run on (the affinity mask, where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", default="100:100,1000:200", help="comma-separated AGENTS:BACKGROUND")
    parser.add_argument("--steps", type=int, default=200, help="timed steps per run (and per condition)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rounds", type=int, default=3, help="populate / SUMO-alone alternations")
    parser.add_argument("--length", type=float, default=30_000.0, help="highway length, metres")
    parser.add_argument("--lanes", type=int, default=3, help="highway lanes")
    parser.add_argument("--policy", type=Path, default=None, help="default: the bundled traffic.pt")
    parser.add_argument("--csv", type=Path, default=None, help="also write the table here")
    parser.add_argument("--profile", action="store_true", help="cProfile top-10 (tottime) of the largest row")
    parser.add_argument("--memory", action="store_true", help="peak RSS of the populate and SUMO-alone runs")
    load = parser.add_mutually_exclusive_group()
    load.add_argument(
        "--beside-cpu-burner",
        action="store_true",
        help=f"also time each row with a CPU-bound process beside it (bar {TARGET_BURNER}x idle)",
    )
    load.add_argument(
        "--parallel",
        type=int,
        nargs="?",
        const=core_count(),
        default=None,
        metavar="N",
        help=f"N populates at once against each alone (bar {TARGET_PARALLEL}x); N: the core count",
    )
    parser.add_argument(
        "--block",
        type=int,
        default=BLOCK_STEPS,
        help="steps per block when idle/loaded or alone/at once take turns",
    )
    parser.add_argument("--insert-timeout", type=float, default=INSERT_TIMEOUT_S,
                        help="seconds the warm-up may wait for SUMO to insert every vehicle")  # fmt: skip
    args = parser.parse_args(argv)
    try:
        args.row_list = parse_rows(args.rows)
    except ValueError:
        parser.error(f"--rows must look like 100:100,1000:200, got {args.rows!r}")
    if min(r.agents for r in args.row_list) < 1 or min(r.background for r in args.row_list) < 0:
        parser.error("--rows needs at least one agent per row and no negative background")
    if min(args.steps, args.rounds) < 1 or args.length < 1000:
        parser.error("--steps and --rounds must be positive, --length at least 1000 m")
    if args.lanes < 1 or args.block < 1 or args.insert_timeout <= 0:
        parser.error("--lanes, --block and --insert-timeout must be positive")
    if args.parallel is not None and args.parallel < 1:
        parser.error("--parallel needs at least 1 populate")
    return args


def run_rows(args: argparse.Namespace, net: Path, tmp: Path, console: Console) -> list[Result]:
    """Every row as the options say: plain, beside a CPU burner, or N at once."""
    plan = Plan(net, tmp, args.steps, args.seed, args.rounds, args.policy, args.block, args.insert_timeout)
    results: list[Result] = []
    for row in args.row_list:
        label = f"{row.agents:,} agents + {row.background} background"
        if args.parallel:
            with progress(console, f"{label}, {args.parallel} populates at once and alone"):
                results += run_parallel_row(row, plan, args.parallel)
        elif args.beside_cpu_burner:
            with progress(console, f"{label}, idle and beside a CPU burner"), CpuBurner() as burner:
                results += run_row(row, net, tmp, args.steps, args.seed, args.rounds, args.policy, burner,
                                   args.block, args.insert_timeout)  # fmt: skip
        else:
            with progress(console, label):
                results += run_row(row, net, tmp, args.steps, args.seed, args.rounds, args.policy,
                                   insert_timeout_s=args.insert_timeout)  # fmt: skip
    return results


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    torch.set_num_threads(POLICY_THREADS)  # as `behave populate` does
    console = Console(width=max(Console().width, 200))
    with tempfile.TemporaryDirectory(prefix="behave_bench_populate_") as tmp_name:
        tmp = Path(tmp_name)
        with progress(console, f"building a {args.length / 1000:.0f} km {args.lanes}-lane highway"):
            net = build_highway(tmp, args.length, args.lanes)
        results = run_rows(args, net, tmp, console)
        print_results(results, args, console)
        for line in target_lines(results):
            console.print(line)
        if args.csv is not None:
            condition = has_conditions(args)
            header = columns(condition) + extra_columns(condition, args.memory)
            write_csv(args.csv, header, csv_rows(results, condition, args.memory))
            console.print(f"wrote {args.csv}")
        if args.profile:
            largest = max(args.row_list, key=lambda r: r.agents)
            with progress(console, f"profiling {largest.agents:,} agents"):
                report = profile_row(largest, net, tmp, args.steps, args.seed, args.policy)
            console.print(f"cProfile, {largest.agents:,} agents, {args.steps} steps, top 10 by tottime:")
            console.print(report, markup=False, highlight=False)


if __name__ == "__main__":
    main()
