"""The batched actor call of `behave populate` with 1 and 2 torch threads, with and without a
CPU-bound process beside it: does populate degrade gracefully under load?

One run measures every setting in turn, round after round (the machine's speed drifts within
minutes, so ratios are taken within a round): for each round, without and then with a busy
process (a pure-Python loop in a child process), `--calls` actor calls with 1 thread, then with 2.
Between two calls the main thread does `--work-ms` of its own CPU work, as populate does SUMO's
step between two actor calls. The policy is populate's (`PopulateConfig`'s default, loaded as
populate loads it, so `auto` precision applies), the observations random, `--agents` rows.

Usage: python benchmarks/bench_policy_threads.py [--agents 1000] [--calls 200] [--rounds 3]
                                                 [--work-ms 20] [--precision auto] [--note TEXT]
"""

from __future__ import annotations

import argparse
import multiprocessing
import time

import numpy as np
import torch
from common import print_table
from rich.console import Console

from behaviors.run.populate_config import PopulateConfig, populate_policy
from behaviors.run.precision import POLICY_THREADS


def spin(seconds: float) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def hog() -> None:
    """A CPU-bound process: what another populate, a training or a build does to this one."""
    while True:
        pass


def time_calls(act, obs: np.ndarray, calls: int, work_s: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    out = np.empty(calls)
    for k in range(calls):
        spin(work_s)
        start = time.perf_counter()
        act(obs, None)
        out[k] = time.perf_counter() - start
    return out * 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", type=int, default=1000)
    parser.add_argument("--calls", type=int, default=200, help="timed calls per setting and round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--work-ms", type=float, default=20.0, help="own CPU work between two calls")
    parser.add_argument("--note", default="", help="what else ran on the machine (printed with the table)")
    parser.add_argument("--precision", default="auto", choices=("auto", "float32", "bfloat16"))
    args = parser.parse_args()
    policy = populate_policy(PopulateConfig(precision=args.precision))
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1.0, 1.0, (args.agents, policy.obs_dim)).astype(np.float32)
    context = multiprocessing.get_context("spawn")
    times: dict[tuple[str, int], list[np.ndarray]] = {}
    ratios: dict[str, list[float]] = {"no": [], "yes": []}
    for _ in range(args.rounds):
        for beside in ("no", "yes"):
            busy = context.Process(target=hog, daemon=True) if beside == "yes" else None
            if busy is not None:
                busy.start()
                time.sleep(0.5)
            try:
                medians = {}
                for threads in (1, 2):
                    torch.set_num_threads(threads)
                    time_calls(policy.act, obs, 10, args.work_ms / 1000)  # warm up
                    t = time_calls(policy.act, obs, args.calls, args.work_ms / 1000)
                    times.setdefault((beside, threads), []).append(t)
                    medians[threads] = float(np.median(t))
                ratios[beside].append(medians[2] / medians[1])
            finally:
                if busy is not None:
                    busy.kill()
                    busy.join()
    rows = []
    for (beside, threads), runs in times.items():
        t = np.concatenate(runs)
        rows.append([beside, str(threads), f"{np.median(t):.2f}", f"{np.percentile(t, 90):.2f}",
                     f"{np.percentile(t, 99):.2f}", f"{t.mean():.2f}"])  # fmt: skip
    console = Console()
    title = (
        f"batched actor call, {args.agents:,} agents, {args.work_ms:g} ms own work between calls, "
        f"{args.rounds} x {args.calls} calls, precision {args.precision} "
        f"(precision.POLICY_THREADS = {POLICY_THREADS})"
    )
    header = ["busy process beside", "threads", "median ms", "p90 ms", "p99 ms", "mean ms"]
    print_table(console, title, header, rows)
    for beside, r in ratios.items():
        console.print(f"busy process beside: {beside}; median 2 threads / 1 thread per round: "
                      + ", ".join(f"{x:.2f}" for x in r))  # fmt: skip
    if args.note:
        console.print(f"machine: {args.note}")


if __name__ == "__main__":
    main()
