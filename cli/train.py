"""`behave train BEHAVIOUR`: PS-DDPG (or a baseline) on a SUMO scenario, into a run directory."""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Annotated

import typer

from behaviors.cli.checks import NET, NON_NEGATIVE, POSITIVE, SEED, number
from behaviors.cli.progress import QUIET, VERBOSE, make_progress, verbosity

DEFAULTS = SimpleNamespace(
    behaviour="lanekeeping", scenario="ring", agents=6, overtakers=0, keepers=0, placement="C",
    opponents=None, max_steps=1000, step_length=0.2, seed=0, lane_weight=0.0, driver="paper",
    hidden=(256, 256), batch_size=64, gamma=0.99, tau=0.001, actor_lr=1e-4, critic_lr=1e-3,
    buffer_size=100_000, warmup=1000, explore_decay_steps=100_000, batched_updates=False,
    algo="ps-ddpg", episodes=100, updates_per_step=None, reward_scale=None, checkpoint_every=10, init=None,
    max_minutes=None, workers=1, net=None, sumocfg=None, reward_weights=None,
)  # fmt: skip
"""Every setting of a run by option name (train_config.OPTIONS) with TrainConfig's default, spelled out so
that `--help` needs no torch; a test keeps them TrainConfig().options()."""
UNIT = number(high=1.0)
FRACTION = number(strict=True, high=1.0)


