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
Each run warms up (all vehicles inserted) before timing. The network is a long straight 3-lane
highway built into a temp dir with the project's own builder (the bundled one holds ~600 cars).

Usage: python benchmarks/bench_populate.py [--rows 100:100,1000:200] [--steps 200] [--seed 0]
                                           [--rounds 3] [--length 30000] [--policy CKPT] [--csv PATH]
                                           [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import multiprocessing
import pstats
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from multiprocessing.connection import Connection
from pathlib import Path

import torch
from common import print_table, progress, write_csv
from rich.console import Console

from behaviors.ddpg.checkpoint import load_checkpoint
from behaviors.lanes import TRAFFIC_OBS_SIZE
from behaviors.populate import DEFAULT_POLICY, POLICY_THREADS, PopulateConfig, Population, partial_path
from behaviors.sensors import OBS_SIZE_WITH_ID
from sumo_scenarios.build import build_straight

WARMUP_STEPS = 20
STEP_LENGTH = 0.2
PHASES = ("read", "sensors", "shield", "policy", "actuation", "sumo")
TARGET_RATIO_1000 = 1.3


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
        return self.ms_per_step / self.alone_ms if self.alone_ms > 0 else float("nan")


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


def build_highway(out_dir: Path, length: float) -> Path:
    scenario = build_straight(
        out_dir / "long_highway",
        name="long_highway",
        length=length,
        edge_length=300.0,
        lanes=3,
        lane_width=3.5,
        kilometrage=True,
        description=f"straight 3-lane motorway, {length / 1000:.0f} km (benchmark)",
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


def warm_up(population: Population) -> dict[str, int]:
    """Steps until every vehicle is in, then a clean timer; the summary's counts at that point."""
    for _ in range(WARMUP_STEPS):
        population.step()
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


def sumo_alone_config(config: PopulateConfig) -> PopulateConfig:
    return replace(config, overtakers=0, keepers=0, background=config.overtakers + config.keepers
                   + config.background)  # fmt: skip


def _stepper(config: PopulateConfig, fcd: Path | None, conn: Connection) -> None:
    """A child process: one run, warmed up, then one timed step per "step" message from the
    parent; on "stop" it sends back the run's phases and counters."""
    torch.set_num_threads(POLICY_THREADS)  # as `behave populate` does
    population = Population(config)
    population.start(None if fcd is None else partial_path(fcd))
    try:
        before = warm_up(population)
        conn.send("ready")
        total = 0.0
        while conn.recv() == "step":
            start = time.perf_counter()
            population.step()
            total += time.perf_counter() - start
            conn.send(None)
        conn.send((total, dict(population.timer.seconds), counters(population, before)))
    finally:
        population.close()


def run_in_lockstep(runs: list[tuple[PopulateConfig, Path | None]], steps: int) -> list[RunOutput]:
    """Each run in a process of its own, all stepped in turn, one step each.

    This machine's speed drifts by tens of percent within minutes, so runs timed one after
    the other measure the drift as much as the code; stepped in turn, every run meets the
    same machine within a fraction of a second (only one steps at a time). A fresh process per
    run also gives each the same start: SUMO's step time depends on what its process ran before.
    """
    context = multiprocessing.get_context("spawn")
    children = []
    try:
        for config, fcd in runs:
            ours, theirs = context.Pipe()
            process = context.Process(target=_stepper, args=(config, fcd, theirs), daemon=True)
            process.start()
            children.append((process, ours))
        for _, conn in children:
            _expect(conn, "ready")
        for _ in range(steps):
            for _, conn in children:
                conn.send("step")
                conn.recv()
        outputs = []
        for _, conn in children:
            conn.send("stop")
            total, phases, counts = conn.recv()
            outputs.append((steps, total, phases, counts))
        return outputs
    except EOFError:
        raise SystemExit("bench_populate: a benchmark run stopped (its error is printed above)") from None
    finally:
        for process, _ in children:
            process.join(timeout=60)
            if process.is_alive():
                process.kill()


def _expect(conn: Connection, message: str) -> None:
    got = conn.recv()
    if got != message:
        raise RuntimeError(f"benchmark child sent {got!r}, expected {message!r}")


def run_row(
    row: Row, net: Path, tmp: Path, steps: int, seed: int, rounds: int, policy: Path | None
) -> Result:
    config = config_for(row, net, tmp / "populate.fcd.xml", steps, seed, policy)
    alone = sumo_alone_config(replace(config, fcd=tmp / "alone.fcd.xml"))
    result = Result(row, config.policy.name, config.overtakers, config.keepers, phase_s={})
    for _ in range(rounds):
        ours, by_sumo, no_fcd = run_in_lockstep(
            [(config, config.fcd), (alone, alone.fcd), (alone, None)], steps
        )
        done, total, phases, counts = ours
        result.steps += done
        result.total_s += total
        for name, seconds in phases.items():
            result.phase_s[name] = result.phase_s.get(name, 0.0) + seconds  # type: ignore[index]
        result.collisions += counts["collisions"]
        result.off_tracks += counts["off_tracks"]
        result.retries += counts["retries"]
        result.on_road = counts["on_road"] if result.on_road == 0 else min(result.on_road, counts["on_road"])
        done, _, phases, counts = by_sumo
        result.alone_s += phases.get("sumo", 0.0)
        result.alone_steps += done
        result.alone_on_road = counts["on_road"]
        result.round_ratios.append((total / ours[0]) / (phases.get("sumo", 0.0) / done))
        done, _, phases, _ = no_fcd
        result.no_fcd_s += phases.get("sumo", 0.0)
        result.no_fcd_steps += done
    return result


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


def row_of(r: Result, for_csv: bool = False) -> list[str]:
    agents = f"{r.row.agents}" if for_csv else f"{r.row.agents:,}"
    return [
        agents,
        r.policy.removesuffix(".pt"),
        f"{r.overtakers}/{r.keepers}",
        str(r.row.background),
        str(r.on_road),
        str(r.steps),
        f"{r.ms_per_step:.2f}",
        f"{r.real_time_factor:.1f}",
        *(f"{r.phase_ms(p):.2f}" for p in (*PHASES, "other")),
        f"{r.alone_ms:.2f}",
        f"{r.ratio:.2f}",
        f"{r.fcd_ms:.2f}",
        str(r.collisions),
        str(r.off_tracks),
        str(r.retries),
    ]


def print_results(results: list[Result], args: argparse.Namespace, console: Console) -> None:
    title = (
        f"behave populate step cost, ms/step, FCD on: {args.rounds} x {args.steps} timed steps of "
        f"{STEP_LENGTH} s (each after {WARMUP_STEPS} warm-up), {args.length / 1000:.0f} km 3-lane highway, "
        f"seed {args.seed}"
    )
    print_table(console, title, COLUMNS, (row_of(r) for r in results))
    console.print(
        "RTF = real-time factor; ot/kp = overtakers/keepers; SUMO alone = ms/step of the SUMO step with "
        "the same vehicle count, all behave_background, FCD on; ratio = ms/step / SUMO alone;\n"
        "FCD = SUMO alone with FCD minus without (ms/step); collisions, off-tracks and insert retries of "
        "the agents during the timed steps"
    )


def target_lines(results: list[Result]) -> Iterator[str]:
    for r in results:
        if r.row.agents == 1000:
            ok = "met" if r.ratio <= TARGET_RATIO_1000 else "MISSED"
            rounds = ", ".join(f"{x:.2f}" for x in r.round_ratios)
            yield (
                f"target: 1,000 agents <= {TARGET_RATIO_1000}x SUMO alone -> {r.ratio:.2f}x ({ok}; "
                f"each round: {rounds})"
            )


def parse_rows(text: str) -> list[Row]:
    rows = []
    for item in text.split(","):
        agents, _, background = item.strip().partition(":")
        rows.append(Row(int(agents), int(background or 0)))
    return rows


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", default="100:100,1000:200", help="comma-separated AGENTS:BACKGROUND")
    parser.add_argument("--steps", type=int, default=200, help="timed steps per run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rounds", type=int, default=3, help="populate / SUMO-alone alternations")
    parser.add_argument("--length", type=float, default=30_000.0, help="highway length, metres")
    parser.add_argument("--policy", type=Path, default=None, help="default: the bundled traffic.pt")
    parser.add_argument("--csv", type=Path, default=None, help="also write the table here")
    parser.add_argument("--profile", action="store_true", help="cProfile top-10 (tottime) of the largest row")
    args = parser.parse_args(argv)
    try:
        args.row_list = parse_rows(args.rows)
    except ValueError:
        parser.error(f"--rows must look like 100:100,1000:200, got {args.rows!r}")
    if min(r.agents for r in args.row_list) < 1 or min(r.background for r in args.row_list) < 0:
        parser.error("--rows needs at least one agent per row and no negative background")
    if min(args.steps, args.rounds) < 1 or args.length < 1000:
        parser.error("--steps and --rounds must be positive, --length at least 1000 m")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    torch.set_num_threads(POLICY_THREADS)  # as `behave populate` does
    console = Console(width=max(Console().width, 200))
    results = []
    with tempfile.TemporaryDirectory(prefix="behave_bench_populate_") as tmp_name:
        tmp = Path(tmp_name)
        with progress(console, f"building a {args.length / 1000:.0f} km highway"):
            net = build_highway(tmp, args.length)
        for row in args.row_list:
            with progress(console, f"{row.agents:,} agents + {row.background} background"):
                results.append(run_row(row, net, tmp, args.steps, args.seed, args.rounds, args.policy))
        print_results(results, args, console)
        for line in target_lines(results):
            console.print(line)
        if args.csv is not None:
            write_csv(args.csv, COLUMNS, (row_of(r, for_csv=True) for r in results))
            console.print(f"wrote {args.csv}")
        if args.profile:
            largest = max(args.row_list, key=lambda r: r.agents)
            with progress(console, f"profiling {largest.agents:,} agents"):
                report = profile_row(largest, net, tmp, args.steps, args.seed, args.policy)
            console.print(f"cProfile, {largest.agents:,} agents, {args.steps} steps, top 10 by tottime:")
            console.print(report, markup=False, highlight=False)


if __name__ == "__main__":
    main()
