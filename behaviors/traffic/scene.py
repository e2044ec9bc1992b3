"""What the traffic driver knows of its agents in one step, as named bundles: each agent's own
motion, its place in the lanes, its neighbours, the shield's bounds and its style; and the
`LaneTraffic` and `Scene` the motives and limits weigh, worked out from them once per step."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from behaviors.traffic.lanes import Surroundings
from behaviors.traffic.law import FreeRoad, behind_leader, free_road, nan_as, new_follower_accel
from behaviors.traffic.settings import CarFollowing, DriverSettings, LaneDriving, LaneHabits


@dataclass(frozen=True)
class Motion:
    """Each agent's own motion, as the driver carries it from one step to the next (+ = fast side)."""

    speed: np.ndarray  # [N] m/s
    desired_speed: np.ndarray  # [N] m/s
    lateral_speed: np.ndarray  # [N] m/s
    lateral_accel: np.ndarray  # [N] m/s^2
    changing: np.ndarray  # [N] int: the lane change under way (`intent.lane_intent`)
    held_for: np.ndarray | None = None  # [N] s held up so far, which patience must reach (None: 0)


@dataclass(frozen=True)
class RoadPlace:
    """Where each agent is: in its lane, on the carriageway and along its route. Sideways values are
    signed as SUMO's lane indices are (+ = fast side); `offset` and `half_width` are the carriageway's."""

    lane_offset: np.ndarray  # [N] m from the own lane's centre
    lane_width: np.ndarray  # [N] m
    lanes_fast: np.ndarray  # [N] lanes on the fast side of the own
    lanes_slow: np.ndarray  # [N] lanes on the slow side of the own
    offset: np.ndarray  # [N] m of the car's centre from the carriageway's centre
    half_width: np.ndarray  # [N] m: half the carriageway
    speed_limit: np.ndarray  # [N] m/s
    lane_leads_on: np.ndarray | None = None  # [N, 3] m the own, fast-side, slow-side lane lead on
    may_begin: np.ndarray | None = None  # [N] bool: a lane change may begin here (None: everywhere)


@dataclass(frozen=True)
class LaneNeighbours:
    """The cars around each agent as its driver weighs them: `gap`/`other_speed` [N, 6] in
    lanes.NEIGHBOUR_SLOTS order (gap +inf where nobody, 0 alongside or no lane; speed NaN where
    nobody); `far_fast_leader` ([N] gap, [N] speed; None: none) the nearest leader in a lane beyond
    the fast-side one; `lane_followers` ([N, 2] gap, speed; None: none) the nearest followers whose
    centres are in the fast-side and slow-side lanes (`limits.gap_acceptable`); `asking` ([N, 2]
    bool; None: nobody) whether the fast-side and slow-side leader wants to come over
    (`cooperative.letting_in`)."""

    gap: np.ndarray
    other_speed: np.ndarray
    far_fast_leader: tuple[np.ndarray, np.ndarray] | None = None
    lane_followers: tuple[np.ndarray, np.ndarray] | None = None
    asking: np.ndarray | None = None

    @classmethod
    def sensed(cls, around: Surroundings, asking: np.ndarray | None) -> LaneNeighbours:
        """The neighbours as the lane sensing (`lanes.surroundings`) found them."""
        return cls(
            around.gap,
            around.other_speed,
            (around.far_fast_gap, around.far_fast_speed),
            (around.lane_follower_gap, around.lane_follower_speed),
            asking,
        )


@dataclass(frozen=True)
class AgentStyle:
    """How each agent drives within the rules; None: as the settings say for all."""

    habits: LaneHabits | None = None  # who passes unasked, at what margin, after what patience
    time_headway: np.ndarray | None = None  # [N] s each car follows its leaders at (not its followers)
    lane_bias: np.ndarray | None = None  # [N] m from the lane's centre line towards the fast side


SETTINGS_STYLE = AgentStyle()
"""Every agent as the settings say: no habits, the law's headway, on the lane's centre line."""


@dataclass(frozen=True)
class LaneTraffic:
    """Each car and its six neighbours (lanes.NEIGHBOUR_SLOTS) as the rules of `actuate_lanes` weigh
    them, with the accelerations several rules share worked out once per step (the fast- and
    slow-side leaders serve both the gap check and the lane the car heads for, the slow-side
    follower both the gap check and keeping right)."""

    speed: np.ndarray  # [N] m/s
    desired_speed: np.ndarray  # [N] m/s
    gap: np.ndarray  # [N, 6] bumper to bumper: +inf nobody, 0 alongside or no lane
    other_speed: np.ndarray  # [N, 6] m/s, NaN where nobody is
    known_speed: np.ndarray  # [N, 6] other_speed with NaN as 0 (a missing lane is a standing wall)
    free: FreeRoad  # the car's own terms of the car-following law
    lead_accel: np.ndarray  # [N, 3] behind the leader in the own, fast-side and slow-side lane
    follower_accel: np.ndarray  # [N, 2] the new follower's in the fast-side and slow-side lane


