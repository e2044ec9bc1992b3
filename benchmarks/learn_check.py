"""Does PS-DDPG learn lane keeping on the ring within a wall-clock budget? (`make learn-check`)

Trains with the library defaults (6 agents on the ring unless told otherwise),
in-process or with `--workers N` Ray rollout workers, then evaluates without
exploration against the bar the project aims for: <= 1% colliding steps, no
off-track, mean speed >= 80% of the limit. Two answers: how soon a checkpoint
first meets the bar (episodes, env steps and wall time since the run began;
every `--checkpoint-every` episodes, `--scan-episodes` each), and whether the
final policy does. Numbers are reported, never asserted.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from common import meets_lanekeeping_bar, numbered_checkpoints

from behaviors.learn.metrics import mean_rows
from behaviors.learn.policy import load_policy
from behaviors.learn.train import prepare_run
from behaviors.learn.train_config import TrainConfig
from behaviors.run.evaluate import evaluate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--behaviour", default="lanekeeping")
    parser.add_argument("--algo", default="ps-ddpg")
    parser.add_argument("--agents", type=int, default=6)
    parser.add_argument("--overtakers", type=int, default=0)
    parser.add_argument("--keepers", type=int, default=0)
    parser.add_argument("--init", default=None, help="start from this checkpoint (curriculum)")
    parser.add_argument("--episodes", type=int, default=1000, help="upper bound on training episodes")
    parser.add_argument("--minutes", type=float, default=10.0, help="wall-clock training budget")
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--eval-agents", type=int, default=None, help="default: as trained")
    parser.add_argument("--workers", type=int, default=1, help="Ray rollout workers (1 = in-process)")
    parser.add_argument("--checkpoint-every", type=int, default=10)
    parser.add_argument("--scan-episodes", type=int, default=3, help="evaluation episodes per checkpoint")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    config = TrainConfig.from_options(
        behaviour=args.behaviour, algo=args.algo, agents=args.agents, overtakers=args.overtakers,
        keepers=args.keepers, init=args.init, episodes=args.episodes, max_minutes=args.minutes,
        seed=args.seed, checkpoint_every=args.checkpoint_every, workers=args.workers,
    )  # fmt: skip
    out = (
        args.out or Path("runs") / f"learn-check-{args.behaviour}-{args.algo}-s{args.seed}-{int(time.time())}"
    )
    start = time.perf_counter()
    trainer = prepare_run(config, out, resume=False)
    since_start: list[float] = []  # wall seconds from the start to the end of each episode

    def on_episode(row: dict) -> None:
        since_start.append(time.perf_counter() - start)
        print(
            f"episode {row['episode']:4d}  reward {row['reward_sum']:10.0f}  steps {row['steps']:5d}  "
            f"colliding {row['colliding_steps_pct']:5.2f}%  off-track {row['off_tracks']}  "
            f"speed {100 * row['mean_speed_frac']:5.1f}%  since start {since_start[-1]:6.1f}s", flush=True,
        )  # fmt: skip

    rows = trainer.run(on_episode)
    wall = time.perf_counter() - start

    env_config = trainer.env.config
    if args.eval_agents:
        env_config = dataclasses.replace(env_config, agents=args.eval_agents)
    env_steps = np.cumsum([row["steps"] for row in rows])
    reached = None
    for episodes, path in numbered_checkpoints(out):
        if episodes == 0:
            continue
        scan_rows = evaluate(env_config, load_policy(path).act, args.scan_episodes, seed=args.seed)
        scan, lost = mean_rows(scan_rows), sum(r["off_tracks"] for r in scan_rows)
        print(
            f"checkpoint {episodes:4d}: colliding {scan['colliding_steps_pct']:.2f}%  "
            f"off-tracks {lost}  speed {100 * scan['mean_speed_frac']:.1f}%", flush=True,
        )  # fmt: skip
        if meets_lanekeeping_bar(scan):
            reached = episodes
            break
    results = evaluate(
        env_config, load_policy(out / "checkpoints" / "final.pt").act, args.eval_episodes, seed=args.seed
    )
    mean = mean_rows(results)
    print()
    print(f"run directory           {out}")
    print(f"training episodes       {len(rows)}")
    print(f"training wall time      {wall / 60:.1f} min, {args.workers} worker(s)")
    print(f"training env steps      {int(env_steps[-1]) if len(rows) else 0:,}")
    full = next((k for k, row in enumerate(rows) if row["steps"] >= env_config.max_steps), None)
    if full is not None:  # a marker on the learning curve itself, between checkpoints
        print(
            f"first full episode      episode {full + 1}, {int(env_steps[full]):,} env steps, "
            f"{since_start[full] / 60:.1f} min"
        )
    if reached is None:
        print(f"first at the bar        none of the checkpoints (every {args.checkpoint_every} episodes)")
    else:
        print(
            f"first at the bar        episode {reached}, {int(env_steps[reached - 1]):,} env steps, "
            f"{since_start[reached - 1] / 60:.1f} min ({args.scan_episodes} evaluation episodes each)"
        )
    print(f"evaluation              {args.eval_episodes} episodes x {env_config.n_agents} agents")
    print(f"% colliding steps       {mean['colliding_steps_pct']:.2f}   (bar <= 1)")
    print(f"off-tracks (total)      {int(np.sum([r['off_tracks'] for r in results]))}   (bar 0)")
    print(f"no-progress (total)     {int(np.sum([r['no_progress'] for r in results]))}")
    print(f"mean speed / limit      {100 * mean['mean_speed_frac']:.1f}%   (bar >= 80)")
    print(f"steps per episode       {mean['steps']:.0f} of {env_config.max_steps}")
    if "passed_frac" in mean:
        print(f"slower cars passed      {100 * mean['passed_frac']:.1f}%")
    for name in ("overtaker", "keeper"):
        if f"{name}_speed_frac" in mean:
            print(f"{name} speed / limit  {100 * mean[f'{name}_speed_frac']:.1f}%")


if __name__ == "__main__":
    main()
