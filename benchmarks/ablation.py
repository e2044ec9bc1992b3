"""Who drives, the network or the rules? An ablation (`make ablation`, writes docs/ablation.md).

On the bundled highway in light and in dense traffic (benchmarks/dense_bars.py's "highway light" and
"highway dense": 30 + 30 and 100 + 100 agents among 20 and 60 SUMO cars, re-inserted as they leave,
the shield on as users run it), for each seed:

(a) `policy`: the shipped traffic.pt as `behave populate` drives it, its actions recorded
    (<out>/<traffic>/policy/s<seed>/actions.npz);
(b) `median`: the same driver, every action replaced by the per-dimension median of (a)'s actions
    over all seeds of that traffic (policy.held_constant; the driver's code untouched);
(c) `rules`: `--driver rules`, the driver's law and lane-change rules with no network
    (policy.RULES_ACTION).

Each run's FCD is measured by `behave report`'s realism measures (each car's first 10 s left out).
Per behaviour: mean speed, lane changes per km, passes per km, median time headway and the share of
time in the rightmost lane, with their seed noise (sample std over seeds). The bar: at least
3 of these 10 figures move between (a) and (b) by more than 3x their seed noise, in light and in
dense traffic; and without the network ((b), (c)) the keepers' and overtakers' gap in lane changes
per km falls under 30% of the learned one.

    python benchmarks/ablation.py [--seeds 0,1,2] [--duration 600] [--out runs/ablation] [--doc PATH]
"""

from __future__ import annotations

import argparse
import math
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from common import write_measured_doc
from dense_bars import SETTINGS, Setting, cell
from highway_anchor import cpu_model

from behaviors.learn.policy import RULES, RULES_ACTION, Act, Policy, held_constant
from behaviors.report.agents_table import agents_path
from behaviors.report.fcd_read import read_fcd
from behaviors.report.realism import measure, read_agents
from behaviors.report.realism_tracks import KEEPERS, OVERTAKERS, read_lanes
from behaviors.run.populate import populate
from behaviors.run.populate_config import DEFAULT_POLICY, PopulateConfig, populate_policy
from behaviors.traffic.lanes import TRAFFIC_SLICES


@dataclass(frozen=True)
class Figure:
    key: str  # the realism report's row
    label: str
    floor: float  # the bar's seed noise for it: the noise counted is at least this
    percent: bool = False


FIGURES = (
    Figure("mean_speed", "mean speed, m/s", 1.0),
    Figure("lane_changes_per_km", "lane changes per km", 0.25),
    Figure("passes_per_km", "passes per km", 0.3),
    Figure("thw_median", "median time headway, s", 0.4),
    Figure("lane_0_share", "rightmost-lane share", 0.2, percent=True),
)
GROUPS = (KEEPERS, OVERTAKERS)
VARIANTS = {"policy": "(a) the policy", "median": "(b) its median action", "rules": "(c) --driver rules"}
TRAFFIC = {"light": "highway light", "dense": "highway dense"}
"""Our name -> dense_bars.SETTINGS' name."""
TIMES_NOISE = 3.0
MOVES_NEEDED = 3
GAP_FRACTION = 0.3
LANE_CHANGES = "lane_changes_per_km"

Samples = dict[str, dict[tuple[str, str], list[float]]]
"""variant -> (group, figure key) -> its value in each seed's run."""


# ---- the bar's arithmetic (pure: tests/run/test_ablation.py) ----


def mean(values: Sequence[float]) -> float:
    known = [v for v in values if not math.isnan(v)]
    return float(np.mean(known)) if known else math.nan


def seed_noise(a: Sequence[float], b: Sequence[float]) -> float:
    """The seed noise of a figure measured in two variants: the pooled sample standard deviation
    over seeds, sqrt((var_a + var_b) / 2) (ddof 1); nan with fewer than two seeds in either."""
    known = [np.asarray([v for v in x if not math.isnan(v)]) for x in (a, b)]
    if any(len(x) < 2 for x in known):
        return math.nan
    return float(np.sqrt((np.var(known[0], ddof=1) + np.var(known[1], ddof=1)) / 2))


def moves(delta: float, noise: float, floor: float = 0.0) -> bool:
    """Whether a change `delta` is more than TIMES_NOISE x the noise, the noise counted as at least
    `floor` (the bar's figure for it); an unknown change or noise moves nothing."""
    if math.isnan(delta) or (math.isnan(noise) and floor <= 0):
        return False
    counted = floor if math.isnan(noise) else max(noise, floor)
    return abs(delta) > TIMES_NOISE * counted


def moves_at_least(delta: float, noise: float, amount: float) -> bool:
    """The bar's other reading: a change more than TIMES_NOISE x the measured noise and at least
    `amount` (the bar's figure read as the least move that counts)."""
    return moves(delta, noise) and abs(delta) >= amount


