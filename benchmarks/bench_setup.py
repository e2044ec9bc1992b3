"""Set-up time of `behave populate` against net size: geometry read cold and from its cache, SUMO's
own start, and the whole CLI run of 1 simulated second (cold cache), per net given.

    python benchmarks/bench_setup.py --policy P.pt NET.net.xml ...

Prints a Markdown table (docs/benchmarks.md has the measured one).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from behaviors.road.geometry_build import cache_path, load_geometry
from behaviors.sumo.sim import SimOptions, SumoSim


def seconds(run) -> float:
    start = time.perf_counter()
    run()
    return time.perf_counter() - start


def cli_run(net: Path, policy: Path) -> float:
    """Wall seconds of a whole `behave populate` of 1 simulated second (torch import included)."""
    with tempfile.TemporaryDirectory() as tmp:
        command = [sys.executable, "-m", "behaviors.cli", "populate", "--net", str(net),
                   "--policy", str(policy), "--keepers", "10", "--overtakers", "10", "--background", "40",
                   "--duration", "1", "--fcd", f"{tmp}/fcd.xml"]  # fmt: skip
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True)
        return time.perf_counter() - start


def row(net: Path, policy: Path) -> str:
    cache_path(net).unlink(missing_ok=True)
    geometry = load_geometry(net)
    lanes, segments = len(geometry.lane_edge), len(geometry.seg_a)
    cold = seconds(lambda: load_geometry(net, cache=True))
    warm = seconds(lambda: load_geometry(net, cache=True))
    sumo = seconds(lambda: SumoSim(SimOptions(net=net)).close())
    cache_path(net).unlink(missing_ok=True)
    whole = cli_run(net, policy)
    cached = cli_run(net, policy)
    size = net.stat().st_size / 1e6
    return (
        f"| {net.name} | {size:.1f} | {lanes:,} | {segments:,} | {cold:.1f} | {warm:.2f} | {sumo:.1f} "
        f"| {whole:.1f} | {cached:.1f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--policy", type=Path, required=True)
    parser.add_argument("nets", type=Path, nargs="+")
    args = parser.parse_args()
    print("| net | MB | car lanes | border segments | geometry cold s | from cache s | SUMO start s "
          "| populate (cold) s | populate (cached) s |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for net in args.nets:
        print(row(net, args.policy), flush=True)


if __name__ == "__main__":
    main()
