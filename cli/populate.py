"""`behave populate`: learned agents among SUMO's traffic on any multi-lane network, traced as FCD."""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

import behaviors
from behaviors.cli.checks import NET, NON_NEGATIVE, POSITIVE, SEED
from behaviors.cli.progress import PROGRESS_SECONDS, QUIET, VERBOSE, Progress, make_progress, verbosity
from behaviors.errors import BehaveError
from behaviors.files import check_output_path
from sumo_scenarios import get_scenario

if TYPE_CHECKING:  # torch: only when run
    from behaviors.run.populate_config import PopulateConfig
    from behaviors.run.records import PopulateSummary

DEFAULTS = SimpleNamespace(
    net=get_scenario("highway").net, overtakers=4, keepers=4, background=20, duration=180.0,
    step_length=0.2, seed=0, shield=True, precision="auto", share=0.0, overtaker_fraction=0.5,
)  # fmt: skip
"""PopulateConfig's defaults, spelled out so that `--help` needs no torch (a test keeps them equal)."""
DEFAULT_POLICY = Path(behaviors.__file__).parent / "pretrained" / "traffic.pt"
DEFAULT_FCD = Path("runs/populate/fcd.xml")
DEFAULT_JOINED_AGENTS = Path("runs/connect/agents.csv")
DEFAULT_ORDER = 2  # behaviors.sumo.joined.DEFAULT_ORDER, spelled out so that `--help` imports nothing heavy


