"""Run a fixed policy (no exploration, no learning) and measure the paper's metrics.

Used by `behave evaluate`, the learn-check benchmark and the model cards.
"""

from __future__ import annotations

import dataclasses
import io
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from behaviors.errors import BehaveError
from behaviors.files import atomic_write_bytes, atomic_write_text, ensure_writable_dir, temp_dir
from behaviors.fleet.drivers import make_driver
from behaviors.learn.env import (
    BEHAVIOURS,
    TRAINING_ROADS,
    EnvConfig,
    create_env,
)
from behaviors.learn.episode import drive_episode
from behaviors.learn.metrics import agent_runs, mean_rows, passed_fraction, summary
from behaviors.learn.policy import RULES, Act, Policy, load_policy, rules_policy
from behaviors.learn.train import episode_seed
from behaviors.report.agents_table import agents_path, cell, table_text
from behaviors.report.fcd_read import fcd_options, read_fcd
from behaviors.report.realism import NothingToMeasure, Report, measure, read_agents, stack_runs
from behaviors.report.realism_output import write_report as write_realism
from behaviors.report.realism_tracks import SKIP_S, read_lanes
from sumo_scenarios import Scenario, get_scenario


def evaluate(
    config: EnvConfig, policy: Act, episodes: int, seed: int, record: Path | None = None, label: str = ""
) -> list[dict[str, Any]]:
    """`episodes` rows of `summary`, each from a fresh, seeded episode.

    `record`: a directory where SUMO writes each episode's FCD (`episode_fcd`) and behave the agents
    table beside it (agents_table, `label` naming the policy): what `behave report` reads.
    """
    env = create_env(config)
    rows = []
    try:
        for episode in range(episodes):
            fcd = None if record is None else episode_fcd(record, episode)
            if fcd is not None:
                env.sim_extra = tuple(fcd_options(fcd, geo=False))
            obs = env.reset_arrays(episode_seed(seed, 1_000_000 + episode))
            limit = max(info.speed for info in env.geometry.edges.values() if info.normal)  # this road's
            stats = drive_episode(env, obs, lambda obs, slots: policy(obs, slots).astype(np.float32))
            assert stats is not None  # nothing stops an evaluation's episode
            if fcd is not None:
                runs = agent_runs(stats, env.possible_agents, label)
                rewards = stats.reward[stats.placed]
                cells = ([*run.cells(), cell(float(r))] for run, r in zip(runs, rewards, strict=True))
                atomic_write_text(agents_path(fcd), table_text("evaluate", cells))
            rows.append({"episode": episode, **summary(stats, limit, passed_fraction(env))})
    finally:
        env.close()
    return rows


def episode_fcd(record: Path, episode: int) -> Path:
    """Where `evaluate` has SUMO write an episode's FCD (csv: read back faster than xml)."""
    return record / f"episode_{episode}.parquet"


def measure_episodes(record: Path, episodes: int, net: Path) -> Report:
    """The realism report of all the episodes `evaluate` recorded in `record`, measured together."""
    fcds = [episode_fcd(record, k) for k in range(episodes)]
    fcd, agents = stack_runs([(read_fcd(path), read_agents(agents_path(path))) for path in fcds])
    return measure(fcd, read_lanes(net), agents=agents)


PAPER_METRICS = (
    ("reward_per_agent", "average total reward per agent"),
    ("progress_per_agent", "average total progress per agent"),
    ("colliding_steps_per_agent", "average colliding steps per agent"),
    ("colliding_steps_pct", "% colliding steps in the system"),
)
BASELINE = "sumo"


MULTI_AGENTS = (4, 4)
"""Overtakers and keepers of a multi-behaviour evaluation when neither is given: as the bundled
multi-behaviour policies trained."""


@dataclass(frozen=True)
class EvaluationPlan:
    """Which policies to run in which settings; `settings` are (label, EnvConfig) pairs."""

    policies: list[tuple[str, Policy | None]]  # (label, policy); None = SUMO's own drivers
    settings: list[tuple[str, EnvConfig]]
    episodes: int
    seed: int


@dataclass(frozen=True)
class EvaluationOptions:
    """What `behave evaluate` was asked for, checked by plan_evaluation.

    `checkpoints`: anything policy.load_policy takes (files, run directories, bundled names), or "rules"
    (policy.rules_policy: the traffic driver's rules with no network, as a baseline); their
    driver model sets the environment, and their behaviour the settings unless `behaviour` is given.
    `scenario`: None = where the driver trains (the paper's ring, the traffic driver's roads).
    `opponents`: slower passive cars ahead (see EnvConfig); `shield`: drive through populate's
    safety shield, to see a policy as `behave populate` drives it.
    `net`/`sumocfg`: a user's road instead of `scenario` (drivers among traffic), as `behave train
    --net/--sumocfg` trains on it: SUMO's cars at drawn densities, or the sumocfg's own traffic.
    """

    checkpoints: list[Path]
    agents: list[int]
    episodes: int
    behaviour: str | None
    overtakers: int
    keepers: int
    placements: list[str] | None
    scenario: str | None
    seed: int
    max_steps: int
    baseline: str | None
    opponents: int | None = None
    shield: bool = False
    net: Path | None = None
    sumocfg: Path | None = None


