"""`behave sweep`: populate runs over a grid of shares, seeds, policies and scenarios, on Ray, into one
table (sweep.csv/.parquet) and one plot (sweep.png)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from behaviors.cli.checks import NON_NEGATIVE, POSITIVE, SEED_MAX, check_number
from behaviors.cli.progress import QUIET, VERBOSE, verbosity
from behaviors.errors import BehaveError


def parse_numbers(name: str, text: str | None, *, integer: bool, high: float | None = None) -> tuple | None:
    """A comma-separated list of numbers (None: not given), each checked as the option's range says."""
    if text is None:
        return None
    kind = int if integer else float
    try:
        values = [kind(part) for part in text.split(",") if part.strip()]
    except ValueError:
        what = "integers" if integer else "numbers"
        raise BehaveError(f"{name} must be a comma-separated list of {what}, got '{text}'") from None
    if not values:
        raise BehaveError(f"{name} names no value: '{text}'")
    return tuple(check_number(name, value, high=high) for value in values)


def sweep_command(
    sumocfg: Annotated[
        list[Path] | None,
        typer.Option(help="a SUMO scenario whose passenger cars become agents by --share (repeatable)"),
    ] = None,
    net: Annotated[
        list[str] | None,
        typer.Option(
            help="a .net.xml or a bundled scenario's name (highway, tiny, ...) with --overtakers/--keepers "
            "agents among --background SUMO cars (repeatable)"
        ),
    ] = None,
    share: Annotated[
        str | None,
        typer.Option(
            help="with --sumocfg (needed there): shares of passenger cars that become agents, e.g. "
            "0,0.25,0.5 (0: SUMO's cars alone)"
        ),
    ] = None,
    seeds: Annotated[str, typer.Option(help="seeds, e.g. 0,1,2: each point runs once per seed")] = "0",
    policy: Annotated[
        list[str] | None,
        typer.Option(help="a policy as populate takes it (repeatable) [default: traffic]"),
    ] = None,
    overtakers: Annotated[
        str | None, typer.Option(help="learned overtakers, e.g. 0,2,4 [default: 4 on a net, 0 on a sumocfg]")
    ] = None,
    keepers: Annotated[
        str | None, typer.Option(help="learned lane keepers, e.g. 0,4 [default: 4 on a net, 0 on a sumocfg]")
    ] = None,
    background: Annotated[
        int | None,
        typer.Option(help="SUMO's own cars on a net [default: 20, 0 on a sumocfg]", callback=NON_NEGATIVE),
    ] = None,
    overtaker_fraction: Annotated[
        float, typer.Option(help="of the agents from --share, the fraction that are overtakers")
    ] = 0.5,
    duration: Annotated[
        float | None,
        typer.Option(help="simulated seconds [default: 180, or the sumocfg's end-begin]", callback=POSITIVE),
    ] = None,
    step_length: Annotated[
        float | None,
        typer.Option(help="seconds per step [default 0.2, or the sumocfg's]", callback=POSITIVE),
    ] = None,
    shield: Annotated[bool, typer.Option(help="the safety shield, as populate")] = True,
    workers: Annotated[
        int | None,
        typer.Option(help="runs at once, each a Ray task with its own SUMO [default: Ray's CPUs]"),
    ] = None,
    ray_address: Annotated[
        str | None,
        typer.Option(
            help="a Ray cluster (HEAD_IP:6379; token authentication: docs/manual/cli.md) instead of a "
            "local Ray; each run takes its scenario and policy files along"
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help="the sweep folder (run again to resume)")] = Path("runs/sweep"),
    keep_fcd: Annotated[bool, typer.Option(help="keep each run's FCD and agents table in OUT/fcd/")] = False,
    quiet: QUIET = False,
    verbose: VERBOSE = False,
) -> None:
    """Populate runs over a grid (shares x seeds x policies x scenarios) in parallel on Ray: one row per
    run in <out>/sweep.csv and .parquet, the main figures against the share in sweep.png.
    -q: errors only; -v: the whole table with every figure."""
    level = verbosity(quiet, verbose)
    from behaviors.run.sweep import Grid, check_grid, resolve_net, resolve_policy, resolve_sumocfg, run_sweep

    if workers is not None:
        check_number("--workers", workers, low=1)
    check_number("--overtaker-fraction", overtaker_fraction, high=1)
    grid = Grid(
        sumocfgs=tuple(resolve_sumocfg(str(path)) for path in sumocfg or ()),
        nets=tuple(resolve_net(name) for name in net or ()),
        shares=parse_numbers("--share", share or "0", integer=False, high=1),  # type: ignore[arg-type]
        seeds=parse_numbers("--seeds", seeds, integer=True, high=SEED_MAX),  # type: ignore[arg-type]
        policies=tuple(resolve_policy(spec) for spec in policy or ("traffic",)),
        overtakers=parse_numbers("--overtakers", overtakers, integer=True),
        keepers=parse_numbers("--keepers", keepers, integer=True),
        background=background, overtaker_fraction=overtaker_fraction, duration=duration,
        step_length=step_length, shield=shield,
    )  # fmt: skip
    notes: list[str] = []
    points = check_grid(grid, notes)
    if sumocfg and share is None and overtakers is None and keepers is None:
        raise BehaveError(
            "--sumocfg needs --share: the fractions of the scenario's passenger cars the policy drives, "
            "e.g. 0,0.25,0.5 (0: SUMO's cars alone)"
        )
    for note in notes if level >= 0 else ():  # how a scenario runs otherwise than `sumo -c` would, and why
        typer.echo(f"sweep: note: {note}", err=True)
    result = run_sweep(
        points, out, workers=workers, address=ray_address, keep_fcd=keep_fcd,
        on_event=(lambda text: typer.echo(f"sweep: {text}", err=True)) if level >= 0 else None,
    )  # fmt: skip
    table = result.table
    if level >= 0:
        brief = [c for c in ("id", "status", "all_mean_speed", "sumo_mean_speed", "collisions") if c in table]
        shown = list(table.columns) if level > 0 else brief
        typer.echo(table[shown].to_string(index=False, float_format=lambda v: f"{v:.2f}"))
        for path in result.outputs:
            typer.echo(f"wrote {path}")
    failed = int((table["status"] != "ok").sum())
    if failed or result.lost:
        typer.echo(f"behave: {ending(len(points), failed, result.lost)}", err=True)
        raise typer.Exit(1)


def ending(runs: int, failed: int, lost: tuple[str, ...]) -> str:
    """The one line of a sweep that did not finish every run: the failed ones, the lost ones by id."""
    parts = [f"{failed} of {runs} runs failed (their error is in the table)"] if failed else []
    if lost:
        parts.append(
            f"{len(lost)} of {runs} runs lost with a Ray node that left the cluster ({', '.join(lost)}): "
            "the same command again runs them"
        )
    return "; ".join(parts)