def populate_command(
    net: Annotated[
        Path | None,
        typer.Option(
            help="SUMO .net.xml or a bundled scenario's name (behave scenario list; default: the 3 km "
            "highway)",
            callback=NET,
        ),
    ] = None,
    sumocfg: Annotated[
        Path | None,
        typer.Option(
            help="run your own SUMO scenario as its .sumocfg sets it (net, routes, additionals, options); "
            "behave adds no cars of its own unless asked"
        ),
    ] = None,
    share: Annotated[
        float | None,
        typer.Option(
            help="with --sumocfg (needed there): this fraction of the scenario's passenger cars become "
            "agents (0-1; 0: SUMO's cars alone, the scenario as `sumo -c` runs it)"
        ),
    ] = None,
    overtaker_fraction: Annotated[
        float,
        typer.Option(
            help="of the agents from --share, the fraction that are overtakers (the rest keep lanes)"
        ),
    ] = DEFAULTS.overtaker_fraction,
    overtakers: Annotated[
        int | None,
        typer.Option(
            help=f"learned overtakers [default: {DEFAULTS.overtakers}, 0 with --sumocfg]",
            callback=NON_NEGATIVE,
        ),
    ] = None,
    keepers: Annotated[
        int | None,
        typer.Option(
            help=f"learned lane keepers [default: {DEFAULTS.keepers}, 0 with --sumocfg]",
            callback=NON_NEGATIVE,
        ),
    ] = None,
    lorries: Annotated[
        int,
        typer.Option(
            help="learned lorries (16.5 m, 80-90 km/h, rightmost lane; a styled policy drives them)",
            callback=NON_NEGATIVE,
        ),
    ] = 0,
    share_lorries: Annotated[
        bool,
        typer.Option(
            "--share-lorries",
            help="with --sumocfg or --connect: --share also draws the scenario's lorries (vClass truck or "
            "trailer), which become learned lorries of their own size (needs a styled policy)",
        ),
    ] = False,
    policy: Annotated[
        Path | None,
        typer.Option(
            help="a bundled policy's name (traffic, lanekeeping, overtaking, multi), a .pt checkpoint or a "
            "training run's directory [default: traffic]"
        ),
    ] = None,
    population: Annotated[
        str | None,
        typer.Option(
            help="the styled driver's population: a preset ('default') or a JSON file of style "
            "distributions (docs/manual/traffic-driver.md)"
        ),
    ] = None,
    driver: Annotated[
        str | None,
        typer.Option(
            help="'rules': the traffic driver's car-following law and lane-change rules with no network "
            "(a baseline; no --policy); paper or traffic: must be the policy's [default: the policy's]"
        ),
    ] = None,
    background: Annotated[
        int | None,
        typer.Option(
            help=f"SUMO's own cars around the agents [default: {DEFAULTS.background}, 0 with --sumocfg]",
            callback=NON_NEGATIVE,
        ),
    ] = None,
    routes: Annotated[Path | None, typer.Option(help="a SUMO routes file of your own traffic")] = None,
    duration: Annotated[
        float | None,
        typer.Option(
            help=f"simulated seconds [default: {DEFAULTS.duration:g}, or the sumocfg's end - begin]",
            callback=POSITIVE,
        ),
    ] = None,
    step_length: Annotated[
        float | None,
        typer.Option(
            help=f"seconds per step [default: the policy's ({DEFAULTS.step_length:g} s); without agents the "
            "sumocfg's, or SUMO's 1 s]",
            callback=POSITIVE,
        ),
    ] = None,
    lateral_resolution: Annotated[
        float | None,
        typer.Option(
            help="with --sumocfg: SUMO's sublane width in metres [default: the sumocfg's; where it sets none "
            "0.8 with agents, no sublanes without]",
            callback=POSITIVE,
        ),
    ] = None,
    outputs: Annotated[
        Path | None,
        typer.Option(
            help="with --sumocfg: write every output the scenario names (detectors, summary, tripinfo, ...) "
            "into this folder instead of where the sumocfg and its additionals put them"
        ),
    ] = None,
    seed: Annotated[
        int, typer.Option(help="same seed, same traces (byte for byte)", callback=SEED)
    ] = DEFAULTS.seed,
    fcd: Annotated[Path, typer.Option(help="FCD output: .xml, .csv or .parquet")] = DEFAULT_FCD,
    geo: Annotated[bool, typer.Option(help="write lon/lat (the net needs a projection)")] = False,
    keep_count: Annotated[
        bool, typer.Option(help="re-insert vehicles that leave so the counts hold")
    ] = False,
    shield: Annotated[
        bool,
        typer.Option(
            help="safety shield: no move into a car alongside, no speed that cannot stop behind "
            "the car ahead (--no-shield: the bare policy)"
        ),
    ] = DEFAULTS.shield,
    precision: Annotated[
        str, typer.Option(help="actor arithmetic: auto (bfloat16 where the CPU has it), float32, bfloat16")
    ] = DEFAULTS.precision,
    plot: Annotated[Path | None, typer.Option(help="also draw the traces into this PNG")] = None,
    json_out: Annotated[
        bool,
        typer.Option(
            "--json",
            help="print the summary as one JSON object on stdout (other messages go to stderr) instead of "
            "the table",
        ),
    ] = False,
    gui: Annotated[
        bool,
        typer.Option(
            help="watch the run in sumo-gui (the same simulation; keepers green, overtakers orange, SUMO's "
            "cars grey); needs a display"
        ),
    ] = False,
    connect: Annotated[
        str | None,
        typer.Option(
            metavar="HOST:PORT",
            help="join a SUMO another program runs (sumo --remote-port PORT --num-clients N) as "
            "one more TraCI client and drive --share of its passenger cars until it ends; no FCD (SUMO's "
            "own outputs hold the vehicles): docs/manual/connect.md",
        ),
    ] = None,
    order: Annotated[
        int, typer.Option(help="with --connect: this client's place in each step (traci.setOrder)")
    ] = DEFAULT_ORDER,
    agents_csv: Annotated[
        Path | None,
        typer.Option(
            "--agents",
            help="with --connect: the per-agent table [default: runs/connect/agents.csv]",
        ),
    ] = None,
    leave_alone: Annotated[
        list[str] | None,
        typer.Option(
            metavar="PREFIX",
            help="with --connect: never draw vehicles whose id starts with this (another client's, as "
            "CARLA's 'carla'); repeatable",
        ),
    ] = None,
    quiet: QUIET = False,
    verbose: VERBOSE = False,
) -> None:
    """Drive learned keepers and overtakers (one batched policy call per step) and write SUMO FCD.

    Ctrl-C stops after the step under way and keeps what was simulated (exit code 130)."""
    from behaviors.report.agents_table import agents_path
    from behaviors.run.populate import PopulateInterrupted, populate
    from behaviors.run.populate_config import config_from, populate_policy

    level = verbosity(quiet, verbose)
    if connect is not None:
        joined_command(connect, order, agents_csv, fcd, level, json_out, plot, sumocfg, net=net,
                       share=share, overtaker_fraction=overtaker_fraction, overtakers=overtakers,
                       keepers=keepers, lorries=lorries, share_lorries=share_lorries, policy=policy,
                       population=population, driver=driver,
                       background=background, routes=routes, duration=duration, step_length=step_length,
                       lateral_resolution=lateral_resolution, outputs=outputs, seed=seed, geo=geo,
                       keep_count=keep_count, shield=shield, precision=precision, gui=gui,
                       leave_alone=tuple(leave_alone) if leave_alone else None)  # fmt: skip
        return
    for option, given in (("--agents", agents_csv is not None), ("--order", order != DEFAULT_ORDER),
                          ("--leave-alone", bool(leave_alone))):  # fmt: skip
        if given:
            raise BehaveError(f"{option} goes with --connect")
    if sumocfg is not None and share is None and overtakers is None and keepers is None:
        raise BehaveError(
            "--sumocfg needs --share F: the fraction of the scenario's passenger cars the policy drives "
            "(--share 0: SUMO's cars alone)"
        )
    notes: list[str] = []
    config = config_from(
        sumocfg, notes, net=net, overtakers=overtakers, keepers=keepers, lorries=lorries,
        share_lorries=share_lorries, policy=policy, background=background,
        routes=routes, duration=duration, step_length=step_length, seed=seed, fcd=fcd, geo=geo,
        keep_count=keep_count, shield=shield, precision=precision, share=share,
        overtaker_fraction=overtaker_fraction, gui=gui, driver=driver, lateral_resolution=lateral_resolution,
        outputs=outputs, population=population,
    )  # fmt: skip
    if plot is not None:  # found unwritable now, not after the whole run
        check_output_path(plot)
    config.validate()
    populate_policy(config)  # a policy that cannot drive the run is one line, before the notes
    for note in notes if level >= 0 else ():  # what behave runs otherwise than `sumo -c` would, and why
        typer.echo(f"note: {note}", err=True)
    progress = make_progress("simulating", config.duration, "s", level=level, stderr=json_out)
    try:
        summary = populate(config, on_step=progress.update, on_status=say(level, "set-up: "))
    except PopulateInterrupted as stop:
        summary = stop.summary
    finally:
        progress.close()
    if json_out:
        import json

        summary_dict = {**summary.as_dict(), "fcd": str(fcd), "agents_csv": str(agents_path(fcd))}
        summary_dict.update({"cut_short": summary.cut_short, "net": str(config.net), "seed": seed})
        typer.echo(json.dumps(summary_dict))
    elif level >= 0:
        Console().print(summary_table(summary, f"behave populate: {config.net.name}, seed {seed}"))
    if level >= 0:
        typer.echo(f"FCD written to {fcd}", err=json_out)
        typer.echo(f"per-agent table written to {agents_path(fcd)}", err=json_out)
    if level > 0:
        for name, seconds in summary.phases.items():
            typer.echo(f"phase {name}: {seconds:,.2f} s of {summary.wall_s:,.2f} s wall", err=True)
    if plot is not None:
        from behaviors.report.fcd_read import read_fcd
        from behaviors.report.plot import plot_fcd

        road = config.net if config.net.is_file() else None  # road positions along it
        plot_fcd(read_fcd(fcd, geo=geo), plot, title=plot_title(config), net=road)
        if level >= 0:
            typer.echo(f"plot written to {plot}", err=json_out)
    if summary.cut_short:
        print(
            f"behave: interrupted after {summary.simulated_s:g} of {config.duration:g} simulated s; "
            f"the FCD and agents table hold the run up to then (cut short)",
            file=sys.stderr,
        )
        sys.exit(130)


