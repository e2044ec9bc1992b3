"""`behave animate`: a top-down GIF or MP4 of any FCD file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from behaviors.cli.checks import NET, POSITIVE
from behaviors.cli.progress import QUIET, VERBOSE, make_progress, verbosity


def animate_command(
    fcd: Annotated[
        Path, typer.Argument(help="FCD file (.xml, .csv or .parquet) from behave populate or SUMO")
    ],
    out: Annotated[Path, typer.Option(help="the animation: .gif (Pillow) or .mp4 (needs ffmpeg)")],
    every: Annotated[
        float, typer.Option(help="simulated seconds between two frames", callback=POSITIVE)
    ] = 1.0,
    fps: Annotated[int, typer.Option(help="frames per second when played", callback=POSITIVE)] = 10,
    follow: Annotated[
        str | None,
        typer.Option(help="a vehicle id: the view follows it (--window metres wide) while it is in the FCD"),
    ] = None,
    whole: Annotated[
        bool,
        typer.Option(
            help="draw the whole road however long (else, where a car would be under 4 px, the view "
            "follows the learned cars)"
        ),
    ] = False,
    window: Annotated[
        float, typer.Option(help="metres shown around the vehicle of --follow", callback=POSITIVE)
    ] = 200.0,
    net: Annotated[
        Path | None,
        typer.Option(
            help="the network (or a bundled scenario's name) whose lanes are drawn [default: the net the "
            "FCD's header names, if found]",
            callback=NET,
        ),
    ] = None,
    geo: Annotated[bool, typer.Option(help="the FCD holds lon/lat")] = False,
    sumocfg: Annotated[
        Path | None,
        typer.Option(
            help="the scenario whose route and additional files define the vTypes: vehicles drawn at their "
            "size and class [default: the files the FCD's header names, behave's vTypes, vClass defaults]"
        ),
    ] = None,
    quiet: QUIET = False,
    verbose: VERBOSE = False,
) -> None:
    """Top-down animation: lanes from the net, keepers and overtakers coloured, a time stamp per frame."""
    from behaviors.report.animate import AnimateOptions, animate_fcd  # matplotlib: only when drawing

    level = verbosity(quiet, verbose)
    options = AnimateOptions(
        every=every, fps=fps, follow=follow, window=window, net=net, geo=geo, whole=whole, sumocfg=sumocfg
    )
    progress = None

    def on_frame(done: int, total: int) -> None:
        nonlocal progress
        if progress is None:
            progress = make_progress("drawing", total, "frames", level=level, stderr=True)
        progress.update(done)

    note = None if level < 0 else (lambda text: typer.echo(f"note: {text}", err=True))
    try:
        frames = animate_fcd(fcd, out, options, on_frame=on_frame, on_status=note)
    finally:
        if progress is not None:
            progress.close()
    if level >= 0:
        typer.echo(f"wrote {out} ({frames} frames, one per {every:g} s)")
