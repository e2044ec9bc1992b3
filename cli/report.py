"""`behave report FCD`: how realistic the traces are, per group, beside naturalistic figures."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from behaviors.cli.checks import NET

GROUP_BY = ("type", "id-prefix")
SKIP_S = 10.0
"""realism's groupings and skipped seconds, spelled out so that `--help` needs no pandas (a test keeps
them equal)."""


def report_command(
    fcd: Annotated[Path, typer.Argument(help="FCD file (.xml, .csv or .parquet) of any SUMO run")],
    net: Annotated[
        Path | None,
        typer.Option(
            help="the run's net (a file or a bundled scenario's name): true lane widths, car lanes, "
            "left-hand traffic",
            callback=NET,
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(help="directory for realism.csv/.md/.png and flow.csv/.png (default: beside the FCD)"),
    ] = None,
    skip_s: Annotated[float, typer.Option(help="seconds left out at the start of each car")] = SKIP_S,
    group_by: Annotated[
        str, typer.Option(help=f"groups: {' or '.join(GROUP_BY)} (vType: keepers, overtakers, sumo)")
    ] = "type",
    cell_m: Annotated[float, typer.Option(help="fundamental diagram: cell length along an edge, m")] = 500.0,
    window_s: Annotated[float, typer.Option(help="fundamental diagram: cell duration, s")] = 60.0,
) -> None:
    """Lane use, lane changes, lateral acceleration, headways, passes, speeds and losses per group,
    and flow against density (flow.csv, flow.png)."""
    from behaviors.errors import BehaveError
    from behaviors.files import ensure_writable_dir

    if not fcd.is_file():  # before pandas and matplotlib load: a typo is answered at once
        raise BehaveError(f"FCD file not found: {fcd}")
    out = out if out is not None else fcd.parent
    ensure_writable_dir(out)  # an unwritable --out fails now, not after the whole report

    from behaviors.report.agents_table import agents_path
    from behaviors.report.fcd_read import read_fcd
    from behaviors.report.realism import check_options, measure, read_agents
    from behaviors.report.realism_output import rows
    from behaviors.report.realism_output import write_report as write_realism
    from behaviors.report.realism_tracks import Lanes, read_lanes

    check_options(skip_s, group_by)
    check_cells(cell_m, window_s)
    lanes = read_lanes(net) if net is not None else Lanes()
    agents = read_agents(agents_path(fcd))
    df = read_fcd(fcd)
    report = measure(df, lanes, agents=agents, skip_s=skip_s, group_by=group_by)
    table = Table(title=f"behave report: {fcd.name}")
    for column in ("metric", *report.table.columns, "naturalistic"):
        table.add_column(column, justify="left" if column in ("metric", "naturalistic") else "right")
    for row in rows(report):
        table.add_row(*row)
    console = Console()
    console.print(table)
    for note in report.notes:
        console.print(f"- {note}")
    cells, lines = fundamental_diagram(df, net, group_by, cell_m, window_s)
    typer.echo("\n".join(lines))
    for path in write_realism(report, out, title=fcd.name, extra=lines):
        typer.echo(f"wrote {path}")
    if cells is not None:
        from behaviors.report.flow import write_flow

        for path in write_flow(cells, out, title=fcd.name):
            typer.echo(f"wrote {path}")


def check_cells(cell_m: float, window_s: float) -> None:
    from behaviors.errors import BehaveError

    for name, value in (("--cell-m", cell_m), ("--window-s", window_s)):
        if not 0 < value < float("inf"):
            raise BehaveError(f"{name} must be a positive number, got {value}")


def fundamental_diagram(
    df: Any, net: Path | None, group_by: str, cell_m: float, window_s: float
) -> tuple[Any, list[str]]:
    """Edie's flow and density per cell and group (None if no cell), and the report's lines on it."""
    from behaviors.report.flow import edie_cells, road_from_fcd, road_from_net, summary, summary_markdown
    from behaviors.report.realism_tracks import group_names

    road = road_from_net(net) if net is not None else road_from_fcd(df)
    groups = group_names(df["id"], df.get("type"), group_by)
    cells = edie_cells(df, road, groups, cell_m=cell_m, window_s=window_s)
    head = ["## Flow against density (Edie's definitions)", ""]
    if cells.empty:
        return None, [*head, f"- no whole {window_s:g} s window on a cell of 50 m or more: no points"]
    where = "the net's edges" if net is not None else "edges as long as the furthest position seen on them"
    notes = [
        f"- cells of {cell_m:g} m (all car lanes of an edge) x {window_s:g} s on {where}, every record "
        "(insertion included), junctions left out; a group's flow and density are its share of the "
        "cell; points in flow.csv and flow.png",
        "- max flow: the highest mean flow over cells in a 5 veh/lane-km density bin (3 cells or more)",
        "",
    ]
    return cells, [*head, *notes, *summary_markdown(summary(cells))]
