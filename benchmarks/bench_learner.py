"""Learner throughput on 1 torch thread: per-agent updates (the paper's n updates per step)
versus one batched update on n * batch samples, and the cost of one batched actor forward.

Run: .venv/bin/python benchmarks/bench_learner.py [--agents 6] [--seconds 1.5]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import torch

from behaviors.learn.ddpg import DDPGConfig, DDPGLearner

OBS_DIM = 65


def timed(fn: Callable[[], object], seconds: float) -> tuple[int, float]:
    """Repeat fn for about `seconds` after one warm-up call; (calls, elapsed)."""
    fn()
    calls, start = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        fn()
        calls += 1
    return calls, elapsed


def ready_learner(config: DDPGConfig) -> DDPGLearner:
    learner = DDPGLearner(OBS_DIM, config, seed=0)
    rng = np.random.default_rng(0)
    n = config.warmup
    obs = rng.uniform(-1, 1, (n, OBS_DIM)).astype(np.float32)
    act = rng.uniform((-1, 0, 0), (1, 1, 1), (n, 3)).astype(np.float32)
    learner.observe(obs, act, rng.normal(size=n).astype(np.float32), obs, np.zeros(n, np.float32))
    return learner


def update_row(hidden: tuple[int, ...], batch: int, batched: bool, agents: int, secs: float) -> str:
    cfg = DDPGConfig(hidden=hidden, batch_size=batch, batched=batched, warmup=5000)
    learner = ready_learner(cfg)
    calls, elapsed = timed(lambda: learner.update(agents), secs)
    steps = calls * (1 if batched else agents)  # optimiser steps taken
    samples = calls * agents * batch
    mode = f"batched 1x{agents * batch}" if batched else f"per-agent {agents}x{batch}"
    return (
        f"| {hidden!s:10} | {batch:5} | {mode:18} | {steps / elapsed:9.0f} | "
        f"{samples / elapsed:10.0f} | {1e3 * elapsed / calls:8.2f} |"
    )


def forward_ms(hidden: tuple[int, ...], n_obs: int, secs: float) -> float:
    learner = DDPGLearner(OBS_DIM, DDPGConfig(hidden=hidden), seed=0)
    obs = np.random.default_rng(0).uniform(-1, 1, (n_obs, OBS_DIM)).astype(np.float32)
    calls, elapsed = timed(lambda: learner.act(obs, explore=True), secs)
    return 1e3 * elapsed / calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--agents", type=int, default=6, help="agents per env step (n)")
    parser.add_argument("--seconds", type=float, default=1.5, help="time per measurement")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, n = {args.agents}")
    print("| hidden     | batch | mode               | updates/s | samples/s  | ms/step  |")
    print("|------------|-------|--------------------|-----------|------------|----------|")
    for hidden in ((256, 256), (300, 600)):
        for batch in (32, 64):
            for batched in (False, True):
                print(update_row(hidden, batch, batched, args.agents, args.seconds))
    print("\nact(): one batched actor forward + OU noise + clip, ms")
    print("| hidden     |      6 obs |    100 obs |   1000 obs |")
    print("|------------|------------|------------|------------|")
    for hidden in ((256, 256), (300, 600)):
        cells = " | ".join(f"{forward_ms(hidden, n, args.seconds / 3):10.3f}" for n in (6, 100, 1000))
        print(f"| {hidden!s:10} | {cells} |")


if __name__ == "__main__":
    main()
