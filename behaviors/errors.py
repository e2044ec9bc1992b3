"""The one domain exception, `BehaveError`, under the name every behaviors module imports.

It is defined in sumo_scenarios.errors, so that sumo_scenarios raises it without importing
behaviors: imports run from behaviors to sumo_scenarios only.
"""

from sumo_scenarios.errors import BehaveError

__all__ = ["BehaveError"]
