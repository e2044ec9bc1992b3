"""Numeric command-line options, checked at the edge the same way for every command.

Each numeric option names its range through one of the callbacks below; a value that is
not finite or out of range ends in one line (`behave: error: --x must be ...`), exit 2,
before any work starts.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TypeVar

import typer

from behaviors.errors import BehaveError

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