def plan_evaluation(options: EvaluationOptions) -> EvaluationPlan:
    """Check every option against the policies before anything runs; BehaveError names the problem."""
    checkpoints, baseline, episodes = options.checkpoints, options.baseline, options.episodes
    placements, opponents, scenario = options.placements, options.opponents, options.scenario
    net, sumocfg = options.net, options.sumocfg
    if not checkpoints and baseline is None:
        raise BehaveError("give at least one checkpoint (or --baseline sumo)")
    if baseline not in (None, BASELINE):
        raise BehaveError(f"unknown baseline '{baseline}' (the only one is '{BASELINE}')")
    if episodes < 1:
        raise BehaveError(f"episodes must be positive, got {episodes}")
    policies = [rules_policy() if str(path) == RULES else load_policy(path) for path in checkpoints]
    driver = common_driver(policies)
    behaviour = options.behaviour or (policies[0].behaviour if policies else "lanekeeping")
    if behaviour not in BEHAVIOURS:
        raise BehaveError(f"unknown behaviour '{behaviour}' (choose from {', '.join(BEHAVIOURS)})")
    size = make_driver(driver).obs_size(behaviour == "multi")
    for policy in policies:
        if policy.obs_dim != size:
            raise BehaveError(
                f"{policy.path} takes {policy.obs_dim} observations but {behaviour} gives {size}"
            )
    among_traffic = make_driver(driver).among_traffic
    if among_traffic:
        refuse_paper_options(driver, baseline, placements, opponents)
    check_own_road(net, sumocfg, scenario, driver, among_traffic)
    home = TRAINING_ROADS if among_traffic else "ring"
    base = EnvConfig(scenario=scenario or home, driver=driver, behaviour=behaviour,
                     max_steps=options.max_steps, opponents=opponents, shield=options.shield, net=net,
                     sumocfg=sumocfg)  # fmt: skip
    if behaviour == "multi":
        settings = multi_settings(
            base,
            options.overtakers,
            options.keepers,
            None if among_traffic else placements or ["A", "B", "C"],
        )
    else:
        settings = agent_settings(base, options.agents, placements)
    for _, config in settings:
        create_env(config).close()  # validates scenario, counts and capacity before any long run
    runs: list[tuple[str, Policy | None]] = [(policy.label, policy) for policy in policies]
    if baseline:
        runs.append((f"{BASELINE} (Krauss + SL2015)", None))
    return EvaluationPlan(runs, settings, episodes, options.seed)


def common_driver(policies: list[Policy]) -> str:
    """The one driver model all the policies drive (the paper's for none: the SUMO baseline)."""
    drivers = sorted({policy.driver for policy in policies})
    if len(drivers) > 1:
        raise BehaveError(
            f"the policies drive different driver models ({', '.join(drivers)}): evaluate apart"
        )
    return drivers[0] if drivers else "paper"


def refuse_paper_options(
    driver: str, baseline: str | None, placements: list[str] | None, opponents: int | None
) -> None:
    """Options of the paper's formations that a driver among SUMO's traffic has no use for."""
    given = [name for name, value in (("--baseline", baseline), ("--placement", placements),
                                      ("--opponents", opponents)) if value is not None]  # fmt: skip
    if given:
        raise BehaveError(
            f"{' and '.join(given)} set the paper's formations; the {driver} driver's agents start at free "
            "places among SUMO's traffic"
        )


def check_own_road(
    net: Path | None, sumocfg: Path | None, scenario: str | None, driver: str, among_traffic: bool
) -> None:
    """--net/--sumocfg in the command's words: one road, no --scenario beside it, and policies that drive
    among SUMO's traffic (EnvConfig says the same in Python's)."""
    if net is None and sumocfg is None:
        return
    option = "--net" if net is not None else "--sumocfg"
    if net is not None and sumocfg is not None:
        raise BehaveError("--net and --sumocfg both name a network: the sumocfg's net is used, drop --net")
    if scenario is not None:
        raise BehaveError(f"--scenario and {option} both name a road: give one")
    if not among_traffic:
        raise BehaveError(f"{option} drives the policies among SUMO's traffic on your road: the {driver} "
                          "driver's policies drive the bundled scenarios (--scenario)")  # fmt: skip


