"""Memory of a long `behave populate` run: does the process grow with simulated time?

SUMO keeps every route it is given until the run ends; when each insertion (and each retry
of a failed one) brought its own route, populate grew by ~0.24 MB per simulated second with
200 agents. This runs a `Population` (FCD on, `--keep-count`, so agents that leave come back
as new insertions) and reads the process's resident memory (VmRSS in /proc/self/status) as
it goes: after a warm-up that fills the road, every `--every` simulated seconds, and at the end.

Usage: python benchmarks/bench_populate_memory.py [--agents 200] [--background 0]
           [--duration 1800] [--warmup 60] [--every 300] [--seed 0] [--net NET] [--label NAME]

To measure another checkout of behave (e.g. the commit before a change), put it first on the
path: `git worktree add /tmp/old <commit>` then
`PYTHONPATH=/tmp/old python benchmarks/bench_populate_memory.py --label old`.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch
from common import print_table
from rich.console import Console

from behaviors.run.fcd_sealing import partial_path
from behaviors.run.populate_config import PopulateConfig
from behaviors.run.population import Population
from behaviors.run.precision import POLICY_THREADS
from sumo_scenarios import get_scenario


def rss_mb() -> float:
    """This process's resident set size in MB, as the kernel reports it."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS in /proc/self/status (Linux only)")


def sumo_route_count() -> int:
    import libsumo

    return len(libsumo.route.getIDList())


def run(config: PopulateConfig, warmup: float, every: float) -> list[tuple[float, float, int]]:
    """(simulated s, RSS MB, routes SUMO holds) after the warm-up, every `every` s, and at the end."""
    population = Population(config)
    population.start(partial_path(config.fcd))
    samples = []
    try:
        steps = round(config.duration / config.step_length)
        marks = {round(warmup / config.step_length)} | set(
            range(round((warmup + every) / config.step_length), steps, round(every / config.step_length))
        )
        for step in range(1, steps + 1):
            population.step()
            if step in marks or step == steps:
                samples.append((step * config.step_length, rss_mb(), sumo_route_count()))
    finally:
        population.close()
    return samples


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--agents", type=int, default=200, help="learned agents, half overtakers")
    parser.add_argument("--background", type=int, default=0)
    parser.add_argument("--duration", type=float, default=1800.0, help="simulated seconds")
    parser.add_argument("--warmup", type=float, default=60.0, help="simulated s before the first reading")
    parser.add_argument("--every", type=float, default=300.0, help="simulated s between readings")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--net", type=Path, default=get_scenario("highway").net)
    parser.add_argument("--label", default="this checkout")
    args = parser.parse_args()
    if not 0 < args.warmup < args.duration:
        parser.error("--warmup must be positive and shorter than --duration")
    torch.set_num_threads(POLICY_THREADS)
    with tempfile.TemporaryDirectory() as tmp:
        config = PopulateConfig(
            net=args.net, overtakers=args.agents // 2, keepers=args.agents - args.agents // 2,
            background=args.background, duration=args.duration, seed=args.seed, fcd=Path(tmp) / "fcd.xml",
            keep_count=True,
        )  # fmt: skip
        start = time.perf_counter()
        samples = run(config, args.warmup, args.every)
        wall = time.perf_counter() - start
    console = Console()
    rows = [(f"{t:.0f}", f"{rss:.1f}", f"{routes:,}") for t, rss, routes in samples]
    print_table(console, f"{args.label}: RSS over the run", ["simulated s", "RSS MB", "SUMO routes"], rows)
    (t0, rss0, _), (t1, rss1, _) = samples[0], samples[-1]
    growth = (rss1 - rss0) / (t1 - t0)
    summary = [(args.label, f"{args.agents}", f"{t1 - t0:.0f}", f"{rss0:.1f}", f"{rss1:.1f}", f"{growth:.4f}",
                f"{wall:.0f}")]  # fmt: skip
    header = ["code", "agents", "measured s", "RSS start MB", "RSS end MB", "MB per simulated s", "wall s"]
    print_table(console, "populate memory", header, summary)


if __name__ == "__main__":
    main()
