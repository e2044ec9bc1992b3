"""`behave report FCD`: how realistic the traces are, per group, beside naturalistic figures."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

GROUP_BY = ("type", "id-prefix")
SKIP_S = 10.0
"""realism's groupings and skipped seconds, spelled out so that `--help` needs no pandas (a test keeps
them equal)."""


def report_command(
    fcd: Annotated[Path, typer.Argument(help="FCD file (.xml, .csv or .parquet) of any SUMO run")],
    net: Annotated[
        Path | None, typer.Option(help="the run's net: true lane widths, car lanes, left-hand traffic")
    ] = None,
    out: Annotated[
        Path | None, typer.Option(help="directory for realism.csv/.md/.png (default: beside the FCD)")
    ] = None,
    skip_s: Annotated[float, typer.Option(help="seconds left out at the start of each car")] = SKIP_S,
    group_by: Annotated[
        str, typer.Option(help=f"groups: {' or '.join(GROUP_BY)} (vType: keepers, overtakers, sumo)")
    ] = "type",
) -> None:
    """Lane use, lane changes, lateral acceleration, headways, passes, speeds and losses per group."""
    from behaviors.export import read_fcd
    from behaviors.realism import Lanes, agents_path, check_options, measure, read_agents, read_lanes, rows
    from behaviors.realism import write_report as write_realism

    check_options(skip_s, group_by)
    lanes = read_lanes(net) if net is not None else Lanes()
    agents = read_agents(agents_path(fcd))
    report = measure(read_fcd(fcd), lanes, agents=agents, skip_s=skip_s, group_by=group_by)
    table = Table(title=f"behave report: {fcd.name}")
    for column in ("metric", *report.table.columns, "naturalistic"):
        table.add_column(column, justify="left" if column in ("metric", "naturalistic") else "right")
    for row in rows(report):
        table.add_row(*row)
    console = Console()
    console.print(table)
    for note in report.notes:
        console.print(f"- {note}")
    for path in write_realism(report, out if out is not None else fcd.parent, title=fcd.name):
        typer.echo(f"wrote {path}")
