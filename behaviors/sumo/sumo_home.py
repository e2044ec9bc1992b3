"""Where SUMO is installed, under the name behaviors modules import; defined in
sumo_scenarios.sumo_home (the scenario builders run netconvert without importing behaviors)."""

from sumo_scenarios.sumo_home import sumo_binary, sumo_home, sumo_tool

__all__ = ["sumo_binary", "sumo_home", "sumo_tool"]
