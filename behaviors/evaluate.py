"""Run a fixed policy (no exploration, no learning) and measure the paper's metrics.

Used by `behave evaluate`, the learn-check benchmark and the model cards.
"""

from __future__ import annotations

import dataclasses
import io
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from behaviors.ddpg.checkpoint import load_actor, load_checkpoint
from behaviors.ddpg.networks import Actor
from behaviors.env import BEHAVIOURS, EnvConfig, create_env
from behaviors.errors import BehaveError
from behaviors.files import atomic_write_bytes, atomic_write_text, ensure_writable_dir
from behaviors.metrics import EpisodeStats, mean_rows, passed_fraction, summary
from behaviors.sensors import OBS_SIZE, OBS_SIZE_WITH_ID
from behaviors.train import episode_seed

Policy = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(observations [n, D], agent slots [n]) -> actions [n, 3]."""


def actor_policy(actor: Actor) -> Policy:
    """The whole fleet through one batched forward pass."""

    def act(obs: np.ndarray, slots: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return actor(torch.as_tensor(obs)).numpy()

    return act


def checkpoint_policy(path: Path, obs_dim: int) -> Policy:
    """A shared policy, or for multi-DDPG checkpoints each agent slot its own actor (slot mod count)."""
    ckpt = load_checkpoint(path, expect_obs_dim=obs_dim)
    actors_state = (ckpt.extra_state or {}).get("actors")
    if ckpt.meta["algorithm"] != "multi-ddpg" or not actors_state:
        return actor_policy(load_actor(path, expect_obs_dim=obs_dim))
    actors = []
    for state in actors_state:
        actor = Actor(obs_dim, ckpt.meta["hidden"])
        actor.load_state_dict(state)
        actors.append(actor.eval())

    def act(obs: np.ndarray, slots: np.ndarray) -> np.ndarray:
        out = np.empty((len(obs), 3), np.float32)
        owner = slots % len(actors)
        with torch.inference_mode():
            for k in np.unique(owner):
                rows = owner == k
                out[rows] = actors[k](torch.as_tensor(obs[rows])).numpy()
        return out

    return act


def evaluate(config: EnvConfig, policy: Policy, episodes: int, seed: int) -> list[dict[str, Any]]:
    """`episodes` rows of `summary`, each from a fresh, seeded episode."""
    env = create_env(config)
    limit = max(info.speed for info in env.geometry.edges.values() if info.normal)
    rows = []
    try:
        for episode in range(episodes):
            obs = env.reset_arrays(episode_seed(seed, 1_000_000 + episode))
            stats = EpisodeStats(config.n_agents, env.slot_behaviour.copy())
            while env.agents:
                slots = env.live_slots
                batch = env.step_arrays(policy(obs, slots).astype(np.float32))
                stats.record(slots, batch)
                obs = env.live_obs
            rows.append({"episode": episode, **summary(stats, limit, passed_fraction(env))})
    finally:
        env.close()
    return rows


PAPER_METRICS = (
    ("reward_per_agent", "average total reward per agent"),
    ("progress_per_agent", "average total progress per agent"),
    ("colliding_steps_per_agent", "average colliding steps per agent"),
    ("colliding_steps_pct", "% colliding steps in the system"),
)
BASELINE = "sumo"


@dataclass(frozen=True)
class EvaluationPlan:
    """Which policies to run in which settings; `settings` are (label, EnvConfig) pairs."""

    policies: list[tuple[str, Path | None]]  # (label, checkpoint); None = SUMO's own drivers
    settings: list[tuple[str, EnvConfig]]
    episodes: int
    seed: int


def plan_evaluation(
    checkpoints: list[Path],
    *,
    agents: list[int],
    episodes: int,
    behaviour: str | None,
    overtakers: int,
    keepers: int,
    placements: list[str] | None,
    scenario: str,
    seed: int,
    max_steps: int,
    baseline: str | None,
    opponents: int | None = None,
    shield: bool = False,
) -> EvaluationPlan:
    """Check every option against the checkpoints before anything runs; BehaveError names the problem.

    `opponents`: slower passive cars ahead (see EnvConfig); `shield`: drive through populate's
    safety shield, to see a policy as `behave populate` drives it.
    """
    if not checkpoints and baseline is None:
        raise BehaveError("give at least one checkpoint (or --baseline sumo)")
    if baseline not in (None, BASELINE):
        raise BehaveError(f"unknown baseline '{baseline}' (the only one is '{BASELINE}')")
    if episodes < 1:
        raise BehaveError(f"episodes must be positive, got {episodes}")
    metas = [load_checkpoint(path).meta for path in checkpoints]
    behaviour = behaviour or (metas[0].get("behaviour") if metas else None) or "lanekeeping"
    if behaviour not in BEHAVIOURS:
        raise BehaveError(f"unknown behaviour '{behaviour}' (choose from {', '.join(BEHAVIOURS)})")
    size = OBS_SIZE_WITH_ID if behaviour == "multi" else OBS_SIZE
    for path, meta in zip(checkpoints, metas, strict=True):
        if meta["obs_dim"] != size:
            raise BehaveError(f"{path} takes {meta['obs_dim']} observations but {behaviour} gives {size}")
    if behaviour == "multi":
        if overtakers + keepers == 0:
            raise BehaveError("multi-behaviour evaluation needs --overtakers and --keepers")
        placements = placements or ["A", "B", "C"]
        settings = [
            (f"case {p}", EnvConfig(scenario=scenario, behaviour="multi", overtakers=overtakers,
                                   keepers=keepers, placement=p, max_steps=max_steps, opponents=opponents,
                                   shield=shield))
            for p in placements
        ]  # fmt: skip
    else:
        if placements:
            raise BehaveError(f"--placement applies to multi-behaviour policies, not {behaviour}")
        if not agents:
            raise BehaveError("the agent list is empty: give e.g. --agents 3,5,7")
        settings = [
            (f"{n} agents", EnvConfig(scenario=scenario, behaviour=behaviour, agents=n, max_steps=max_steps,
                                      opponents=opponents, shield=shield))
            for n in agents
        ]  # fmt: skip
    for _, config in settings:
        create_env(config).close()  # validates scenario, counts and capacity before any long run
    policies: list[tuple[str, Path | None]] = [(path.stem, path) for path in checkpoints]
    if baseline:
        policies.append((f"{BASELINE} (Krauss + SL2015)", None))
    return EvaluationPlan(policies, settings, episodes, seed)


def run_plan(plan: EvaluationPlan, on_setting: Callable[[str, str], None] | None = None) -> pd.DataFrame:
    """One row per (policy, setting) with the episode-averaged metrics."""
    rows = []
    for label, path in plan.policies:
        for setting, config in plan.settings:
            if on_setting:
                on_setting(label, setting)
            if path is None:
                env_config = dataclasses.replace(config, sumo_drives=True)
                policy: Policy = lambda obs, slots: np.zeros((len(obs), 3), np.float32)  # noqa: E731
            else:
                env_config = config
                policy = checkpoint_policy(path, config.obs_size)
            episodes = evaluate(env_config, policy, plan.episodes, plan.seed)
            mean = mean_rows(episodes)
            if "passed_frac" in mean:
                mean["overtakes_per_agent"] = mean["passed_frac"] * config.n_opponents
            rows.append({"policy": label, "setting": setting, "agents": config.n_agents,
                         "episodes": plan.episodes, **mean})  # fmt: skip
    return pd.DataFrame(rows)


def write_report(results: pd.DataFrame, out: Path) -> list[Path]:
    """results.csv, results.md and one bar chart per paper metric (metrics.png)."""
    ensure_writable_dir(out)
    csv_path, md_path, png_path = out / "results.csv", out / "results.md", out / "metrics.png"
    atomic_write_text(csv_path, results.to_csv(index=False))
    atomic_write_text(md_path, markdown_table(results))
    plot_metrics(results, png_path)
    return [csv_path, md_path, png_path]


def markdown_table(results: pd.DataFrame) -> str:
    columns = [
        "policy",
        "setting",
        *(c for c, _ in PAPER_METRICS),
        "reward_sum",
        "off_tracks",
        "mean_speed_frac",
        "lane_deviation",
    ]
    columns += [c for c in ("overtakes_per_agent", "passed_frac", "overtaker_speed_frac", "keeper_speed_frac")
                if c in results]  # fmt: skip
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for _, row in results.iterrows():
        cells = [row[c] if isinstance(row[c], str) else f"{row[c]:,.2f}" for c in columns]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


def plot_metrics(results: pd.DataFrame, path: Path) -> None:
    """The paper's bar charts: each metric against the setting, one bar per policy."""
    from matplotlib.figure import Figure

    settings = list(dict.fromkeys(results["setting"]))
    policies = list(dict.fromkeys(results["policy"]))
    fig = Figure(figsize=(11, 7.5), layout="constrained")
    axes = fig.subplots(2, 2).ravel()
    width = 0.8 / len(policies)
    x = np.arange(len(settings))
    for ax, (metric, title) in zip(axes, PAPER_METRICS, strict=True):
        for k, policy in enumerate(policies):
            sub = results[results["policy"] == policy].set_index("setting").reindex(settings)
            ax.bar(x + (k - (len(policies) - 1) / 2) * width, sub[metric].to_numpy(), width, label=policy)
        ax.set_xticks(x, settings)
        ax.set_title(title)
        ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]), top=max(ax.get_ylim()[1], 1.0))
        ax.grid(axis="y", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=len(policies))
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    atomic_write_bytes(path, buffer.getvalue())
