"""behave: learned, behaviour-based traffic in SUMO (PS-DDPG after Kaushik et al.)."""

from behaviors.env import BehaveEnv, EnvConfig, make_env
from behaviors.errors import BehaveError

__all__ = ["BehaveEnv", "BehaveError", "EnvConfig", "make_env"]
