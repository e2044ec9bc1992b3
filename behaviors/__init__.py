"""behave: learned, behaviour-based traffic in SUMO (PS-DDPG after Kaushik et al.).

The env names are loaded on first use: every `behave` command imports this package, and
behaviors.learn.env (numpy, gymnasium, libsumo) would add ~0.4 s to each, `behave --help` included.
"""

from __future__ import annotations

import importlib
from typing import Any

from behaviors.errors import BehaveError

_LAZY = {
    "BehaveEnv": "behaviors.learn.env",
    "EnvConfig": "behaviors.learn.env",
    "make_env": "behaviors.learn.env",
}

__all__ = ["BehaveEnv", "BehaveError", "EnvConfig", "make_env"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'behaviors' has no attribute {name!r}")
