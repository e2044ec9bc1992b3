"""Numeric command-line options, checked at the edge the same way for every command.

Each numeric option names its range through one of the callbacks below; a value that is
not finite or out of range ends in one line (`behave: error: --x must be ...`), exit 2,
before any work starts.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import typer

from behaviors.errors import BehaveError
from sumo_scenarios import SCENARIO_NAMES, get_scenario

N = TypeVar("N", int, float)

SEED_MAX = 2**31 - 1
"""SUMO and numpy take seeds up to a signed 32-bit int."""


def check_number(
    name: str, value: N, *, low: float = 0.0, strict: bool = False, high: float | None = None
) -> N:
    """`value` if finite and in range (above `low`, or at least `low`; at most `high`), else a BehaveError."""
    above = value > low if strict else value >= low
    if math.isfinite(value) and above and (high is None or value <= high):
        return value
    bound = f"{'>' if strict else '>='} {low:g}" + (f" and <= {high:.0f}" if high is not None else "")
    raise BehaveError(f"{name} must be a finite number {bound}, got {value}")


def number(*, low: float = 0.0, strict: bool = False, high: float | None = None) -> Callable[..., N | None]:
    """A typer callback applying `check_number` to its option (None, an unset optional, passes)."""

    def callback(param: typer.CallbackParam, value: N | None) -> N | None:
        if value is None:
            return None
        return check_number(param.opts[0], value, low=low, strict=strict, high=high)

    return callback


POSITIVE = number(strict=True)
"""Counts and lengths that cannot be zero: durations, steps, intervals, sizes."""
NON_NEGATIVE = number()
"""Counts that may be zero: agents of one kind, background cars, budgets."""
SEED = number(high=SEED_MAX)


def net_or_name(ctx: typer.Context, param: typer.CallbackParam, value: Path | None) -> Path | None:
    """`--net`: a SUMO net file or a bundled scenario's name (`behave scenario list`: `--net motorway`).

    A .sumocfg is a whole scenario, not a net: the error points to the command's --sumocfg, or to
    populate's for a command without one.
    """
    if value is None:
        return None
    option = param.opts[0]
    if value.suffix == ".sumocfg":
        takes_sumocfg = any(p.name == "sumocfg" for p in ctx.command.params)
        run = (
            f"pass it as --sumocfg {value}"
            if takes_sumocfg
            else f"run it with `behave populate --sumocfg {value}`"
        )
        raise BehaveError(f"{option} {value} is a SUMO configuration, not a network: {run}")
    if value.exists() or value.suffix or value.parent != Path("."):
        return value
    if value.name in SCENARIO_NAMES:
        return get_scenario(value.name).net
    raise BehaveError(
        f"{option} {value}: no such file and no bundled scenario of that name "
        f"(give a .net.xml or one of {', '.join(SCENARIO_NAMES)})"
    )


NET = net_or_name
"""The callback of every `--net` option."""
