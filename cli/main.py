"""The `behave` command line: thin commands that declare options and call the library.

Every user error surfaces as a BehaveError; `main` turns it into one line on
stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import functools
import signal
import sys
from typing import Annotated, NoReturn

import typer
from typer import _click as click

from behaviors.cli import animate, evaluate, export, policy, populate, report, scenario, sweep, train
from behaviors.cli.group import QuickHelpGroup
from behaviors.errors import BehaveError

app = typer.Typer(
    help="behave: learned, behaviour-based traffic in SUMO (PS-DDPG lane keepers and overtakers).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    cls=QuickHelpGroup,
    rich_markup_mode=None,  # plain help: rich's help renderer alone takes ~0.3 s to import
)
app.add_typer(scenario.app, name="scenario")
app.add_typer(policy.app, name="policy")
app.command("train")(train.train)
app.command("populate")(populate.populate_command)
app.command("export")(export.export_command)
app.command("plot")(export.plot_command)
app.command("animate")(animate.animate_command)
app.command("evaluate")(evaluate.evaluate_command)
app.command("report")(report.report_command)
app.command("sweep")(sweep.sweep_command)


def _print_version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            typer.echo(f"behave {version('behave-traffic')}")
        except PackageNotFoundError:  # run from a checkout that was never installed
            typer.echo("behave (not installed: version unknown)")
        raise typer.Exit()


@app.callback()
def _options(
    show_version: Annotated[
        bool,
        typer.Option("--version", help="print the version and exit", is_eager=True, callback=_print_version),
    ] = False,
) -> None:
    pass


EXIT_CODES: dict[int, int] = {signal.SIGINT: 130, signal.SIGTERM: 143}
"""Exit codes of a run stopped by a signal (128 + its number, as a shell reports a killed one)."""


def main() -> None:
    """Console-script entry point: every failure ends in one line on stderr and a non-zero exit."""
    stopped_by: list[int] = []
    signal.signal(signal.SIGTERM, functools.partial(_interrupt, stopped_by))
    try:
        code = app(standalone_mode=False)  # typer turns Ctrl-C into exit code 130
    except (BehaveError, OSError) as exc:  # OSError: a file the user named that cannot be read or written
        fail(str(exc))
    except click.exceptions.ClickException as exc:  # usage errors, as one line
        if not exc.format_message():  # no arguments: the help was shown
            sys.exit(exc.exit_code)
        fail(exc.format_message(), exc.exit_code)
    except typer.Abort:
        code = 130
    if code == 130:  # outputs are atomic and temp files removed: nothing half-written is left
        signum = stopped_by[0] if stopped_by else signal.SIGINT
        fail(f"{'terminated' if signum == signal.SIGTERM else 'interrupted'}; nothing was left half-written",
             EXIT_CODES[signum])  # fmt: skip
    sys.exit(code if isinstance(code, int) else 0)


def _interrupt(stopped_by: list[int], signum: int, frame: object) -> None:
    """SIGTERM stops like Ctrl-C: the exception unwinds through every cleanup on its way out."""
    stopped_by.append(signum)
    raise KeyboardInterrupt


def fail(message: str, code: int = 2) -> NoReturn:
    print(f"behave: error: {message}", file=sys.stderr)
    sys.exit(code)
