"""The command group every `behave` app uses: `--help` of a subcommand answers without pydantic."""

from __future__ import annotations

import typer
from typer import _click as click


class QuickHelpGroup(typer.core.TyperGroup):
    """typer coerces an absent `--help` flag (None) of a group through pydantic, about 0.3 s of imports
    before `behave CMD --help` can answer: the flag defaults to False, a bool, which typer passes as is."""

    def get_help_option(self, ctx: click.Context) -> typer.core.TyperOption | None:
        option = super().get_help_option(ctx)
        if option is not None and option.default is None:
            option.default = False
        return option
