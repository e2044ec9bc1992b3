"""Strategic: out of a lane that stops leading on along the route, falling in behind the car beside
to do so."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from behaviors.traffic.motives.cooperative import yielding
from behaviors.traffic.scene import LaneTraffic, Motion, RoadPlace, ends_soon
from behaviors.traffic.settings import LaneDriving


def leaving_lane(motion: Motion, place: RoadPlace, lateral: LaneDriving) -> np.ndarray | None:
    """[N] the side a car whose own lane stops leading on within max(`leave_ending_m`,
    `leave_ending_s` at speed) moves out to early, before SUMO would take it: +1 the fast side where
    that lane leads on, else -1 the slow side where it does, 0 none (None: the rule is off, or no
    lane's end is known)."""
    leads_on = place.lane_leads_on
    if leads_on is None or not lateral.rules.leave_ending_lane:
        return None
    soon = ends_soon(motion.speed, lateral)
    leave_within = np.maximum(lateral.leave_ending_m, lateral.leave_ending_s * motion.speed)
    ending = leads_on[:, 0] < leave_within
    leave = np.where(ending & (leads_on[:, 1] >= soon), 1, 0)
    return np.where(ending & (leave == 0) & (leads_on[:, 2] >= soon), -1, leave)


def falling_in(traffic: LaneTraffic, waiting: np.ndarray, lateral: LaneDriving) -> np.ndarray:
    """[N] the acceleration of a car that must leave its ending lane (`waiting` [N]: +1 to the fast
    side, -1 to the slow side, 0 not waiting) and has no gap yet: it falls in behind the nearest car
    ahead of or alongside it in that lane, as the car the through lane lets in does, braking no harder
    than `safe_decel` (+inf where it is not waiting): matching the speed of the platoon beside it, a
    car would reach the end of its lane still alongside."""
    t = traffic
    rows = np.arange(len(t.speed))
    column = np.where(waiting > 0, 2, 4)
    leader_gap, leader_speed = t.gap[rows, column], t.other_speed[rows, column]
    applies = (waiting != 0) & np.isfinite(leader_speed) & np.isfinite(leader_gap)
    courtesy = replace(lateral.following, time_headway=lateral.let_in_headway)
    return yielding(t.free, leader_gap, t.known_speed[rows, column], applies, courtesy, lateral)
