"""`behave scenario`: list the bundled road networks or regenerate them with netconvert."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from behaviors.cli.group import QuickHelpGroup
from sumo_scenarios import SCENARIO_NAMES, build_scenarios, get_scenario, scenario_info

app = typer.Typer(help="Road networks (SUMO scenarios): list them or rebuild them.", cls=QuickHelpGroup)


@app.command("list")
def list_scenarios() -> None:
    """Show each bundled scenario as read back from its generated net."""
    table = Table(title="behave scenarios")
    for column in ("name", "lanes", "length", "lane width", "edges", "looping", "description"):
        table.add_column(column)
    for name in SCENARIO_NAMES:
        scenario = get_scenario(name)
        info = scenario_info(scenario)
        table.add_row(
            info.name,
            info.lanes_text,
            f"{info.length_m:,.0f} m",
            f"{info.lane_width_m:.1f} m",
            str(info.edges),
            "yes" if info.looping else "no",
            scenario.description,
        )
    Console().print(table)


@app.command("build")
def build(
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Write <DIR>/<name>/ instead of the package's data/."),
    ] = None,
) -> None:
    """Regenerate the scenario networks (nodes/edges XML -> netconvert)."""
    start = time.perf_counter()
    scenarios = build_scenarios(out)
    for scenario in scenarios:
        typer.echo(f"{scenario.name}: {scenario.net}")
    typer.echo(f"built {len(scenarios)} scenarios in {time.perf_counter() - start:.1f} s")
