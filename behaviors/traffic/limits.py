"""The limits of the traffic driver, as ordered lists of named limits, each tied to its switch in
`Rules` (or always on): lane vetoes close a neighbour lane to a change, speed bounds cap the
acceleration the policy may push to. Limits only forbid; the motives (motives/) choose, and the
two that choose a speed, letting in and falling in, do it by a bound here. The composition
(`actuation.actuate_lanes`) applies them in this order and says, per limit, which agents it vetoed
or bound (`LIMIT_NAMES`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from behaviors.traffic.law import behind_leader, nan_as, new_follower_accel
from behaviors.traffic.motives.cooperative import letting_in
from behaviors.traffic.motives.strategic import falling_in
from behaviors.traffic.scene import LaneTraffic, Motion, RoadPlace, Scene, ends_soon
from behaviors.traffic.settings import DriverSettings, LaneDriving, Rules


def gap_acceptable(
    traffic: LaneTraffic,
    lateral: LaneDriving,
    merging: np.ndarray | None = None,
    lane_followers: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """[N, 2] bool: whether the fast-side (column 0) and slow-side (column 1) lane have room to
    change into, as a driver checks it: nobody alongside, and neither the new leader nor the new
    follower would make the car or its follower brake harder than `safe_decel` (the safety
    criterion of MOBIL, Kesting, Treiber and Helbing 2007), nor would a faster new follower come
    alongside within `change_time` (a follower that sees the car only once it is over the line,
    as an agent does, may not brake in time), nor be nearer behind than `lag_headway` at its speed.
    Gap 0 in `traffic`: alongside, or no lane. Where `merging` [N, 2] (a car whose lane ends,
    towards the side it leaves to), the car's own braking and the follower's lag are judged at
    `let_in_headway`, the gap it falls in to: by the full headway no gap behind a car beside it at
    its own speed is ever room, and the car stands at the end of its lane.

    `lane_followers` ([N, 2] gap and speed, NaN where nobody; None: none) are the nearest followers
    whose centres are in the fast-side and slow-side lane, held to the same terms: the follower
    slots count a car in every lane its body overlaps, so a slow car just over the line behind would
    hide a fast one coming up in that lane."""
    t, law = traffic, lateral.following
    out = np.zeros((len(t.speed), 2), bool)
    courtesy = replace(law, time_headway=lateral.let_in_headway)
    leaving = np.zeros((len(t.speed), 2), bool) if merging is None else merging
    for side, lead in enumerate((2, 4)):
        own = t.lead_accel[:, side + 1]
        if leaving[:, side].any():
            behind = behind_leader(t.free, t.gap[:, lead], t.known_speed[:, lead], courtesy)
            own = np.where(leaving[:, side], behind, own)
        out[:, side] = (t.gap[:, lead] > 0) & (own >= -lateral.safe_decel)
    lag = np.where(leaving, lateral.let_in_headway, lateral.lag_headway)
    out &= follower_room(t.speed, t.gap[:, [3, 5]], t.known_speed[:, [3, 5]], t.follower_accel, lag, lateral)
    if lane_followers is not None:  # where the slots hold another, nearer car than these
        hidden = np.flatnonzero((lane_followers[0] != t.gap[:, [3, 5]]).any(axis=1))
        if len(hidden):
            gap, known = lane_followers[0][hidden], nan_as(lane_followers[1][hidden], 0.0)
            theirs = new_follower_accel(t.speed[hidden], gap.T, known.T, law).T
            out[hidden] &= follower_room(t.speed[hidden], gap, known, theirs, lag[hidden], lateral)
    return out


def follower_room(
    speed: np.ndarray,
    gap: np.ndarray,
    follower_speed: np.ndarray,
    follower_accel: np.ndarray,
    lag: np.ndarray,
    lateral: LaneDriving,
) -> np.ndarray:
    """[N, 2] bool: a new follower `gap` metres behind at `follower_speed` (0 where nobody), which
    would brake at `follower_accel` for the car, leaves room for the change (`gap_acceptable`): no
    harder braking than `safe_decel`, not alongside within `change_time`, not nearer than `lag` [N, 2]
    seconds at its speed."""
    closing = np.maximum(follower_speed - speed[:, None], 0.0)
    room = np.maximum(closing * lateral.change_time, lag * follower_speed)
    return (follower_accel >= -lateral.safe_decel) & (gap > lateral.following.min_gap + room)


def lanes_lead_on(scene: Scene) -> np.ndarray | None:
    """[N, 2] bool: the fast-side and slow-side lane lead on beyond `ends_soon` and, unless the own
    lane ends, no less than `shorter_lane_m` short of the own one (a weave's, an exit's lane): no
    change into a lane SUMO would take the car right back out of (None: no lane's end is known)."""
    leads_on, lateral = scene.place.lane_leads_on, scene.lateral
    if leads_on is None:
        return None
    soon = ends_soon(scene.motion.speed, lateral)
    shorter = leads_on[:, 1:] < leads_on[:, :1] - lateral.shorter_lane_m
    leaving = scene.leaving
    return (leads_on[:, 1:] >= soon[:, None]) & (~shorter | (False if leaving is None else leaving))


def gap_room(scene: Scene) -> np.ndarray:
    """[N, 2] bool: `gap_acceptable` for the scene's cars, a car leaving its ending lane judged as one
    that falls in."""
    return gap_acceptable(scene.traffic, scene.lateral, scene.leaving, scene.neighbours.lane_followers)


def lost_gap(motion: Motion, place: RoadPlace, open_lanes: np.ndarray) -> np.ndarray:
    """[N] bool: a change under way whose lane is no longer open before the car crosses the line (a
    car came up alongside, or one of two cars crossing paths): it is given up."""
    changing = motion.changing
    before_line = changing * place.lane_offset >= 0.0
    lost = ~open_lanes[np.arange(len(changing)), np.where(changing > 0, 0, 1)]
    return (changing != 0) & before_line & lost


def reaching_over(
    traffic: LaneTraffic, lane_offset: np.ndarray, lateral_speed: np.ndarray, lane_width: np.ndarray,
    car_width: float,
) -> np.ndarray:  # fmt: skip
    """[N] m/s^2: behind the leader of each neighbour lane the car's body reaches into while it is not
    moving away from that lane (np.inf where there is none, or nobody ahead there). A car that gives
    up a lane change drifts on sideways while its lateral speed comes down: it keeps behind that
    lane's leader until it turns back, or it runs into it. A car moving away from a lane, as one
    that has just passed into the next lane beside a slower car, does not: bound by that car too,
    every pass would slow down. A car alongside there (gap 0) is no leader: moving back is the answer
    to it, not full braking; where there is no lane, the gap is 0 too."""
    half_room = (lane_width - car_width) / 2
    over = np.stack([
        (lane_offset > half_room) & (lateral_speed >= 0.0),
        (lane_offset < -half_room) & (lateral_speed <= 0.0),
    ], 1)  # fmt: skip
    ahead = traffic.gap[:, [2, 4]] > 0
    return np.min(np.where(over & ahead, traffic.lead_accel[:, 1:], np.inf), axis=1)


def reaching_accel(
    traffic: LaneTraffic, motion: Motion, place: RoadPlace, driver: DriverSettings
) -> np.ndarray:
    """[N] m/s^2: `reaching_over` where its rule is on, or no rule is (the bare law keeps behind such
    a leader too); +inf elsewhere."""
    rules = driver.lateral.rules
    if not rules.reaching_over and rules.any:
        return np.full(len(motion.speed), np.inf)
    return reaching_over(traffic, place.lane_offset, motion.lateral_speed, place.lane_width, driver.car.width)


def not_undertaking(
    traffic: LaneTraffic, lateral: LaneDriving, far_fast_leader: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """[N] the acceleration that keeps behind the fast-side lane's leader and `far_fast_leader`
    ([N] gap, [N] speed: the nearest in the lanes beyond; None: none) while they drive faster than
    `no_undertaking_above` (+inf where there is none, or they are slower: passing on the slow side is
    allowed in a queue). The car may close up beside them, so the gap kept is short."""
    t = traffic
    gaps, speeds = [t.gap[:, 2]], [t.known_speed[:, 2]]
    if far_fast_leader is not None:
        gaps.append(far_fast_leader[0])
        speeds.append(nan_as(far_fast_leader[1], 0.0))
    gap, speed_ahead = np.stack(gaps), np.stack(speeds)  # [k, N]: one law call for both leaders
    applies = np.isfinite(gap) & (gap > 0) & (speed_ahead > lateral.no_undertaking_above)
    if not applies.any():
        return np.full(len(t.speed), np.inf)
    diagonal = replace(lateral.following, time_headway=lateral.diagonal_headway, min_gap=0.0)
    behind = behind_leader(t.free, np.where(applies, gap, np.inf), speed_ahead, diagonal)
    return np.where(applies, behind, np.inf).min(axis=0)


def toward(traffic: LaneTraffic, heading: np.ndarray) -> np.ndarray:
    """[N] m/s^2: behind the leader of the lane each car heads for (`intent.lane_intent`)."""
    column = np.where(heading > 0, 1, np.where(heading < 0, 2, 0))
    return traffic.lead_accel[np.arange(len(heading)), column]


def target_leader(scene: Scene, heading: np.ndarray) -> np.ndarray:
    """[N] m/s^2: during a change, behind the leader of the lane the car heads for, as a driver who
    moves over follows it (+inf where no change is under way)."""
    return np.where(heading != 0, toward(scene.traffic, heading), np.inf)


def reaching_leader(scene: Scene, heading: np.ndarray) -> np.ndarray:
    """[N] m/s^2: `reaching_over`, worked out once per step with the law (`Scene.reaching`)."""
    return scene.reaching


def undertaking_leader(scene: Scene, heading: np.ndarray) -> np.ndarray:
    """[N] m/s^2: `not_undertaking` of the fast-side lane's leader and the one beyond it."""
    return not_undertaking(scene.traffic, scene.lateral, scene.neighbours.far_fast_leader)


def merging_car(scene: Scene, heading: np.ndarray) -> np.ndarray | None:
    """[N] m/s^2: `letting_in` for a car that keeps its lane (one on its way to another lane leaves
    letting in to the next one back); None where no lane's end is known."""
    leads_on = scene.place.lane_leads_on
    if leads_on is None:
        return None
    let_in = letting_in(scene.traffic, leads_on, scene.lateral, scene.neighbours.asking)
    return np.where(heading == 0, let_in, np.inf)


def falling_behind(scene: Scene, heading: np.ndarray) -> np.ndarray | None:
    """[N] m/s^2: `falling_in` for a car that must leave its ending lane and has not begun to (None:
    no car must)."""
    if scene.leave is None:
        return None
    return falling_in(scene.traffic, np.where(heading == 0, scene.leave, 0), scene.lateral)


def min_headway(scene: Scene, heading: np.ndarray) -> np.ndarray:
    """[N] m/s^2: the law at `min_time_headway` behind the own leader, which the policy's push may not
    pass (it lies above the law's own: it only limits a push)."""
    lateral, traffic = scene.lateral, scene.traffic
    closest = replace(lateral.following, time_headway=lateral.min_time_headway)
    return behind_leader(traffic.free, traffic.gap[:, 0], traffic.known_speed[:, 0], closest)


@dataclass(frozen=True)
class LaneVeto:
    """A limit that closes neighbour lanes to a change."""

    name: str
    rule: str | None  # its switch in `Rules`; None: always on
    opens: Callable[[Scene], np.ndarray | None]  # [N, 2] bool: fast-side, slow-side lane open (None: both)


@dataclass(frozen=True)
class SpeedBound:
    """A limit that caps the acceleration, given the lane each car heads for."""

    name: str
    rule: str | None  # its switch in `Rules`; None: always on
    bound: Callable[[Scene, np.ndarray], np.ndarray | None]  # [N] m/s^2 (None: no bound)


LANE_VETOES = (
    LaneVeto("gap_acceptable", None, gap_room),
    LaneVeto("avoid_ending_lanes", "avoid_ending_lanes", lanes_lead_on),
)
"""Checked before a change begins; `give_up_lost_gap` (`lost_gap`) then ends a change under way whose
lane they close."""
GIVE_UP = "give_up_lost_gap"
SPEED_BOUNDS = (
    SpeedBound("target_leader", "target_leader", target_leader),
    SpeedBound("reaching_over", "reaching_over", reaching_leader),
    SpeedBound("no_undertaking", "no_undertaking", undertaking_leader),
    SpeedBound("letting_in", "letting_in", merging_car),
    SpeedBound("falling_in", "falling_in", falling_behind),
    SpeedBound("no_tailgating", "no_tailgating", min_headway),
)
"""Bound the policy's push once the lane each car heads for is known (with any rule on)."""
LIMIT_NAMES = (*(veto.name for veto in LANE_VETOES), GIVE_UP, *(bound.name for bound in SPEED_BOUNDS))
"""Every named limit, in the order they act: the names `LaneCommand.limited` counts by."""


def switched_on(rule: str | None, rules: Rules) -> bool:
    return rule is None or bool(getattr(rules, rule))


@dataclass(frozen=True)
class LaneRoom:
    """The lanes open to a change after every veto, and what each veto did."""

    open: np.ndarray  # [N, 2] bool: the fast-side, slow-side lane
    give_up: np.ndarray | None  # [N] bool: changes under way to give up (None: the rule is off)
    vetoed: dict[str, np.ndarray]  # name -> [N] bool: the agents it kept from a change they wished


def lane_room(scene: Scene, wish: np.ndarray) -> LaneRoom:
    """The vetoes of LANE_VETOES and `give_up_lost_gap` that are on, applied to the scene's cars; a
    car is vetoed where it wishes for a lane it is not yet heading for and the veto closes it."""
    rules, changing = scene.lateral.rules, scene.motion.changing
    rows = np.arange(len(wish))
    wished = np.where(wish > 0, 0, 1)
    wants = (wish != 0) & (changing != wish)
    open_lanes = np.ones((len(wish), 2), bool)
    vetoed: dict[str, np.ndarray] = {}
    for veto in LANE_VETOES:
        opens = veto.opens(scene) if switched_on(veto.rule, rules) else None
        vetoed[veto.name] = np.zeros(len(wish), bool) if opens is None else wants & ~opens[rows, wished]
        if opens is not None:
            open_lanes &= opens
    give_up = lost_gap(scene.motion, scene.place, open_lanes) if rules.give_up_lost_gap else None
    vetoed[GIVE_UP] = np.zeros(len(wish), bool) if give_up is None else give_up
    return LaneRoom(open_lanes, give_up, vetoed)


def bounded(push: np.ndarray, scene: Scene, heading: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """[N] the policy's `push` (m/s^2) under every bound of SPEED_BOUNDS that is on, and per bound the
    agents whose push it cut."""
    rules = scene.lateral.rules
    bound = np.full(len(push), np.inf)
    cut: dict[str, np.ndarray] = {}
    for limit in SPEED_BOUNDS:
        value = limit.bound(scene, heading) if switched_on(limit.rule, rules) else None
        cut[limit.name] = np.zeros(len(push), bool) if value is None else value < push
        if value is not None:
            bound = np.minimum(bound, value)
    return np.minimum(push, bound), cut