def train(
    behaviour: Annotated[str, typer.Argument(help="lanekeeping, overtaking or multi")],
    algo: Annotated[
        str, typer.Option(help="ps-ddpg (shared), ddpg (one agent) or multi-ddpg")
    ] = DEFAULTS.algo,
    agents: Annotated[
        int, typer.Option(help="learning agents (lanekeeping/overtaking)", callback=POSITIVE)
    ] = DEFAULTS.agents,
    overtakers: Annotated[
        int, typer.Option(help="overtakers (multi)", callback=NON_NEGATIVE)
    ] = DEFAULTS.overtakers,
    keepers: Annotated[
        int, typer.Option(help="lane keepers (multi)", callback=NON_NEGATIVE)
    ] = DEFAULTS.keepers,
    placement: Annotated[
        str, typer.Option(help="multi start: A overtakers ahead, B keepers ahead, C mixed")
    ] = DEFAULTS.placement,
    opponents: Annotated[
        int | None,
        typer.Option(help="slower passive cars ahead (overtaking; multi: default 0)", callback=NON_NEGATIVE),
    ] = DEFAULTS.opponents,
    episodes: Annotated[
        int | None,
        typer.Option(
            help=f"episodes in all (default {DEFAULTS.episodes}; with --resume: the stored total)",
            callback=POSITIVE,
        ),
    ] = None,
    max_steps: Annotated[
        int, typer.Option(help="steps per episode (time limit)", callback=POSITIVE)
    ] = DEFAULTS.max_steps,
    step_length: Annotated[
        float, typer.Option(help="seconds per step", callback=POSITIVE)
    ] = DEFAULTS.step_length,
    seed: Annotated[int, typer.Option(help="makes the run repeatable", callback=SEED)] = DEFAULTS.seed,
    scenario: Annotated[
        str,
        typer.Option(
            help="ring, highway or tiny; roads = the traffic driver's 5 closed roads, roads+ramps = 7,"
            " roads+queues = the 5 with a queue in the slow lane in half the episodes"
        ),
    ] = DEFAULTS.scenario,
    net: Annotated[
        Path | None,
        typer.Option(
            help="traffic driver: train on your .net.xml (or a bundled scenario's name) instead of "
            "--scenario, among SUMO's cars at densities drawn per episode",
            callback=NET,
        ),
    ] = DEFAULTS.net,
    sumocfg: Annotated[
        Path | None,
        typer.Option(help="traffic driver: train in your .sumocfg instead, its routes being SUMO's cars"),
    ] = DEFAULTS.sumocfg,
    reward_weights: Annotated[
        list[str] | None,
        typer.Option(
            "--reward-weight",
            metavar="TERM=WEIGHT",
            help="weigh a term of the driver's reward, e.g. speed=2 (repeatable; the others keep 1)",
        ),
    ] = DEFAULTS.reward_weights,
    out: Annotated[
        Path | None, typer.Option(help="run directory (default runs/BEHAVIOUR-ALGO-sSEED)")
    ] = None,
    init: Annotated[
        str | None,
        typer.Option(help="start from this policy: a .pt file, a run directory or a bundled name"),
    ] = DEFAULTS.init,
    resume: Annotated[Path | None, typer.Option(help="continue the run in this directory")] = None,
    updates_per_step: Annotated[
        int | None,
        typer.Option(help="network updates per step (default: one per live agent)", callback=POSITIVE),
    ] = DEFAULTS.updates_per_step,
    batched_updates: Annotated[
        bool, typer.Option(help="do a step's updates as one big batch")
    ] = DEFAULTS.batched_updates,
    hidden: Annotated[str, typer.Option(help="hidden layer sizes, e.g. 256,256")] = ",".join(
        map(str, DEFAULTS.hidden)
    ),
    batch_size: Annotated[
        int, typer.Option(help="replay minibatch size", callback=POSITIVE)
    ] = DEFAULTS.batch_size,
    gamma: Annotated[float, typer.Option(help="discount factor", callback=UNIT)] = DEFAULTS.gamma,
    tau: Annotated[
        float, typer.Option(help="target networks' soft-update rate", callback=FRACTION)
    ] = DEFAULTS.tau,
    actor_lr: Annotated[
        float, typer.Option(help="actor learning rate", callback=POSITIVE)
    ] = DEFAULTS.actor_lr,
    critic_lr: Annotated[
        float, typer.Option(help="critic learning rate", callback=POSITIVE)
    ] = DEFAULTS.critic_lr,
    buffer_size: Annotated[
        int, typer.Option(help="replay buffer size (transitions)", callback=POSITIVE)
    ] = DEFAULTS.buffer_size,
    warmup: Annotated[
        int, typer.Option(help="transitions stored before the first update", callback=NON_NEGATIVE)
    ] = DEFAULTS.warmup,
    reward_scale: Annotated[
        float | None,
        typer.Option(
            help="reward multiplier seen by the critic (default: 0.01 paper, 0.1 traffic)", callback=POSITIVE
        ),
    ] = DEFAULTS.reward_scale,
    driver: Annotated[
        str,
        typer.Option(help="paper (TORCS state, the paper's reward) or traffic (lanes, among SUMO's cars)"),
    ] = DEFAULTS.driver,
    explore_decay_steps: Annotated[
        int, typer.Option(help="env steps over which exploration noise decays to 0", callback=NON_NEGATIVE)
    ] = DEFAULTS.explore_decay_steps,
    lane_weight: Annotated[
        float,
        typer.Option(help="lane-discipline reward weight (0 = the paper's reward)", callback=NON_NEGATIVE),
    ] = DEFAULTS.lane_weight,
    checkpoint_every: Annotated[
        int, typer.Option(help="episodes between numbered checkpoints", callback=POSITIVE)
    ] = DEFAULTS.checkpoint_every,
    max_minutes: Annotated[
        float | None, typer.Option(help="wall-clock budget; stops after that episode", callback=NON_NEGATIVE)
    ] = DEFAULTS.max_minutes,
    workers: Annotated[
        int, typer.Option(help="rollout workers (over 1: on Ray, each with its own SUMO)", callback=POSITIVE)
    ] = DEFAULTS.workers,
    ray_address: Annotated[
        str | None, typer.Option(help="join this Ray cluster (default: a local Ray) with --workers")
    ] = None,
    quiet: QUIET = False,
    verbose: VERBOSE = False,
) -> None:
    """Train a behaviour; Ctrl-C or SIGTERM stops it (exit 130 or 143), resumable with --resume.

    Progress: a bar in a terminal, a line every tenth of the run or 30 s in a log, one line per
    episode with -v, nothing with -q."""
    given = dict(locals())  # the options as typer parsed them, by name
    level = verbosity(quiet, verbose)
    from behaviors.learn.train import prepare_run  # torch: only when training
    from behaviors.learn.train_config import TrainConfig

    check_road(net, sumocfg, driver)
    config = TrainConfig.from_options(**{
        **{name: given[name] for name in vars(DEFAULTS)},
        "episodes": DEFAULTS.episodes if episodes is None else episodes,
        "hidden": parse_sizes(hidden),
        "net": None if net is None else net.resolve(),
        "sumocfg": None if sumocfg is None else sumocfg.resolve(),
        "reward_weights": parse_weights(reward_weights or []),
    })  # fmt: skip
    run_dir = resume or out or Path("runs") / f"{behaviour}-{algo}-s{seed}"
    trainer = prepare_run(
        config, run_dir, resume=resume is not None, episodes=episodes, ray_address=ray_address
    )
    total = trainer.config.episodes
    progress = make_progress("training", total, "episodes", level=level, stderr=False)
    progress.update(trainer.episode, "starting SUMO")

    def show(row: dict) -> None:
        detail = episode_detail(row)
        progress.update(trainer.episode, detail)
        if level > 0:
            typer.echo(f"episode {trainer.episode}/{total}: {detail}", err=True)

    try:
        trainer.run(show)
    except KeyboardInterrupt:  # a second Ctrl-C: the last finished episode's state is saved
        trainer.stop_signal = signal.SIGINT
    finally:
        progress.close()
    resume_with = f"continue with: behave train {trainer.config.env.behaviour} --resume {run_dir}"
    done = f"{trainer.episode} of {total} episodes in {run_dir}"
    if trainer.stop_signal is not None:
        name = signal.Signals(trainer.stop_signal).name
        print(f"behave: {name} stopped training after {done}; {resume_with}", file=sys.stderr)
        sys.exit(128 + trainer.stop_signal)  # 130 for Ctrl-C, 143 for SIGTERM, as a shell reports them
    if level < 0:
        return
    if trainer.episode < total:
        typer.echo(f"stopped at the --max-minutes budget after {done}; {resume_with}")
    else:
        typer.echo(f"done: {done}")