def road_label(plan: EvaluationPlan) -> str:
    """The road the plan's settings drive: the user's net or sumocfg (its file name), or the scenario."""
    config = plan.settings[0][1]
    own = config.sumocfg if config.sumocfg is not None else config.net
    if own is not None:
        return Path(own).name
    scenario = config.scenario
    return scenario.name if isinstance(scenario, Scenario) else str(scenario)


def multi_settings(
    base: EnvConfig, overtakers: int, keepers: int, placements: list[str] | None
) -> list[tuple[str, EnvConfig]]:
    """One setting per placement (the paper's cases), or one (None: agents among traffic)."""
    if overtakers + keepers == 0:
        overtakers, keepers = MULTI_AGENTS
    config = dataclasses.replace(base, overtakers=overtakers, keepers=keepers)
    if placements is None:
        return [(f"{overtakers} overtakers + {keepers} keepers", config)]
    return [(f"case {p}", dataclasses.replace(config, placement=p)) for p in placements]


def agent_settings(
    base: EnvConfig, agents: list[int], placements: list[str] | None
) -> list[tuple[str, EnvConfig]]:
    """One setting per agent count (single-behaviour policies)."""
    if placements:
        raise BehaveError(f"--placement applies to multi-behaviour policies, not {base.behaviour}")
    if not agents:
        raise BehaveError("the agent list is empty: give e.g. --agents 3,5,7")
    return [(f"{n} agents", dataclasses.replace(base, agents=n)) for n in agents]


def records_fcd(config: EnvConfig) -> bool:
    """Whether SUMO can record the setting's episodes for the realism report: the paper's environment
    passes `sim_extra` (the FCD options) to SUMO, TrafficEnv does not."""
    return not make_driver(config.driver).among_traffic


