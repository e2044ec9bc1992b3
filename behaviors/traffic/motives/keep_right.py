"""Keep right: with no other wish, a car moves to a slow-side lane that is free."""

from __future__ import annotations

import numpy as np

from behaviors.traffic.scene import LaneTraffic, lane_clear
from behaviors.traffic.settings import LaneDriving


def slow_side_free(
    traffic: LaneTraffic, lateral: LaneDriving, lane_leads_on: np.ndarray | None = None
) -> np.ndarray:
    """[N] bool: the slow-side lane is clear (`lane_clear`),
    nobody behind there who would have to brake for the car moving in (`polite_decel`): keeping
    right is no reason to cut in; and that lane leads on along the route as far as the own one does
    and at least `keep_right_reach` (an exit, a lane drop or an acceleration lane is not kept to).
    Gap 0 in `traffic`: no lane, or alongside; `lane_leads_on` [N, 3] metres (own, fast side, slow
    side), None: every lane leads on."""
    t = traffic
    clear = lane_clear(t, 4, lateral)
    free = clear & (t.gap[:, 5] > 0) & (t.follower_accel[:, 1] >= -lateral.polite_decel)
    if lane_leads_on is not None:
        slow = lane_leads_on[:, 2]
        free &= (slow >= lane_leads_on[:, 0]) & (slow >= lateral.keep_right_reach)
    return free