@dataclass(frozen=True)
class Move:
    group: str
    figure: Figure
    policy: float  # mean over seeds
    median: float
    rules: float
    delta: float  # median - policy
    noise: float  # seed_noise of (a) and (b)
    moved: bool  # beyond 3x max(noise, the bar's floor): the bar
    moved_measured: bool  # beyond 3x the measured noise alone
    moved_amount: bool  # beyond 3x the measured noise and at least the bar's figure (its other reading)


@dataclass(frozen=True)
class Verdict:
    moves: list[Move]
    gap: dict[str, float]  # variant -> overtakers' minus keepers' lane changes per km (means over seeds)
    gap_fraction: dict[str, float] = field(default_factory=dict)  # median, rules -> gap / policy's gap

    @property
    def moved(self) -> int:
        return sum(m.moved for m in self.moves)

    @property
    def moved_measured(self) -> int:
        return sum(m.moved_measured for m in self.moves)

    @property
    def moved_amount(self) -> int:
        return sum(m.moved_amount for m in self.moves)


def verdict(samples: Samples) -> Verdict:
    """The ablation's figures and its bar for one traffic, from each variant's per-seed values."""
    rows = []
    for group in GROUPS:
        for figure in FIGURES:
            a, b, c = (samples[v].get((group, figure.key), []) for v in VARIANTS)
            delta = mean(b) - mean(a)
            noise = seed_noise(a, b)
            rows.append(Move(group, figure, mean(a), mean(b), mean(c), delta, noise,
                             moves(delta, noise, figure.floor), moves(delta, noise),
                             moves_at_least(delta, noise, figure.floor)))  # fmt: skip
    gap = {
        v: mean(samples[v].get((OVERTAKERS, LANE_CHANGES), []))
        - mean(samples[v].get((KEEPERS, LANE_CHANGES), []))
        for v in VARIANTS
    }
    learned = gap["policy"]
    fraction = {v: gap[v] / learned if learned and not math.isnan(learned) else math.nan
                for v in VARIANTS if v != "policy"}  # fmt: skip
    return Verdict(rows, gap, fraction)


def median_action(actions: Sequence[np.ndarray]) -> np.ndarray:
    """The per-dimension median [3] of every agent-step's action [n, 3] over the runs given."""
    return np.median(np.concatenate([np.asarray(a, float).reshape(-1, 3) for a in actions]), axis=0)


# ---- the runs ----


class Recorder:
    """A policy's act function that keeps a copy of every action it returns (the actor's buffers are
    reused between calls) and each row's behaviour id (1 overtaker)."""

    def __init__(self, act: Act, behaviour_column: int | None) -> None:
        self.act = act
        self.column = behaviour_column  # None: the observation holds no behaviour id (a styled policy)
        self.actions: list[np.ndarray] = []
        self.behaviour: list[np.ndarray] = []

    def __call__(self, obs: np.ndarray, slots: np.ndarray | None = None) -> np.ndarray:
        out = self.act(obs, slots)
        self.actions.append(np.array(out, np.float32, copy=True))
        if self.column is not None:
            self.behaviour.append(np.asarray(obs)[:, self.column].ravel().copy())
        return out

    def save(self, path: Path) -> tuple[np.ndarray, np.ndarray]:
        actions = np.concatenate(self.actions) if self.actions else np.zeros((0, 3), np.float32)
        behaviour = np.concatenate(self.behaviour) if self.behaviour else np.zeros(0, np.float32)
        np.savez_compressed(path, actions=actions, behaviour=behaviour)
        return actions, behaviour


def setting(traffic: str) -> Setting:
    return next(s for s in SETTINGS if s.name == TRAFFIC[traffic])


def run_config(
    traffic: str, variant: str, seed: int, duration: float, out: Path, policy: Path = DEFAULT_POLICY
) -> PopulateConfig:
    fcd = out / traffic / variant / f"s{seed}" / "fcd.parquet"
    config = replace(setting(traffic).config(policy, seed, True, fcd), duration=duration)
    return replace(config, driver=RULES) if variant == "rules" else config


def figures(config: PopulateConfig) -> dict[tuple[str, str], float]:
    """(group, figure key) -> value in one run's FCD."""
    report = measure(
        read_fcd(config.fcd), read_lanes(config.net), agents=read_agents(agents_path(config.fcd))
    )
    return {(g, f.key): cell(report.table, f.key, g) for g in GROUPS for f in FIGURES}


def run(config: PopulateConfig, policy: Policy | None) -> dict[tuple[str, str], float]:
    started = time.perf_counter()
    summary = populate(config, policy=policy)
    values = figures(config)
    print(f"  {config.fcd.parent}: {summary.agent_steps:,} agent-steps, {summary.collisions} collisions, "
          f"{time.perf_counter() - started:.0f} s wall", flush=True)  # fmt: skip
    return values


