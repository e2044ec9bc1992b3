"""Whether sumo-gui can open its window here: found before a run starts, not after."""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping

from behaviors.errors import BehaveError


def display_missing(environ: Mapping[str, str], platform: str) -> str | None:
    """Why sumo-gui could not open its window here, or None. sumo-gui draws through X11 (FOX) on
    Linux and macOS (XQuartz sets DISPLAY), so without DISPLAY it would fail once started."""
    if platform == "win32" or environ.get("DISPLAY"):
        return None
    return (
        "--gui needs a display, and DISPLAY is not set (sumo-gui opens an X11 window): run on a "
        "desktop or with X forwarding, or leave out --gui and watch with `behave animate`"
    )


def check_display() -> None:
    """BehaveError before anything runs if sumo-gui could not show a window."""
    reason = display_missing(os.environ, sys.platform)
    if reason is not None:
        raise BehaveError(reason)
