"""The traffic driver's own per-agent rows: what it keeps between sensing and acting, and from step
to step, beside the fleet's rows (`AgentRows.own`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from behaviors.traffic.lanes import LaneAgents, Surroundings


def desired_speed(own: TrafficRows, speed_limit: np.ndarray) -> np.ndarray:
    """[N] m/s each agent wants here: its share of the local limit, never beyond its top speed."""
    return np.minimum(own.desired_fraction * speed_limit, own.top_speed)


@dataclass
class TrafficRows:
    """The traffic driver's own per-agent rows (taken and extended with the fleet's)."""

    desired_fraction: np.ndarray = field(default_factory=lambda: np.zeros(0))  # of the local speed limit
    top_speed: np.ndarray = field(default_factory=lambda: np.zeros(0))  # m/s never wanted beyond (a limiter)
    lateral_speed: np.ndarray = field(default_factory=lambda: np.zeros(0))  # + = fast side
    lateral_accel: np.ndarray = field(default_factory=lambda: np.zeros(0))  # + = fast side
    changing: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # see intent.lane_intent
    held_for: np.ndarray = field(default_factory=lambda: np.zeros(0))  # s held up without a break
    lane_number: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # -1 = not sensed yet
    lane_count: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lane_changed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # at the last sensing
    lane_ends: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # own/fast/slow, lane coords
    best_end: np.ndarray = field(default_factory=lambda: np.zeros(0))  # the edge's farthest-leading lane
    one_lane_at: np.ndarray = field(default_factory=lambda: np.zeros(0))  # route's next 1-lane road
    around: Surroundings | None = None  # leaders and followers at the last sensing
    lanes: LaneAgents | None = None  # the agents in their lanes at the last sensing
    asking: np.ndarray | None = None  # [N, 2] the fast-side, slow-side leader asks to come over (ditto)
    time_headway: np.ndarray = field(default_factory=lambda: np.zeros(0))  # s, the style's (StyledDriver)
    eagerness: np.ndarray = field(default_factory=lambda: np.zeros(0))  # to pass, the style's (StyledDriver)
    lane_bias: np.ndarray = field(default_factory=lambda: np.zeros(0))  # m off the lane centre (ditto)
