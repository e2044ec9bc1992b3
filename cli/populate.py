"""`behave populate`: learned agents among SUMO's traffic on any multi-lane network, traced as FCD."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from behaviors.files import check_output_path
from behaviors.populate import DEFAULT_POLICY, PopulateConfig, agents_csv_path, populate
from cli.checks import NON_NEGATIVE, POSITIVE, SEED

DEFAULTS = PopulateConfig()


def populate_command(
    net: Annotated[
        Path, typer.Option(help="SUMO .net.xml (default: the bundled 3 km highway)")
    ] = DEFAULTS.net,
    overtakers: Annotated[
        int, typer.Option(help="learned overtakers", callback=NON_NEGATIVE)
    ] = DEFAULTS.overtakers,
    keepers: Annotated[
        int, typer.Option(help="learned lane keepers", callback=NON_NEGATIVE)
    ] = DEFAULTS.keepers,
    policy: Annotated[
        Path, typer.Option(help="checkpoint (default: bundled multi-behaviour policy)")
    ] = DEFAULT_POLICY,
    background: Annotated[
        int, typer.Option(help="SUMO's own cars around the agents", callback=NON_NEGATIVE)
    ] = DEFAULTS.background,
    routes: Annotated[Path | None, typer.Option(help="a SUMO routes file of your own traffic")] = None,
    duration: Annotated[float, typer.Option(help="simulated seconds", callback=POSITIVE)] = DEFAULTS.duration,
    step_length: Annotated[
        float, typer.Option(help="seconds per step", callback=POSITIVE)
    ] = DEFAULTS.step_length,
    seed: Annotated[
        int, typer.Option(help="same seed, same traces (byte for byte)", callback=SEED)
    ] = DEFAULTS.seed,
    fcd: Annotated[Path, typer.Option(help="FCD output: .xml, .csv or .parquet")] = Path(
        "runs/populate/fcd.xml"
    ),
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
) -> None:
    """Drive learned keepers and overtakers (one batched policy call per step) and write SUMO FCD."""
    config = PopulateConfig(
        net=net, overtakers=overtakers, keepers=keepers, policy=policy, background=background, routes=routes,
        duration=duration, step_length=step_length, seed=seed, fcd=fcd, geo=geo, keep_count=keep_count,
        shield=shield, precision=precision,
    )  # fmt: skip
    columns = (TextColumn("simulating"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
               TimeElapsedColumn())  # fmt: skip
    progress = Progress(*columns, transient=True)
    task = progress.add_task("populate", total=duration)

    def advance(simulated: float) -> None:
        if not progress.live.is_started:  # started only once the set-up passed its checks
            progress.start()
        progress.update(task, completed=simulated)

    if plot is not None:  # found unwritable now, not after the whole run
        check_output_path(plot)
    try:
        summary = populate(config, on_step=advance)
    finally:
        if progress.live.is_started:
            progress.stop()
    table = Table(title=f"behave populate: {net.name}, seed {seed}")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key, value in summary.as_dict().items():
        text = f"{value:,.2f}" if isinstance(value, float) else f"{value:,}"
        if key.endswith("mean_speed"):
            text = f"{value:.1f} m/s ({3.6 * value:.0f} km/h) from SUMO"
        if key == "longest_standstill_s":
            text = f"{value:.1f} s"
        table.add_row(key.replace("_", " "), text)
    Console().print(table)
    typer.echo(f"FCD written to {fcd}")
    typer.echo(f"per-agent table written to {agents_csv_path(fcd)}")
    if plot is not None:
        from behaviors.export import read_fcd
        from behaviors.plot import plot_fcd

        plot_fcd(
            read_fcd(fcd, geo=geo), plot, title=f"{net.name}: {keepers} keepers, {overtakers} overtakers"
        )
        typer.echo(f"plot written to {plot}")