@dataclass
class Traffic:
    """One traffic's runs: the per-seed figures of each variant, and the actions (a) took."""

    samples: Samples = field(default_factory=lambda: {v: {} for v in VARIANTS})
    median: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    by_behaviour: dict[str, np.ndarray] = field(default_factory=dict)  # group -> median action
    accel_at_one: float = math.nan  # share of (a)'s agent-steps with accel >= 0.999
    agent_steps: int = 0

    def add(self, variant: str, values: dict[tuple[str, str], float]) -> None:
        for key, value in values.items():
            self.samples[variant].setdefault(key, []).append(value)


def run_traffic(traffic: str, seeds: list[int], duration: float, out: Path, policy: Path) -> Traffic:
    result = Traffic()
    recorded, behaviours = [], []
    for seed in seeds:
        config = run_config(traffic, "policy", seed, duration, out, policy)
        loaded = populate_policy(config)
        column = TRAFFIC_SLICES["behaviour"].start if loaded.driver == "traffic" else None
        recorder = Recorder(loaded.act, column)
        result.add("policy", run(config, replace(loaded, act=recorder)))
        actions, behaviour = recorder.save(config.fcd.parent / "actions.npz")
        recorded.append(actions)
        behaviours.append(behaviour)
    actions, behaviour = np.concatenate(recorded), np.concatenate(behaviours)
    result.median = median_action([actions])
    if len(behaviour) == len(actions):
        result.by_behaviour = {
            g: median_action([actions[(behaviour > 0.5) == (g == OVERTAKERS)]]) for g in GROUPS
        }
    result.accel_at_one = float((actions[:, 1] >= 0.999).mean()) if len(actions) else math.nan
    result.agent_steps = len(actions)
    print(f"{traffic}: median action of {policy.name} (steer, accel, brake) = "
          f"{', '.join(f'{v:.4f}' for v in result.median)}", flush=True)  # fmt: skip
    for seed in seeds:
        config = run_config(traffic, "median", seed, duration, out, policy)
        result.add("median", run(config, held_constant(populate_policy(config), result.median)))
    for seed in seeds:
        result.add("rules", run(run_config(traffic, "rules", seed, duration, out, policy), None))
    return result


# ---- the table and the doc ----


def fmt(value: float, figure: Figure | None = None, digits: int = 2) -> str:
    if math.isnan(value):
        return "-"
    if figure is not None and figure.percent:
        return f"{100 * value:.1f}%"
    return f"{value:.{digits}f}"


def spread(values: Sequence[float], figure: Figure) -> str:
    """mean +- sample std over seeds."""
    known = [v for v in values if not math.isnan(v)]
    if not known:
        return "-"
    std = float(np.std(known, ddof=1)) if len(known) > 1 else math.nan
    return f"{fmt(float(np.mean(known)), figure)} ± {fmt(std, figure)}"