def run_plan(
    plan: EvaluationPlan,
    on_setting: Callable[[str, str], None] | None = None,
    realism: Path | None = None,
    *,
    pictures: bool = True,
    on_result: Callable[[dict], None] | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """One row per (policy, setting) with the episode-averaged metrics, and the realism table.

    With `realism` (a directory), SUMO records every episode's FCD and each (policy, setting)
    gets its realism report in realism/<policy>/<setting>/ (`pictures`: with realism.png); the
    table has its main metrics per group (REALISM_COLUMNS). Without, that table is empty.
    """
    rows, realism_rows = [], []
    record = None
    if realism is not None:
        ensure_writable_dir(realism)
        record = temp_dir(realism / "fcd")
    try:
        for label, policy in plan.policies:
            for setting, config in plan.settings:
                if on_setting:
                    on_setting(label, setting)
                if policy is None:
                    env_config = dataclasses.replace(config, sumo_drives=True)
                    act: Act = lambda obs, slots: np.zeros((len(obs), 3), np.float32)  # noqa: E731
                else:
                    env_config, act = config, policy.act
                fcd = record if records_fcd(config) else None
                episodes = evaluate(env_config, act, plan.episodes, plan.seed, record=fcd, label=label)
                mean = mean_rows(episodes)
                if "passed_frac" in mean:
                    mean["overtakes_per_agent"] = mean["passed_frac"] * config.n_opponents
                rows.append({"policy": label, "setting": setting, "agents": config.n_agents,
                             "episodes": plan.episodes, **mean})  # fmt: skip
                if on_result:
                    on_result(rows[-1])
                if realism is not None:
                    realism_rows += realism_of_setting(fcd, plan.episodes, config, realism, label, setting,
                                                       picture=pictures)  # fmt: skip
    finally:
        if record is not None:
            shutil.rmtree(record, ignore_errors=True)
    return pd.DataFrame(rows), pd.DataFrame(realism_rows)


def realism_of_setting(
    record: Path | None,
    episodes: int,
    config: EnvConfig,
    realism: Path,
    policy: str,
    setting: str,
    *,
    picture: bool,
) -> list[dict[str, Any]]:
    """Measure the recorded episodes (None: not recorded, see records_fcd), write their report to
    realism/<policy>/<setting>/ and return its main rows; if there is nothing to measure, one row
    that says why."""
    if record is None:
        return [
            {"policy": policy, "setting": setting, "group": f"none: no FCD of the {config.driver} driver"}
        ]
    try:
        report = measure_episodes(record, episodes, scenario_net(config))
    except NothingToMeasure:
        return [{"policy": policy, "setting": setting, "group": f"none: every car left within {SKIP_S:g} s"}]
    write_realism(report, realism / slug(policy) / slug(setting), f"{policy}, {setting}", picture=picture)
    return main_realism(report, policy, setting)


def scenario_net(config: EnvConfig) -> Path:
    scenario = config.scenario
    return (scenario if isinstance(scenario, Scenario) else get_scenario(scenario)).net


def slug(label: str) -> str:
    """A directory name for a policy or setting label: `sumo (Krauss + SL2015)` -> `sumo-krauss-sl2015`."""
    return re.sub(r"[^a-z0-9]+", "-", label.lower()).strip("-") or "unnamed"


REALISM_COLUMNS = (  # the realism report's main metrics in results.md: key, title, shown as a share
    ("lane_changes_per_km", "lane changes / km", False),
    ("lane_0_share", "rightmost lane", True),
    ("lat_accel_over_limit", "lat. accel > 1.5 m/s^2", True),
    ("lc_peak_accel_median", "LC peak lat. accel, median", False),
    ("thw_below_limit", "THW < 1 s", True),
    ("passes_overtaking_side", "passes on the left", True),
    ("losses_per_agent_hour", "collisions + off-tracks / agent-h", False),
    ("lane_offset_mean", "lane-centre offset (m)", False),
)


def main_realism(report: Report, policy: str, setting: str) -> list[dict[str, Any]]:
    """One row per group of a realism report with the REALISM_COLUMNS metrics."""
    table = report.table
    losses = table.loc["collisions_per_agent_hour"] + table.loc["off_tracks_per_agent_hour"]
    main = table.reindex([key for key, _, _ in REALISM_COLUMNS if key != "losses_per_agent_hour"])
    return [
        {"policy": policy, "setting": setting, "group": group, **main[group].to_dict(),
         "losses_per_agent_hour": losses[group]}
        for group in table.columns
    ]  # fmt: skip


def realism_markdown(realism: pd.DataFrame) -> str:
    """The REALISM_COLUMNS table: one line per policy, setting and group."""
    header = ["policy", "setting", "group", *(title for _, title, _ in REALISM_COLUMNS)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for _, row in realism.iterrows():
        values = [_realism_cell(row.get(key, np.nan), share) for key, _, share in REALISM_COLUMNS]
        lines.append("| " + " | ".join([row["policy"], row["setting"], row["group"], *values]) + " |")
    return "\n".join(lines) + "\n"


def _realism_cell(value: float, share: bool) -> str:
    if value is None or np.isnan(value):
        return "-"
    return f"{100 * value:.1f}%" if share else f"{value:.2f}"


def write_report(results: pd.DataFrame, out: Path, realism: pd.DataFrame | None = None) -> list[Path]:
    """results.csv, results.md and one bar chart per paper metric (metrics.png); with a realism
    table (`run_plan`), realism_summary.csv and that table in results.md too."""
    ensure_writable_dir(out)
    csv_path, md_path, png_path = out / "results.csv", out / "results.md", out / "metrics.png"
    atomic_write_text(csv_path, results.to_csv(index=False))
    markdown = markdown_table(results)
    paths = [csv_path, md_path, png_path]
    if realism is not None and not realism.empty:
        summary_path = out / "realism_summary.csv"
        atomic_write_text(summary_path, realism.to_csv(index=False))
        title = "## Realism (`behave report` per group; the full reports in realism/)"
        markdown += f"\n{title}\n\n{realism_markdown(realism)}"
        paths.insert(2, summary_path)
    atomic_write_text(md_path, markdown)
    plot_metrics(results, png_path)
    return paths


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
    columns += [c for c in ("overtakes_per_agent", "passed_frac", "overtaker_speed_frac", "keeper_speed_frac",
                            "agents", "agents_placed") if c in results]  # fmt: skip
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for _, row in results.iterrows():
        cells = [row[c] if isinstance(row[c], str) else f"{row[c]:,.2f}" for c in columns]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


def placed_text(row: Any) -> str:
    """`8 of 8`, `1 of 8`, `4.5 of 8` (episodes averaged): the agents that started of those asked for."""
    if "agents_placed" not in row or pd.isna(row["agents_placed"]):
        return f"{row['agents']:g} of {row['agents']:g}"
    return f"{round(float(row['agents_placed']), 2):g} of {row['agents']:g}"


def short_placements(results: pd.DataFrame) -> list[str]:
    """One line per setting where fewer agents started than it asked for, on average (the traffic env
    puts agents down at free places: dense traffic on a short road leaves some slots out)."""
    if "agents_placed" not in results:
        return []
    short = results[results["agents_placed"] < results["agents"] - 1e-9]
    return [
        f"{row['policy']}, {row['setting']}: {placed_text(row)} agents started per episode on average "
        "(no free place for the others); per-agent figures count those that started"
        for _, row in short.iterrows()
    ]


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
