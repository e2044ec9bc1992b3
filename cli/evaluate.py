"""`behave evaluate`: the paper's metrics for one or more policies across agent counts or placements."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from behaviors.cli.checks import NET, NON_NEGATIVE, POSITIVE, SEED, check_number
from behaviors.cli.progress import QUIET, VERBOSE, verbosity
from behaviors.errors import BehaveError
from behaviors.files import check_output_path


def evaluate_command(
    checkpoints: Annotated[
        list[Path] | None,
        typer.Argument(
            help="policies to compare: .pt files, training run directories or bundled names (traffic, ...); "
            "'rules': the traffic driver's rules with no network (behave populate --driver rules)"
        ),
    ] = None,
    agents: Annotated[str, typer.Option(help="agent counts to test, e.g. 3,5,7,10")] = "3,5,7,10,12,15,20",
    episodes: Annotated[int, typer.Option(help="episodes averaged per setting", callback=POSITIVE)] = 20,
    behaviour: Annotated[str | None, typer.Option(help="default: the checkpoint's own")] = None,
    overtakers: Annotated[
        int, typer.Option(help="overtakers (multi; 4 + 4 if neither)", callback=NON_NEGATIVE)
    ] = 0,
    keepers: Annotated[
        int, typer.Option(help="lane keepers (multi; 4 + 4 if neither)", callback=NON_NEGATIVE)
    ] = 0,
    placement: Annotated[str | None, typer.Option(help="multi cases, e.g. A,B,C")] = None,
    scenario: Annotated[
        str | None,
        typer.Option(
            help="ring, highway or tiny; traffic driver: roads, roads+ramps, roads+queues or ring "
            "[default: ring; roads for the traffic driver]"
        ),
    ] = None,
    max_steps: Annotated[int, typer.Option(help="steps per episode", callback=POSITIVE)] = 1000,
    seed: Annotated[int, typer.Option(help="makes the evaluation repeatable", callback=SEED)] = 0,
    baseline: Annotated[
        str | None, typer.Option(help="'sumo': SUMO's own drivers as a reference row")
    ] = None,
    opponents: Annotated[
        int | None,
        typer.Option(
            help="slower passive cars ahead (overtaking: default as many as agents)", callback=NON_NEGATIVE
        ),
    ] = None,
    net: Annotated[
        Path | None,
        typer.Option(
            help="traffic driver: evaluate on your .net.xml (or a bundled scenario's name) instead of "
            "--scenario, among SUMO's cars at densities drawn per episode",
            callback=NET,
        ),
    ] = None,
    sumocfg: Annotated[
        Path | None,
        typer.Option(help="traffic driver: evaluate in your .sumocfg instead, its routes being SUMO's cars"),
    ] = None,
    shield: Annotated[bool, typer.Option(help="drive through populate's safety shield")] = False,
    realism: Annotated[
        bool, typer.Option(help="record SUMO's FCD and write the realism report of each policy and setting")
    ] = True,
    out: Annotated[Path, typer.Option(help="directory for results.csv, results.md, metrics.png")] = Path(
        "runs/evaluate"
    ),
    quiet: QUIET = False,
    verbose: VERBOSE = False,
) -> None:
    """Average the paper's metrics over episodes for every policy and setting (-q: only the files
    and errors; -v: each setting's figures as it finishes)."""
    level = verbosity(quiet, verbose)
    from behaviors.report.realism_tracks import SKIP_S
    from behaviors.run.evaluate import (
        PAPER_METRICS,
        EvaluationOptions,
        placed_text,
        plan_evaluation,
        realism_markdown,
        road_label,
        run_plan,
        short_placements,
        write_report,
    )

    plan = plan_evaluation(EvaluationOptions(
        list(checkpoints or []), agents=parse_ints(agents), episodes=episodes, behaviour=behaviour,
        overtakers=overtakers, keepers=keepers, placements=parse_list(placement), scenario=scenario,
        seed=seed, max_steps=max_steps, baseline=baseline, opponents=opponents, shield=shield,
        net=None if net is None else net.resolve(), sumocfg=None if sumocfg is None else sumocfg.resolve(),
    ))  # fmt: skip
    console = Console(quiet=level < 0)
    seconds = max_steps * plan.settings[0][1].step_length
    if realism and seconds <= SKIP_S:
        console.print(f"no realism report: episodes of {seconds:g} s, and each car's first {SKIP_S:g} s are "
                      "left out", style="yellow")  # fmt: skip
        realism = False
    for name in ("results.csv", "results.md", "metrics.png", "realism_summary.csv"):  # unwritable: now
        check_output_path(out / name)
    results, realism_table = run_plan(
        plan,
        on_setting=lambda p, s: console.print(f"evaluating {p}: {s}", style="dim"),
        realism=out / "realism" if realism else None,
        on_result=(lambda row: console.print(setting_line(row), style="dim")) if level > 0 else None,
    )
    per = f"{episodes} episode{'' if episodes == 1 else 's'} per setting"
    table = Table(title=f"behave evaluate on {road_label(plan)} ({per})")
    columns = ["policy", "setting", *(m for m, _ in PAPER_METRICS), "off_tracks", "mean_speed_frac"]
    columns += [
        c for c in ("overtakes_per_agent", "overtaker_speed_frac", "keeper_speed_frac") if c in results
    ]
    for column in columns:
        table.add_column(
            column.replace("_", " "), justify="left" if column in ("policy", "setting") else "right"
        )
    for _, row in results.iterrows():
        cells = [row[c] if isinstance(row[c], str) else f"{row[c]:,.2f}" for c in columns]
        if row.get("agents_placed", row["agents"]) < row["agents"]:  # say so where not all started
            cells[1] += f"\n({placed_text(row)} started)"
        table.add_row(*cells)
    console.print(table)
    for line in short_placements(results):
        console.print(line, style="yellow", markup=False, highlight=False)
    if not realism_table.empty:
        console.print(f"\nRealism (full reports in {out / 'realism'}/<policy>/<setting>/):\n")
        console.print(realism_markdown(realism_table), markup=False, highlight=False)
    for path in write_report(results, out, realism_table):
        console.print(f"wrote {path}", markup=False, highlight=False)


def setting_line(row: dict) -> str:
    """A finished setting's figures, for -v."""
    figures = ", ".join(f"{SHORT.get(k, k)} {v:,.2f}" for k, v in row.items() if isinstance(v, float))
    return f"  {row['policy']} {row['setting']}: {figures}"


SHORT = {
    "reward_per_agent": "reward/agent",
    "progress_per_agent": "progress/agent",
    "colliding_steps_per_agent": "coll. steps/agent",
    "colliding_steps_pct": "% coll. steps",
    "off_tracks": "off-tracks",
    "mean_speed_frac": "speed/limit",
    "overtakes_per_agent": "overtakes/agent",
    "overtaker_speed_frac": "overtaker speed",
    "keeper_speed_frac": "keeper speed",
}


def parse_ints(text: str) -> list[int]:
    try:
        counts = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise BehaveError(f"--agents must be a comma-separated list of integers, got '{text}'") from None
    return [check_number("--agents", count, strict=True) for count in counts]


def parse_list(text: str | None) -> list[str] | None:
    return [part.strip() for part in text.split(",") if part.strip()] if text else None
