"""Train the bundled policies and write their model card (`make pretrained`).

By default the paper's policies: lane keeping first (PS-DDPG, 6 agents on the ring), then
overtaking from the lane-keeping weights (the paper's curriculum) and multi-behaviour 4+4 from the
same weights (the behaviour id's inputs start at zero), two at a time. Each policy is evaluated
without exploration; the safest, then most rewarded, saved checkpoint ships as actor-only weights
in behaviors/pretrained/.

`--stages traffic` (or `paper,traffic`, `make traffic-policy`) runs the recipe of the shipped
traffic.pt: the fine-tuning that made it, from the actor and critic it started from
(behaviors/pretrained/starts/traffic_start.pt, episode 120 of a from-scratch run under earlier
rules of the road, which the model card names), seed 5, to episode 210, whose actor ships. Training
is deterministic for a seed on one core, so on the code the shipped file was trained on the recipe
gives it weight for weight (MODEL_CARD.md names that code); after a change to the rules of the
road, which changes what the agents meet, it gives a sibling policy. The stage keeps the shipped
file and its model card section if the result is the same, and otherwise ships the result with a
generated section: put it through `make dense`, `make flow`, `make realism` and `make own-nets`
(each takes `--policy`) before it stays.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

from behaviors.files import atomic_write_text
from behaviors.learn.ddpg.checkpoint import load_actor, save_actor_only
from behaviors.learn.env import EnvConfig
from behaviors.learn.metrics import mean_rows
from behaviors.learn.policy import load_policy
from behaviors.run.evaluate import evaluate

REPOSITORY = Path(__file__).resolve().parents[1]
PRETRAINED = REPOSITORY / "behaviors" / "pretrained"
LANE_WEIGHT = 0.5
"""Lane-discipline reward for the bundled policies (see README, Rewards). With the paper's
reward alone, they settled astride lane lines (mean offset 0.56-0.62 of half a lane width);
traces for other simulators should show cars in lanes."""

MULTI_LANE_WEIGHT = 2.0
"""The multi-behaviour policy needs more: at 0.5 its agents drove astride a lane line 34% of the
time among 1,000 agents on the highway (which also made SUMO's own step 14% slower around them);
at 2.0, 0.6% (benchmarks/bench_populate.py, docs/benchmarks.md)."""


def train_command(
    name: str, args: list[str], runs: Path, seed: int, minutes: float, lane_weight: float = LANE_WEIGHT
) -> list[str]:
    return [sys.executable, "-m", "behaviors.cli", "train", *args, "--seed", str(seed),
            "--out", str(runs / name), "--max-minutes", str(minutes), "--episodes", "2000",
            "--checkpoint-every", "10", "--lane-weight", str(lane_weight)]  # fmt: skip


TRAFFIC_START = PRETRAINED / "starts" / "traffic_start.pt"
TRAFFIC_SEED = 5
TRAFFIC_EPISODE = 210
TRAFFIC_ARGS = ["multi", "--driver", "traffic", "--scenario", "roads", "--overtakers", "4",
                "--keepers", "4", "--max-steps", "500", "--updates-per-step", "2",
                "--explore-decay-steps", "15000", "--actor-lr", "0.00002",
                "--critic-lr", "0.0005"]  # fmt: skip
"""The shipped traffic.pt's fine-tuning: 100 s episodes, two updates per step (not one per agent:
the wall-clock budget buys more experience), exploration decaying over 15,000 steps, learning
rates a tenth of the defaults' (the start's critic already knows the task)."""
TRAFFIC_EVAL = EnvConfig(scenario="roads", driver="traffic", behaviour="multi", overtakers=4, keepers=4,
                         max_steps=500)  # fmt: skip


def traffic_command(runs: Path, minutes: float) -> list[str]:
    """The fine-tuning that made traffic.pt, to its shipped episode (within `minutes`)."""
    return [sys.executable, "-m", "behaviors.cli", "train", *TRAFFIC_ARGS, "--init", str(TRAFFIC_START),
            "--seed", str(TRAFFIC_SEED), "--out", str(runs / "traffic"), "--max-minutes", str(minutes),
            "--episodes", str(TRAFFIC_EPISODE), "--checkpoint-every", "10"]  # fmt: skip


def run_parallel(commands: list[list[str]]) -> list[float]:
    """Run training commands side by side (one core each); wall seconds of each."""
    start = time.perf_counter()
    procs = [subprocess.Popen(cmd) for cmd in commands]
    walls = []
    for proc, cmd in zip(procs, commands, strict=True):
        if proc.wait() != 0:
            raise SystemExit(f"training failed: {shlex.join(cmd)}")
        walls.append(time.perf_counter() - start)
    return walls


def recorded_walls(run_dirs: list[Path]) -> list[float]:
    """Training seconds of finished runs, from their metrics (for --pick-only)."""
    import pandas as pd

    return [float(pd.read_csv(run / "metrics.csv")["wall_s"].sum()) for run in run_dirs]


def pick(out: Path, env: EnvConfig, seed: int, episodes: int) -> tuple[Path, dict[str, float]]:
    """Evaluate every saved checkpoint of a run; ship the safest, then the most rewarded.

    Safest = fewest collisions, off-tracks and no-progress ends per episode: a policy that
    populates other people's networks should first of all not crash.
    """
    scored = []
    for path in sorted((out / "checkpoints").glob("*.pt")):
        if path.stem in ("last", "interrupted", "episode_00000"):
            continue  # last = final or a numbered one; episode 0 is the untrained start
        mean = mean_rows(evaluate(env, load_policy(path).act, episodes, seed))
        failures = mean["collisions"] + mean["off_tracks"] + mean["no_progress"]
        scored.append(((failures, -mean["reward_sum"]), mean, path))
    _, mean, path = min(scored, key=lambda item: item[0])
    return path, mean


AUTOMATIC_PICK = "of all saved checkpoints: fewest failures, then most reward"


def as_shown(arg: str) -> str:
    """A command's argument as the model card shows it: a path inside the repository relative to it,
    as a user in a clean checkout types it (not where this checkout happens to be)."""
    path = Path(arg)
    inside = path.is_absolute() and path.is_relative_to(REPOSITORY)
    return str(path.relative_to(REPOSITORY)) if inside else arg


def card_section(
    title: str,
    cmd: list[str],
    seed: int,
    wall: float,
    out: Path,
    chosen: Path,
    m: dict,
    how: str = AUTOMATIC_PICK,
) -> str:
    import pandas as pd

    metrics = pd.read_csv(out / "metrics.csv")
    lines = [
        f"## {title}",
        "",
        f"- command: `{shlex.join(['behave', *map(as_shown, cmd[3:])])}`",
        f"- seed: {seed}; training episodes: {len(metrics)}; wall time: {wall / 60:.1f} min",
        f"- shipped checkpoint: {chosen.stem} ({how})",
        f"- evaluation ({m['episodes']:.0f} episodes, no exploration): "
        f"{m['colliding_steps_pct']:.2f}% colliding steps, {m['off_tracks']:.2f} off-tracks and "
        f"{m['collisions']:.2f} collisions per episode, "
        f"mean speed {100 * m['mean_speed_frac']:.1f}% of the limit, mean offset from the lane "
        f"centre {m['lane_deviation']:.2f} of half a lane width (0 = centred, 1 = on a lane line)",
    ]
    for name in ("overtaker", "keeper"):
        if f"{name}_speed_frac" in m:
            lines.append(f"- {name}s' mean speed: {100 * m[f'{name}_speed_frac']:.1f}% of the limit")
    if "passed_frac" in m:
        lines.append(f"- slower cars passed: {100 * m['passed_frac']:.1f}% of (agent, slower car) pairs")
    return "\n".join(lines) + "\n"


TRAFFIC_TITLE = "Traffic driver, keepers and overtakers in one network (traffic.pt)"


def same_actor(checkpoint: Path, shipped: Path) -> bool:
    """Whether `checkpoint`'s actor is the `shipped` file's, weight for weight."""
    import torch

    if not shipped.exists():
        return False
    new, old = (load_actor(path).state_dict() for path in (checkpoint, shipped))
    return new.keys() == old.keys() and all(torch.equal(new[k], old[k]) for k in new)


def paper_stage(args: argparse.Namespace, minutes: list[float]) -> tuple[list[str], dict]:
    """Lane keeping, then overtaking and multi from its weights (side by side); their card sections."""
    runs, s = args.runs, args.seed
    lk_min, ot_min, multi_min = minutes
    sections, results = [], {}
    lk_cmd = train_command("lanekeeping", ["lanekeeping", "--agents", "6"], runs, s, lk_min)
    [wall] = recorded_walls([runs / "lanekeeping"]) if args.pick_only else run_parallel([lk_cmd])
    lk_env = EnvConfig(agents=6, max_steps=1000)
    lk_chosen, m = pick(runs / "lanekeeping", lk_env, s, args.eval_episodes)
    save_actor_only(lk_chosen, PRETRAINED / "lanekeeping.pt")
    results["lanekeeping"] = m
    sections.append(card_section("Lane keeping (lanekeeping.pt)", lk_cmd, s, wall, runs / "lanekeeping",
                                 lk_chosen, {**m, "episodes": args.eval_episodes}))  # fmt: skip

    ot_cmd = train_command("overtaking", ["overtaking", "--agents", "4", "--opponents", "4",
                                          "--init", str(lk_chosen)], runs, s, ot_min)  # fmt: skip
    mb_args = ["multi", "--overtakers", "4", "--keepers", "4", "--placement", "C", "--init", str(lk_chosen)]
    mb_cmd = train_command("multi", mb_args, runs, s, multi_min, MULTI_LANE_WEIGHT)
    walls = (
        recorded_walls([runs / "overtaking", runs / "multi"])
        if args.pick_only
        else run_parallel([ot_cmd, mb_cmd])
    )
    setups = [
        ("overtaking", "Overtaking (overtaking.pt)", ot_cmd,
         EnvConfig(behaviour="overtaking", agents=4, opponents=4, max_steps=1000)),
        ("multi", "Multi-behaviour 4+4, placement C (multi.pt)", mb_cmd,
         EnvConfig(behaviour="multi", overtakers=4, keepers=4, placement="C", max_steps=1000)),
    ]  # fmt: skip
    for (name, title, cmd, env), wall in zip(setups, walls, strict=True):
        chosen, m = pick(runs / name, env, s, args.eval_episodes)
        save_actor_only(chosen, PRETRAINED / f"{name}.pt")
        results[name] = m
        sections.append(card_section(title, cmd, s, wall, runs / name, chosen,
                                     {**m, "episodes": args.eval_episodes}))  # fmt: skip
    return sections, results


def kept_sections(traffic: bool) -> list[str]:
    """The current model card's sections of the traffic policy (`traffic`) or of the paper's, for the
    stage that does not run."""
    card = PRETRAINED / "MODEL_CARD.md"
    if not card.exists():
        return []
    parts = card.read_text().split("\n## ")[1:]
    return ["## " + part.rstrip("\n") + "\n" for part in parts if part.startswith(TRAFFIC_TITLE) == traffic]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--runs", type=Path, default=Path("runs/pretrained"))
    parser.add_argument(
        "--minutes", default="8,12,20,150", help="budgets: lanekeeping,overtaking,multi,traffic"
    )
    parser.add_argument("--stages", default="paper", help="paper, traffic or both (see the docstring)")
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--pick-only", action="store_true", help="re-evaluate existing runs, no training")
    args = parser.parse_args()
    *paper_minutes, traffic_min = (float(x) for x in args.minutes.split(","))
    stages = set(args.stages.split(","))
    runs = args.runs
    traffic_cmd = traffic_command(runs, traffic_min)
    training = "traffic" in stages and not args.pick_only
    traffic = subprocess.Popen(traffic_cmd) if training else None
    sections, results = paper_stage(args, paper_minutes) if "paper" in stages else (kept_sections(False), {})
    if "traffic" in stages:
        if traffic is not None and traffic.wait() != 0:
            raise SystemExit(f"training failed: {shlex.join(traffic_cmd)}")
        chosen = runs / "traffic" / "checkpoints" / f"episode_{TRAFFIC_EPISODE:05d}.pt"
        if not chosen.exists():
            raise SystemExit(
                f"{chosen} is missing: the traffic run stopped early (raise its --minutes budget)"
            )
        [traffic_wall] = recorded_walls([runs / "traffic"])
        m = mean_rows(evaluate(TRAFFIC_EVAL, load_policy(chosen).act, args.eval_episodes, TRAFFIC_SEED))
        results["traffic"] = m
        if same_actor(chosen, PRETRAINED / "traffic.pt"):
            print(f"{chosen} rebuilt traffic.pt weight for weight; the model card's section stays")
            sections = kept_sections(True) + sections
        else:
            print(f"{chosen} is not the shipped traffic.pt: screen it in dense traffic (benchmarks/flow.py)")
            save_actor_only(chosen, PRETRAINED / "traffic.pt")
            how = "the recipe's last, not the file it replaced: screen it before shipping"
            metrics = {**m, "episodes": args.eval_episodes}
            section = card_section(TRAFFIC_TITLE, traffic_cmd, TRAFFIC_SEED, traffic_wall, runs / "traffic",
                                   chosen, metrics, how)  # fmt: skip
            sections.insert(0, section)
    else:
        sections = kept_sections(True) + sections

    header = (
        "# Bundled policies: model card\n\n"
        "Trained by this project with `make pretrained` (benchmarks/make_pretrained.py) on a 2-core CPU, "
        "PS-DDPG with the defaults of `behave train` unless the command says otherwise. "
        "Files hold actor weights only (`behave` never needs the critic to drive). "
        "Paper policies: the bundled 3 km, 3-lane ring, 1000 steps of 0.2 s per episode. Traffic policy: "
        "the five training roads among SUMO's cars, 500 steps per episode; its realism against the driving "
        "bars is in docs/realism.md (`make realism`).\n\n"
    )
    atomic_write_text(PRETRAINED / "MODEL_CARD.md", header + "\n".join(sections))
    atomic_write_text(args.runs / "evaluation.json", json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
