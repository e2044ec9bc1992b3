"""Cooperative: letting in a car whose lane ends or that asks for the agent's lane, zip fashion."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from behaviors.car.model import CarModel
from behaviors.traffic.law import FreeRoad, behind_leader
from behaviors.traffic.scene import LaneTraffic, ends_soon, look_ahead
from behaviors.traffic.settings import CarFollowing, LaneDriving


def yielding(
    free: FreeRoad,
    leader_gap: np.ndarray,
    leader_speed: np.ndarray,
    applies: np.ndarray,
    law: CarFollowing,
    lateral: LaneDriving,
) -> np.ndarray:
    """[N] the acceleration that keeps a car behind a leader it yields to (`law`: a courtesy
    headway) where `applies`, braking no harder than `safe_decel`; +inf elsewhere. `leader_speed`
    has no NaN."""
    if not applies.any():  # most steps: nobody to yield to (and no law to work out)
        return np.full(len(applies), np.inf)
    follow = behind_leader(free, np.where(applies, leader_gap, np.inf), leader_speed, law)
    return np.where(applies, np.maximum(follow, -lateral.safe_decel), np.inf)


def zipper_reach(closing: np.ndarray, courtesy: CarFollowing) -> np.ndarray:
    """[N] metres within which a car in a lane that ends is let in (`letting_in`) beyond the look-ahead:
    what dropping back behind it at the comfortable deceleration takes, closing at `closing` m/s,
    to `courtesy`'s standing gap. Within the look-ahead alone a car standing at the end of a dropped
    lane would ask more than `safe_decel` of every car coming up beside it at speed: each would pass
    it for the next one back, and none would let it in."""
    return closing**2 / (2.0 * courtesy.comfortable_decel) + courtesy.min_gap


def letting_in(
    traffic: LaneTraffic, lane_leads_on: np.ndarray, lateral: LaneDriving, asking: np.ndarray | None = None
) -> np.ndarray:
    """[N] the acceleration that lets a car merge in front, zip fashion (+inf where there is none):
    the nearest car ahead in a neighbour lane that ends within max(`ending_lane_m`, `ending_lane_s`
    at speed), and sooner than the own lane, or that asks to come over (`asking` [N, 2], fast side
    and slow side; None: nobody), as a car bound for an exit does, is followed as a leader where it
    is within `look_ahead` (one in a lane that ends, within `zipper_reach` too), would fit in front
    of the own leader (or, its lane ending, is being passed by an own leader faster by more than
    `pass_margin`: a car slowing to a stop at its lane's end is let in before the own leader has
    passed it and left it too near to brake for), and is not being closed on so fast that keeping
    clear of it takes more than `safe_decel`. The gap opens at the full headway (SUMO's drivers, who
    take the cars whose lane ends, move over only into a gap safe at their own 1 s) and the courtesy's
    standing gap, braking no harder than the law's comfortable deceleration unless keeping clear
    takes more. A car nearer than the standing gap, or alongside, is passed, as is one that would
    take harder braking: the next car back lets it in, so a through lane and an ending lane take
    turns. One alongside that asks, its front ahead of the car's, is dropped back for unless the car
    is closing on it, as SUMO's own drivers do. `lane_leads_on` [N, 3] metres (own, fast side, slow
    side)."""
    t = traffic
    soon = ends_soon(t.speed, lateral)
    law = lateral.following
    courtesy = replace(law, min_gap=law.min_gap + 1.0)
    reach = look_ahead(t.speed, lateral)
    own_room = t.gap[:, 0] - (CarModel.length + law.min_gap)  # the road a car let in takes up
    out = np.full(len(t.speed), np.inf)
    for column, lane in ((2, 1), (4, 2)):
        gap, ahead_speed = t.gap[:, column], t.known_speed[:, column]
        ending = (lane_leads_on[:, lane] < soon) & (lane_leads_on[:, lane] < lane_leads_on[:, 0])
        closing = np.maximum(t.speed - ahead_speed, 0.0)
        # one whose lane ends is looked for as far as dropping back behind it takes at the comfortable
        # deceleration: a car standing at its lane's end is seen in time to be let in (`zipper_reach`)
        seen = np.where(ending, np.maximum(reach, zipper_reach(closing, courtesy)), reach)
        # it fits in front of the own leader, or already reaches over the line and leads the car, or
        # its lane ends and the own leader, faster by more than `pass_margin`, is passing it
        passed = ending & (ahead_speed < t.known_speed[:, 0] - lateral.pass_margin)
        fits = (gap < own_room) | (gap == t.gap[:, 0]) | passed
        there = np.isfinite(t.other_speed[:, column]) & (gap < seen) & fits
        asks = np.zeros(len(gap), bool) if asking is None else asking[:, lane - 1]
        there &= (gap > law.min_gap) | asks  # one nearer (or alongside) is passed, unless it asks
        there &= ending | asks
        if not there.any():
            continue
        needed = closing**2 / (2.0 * np.maximum(gap - law.min_gap, 0.1))  # to keep clear of it
        there &= needed <= lateral.safe_decel
        # its being faster earns it no shorter gap: SUMO's driver wants the full one before it moves
        behind = behind_leader(
            t.free, np.where(there, gap, np.inf), np.minimum(ahead_speed, t.speed), courtesy
        )
        gentle = np.maximum(behind, -np.maximum(law.comfortable_decel, needed))
        out = np.minimum(out, np.where(there, gentle, np.inf))
    return out
