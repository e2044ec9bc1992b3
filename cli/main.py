"""The `behave` command line: thin commands that declare options and call the library.

Every user error surfaces as a BehaveError; `main` turns it into one line on
stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import sys

import typer

from behaviors.errors import BehaveError
from cli import evaluate, export, populate, report, scenario, train

app = typer.Typer(
    help="behave: learned, behaviour-based traffic in SUMO (PS-DDPG lane keepers and overtakers).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
app.add_typer(scenario.app, name="scenario")
app.command("train")(train.train)
app.command("populate")(populate.populate_command)
app.command("export")(export.export_command)
app.command("plot")(export.plot_command)
app.command("evaluate")(evaluate.evaluate_command)
app.command("report")(report.report_command)


def main() -> None:
    """Console-script entry point."""
    try:
        app()
    except BehaveError as exc:
        print(f"behave: error: {exc}", file=sys.stderr)
        sys.exit(2)
    except OSError as exc:  # a file the user named that cannot be read or written
        print(f"behave: error: {exc}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:  # outputs are atomic: nothing half-written is left behind
        print("behave: interrupted", file=sys.stderr)
        sys.exit(130)
