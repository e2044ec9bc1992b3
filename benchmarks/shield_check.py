"""What the populate safety shield changes: crashes and speeds with and without it, same seeds.

Two settings, each run with `--shield` and `--no-shield`:
1. `make run`'s: the bundled highway, 4 overtakers + 4 keepers among 20 SUMO cars, 180 s, keep-count;
2. crowded: 1,000 agents (500/500) among 200 SUMO cars on a 30 km 3-lane highway, 44 s, keep-count
   (bench_populate's 1,000-agent row).
Collision counts are deterministic for a seed, so this needs no idle machine.

Usage: python benchmarks/shield_check.py [--seeds 0,1,2] [--policy CKPT] [--csv PATH]
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import torch
from bench_populate import STEP_LENGTH, WARMUP_STEPS, Row, build_highway, config_for
from common import print_table, progress, write_csv
from rich.console import Console

from behaviors.run.populate import populate
from behaviors.run.populate_config import DEFAULT_POLICY, PopulateConfig
from behaviors.run.precision import POLICY_THREADS
from behaviors.run.records import PopulateSummary


@dataclass(frozen=True)
class Setting:
    name: str
    config: PopulateConfig


def settings(tmp: Path, policy: Path) -> list[Setting]:
    make_run = PopulateConfig(policy=policy, keep_count=True, fcd=tmp / "fcd.xml")
    crowded = config_for(Row(1000, 200), build_highway(tmp, 30_000.0), tmp / "fcd.xml", 200, 0, policy)
    return [Setting("make run, 8 + 20, 180 s", make_run),
            Setting("crowded, 1,000 + 200, 44 s", crowded)]  # fmt: skip


COLUMNS = ("setting", "seed", "shield", "agent-h", "collisions", "per agent-h", "off-tracks",
           "side cuts %", "speed cuts %", "keeper m/s", "overtaker m/s")  # fmt: skip


def row_of(setting: Setting, seed: int, shield: bool, s: PopulateSummary) -> list[str]:
    hours = s.agent_steps * STEP_LENGTH / 3600
    speeds = s.as_dict()
    return [
        setting.name,
        str(seed),
        "on" if shield else "off",
        f"{hours:.2f}",
        str(s.collisions),
        f"{s.collisions / max(hours, 1e-9):.1f}",
        str(s.off_tracks),
        f"{100 * s.side_cuts / max(s.agent_steps, 1):.1f}",
        f"{100 * s.speed_cuts / max(s.agent_steps, 1):.1f}",
        f"{speeds.get('keeper_mean_speed', float('nan')):.1f}",
        f"{speeds.get('overtaker_mean_speed', float('nan')):.1f}",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--policy", type=Path, default=DEFAULT_POLICY)
    parser.add_argument("--csv", type=Path, default=None)
    args = parser.parse_args()
    seeds = [int(x) for x in args.seeds.split(",")]
    torch.set_num_threads(POLICY_THREADS)
    console = Console(width=max(Console().width, 160))
    rows = []
    with tempfile.TemporaryDirectory(prefix="behave_shield_") as tmp_name:
        for setting in settings(Path(tmp_name), args.policy):
            for seed in seeds:
                for shield in (False, True):
                    config = replace(setting.config, seed=seed, shield=shield)
                    label = f"{setting.name}, seed {seed}, shield {'on' if shield else 'off'}"
                    with progress(console, label):
                        rows.append(row_of(setting, seed, shield, populate(config)))
    title = (
        f"populate with and without the safety shield ({args.policy.name}); crowded runs include "
        f"{WARMUP_STEPS} warm-up steps"
    )
    print_table(console, title, COLUMNS, rows)
    console.print("agent-h = hours driven by agents; cuts = % of agent-steps whose move or speed was cut")
    if args.csv is not None:
        write_csv(args.csv, COLUMNS, rows)


if __name__ == "__main__":
    main()
