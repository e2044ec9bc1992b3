"""Locate the SUMO installation that the `eclipse-sumo` wheel brings.

Done lazily (never at import time) so importing behave has no side effects.
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path

from sumo_scenarios.errors import BehaveError


@cache
def sumo_home() -> Path:
    """The installed `sumo` package's home (it has bin/, tools/, data/), exported for tools.

    The wheel is preferred over an inherited SUMO_HOME: importing libsumo points SUMO_HOME
    at the `sumo_data` package, which has data/ but no binaries or tools.
    """
    try:
        import sumo  # the eclipse-sumo wheel
    except ImportError:
        home = os.environ.get("SUMO_HOME")
        if not home:
            raise BehaveError("SUMO is not installed: pip install eclipse-sumo") from None
        return Path(home)
    os.environ["SUMO_HOME"] = sumo.SUMO_HOME  # PROJ (geo output) and SUMO's tools read it
    return Path(sumo.SUMO_HOME)


def sumo_binary(name: str) -> str:
    """Path of a SUMO executable such as 'sumo' or 'netconvert'."""
    path = sumo_home() / "bin" / name
    if not path.exists():
        raise BehaveError(f"SUMO executable not found: {path}")
    return str(path)


def sumo_tool(relative: str) -> Path:
    """Path of a script under $SUMO_HOME/tools, e.g. 'traceExporter.py'."""
    path = sumo_home() / "tools" / relative
    if not path.exists():
        raise BehaveError(f"SUMO tool not found: {path}")
    return path
