"""The agents' vTypes as TraCI setters, for a simulation behave joins that did not load behave's
vtypes file (sumo_scenarios.build.write_vtypes writes the same types as XML)."""

from __future__ import annotations

from typing import Any

from sumo_scenarios.build import LORRY_ACCEL, LORRY_SIZE, LORRY_TOP_SPEED, PASSENGER_DECEL, PASSENGER_MIN_GAP

BASE_VTYPE = "DEFAULT_VEHTYPE"
"""The vType the agents' types are copied from when the other simulation lacks them."""
AGENT_TYPE_SETTINGS: tuple[tuple[str, Any], ...] = (
    ("setVehicleClass", "passenger"), ("setLength", 5.0), ("setWidth", 1.8),
    ("setMinGap", PASSENGER_MIN_GAP), ("setMaxSpeed", 50.0), ("setSpeedFactor", 1.0),
    ("setSpeedDeviation", 0.0), ("setAccel", 3.0), ("setDecel", 7.5), ("setApparentDecel", PASSENGER_DECEL),
    ("setEmergencyDecel", 9.0), ("setImperfection", 0.0), ("setMaxSpeedLat", 5.0),
    ("setLateralAlignment", "center"),
)  # fmt: skip
"""sumo_scenarios.build.write_vtypes's agent vType as TraCI setters. Not set: its carFollowModel and
lcModel (TraCI cannot; the copy keeps the base type's, Krauss and, with sublanes, SL2015 unless the
other simulation changed its defaults), its lcAccelLat (set on each car as it becomes an agent) and
its actionStepLength of 1 s (`JoinedSim.agent_action_step`)."""
LORRY_TYPE_SETTINGS: tuple[tuple[str, Any], ...] = (
    ("setVehicleClass", "truck"), ("setLength", LORRY_SIZE[0]), ("setWidth", LORRY_SIZE[1]),
    ("setAccel", LORRY_ACCEL), ("setMaxSpeed", LORRY_TOP_SPEED),
)  # fmt: skip
"""What the learned lorry's vType sets on top of AGENT_TYPE_SETTINGS."""
AGENT_COLORS = {
    "behave_keeper": (0, 200, 0, 255),
    "behave_overtaker": (230, 120, 0, 255),
    "behave_lorry": (120, 60, 200, 255),
}
