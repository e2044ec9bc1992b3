"""`behave export` and `behave plot`: FCD traces for other simulators, and a picture of them."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from behaviors.cli.checks import NET
from behaviors.export import EXPORT_FORMATS, export_fcd, read_fcd


def export_command(
    fcd: Annotated[
        Path, typer.Argument(help="FCD file (.xml, .csv or .parquet) from behave populate or SUMO")
    ],
    to: Annotated[str, typer.Option("--to", help=f"target format: {', '.join(EXPORT_FORMATS)}")],
    out: Annotated[Path, typer.Option(help="output file (ns2 also writes .config and .activity beside it)")],
    net: Annotated[
        Path | None,
        typer.Option(
            help="the network (.net.xml or .net.xml.gz): projects metres to lon/lat for gpx/kml, "
            "or a geo FCD back to metres for ns2/omnet/ipg; or a bundled scenario's name",
            callback=NET,
        ),
    ] = None,
) -> None:
    """Convert FCD with SUMO's traceExporter, fixing the outputs it writes malformed."""
    for path in export_fcd(fcd, to, net=net, out=out):
        typer.echo(f"wrote {path}")


def plot_command(
    fcd: Annotated[Path, typer.Argument(help="FCD file (.xml, .csv or .parquet)")],
    out: Annotated[Path, typer.Option(help="PNG to write")],
    geo: Annotated[bool, typer.Option(help="the FCD holds lon/lat")] = False,
    title: Annotated[str, typer.Option(help="figure title")] = "",
    net: Annotated[
        Path | None,
        typer.Option(help="the network (or a bundled scenario's name), for true lane widths", callback=NET),
    ] = None,
) -> None:
    """Time-space diagram and lateral position over time, coloured by behaviour."""
    from behaviors.plot import plot_fcd  # matplotlib: only when plotting

    plot_fcd(read_fcd(fcd, geo=geo), out, title=title or fcd.name, net=net)
    typer.echo(f"wrote {out}")
