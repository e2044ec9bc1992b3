"""`behave export` and `behave plot`: FCD traces for other simulators, and a picture of them."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import Annotated

import typer

from behaviors.cli.checks import NET
from behaviors.errors import BehaveError
from behaviors.report.export import EXPORT_FORMATS, export_fcd
from behaviors.report.fcd_read import read_fcd


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
    start_time: Annotated[
        str | None,
        typer.Option(
            help="gpx: the date and time of the FCD's time 0, ISO 8601 (2024-05-06T08:00:00Z; no zone: "
            "UTC) [default: 1970-01-01T00:00:00Z]"
        ),
    ] = None,
) -> None:
    """Convert FCD with SUMO's traceExporter, fixing the outputs it writes malformed (ipg: one block
    of rows per vehicle, under its id)."""
    for path in export_fcd(fcd, to, net=net, out=out, start=parse_start(start_time)):
        typer.echo(f"wrote {path}")


def parse_start(text: str | None) -> datetime | None:
    """--start-time as a datetime (UTC where no zone is given)."""
    if text is None:
        return None
    try:
        start = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise BehaveError(f"--start-time takes an ISO 8601 date and time such as 2024-05-06T08:00:00Z, "
                          f"got '{text}'") from None  # fmt: skip
    return start if start.tzinfo else start.replace(tzinfo=timezone.utc)


def plot_command(
    fcd: Annotated[Path, typer.Argument(help="FCD file (.xml, .csv or .parquet)")],
    out: Annotated[Path, typer.Option(help="PNG to write")],
    geo: Annotated[bool, typer.Option(help="the FCD holds lon/lat")] = False,
    title: Annotated[str, typer.Option(help="figure title")] = "",
    net: Annotated[
        Path | None,
        typer.Option(
            help="the network (or a bundled scenario's name): road positions along it and true lane widths "
            "[default: the net the FCD's header names, if found]",
            callback=NET,
        ),
    ] = None,
) -> None:
    """Time-space diagram (by road position) and lateral position over time, coloured by behaviour."""
    from behaviors.report.animate import named_net
    from behaviors.report.plot import plot_fcd  # matplotlib: only when plotting

    plot_fcd(read_fcd(fcd, geo=geo), out, title=title or fcd.name, net=net or named_net(fcd))
    typer.echo(f"wrote {out}")
