"""behave: learned, behaviour-based traffic in SUMO (PS-DDPG after Kaushik et al.).

The public names are loaded on first use, so `import behaviors` stays light and
`sumo_scenarios` can use `behaviors.errors` without an import cycle.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "BehaveEnv": "behaviors.env",
    "EnvConfig": "behaviors.env",
    "make_env": "behaviors.env",
    "BehaveError": "behaviors.errors",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'behaviors' has no attribute {name!r}")