def lane_traffic(
    speed: np.ndarray, desired_speed: np.ndarray, gap: np.ndarray, other_speed: np.ndarray, law: CarFollowing
) -> LaneTraffic:
    """The cars' LaneTraffic; `gap`/`other_speed` [N, 6] in lanes.NEIGHBOUR_SLOTS order. The three
    leaders, and the two followers, are one law call each on [k, N] rows (the per-car terms
    broadcast along them): the same arithmetic per car as a call per column, in a third of the calls."""
    known = nan_as(other_speed, 0.0)
    free = free_road(speed, desired_speed, law)
    gap_rows, known_rows = gap.T, known.T
    lead = behind_leader(free, gap_rows[[0, 2, 4]], known_rows[[0, 2, 4]], law).T
    follower = new_follower_accel(speed, gap_rows[[3, 5]], known_rows[[3, 5]], law).T
    return LaneTraffic(speed, desired_speed, gap, other_speed, known, free, lead, follower)


def own_lane_traffic(
    motion: Motion, neighbours: LaneNeighbours, law: CarFollowing, time_headway: np.ndarray | None
) -> LaneTraffic:
    """The agents' LaneTraffic, each following its leaders at its own `time_headway` where given
    (None: the law's); its new followers keep the law's."""
    traffic = lane_traffic(motion.speed, motion.desired_speed, neighbours.gap, neighbours.other_speed, law)
    if time_headway is None:
        return traffic
    own_law = replace(law, time_headway=time_headway)  # type: ignore[arg-type]
    leaders = behind_leader(
        traffic.free, neighbours.gap[:, [0, 2, 4]].T, traffic.known_speed[:, [0, 2, 4]].T, own_law
    )
    return replace(traffic, lead_accel=leaders.T)


def ends_soon(speed: np.ndarray, lateral: LaneDriving) -> np.ndarray:
    """[N] metres: a lane that stops leading on within max(`ending_lane_m`, `ending_lane_s` at speed)
    ends soon (no change goes into it; a car in it is let in)."""
    return np.maximum(lateral.ending_lane_m, lateral.ending_lane_s * speed)


def look_ahead(speed: np.ndarray, lateral: LaneDriving) -> np.ndarray:
    """[N] metres within which a leader counts for the rules of the road: max(`free_ahead`,
    `free_ahead_s` at speed)."""
    return np.maximum(lateral.free_ahead, lateral.free_ahead_s * speed)


@dataclass(frozen=True)
class Scene:
    """One step's agents as the motives and limits weigh them: the bundles, their LaneTraffic, the
    side each car must leave its ending lane to (`strategic.leaving_lane`) and the law's acceleration
    behind the leader of a lane its body reaches into (`limits.reaching_over`)."""

    traffic: LaneTraffic
    motion: Motion
    place: RoadPlace
    neighbours: LaneNeighbours
    driver: DriverSettings
    leave: np.ndarray | None  # [N] +1 fast side, -1 slow side, 0 stays; None: the rule is off
    reaching: np.ndarray  # [N] m/s^2, +inf where it does not reach over (or the rule is off)

    @property
    def lateral(self) -> LaneDriving:
        return self.driver.lateral

    @cached_property
    def leaving(self) -> np.ndarray | None:
        """[N, 2] bool: the car leaves its ending lane to the fast side, the slow side."""
        return None if self.leave is None else self.leave[:, None] == np.array([1, -1])


def lane_clear(traffic: LaneTraffic, column: int, lateral: LaneDriving) -> np.ndarray:
    """[N] bool: the leader in a neighbour lane (`column` of the traffic's slots) would not come
    within `look_ahead` for `keep_right_catch_up_s`, at the speed the car wants (a driver does not
    change lanes only to be held up again; judged at its own speed, a car slowed down behind a leader
    would find the lane beside free as soon as that leader dropped back, and move back and forth
    across the line)."""
    t = traffic
    wanted = np.maximum(t.speed, t.desired_speed)
    closing = np.maximum(wanted - nan_as(t.other_speed[:, column], np.inf), 0.0)
    return t.gap[:, column] > look_ahead(t.speed, lateral) + closing * lateral.keep_right_catch_up_s