def joined_command(
    connect: str,
    order: int,
    agents_csv: Path | None,
    fcd: Path,
    level: int,
    json_out: bool,
    plot: Path | None,
    sumocfg: Path | None,
    **given: Any,
) -> None:
    """`behave populate --connect HOST:PORT`: join a running SUMO (behaviors.run.populate.populate_joined)."""
    from behaviors.run.populate import PopulateInterrupted, populate_joined
    from behaviors.run.populate_config import config_from, populate_policy

    for option, value in (("--fcd", fcd != DEFAULT_FCD), ("--plot", plot is not None)):
        if value:
            raise BehaveError(
                f"--connect writes no FCD of its own (SUMO's --fcd-output holds every vehicle): drop {option}"
            )
    if sumocfg is not None:
        raise BehaveError("--connect joins a running simulation: --sumocfg does not apply (SUMO -c runs it)")
    table = agents_csv if agents_csv is not None else DEFAULT_JOINED_AGENTS
    config = config_from(None, connect=connect, order=order, agents_csv=table, **given)
    config.validate()
    populate_policy(config)  # a policy that cannot drive is one line, before joining
    progress: Progress | UnboundedProgress = (
        make_progress("simulating", config.duration, "s", level=level, stderr=json_out)
        if math.isfinite(config.duration)
        else UnboundedProgress(level)
    )
    try:
        summary = populate_joined(config, on_step=progress.update, on_status=say(level, "set-up: "))
    except PopulateInterrupted as stop:
        summary = stop.summary
    finally:
        progress.close()
    if json_out:
        import json

        out = {**summary.as_dict(), "agents_csv": str(table), "connect": connect, "order": order}
        out.update(left_simulation=summary.left_simulation, note=summary.left_note, seed=config.seed)
        typer.echo(json.dumps(out))
    elif level >= 0:
        Console().print(summary_table(summary, f"behave populate --connect {connect}, seed {config.seed}"))
    if level >= 0:
        typer.echo(f"per-agent table written to {table}", err=json_out)
    if level > 0:
        for name, seconds in summary.phases.items():
            typer.echo(f"phase {name}: {seconds:,.2f} s of {summary.wall_s:,.2f} s wall", err=True)
    print(f"behave: {summary.left_note}", file=sys.stderr)
    if summary.cut_short:
        sys.exit(130)