def figures_table(traffic: str, result: Traffic, judged: Verdict) -> str:
    header = ["traffic", "group", "figure", *VARIANTS.values(), "(b) - (a)", "seed noise (floor)", "moves"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for move in judged.moves:
        f = move.figure
        cells = [traffic, move.group, f.label]
        cells += [spread(result.samples[v].get((move.group, f.key), []), f) for v in VARIANTS]
        floor = f"{100 * f.floor:.0f}%" if f.percent else f"{f.floor:g}"
        moved = "yes" if move.moved else ("(measured noise only)" if move.moved_measured else "no")
        cells += [fmt(move.delta, f), f"{fmt(move.noise, f)} ({floor})", moved]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def bars_table(verdicts: dict[str, Verdict]) -> str:
    header = ["bar", "threshold", *verdicts, "met"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    moved = [v.moved for v in verdicts.values()]
    lines.append("| " + " | ".join([
        f"figures moved from (a) to (b) by > {TIMES_NOISE:g}x max(seed noise, the bar's floor), of "
        f"{len(GROUPS) * len(FIGURES)}", f">= {MOVES_NEEDED}", *(str(m) for m in moved),
        "yes" if all(m >= MOVES_NEEDED for m in moved) else "no",
    ]) + " |")  # fmt: skip
    amount = [v.moved_amount for v in verdicts.values()]
    lines.append("| " + " | ".join([
        f"... by > {TIMES_NOISE:g}x the measured seed noise and at least the bar's figure (its 2nd reading)",
        f">= {MOVES_NEEDED}", *(str(m) for m in amount),
        "yes" if all(m >= MOVES_NEEDED for m in amount) else "no",
    ]) + " |")  # fmt: skip
    lines.append("| " + " | ".join([
        f"... by > {TIMES_NOISE:g}x the measured seed noise alone (not the bar)", "",
        *(str(v.moved_measured) for v in verdicts.values()), "",
    ]) + " |")  # fmt: skip
    lines.append("| " + " | ".join([
        "overtakers' minus keepers' lane changes per km, (a)", "",
        *(fmt(v.gap["policy"]) for v in verdicts.values()), "",
    ]) + " |")  # fmt: skip
    for variant in ("median", "rules"):
        fractions = [v.gap_fraction[variant] for v in verdicts.values()]
        ok = all(not math.isnan(f) and abs(f) < GAP_FRACTION for f in fractions)
        lines.append("| " + " | ".join([
            f"that gap under {VARIANTS[variant]} / under (a)", f"< {GAP_FRACTION:g}",
            *(fmt(f) for f in fractions), "yes" if ok else "no",
        ]) + " |")  # fmt: skip
    return "\n".join(lines)


def actions_table(results: dict[str, Traffic]) -> str:
    header = ["traffic", "agent-steps of (a)", "median action (steer, accel, brake): all",
              "keepers", "overtakers", "accel >= 0.999"]  # fmt: skip
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]

    def triple(a: np.ndarray | None) -> str:
        return "-" if a is None else "(" + ", ".join(f"{v:.3f}" for v in a) + ")"

    for traffic, r in results.items():
        at_one = "-" if math.isnan(r.accel_at_one) else f"{100 * r.accel_at_one:.2f}%"
        lines.append("| " + " | ".join([
            traffic, f"{r.agent_steps:,}", triple(r.median), triple(r.by_behaviour.get(KEEPERS)),
            triple(r.by_behaviour.get(OVERTAKERS)), at_one,
        ]) + " |")  # fmt: skip
    return "\n".join(lines)


def commit() -> str:
    """HEAD's short hash, and the tracked files that differ from it (another hand's work in the checkout)."""
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "diff", "--name-only", "HEAD"], capture_output=True, text=True)
    files = dirty.stdout.split()
    text = head.stdout.strip() or "unknown"
    return f"{text} with uncommitted changes to {', '.join(files)}" if files else text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--duration", type=float, default=600.0, help="simulated seconds per run")
    parser.add_argument("--out", type=Path, default=Path("runs/ablation"))
    parser.add_argument("--doc", type=Path, default=Path("docs/ablation.md"))
    parser.add_argument("--policy", type=Path, default=DEFAULT_POLICY, help="the policy of (a) [traffic.pt]")
    args = parser.parse_args()
    name = args.policy.name
    seeds = [int(s) for s in args.seeds.split(",")]
    started, cpu = time.perf_counter(), time.process_time()  # libsumo: SUMO runs in this process
    results = {
        traffic: run_traffic(traffic, seeds, args.duration, args.out, args.policy) for traffic in TRAFFIC
    }
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    verdicts = {traffic: verdict(r.samples) for traffic, r in results.items()}
    text = "\n\n".join([
        f"### What {name} did in (a)", actions_table(results),
        "### The figures, per traffic and behaviour",
        *(figures_table(t, results[t], verdicts[t]) for t in results),
        "### The bar: the network makes the behaviour", bars_table(verdicts),
    ])  # fmt: skip
    print(text)
    light, dense = (setting(t) for t in TRAFFIC)
    doc = (
        f"# Who drives: {name}, its median action held constant, and the rules alone\n\n"
        f"Written by `make ablation` (`python benchmarks/ablation.py --seeds {args.seeds} "
        f"--duration {args.duration:g} --policy {args.policy} --doc {args.doc}`) on commit {commit()}; "
        f"CPU: {cpu_model()} (`lscpu`); "
        f"the {len(seeds) * len(VARIANTS) * len(TRAFFIC)} runs and their measures took {cpu / 60:.0f} min of "
        f"CPU ({wall / 60:.0f} min wall).\n\n"
        f"The bundled 3-lane, 3 km highway, {args.duration:g} simulated s per run, agents re-inserted as "
        f"they leave, the shield on: light = {light.keepers} keepers + {light.overtakers} overtakers among "
        f"{light.background} SUMO cars, dense = {dense.keepers} + {dense.overtakers} among "
        f"{dense.background}. "
        f"(a) {name}; (b) every action replaced by the per-dimension median of (a)'s "
        "actions in that traffic (all seeds pooled); (c) `--driver rules` (the driver's law and rules, "
        f"the constant action {RULES_ACTION}). Figures: `behave report`'s realism measures on each run's "
        "FCD (each car's first 10 s left out), mean ± sample std over seeds. A figure moves when "
        f"|(b) - (a)| > {TIMES_NOISE:g} x its seed noise, the pooled std of (a) and (b) over seeds, counted "
        "as at least the bar's figure for it (the floor in brackets).\n\n" + text + "\n"
    )
    write_measured_doc(args.doc, doc)
    print(f"wrote {args.doc}")


if __name__ == "__main__":
    main()