def episode_detail(row: dict) -> str:
    """One finished episode in a few figures: return, colliding share, speed and throughput."""
    rate = row["agent_steps"] / max(row["wall_s"], 1e-9)
    return (
        f"reward {row['reward_sum']:.0f}, colliding {row['colliding_steps_pct']:.1f}%, "
        f"speed {100 * row['mean_speed_frac']:.0f}%, {rate:.0f} agent-steps/s"
    )


def parse_sizes(text: str) -> tuple[int, ...]:
    from behaviors.errors import BehaveError

    try:
        sizes = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise BehaveError(f"network sizes must be integers like 256,256, got '{text}'") from None
    return sizes


def check_road(net: Path | None, sumocfg: Path | None, driver: str) -> None:
    """--net and --sumocfg in the command's words (EnvConfig checks the same in Python's): one road,
    for a driver that trains among traffic."""
    from behaviors.errors import BehaveError
    from behaviors.fleet.drivers import make_driver

    if net is not None and sumocfg is not None:
        raise BehaveError("--net and --sumocfg both name a network: the sumocfg's net is used, drop --net")
    if (net is not None or sumocfg is not None) and not make_driver(driver).among_traffic:
        option = "--net" if net is not None else "--sumocfg"
        raise BehaveError(f"{option} trains among SUMO's traffic: add --driver traffic (the {driver} "
                          "driver trains on the bundled scenarios)")  # fmt: skip


def parse_weights(texts: list[str]) -> dict[str, float] | None:
    """--reward-weight TERM=WEIGHT, each term once (the driver's reward checks the terms and that
    the weights are finite); None when none is given: the default reward, untouched."""
    from behaviors.errors import BehaveError

    weights: dict[str, float] = {}
    for text in texts:
        term, sep, weight = text.partition("=")
        term = term.strip()
        if not sep or not term:
            raise BehaveError(f"--reward-weight takes TERM=WEIGHT, e.g. speed=2, got '{text}'")
        if term in weights:
            raise BehaveError(f"--reward-weight gives '{term}' twice")
        try:
            weights[term] = float(weight)
        except ValueError:
            raise BehaveError(
                f"--reward-weight {text}: the weight must be a number, got '{weight}'"
            ) from None
    return weights or None