class UnboundedProgress:
    """Progress of a run with no known end (a joined simulation runs until it ends): a line on stderr
    every PROGRESS_SECONDS of wall time, nothing when quiet."""

    def __init__(self, level: int) -> None:
        self.level, self.start = level, time.monotonic()
        self.last = self.start

    def update(self, done: float, detail: str = "") -> None:
        now = time.monotonic()
        if self.level >= 0 and now - self.last >= PROGRESS_SECONDS:
            print(
                f"simulating: {done:,.0f} s so far, {now - self.start:,.0f} s elapsed",
                file=sys.stderr,
                flush=True,
            )
            self.last = now

    def close(self) -> None:
        pass


def say(level: int, prefix: str) -> Callable[[str], None] | None:
    """Status lines on stderr, unless quiet."""
    if level < 0:
        return None
    return lambda text: typer.echo(f"{prefix}{text}", err=True)


def summary_table(summary: PopulateSummary, title: str) -> Table:
    table = Table(title=title)
    table.add_column("metric")
    table.add_column("value", justify="right")
    if summary.cut_short:
        table.add_row("cut short (Ctrl-C)", f"after {summary.simulated_s:g} s")
    for key, value in summary.as_dict().items():
        if isinstance(value, str):  # a line of its own: the limits' counts
            text = value
        else:
            text = f"{value:,.2f}" if isinstance(value, float) else f"{value:,}"
        if key.endswith("mean_speed"):
            text = f"{value:.1f} m/s ({3.6 * value:.0f} km/h) from SUMO"
        if key.endswith("longest_standstill_s"):
            text = f"{value:.1f} s"
        table.add_row(key.replace("_", " "), text)
    return table


def plot_title(config: PopulateConfig) -> str:
    """What the run was: the net and its agents, or the sumocfg and the share of its cars that drove."""
    if config.sumocfg is None:
        lorries = f", {config.lorries} lorries" if config.lorries else ""
        return f"{config.net.name}: {config.keepers} keepers, {config.overtakers} overtakers{lorries}"
    return (
        f"{config.sumocfg.name}: {config.share:g} of its passenger cars learned "
        f"({config.overtaker_fraction:g} of them overtakers), seed {config.seed}"
    )
