"""Speed gain: the fast side is worth wishing for once a slower leader holds the car up."""

from __future__ import annotations

import numpy as np

from behaviors.traffic.law import nan_as
from behaviors.traffic.scene import LaneTraffic, lane_clear, look_ahead
from behaviors.traffic.settings import LaneDriving


def held_up(
    traffic: LaneTraffic,
    lateral: LaneDriving,
    pass_margin: np.ndarray | float | None = None,
    once_slowed: np.ndarray | None = None,
) -> np.ndarray:
    """[N] bool: a leader within `look_ahead` drives slower than the car wants by more than
    `pass_margin` (m/s, per agent; None: `lateral.pass_margin`), and the fast-side lane is better:
    clear (`lane_clear`), or its leader faster than the own one by as much. The reason to move to
    the fast side. Cars `once_slowed` [N] bool (None: none) count as held up only once that leader
    has slowed them down by the margin: they wait and see, as a lane keeper behind a car coming on
    from a ramp does while it speeds up."""
    t = traffic
    margin = lateral.pass_margin if pass_margin is None else pass_margin
    near = np.isfinite(t.gap[:, 0]) & (t.gap[:, 0] < look_ahead(t.speed, lateral))
    lead_speed = nan_as(t.other_speed[:, 0], np.inf)
    fast_speed = nan_as(t.other_speed[:, 2], np.inf)
    better = lane_clear(t, 2, lateral) | (fast_speed > lead_speed + margin)
    held = near & (lead_speed < t.desired_speed - margin) & better
    if once_slowed is not None:
        held &= ~once_slowed | (t.speed < t.desired_speed - margin)
    return held
