"""The motives that move a car to another lane or change its speed for one, each tied to its switch
in `Rules`: strategic (out of a lane that stops leading on, falling in behind the car beside to do
so), cooperative (letting in a car whose lane ends or that asks, zip fashion), speed gain (passing a
slower leader) and keeping right. `lane_wishes` gathers them into each car's lane wish."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from behaviors.car.model import CarModel
from behaviors.traffic.law import FreeRoad, behind_leader, nan_as
from behaviors.traffic.scene import LaneTraffic, Motion, RoadPlace, Scene, ends_soon, look_ahead
from behaviors.traffic.settings import CarFollowing, LaneDriving, LaneHabits


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


@dataclass(frozen=True)
class LaneWishes:
    """What the motives make of the policy's steer: the steer they leave, and what the lane choice
    (`intent.lane_wish`) weighs. `slow_side_free`/`held_up` None: no rule judges the lanes."""

    steer: np.ndarray  # [N] in [-1, 1]
    slow_side_free: np.ndarray | None  # [N] bool: keeping right moves the car there
    held_up: np.ndarray | None  # [N] bool: a wish for the fast side counts
    held_for: np.ndarray  # [N] s each car has been held up without a break


def lane_wishes(steer: np.ndarray, scene: Scene, habits: LaneHabits | None) -> LaneWishes:
    """The wishes as the rules of the road and the habits make them: keeping right where the slow
    side is free, passing a slower leader once patience runs out, and (with habits) the slow side
    the rules' alone. Where the network chooses, no rule wishes for a lane: every lane may be
    wished for and none is kept to."""
    n = len(steer)
    lateral = scene.lateral
    if lateral.network_chooses:
        return LaneWishes(steer, np.zeros(n, bool), np.ones(n, bool), np.zeros(n))
    rules, traffic = lateral.rules, scene.traffic
    free = slow_side_free(traffic, lateral, scene.place.lane_leads_on) if rules.keep_right else None
    if free is not None and habits is not None:
        free &= habits.overtakes
    margin, patient = (None, None) if habits is None else (habits.pass_margin, ~habits.overtakes)
    held = held_up(traffic, lateral, margin, patient) if rules.speed_gain else None
    waited = np.zeros(n)
    if held is not None:
        held_for = scene.motion.held_for
        waited = np.where(held, (0.0 if held_for is None else held_for) + scene.driver.dt, 0.0)
    if habits is not None and rules.keep_right:  # the slow side is the rules' alone
        steer = np.maximum(steer, 0.0)
    if habits is not None and held is not None:
        if free is not None:  # waiting to pass is no time to move right
            free &= ~held
        held = held & (waited >= habits.patience - 1e-9)
        steer = np.where(habits.overtakes & held, 1.0, steer)
    if rules.any:  # the rules judge the lanes: none is free or a reason where its rule is off
        free = np.zeros(n, bool) if free is None else free
        held = np.ones(n, bool) if held is None else held
    return LaneWishes(steer, free, held, waited)
