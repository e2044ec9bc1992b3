"""Turn the policy's (steer, accel, brake) into SUMO commands, TORCS-style.

SUMO's sublane model moves a car sideways but has no heading of its own
(`changeSublane` with 0 means "follow the lane"), so each agent carries a
heading relative to the road axis. Steering turns it (kinematic bicycle,
capped by a lateral-acceleration limit), road curvature turns the road under
it (so steer 0 on a curve drifts outward), and the car then moves
v*cos(angle) along the lane (setSpeed) and v*sin(angle) across it
(changeSublane). Pure numpy; `SumoSim.command_agents` writes the result.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from behaviors.road.geometry import wrap_angle
from sumo_scenarios.build import PASSENGER_MIN_GAP


@dataclass(frozen=True)
class CarModel:
    """Physical limits of a learned agent; length/width match the behave vTypes."""

    length: float = 5.0
    width: float = 1.8
    max_accel: float = 3.0  # m/s^2 at accel = 1
    max_brake: float = 7.5  # m/s^2 at brake = 1
    max_steer: float = 0.366  # rad at steer = +-1 (TORCS' steer lock)
    wheelbase: float = 2.7
    max_lateral_accel: float = 8.0  # m/s^2, caps the yaw rate at speed
    max_lateral_speed: float = 5.0  # m/s, the vTypes' maxSpeedLat: SUMO's per-step cap


@dataclass(frozen=True)
class Actuation:
    speed: np.ndarray  # [N] new car speed, m/s (along its heading)
    angle: np.ndarray  # [N] new heading relative to the road axis, radians
    lane_speed: np.ndarray  # [N] speed to command along the lane, m/s
    lateral_move: np.ndarray  # [N] sideways move this step, metres (positive = left)
    off_track: np.ndarray  # [N] bool: the move would have crossed the carriageway border
    side_cut: np.ndarray  # [N] bool: the sideways move was cut by `side_limit`
    speed_cut: np.ndarray  # [N] bool: the speed was cut by `speed_cap`
    lateral_speed: np.ndarray | None = None  # [N] m/s towards the fast side (traffic model only)


def longitudinal(
    actions: np.ndarray,
    speed: np.ndarray,
    speed_limit: np.ndarray,
    dt: float,
    car: CarModel,
    speed_cap: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """New speed from accel and brake, within [0, limit] and under `speed_cap`; and where the cap cut it."""
    accel = np.clip(actions[:, 1], 0.0, 1.0)
    brake = np.clip(actions[:, 2], 0.0, 1.0)
    new_speed = np.clip(speed + (car.max_accel * accel - car.max_brake * brake) * dt, 0.0, speed_limit)
    if speed_cap is None:
        return new_speed, np.zeros(len(new_speed), bool)
    speed_cut = new_speed > speed_cap
    return np.where(speed_cut, np.maximum(speed_cap, 0.0), new_speed), speed_cut


def clamp_to_road(
    offset: np.ndarray, move: np.ndarray, half_width: np.ndarray, car: CarModel
) -> tuple[np.ndarray, np.ndarray]:
    """The sideways move cut to the room left on the carriageway, and where it would have left it."""
    room = half_width - car.width / 2
    target = offset + move
    return np.clip(target, -room, room) - offset, np.abs(target) > room


def actuate(
    actions: np.ndarray,
    speed: np.ndarray,
    angle: np.ndarray,
    offset: np.ndarray,
    half_width: np.ndarray,
    curvature: np.ndarray,
    speed_limit: np.ndarray,
    dt: float,
    car: CarModel,
    side_limit: np.ndarray | None = None,
    speed_cap: np.ndarray | None = None,
) -> Actuation:
    """One control step for all agents.

    `offset` is the car centre's distance from the carriageway centre (positive =
    left), `half_width` half the carriageway width, `curvature` the road axis's
    curvature (1/m, positive = turning left) at the car. `side_limit` [N, 2], if given,
    caps the sideways move to the left and right, `speed_cap` [N] the speed (see shield.py);
    a car whose sideways move was cut has its heading turned back to match the move it makes.
    """
    steer = np.clip(actions[:, 0], -1.0, 1.0)
    new_speed, speed_cut = longitudinal(actions, speed, speed_limit, dt, car, speed_cap)
    yaw_rate = steer * np.minimum(
        new_speed * np.tan(car.max_steer) / car.wheelbase,
        car.max_lateral_accel / np.maximum(new_speed, 1.0),
    )
    along = new_speed * np.cos(angle) / np.maximum(1.0 - curvature * offset, 0.1)
    new_angle = wrap_angle(angle + (yaw_rate - curvature * along) * dt)
    cap = car.max_lateral_speed * dt
    move = np.clip(new_speed * np.sin(new_angle) * dt, -cap, cap)
    side_cut = np.zeros(len(move), bool)
    if side_limit is not None:
        limited = np.clip(move, -side_limit[:, 1], side_limit[:, 0])
        side_cut = limited != move
        travel = np.maximum(new_speed * dt, 1e-9)
        new_angle = np.where(side_cut, np.arcsin(np.clip(limited / travel, -1.0, 1.0)), new_angle)
        move = limited
    move, off_track = clamp_to_road(offset, move, half_width, car)
    lane_speed = np.maximum(new_speed * np.cos(new_angle), 0.0)
    return Actuation(new_speed, new_angle, lane_speed, move, off_track, side_cut, speed_cut)


@dataclass(frozen=True)
class CarFollowing:
    """The car-following law the traffic driver's longitudinal action adjusts: the Improved
    Intelligent Driver Model (Treiber and Kesting 2013) with a human's time headway and comfort.

    A policy that only learns an acceleration from reward follows at 3-4 s and pulls away from a
    stop at 0.5 m/s^2, so the traffic it makes jams at a third of a motorway's capacity; with this
    law under it the policy starts from human following and learns where to deviate from it. The
    improved model, unlike the original IDM, holds the desired speed until the gap nears
    `time_headway` (the original's equilibrium gap at 20 cars per lane-km costs 15% of the flow).
    """

    time_headway: float = 1.2  # s: desired gap at speed (drivers: median about 1.4 s, fined below 0.9)
    min_gap: float = PASSENGER_MIN_GAP  # m: bumper to bumper when standing, as SUMO's cars stand (at
    # 2 m, a SUMO driver merging in front of an agent waited for the 2.5 m it keeps itself, the agent
    # for it to move over: at a lane drop, standing queues that lasted minutes)
    accel: float = 2.0  # m/s^2: pulling away (SUMO's passenger cars: 2.6)
    comfortable_decel: float = 2.0  # m/s^2
    exponent: float = 4.0


@dataclass(frozen=True)
class FreeRoad:
    """Each car's terms of the improved IDM that no leader changes (its speed against its desired
    speed): `actuate_lanes` weighs up to ten leaders per car each step, under laws that differ only
    in headway and standing gap, so these are worked out once for all of them."""

    speed: np.ndarray  # [N] m/s
    accel: np.ndarray  # [N] m/s^2 with nobody ahead
    below: np.ndarray  # [N] bool: at or under the desired speed
    loose_exponent: np.ndarray  # [N] of the leader's term while the gap is wider than wanted
    law: CarFollowing  # whose accel, comfortable_decel and exponent these come from


def free_road(speed: np.ndarray, desired_speed: np.ndarray, law: CarFollowing) -> FreeRoad:
    a, b = law.accel, law.comfortable_decel
    desired = np.maximum(desired_speed, 0.1)
    below = speed <= desired
    accel = np.where(
        below,
        a * (1.0 - (speed / desired) ** law.exponent),
        -b * (1.0 - (desired / np.maximum(speed, 0.1)) ** (a * law.exponent / b)),
    )
    return FreeRoad(speed, accel, below, 2.0 * a / np.maximum(accel, 1e-9), law)


def behind_leader(free: FreeRoad, gap: np.ndarray, leader_speed: np.ndarray, law: CarFollowing) -> np.ndarray:
    """[N] acceleration by the improved IDM of cars whose free-road terms are `free`; `gap` is bumper
    to bumper (+inf with no leader, then `leader_speed` is ignored), `leader_speed` has no NaN. `law`
    may differ from `free.law` in its headway and standing gap only. `gap`/`leader_speed` may also be
    [k, N], k leaders per car: then so is the result."""
    a, b = law.accel, law.comfortable_decel
    if (a, b, law.exponent) != (free.law.accel, free.law.comfortable_decel, free.law.exponent):
        raise ValueError("behind_leader: the law's free-road terms differ from those worked out")
    speed = free.speed
    has_leader = np.isfinite(gap)
    closing = speed - np.where(has_leader, leader_speed, speed)
    wanted = law.min_gap + np.maximum(
        speed * law.time_headway + speed * closing / (2.0 * np.sqrt(a * b)), 0.0
    )
    z = np.where(has_leader, wanted / np.maximum(np.where(has_leader, gap, 1.0), 0.1), 0.0)
    pushed = a * (1.0 - z**2)
    close = np.where(free.below, pushed, free.accel + pushed)
    loose = np.where(free.below, free.accel * (1.0 - np.minimum(z, 1.0) ** free.loose_exponent), free.accel)
    return np.where(z >= 1.0, close, loose)


def nan_as(values: np.ndarray, fill: float) -> np.ndarray:
    """`values` with NaN (nobody there) as `fill`: np.nan_to_num without its handling of infinities,
    which speeds never hold, at half the cost."""
    return np.where(np.isnan(values), fill, values)


def following_accel(
    speed: np.ndarray,
    desired_speed: np.ndarray,
    gap: np.ndarray,
    leader_speed: np.ndarray,
    law: CarFollowing,
) -> np.ndarray:
    """[N] acceleration by the improved IDM; `gap` is bumper to bumper (+inf with no leader, then
    `leader_speed` is ignored; NaN counts as a standing leader)."""
    return behind_leader(free_road(speed, desired_speed, law), gap, nan_as(leader_speed, 0.0), law)


@dataclass(frozen=True)
class Rules:
    """The traffic driver's hand-written rules, each switchable alone; docs/manual/traffic-driver.md
    tables them (motive, function, test). Motives choose a lane or a speed; limits only forbid."""

    leave_ending_lane: bool = True  # strategic motive: out of a lane that stops leading on, early
    avoid_ending_lanes: bool = True  # strategic limit: no change into a lane that ends soon
    speed_gain: bool = True  # motive: pass a leader slower than wanted (`held_up`, habits' patience)
    keep_right: bool = True  # motive: back to a free slow-side lane; the slow side is the rules' alone
    give_up_lost_gap: bool = True  # limit: a change whose gap closes before the line is given up
    letting_in: bool = True  # cooperative motive: drop back for a car whose lane ends or that asks
    falling_in: bool = True  # strategic: drop back behind the car beside to merge into its lane
    target_leader: bool = True  # limit: follow the leader of the lane the car heads for
    reaching_over: bool = True  # limit: follow the leader of a lane the car's body reaches into
    no_undertaking: bool = True  # limit: no passing on the slow side of a fast-moving lane
    no_tailgating: bool = True  # limit: no push closer than `min_time_headway`

    @classmethod
    def none(cls) -> Rules:
        """Every rule off: the execution layer alone (the policy's lane choice and the law)."""
        return cls(**{f.name: False for f in fields(cls)})

    @property
    def any(self) -> bool:
        return any(getattr(self, f.name) for f in fields(self))


@dataclass(frozen=True)
class LaneDriving:
    """How the traffic driver executes what its policy chooses (the paper's heading model,
    `actuate`, stays for the paper's policies).

    Steer chooses where in the road to be: within `change_threshold` of 0 the centre of the
    own lane, beyond it the centre of the neighbour lane on that side. A lane change, once
    begun, is a commitment: it goes on until the car is in the new lane, and ends early only
    when the shield blocks it or the lane ends (then the car returns to its lane's centre). The car
    moves towards its target at a lateral speed that rises and falls within human comfort
    (a 3.5 m change takes about 4.6 s with a peak lateral acceleration of 0.8 m/s^2, where
    recorded drivers take 5-6 s at 0.5-1 m/s^2), so steer 0 centres the car and holds it there.

    Accel and brake adjust the car-following law: accel 0.5 and brake 0 drive as `following`
    says, accel 1 (0) adds (takes) `accel_span`, brake takes up to the car's max_brake.

    Two rules of the road hold whatever the policy (`rules`, as German and most EU traffic law
    has them, and as SUMO's own lane changer models them): a car that wishes no change moves to the
    slow-side lane where that lane is free ahead for `free_ahead` m or `free_ahead_s` at its speed and
    has an acceptable gap; a wish for the fast-side lane counts only when a slower leader holds the
    car up (`held_up`); and while the fast-side lane's leader drives faster than
    `no_undertaking_above`, the car follows that leader too instead of passing it on its slow side.
    Both were asked of the policies by reward and not learnt (overtakers spent 7% of their time in a
    free rightmost lane and made a third of their passes on the right).
    """

    change_threshold: float = 0.5
    max_lateral_speed: float = 1.2  # m/s
    max_lateral_accel: float = 0.8  # m/s^2
    max_lateral_jerk: float = 2.5  # m/s^3
    arrival_decel: float = 0.3  # m/s^2: the lateral speed falls so as to arrive at the target gently
    response_time: float = 0.4  # s: how fast the lateral speed follows that profile
    max_slip: float = 0.25  # lateral speed at most this fraction of the forward speed
    crawl_lateral_speed: float = 0.3  # m/s: but this much at walking pace or standing (SUMO's own
    # cars move sideways standing; without it a car let in from a queue in an ending lane never came)
    arrived: float = 0.35  # lane widths past the new lane's centre line: the change is over
    accel_span: float = 1.5  # m/s^2
    safe_decel: float = 3.0  # m/s^2: a change may ask no harder braking of the car or its new follower
    change_time: float = 5.0  # s: a faster new follower must not come alongside within this
    lag_headway: float = 1.0  # s: nor be nearer behind than this at its speed (SUMO's drivers brake
    # hard inside their 1 s; cut-ins nearer doubled their hard braking among agents)
    following: CarFollowing = CarFollowing()
    rules: Rules = Rules()  # the rules of the road and the limits, each switchable alone
    free_ahead: float = 60.0  # m: the slow-side lane is free for keeping right beyond max(this, 3 s at speed)
    free_ahead_s: float = 3.0
    ending_lane_m: float = 350.0  # a change into a lane that stops leading on within max(this,
    ending_lane_s: float = 14.0  # this at speed) is no change: SUMO would take the car right back
    leave_ending_m: float = 600.0  # a car whose own lane stops leading on within max(this, this at
    leave_ending_s: float = 24.0  # speed) moves out where the gap allows, before SUMO would take it
    shorter_lane_m: float = 100.0  # m: a lane that stops leading on this much before the own one
    keep_right_reach: float = 1000.0  # m: a slow-side lane kept to leads on this far, and as far as the own
    keep_right_catch_up_s: float = 20.0  # s: a slow-side leader the car would reach this soon: not free
    entry_clearance: float = 200.0  # m: no change begins within this of the start of an edge nothing
    # leads onto, where SUMO puts a scenario's cars down at speed into a lane it finds free of cars
    # whose centre is in it (a car came in at 40 m/s behind an agent moving over into its lane)
    polite_decel: float = 0.5  # m/s^2: keeping right asks no harder braking of the new follower
    min_time_headway: float = 1.15  # s: the policy's accel may not push the car closer behind its leader
    diagonal_headway: float = 0.3  # s: kept behind the fast-side lane's leader not to be passed
    pass_margin: float = 2.0  # m/s: a leader this much slower than the car wants is a reason to pass
    keeper_pass_margin: float = 8.0  # m/s: the same for a lane keeper, who passes only a much slower car
    # (at 6 m/s keepers passed 25 m/s lorries and came back, 0.13-0.22 lane changes per km on motorway3)
    patience: float = 1.0  # s: held up this long before passing (a leader seen for a moment, half out
    # of the lane as it changes away, is no reason)
    keeper_patience: float = 10.0  # s: the same for a lane keeper, who follows a while first
    let_in_headway: float = 0.5  # s: kept behind a car being let in, until it has moved over
    # m/s: above this the fast-side leader is not passed on its slow side
    no_undertaking_above: float = 60 / 3.6
    network_chooses: bool = False  # True: the lane wish is the network's alone, both ways, and its
    # accel action sets the headway (`time_headway`); the rules only forbid (gaps, lanes that end, the
    # slow side, the route's lane ends, `min_time_headway`) and never move a car on their own


def new_follower_accel(
    speed: np.ndarray, follower_gap: np.ndarray, follower_speed: np.ndarray, law: CarFollowing
) -> np.ndarray:
    """[N] the acceleration the car behind in a neighbour lane would need were the car to move in
    front of it (0 where nobody is behind), by the same car-following law at its own speed;
    `follower_speed` has no NaN. `follower_gap`/`follower_speed` may be [k, N] (k followers per car)."""
    braking = behind_leader(free_road(follower_speed, follower_speed, law), follower_gap, speed, law)
    return np.where(np.isfinite(follower_gap), braking, 0.0)


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


def ends_soon(speed: np.ndarray, lateral: LaneDriving) -> np.ndarray:
    """[N] metres: a lane that stops leading on within max(`ending_lane_m`, `ending_lane_s` at speed)
    ends soon (no change goes into it; a car in it is let in)."""
    return np.maximum(lateral.ending_lane_m, lateral.ending_lane_s * speed)


def look_ahead(speed: np.ndarray, lateral: LaneDriving) -> np.ndarray:
    """[N] metres within which a leader counts for the rules of the road: max(`free_ahead`,
    `free_ahead_s` at speed)."""
    return np.maximum(lateral.free_ahead, lateral.free_ahead_s * speed)


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
    its own speed is ever room (the car stood at the end of a dropped lane).

    `lane_followers` ([N, 2] gap and speed, NaN where nobody; None: none) are the nearest followers
    whose centres are in the fast-side and slow-side lane, held to the same terms: the follower
    slots count a car in every lane its body overlaps, so a slow car just over the line behind hid
    a fast one coming up in that lane (on `motorway4`, an agent moved out of a queue in front of a
    car at 29 m/s, 50 m back, and was run into)."""
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


def lane_intent(
    steer: np.ndarray,
    changing: np.ndarray,
    lane_offset: np.ndarray,
    lane_width: np.ndarray,
    lanes_fast: np.ndarray,
    lanes_slow: np.ndarray,
    acceptable: np.ndarray,
    lateral: LaneDriving,
    slow_side_free: np.ndarray | None = None,
    held_up: np.ndarray | None = None,
    leave: np.ndarray | None = None,
    may_begin: np.ndarray | None = None,
) -> np.ndarray:
    """[N] int: the lane each agent heads for, relative to its own (+1 the fast side, -1 the slow
    side, 0 its own), given `changing`, the same at the last step. A change begins only where
    that side's lane exists and its gap is `acceptable` ([N, 2]: fast, slow; `gap_acceptable`);
    until then the wish waits. With the rules of the road (`slow_side_free` [N] bool given), no
    wish means keeping right where that lane is free, a wish for the fast side counts only where
    `held_up` [N] bool, a car whose own lane ends moves to the side `leave` [N] (+1/-1, 0: none)
    says, and a change whose gap stops being acceptable before the car crosses the
    line is given up (a car came up alongside, or one of the two cars crossing paths). No change
    begins where `may_begin` [N] bool is False (inside a junction, whose lanes are a connection's,
    not the carriageway's: SUMO's lane numbers and neighbours there are no guide). Otherwise a
    change under way goes on whatever the steer: a policy that could call changes off learnt to
    start one and call it off at the next step, riding beside the line.

    A change is over once the car's centre is `arrived` lane widths on the far side of its new
    lane's centre line, which is where SUMO puts it right after it crossed the line (its offset
    jumps from +w/2 to -w/2): no lane index is needed, so this holds across edges too. A car that
    still wishes the same way then goes on to the next lane in one move: the test stays true until
    it leaves the line behind, and restarting the change at every other step swung its target
    between the two lanes.
    """
    wish = np.where(steer > lateral.change_threshold, 1, np.where(steer < -lateral.change_threshold, -1, 0))
    if slow_side_free is not None:  # a wish for a lane that is not there is no wish
        possible = np.where(wish > 0, lanes_fast > 0, np.where(wish < 0, lanes_slow > 0, True))
        may_pass = np.ones(len(wish), bool) if held_up is None else held_up
        wish = np.where(possible & ((wish <= 0) | may_pass), wish, 0)
        wish = np.where((wish == 0) & slow_side_free, -1, wish)
    if leave is not None:  # the own lane ends: over to the side given (+1/-1), whatever the wish
        wish = np.where(leave != 0, leave, wish)
    crossed = changing * lane_offset < -lateral.arrived * lane_width
    vanished = np.where(changing > 0, lanes_fast == 0, np.where(changing < 0, lanes_slow == 0, False))
    going = np.where(crossed | vanished, 0, changing)
    if slow_side_free is not None and lateral.rules.give_up_lost_gap:
        before_line = changing * lane_offset >= 0.0
        lost = ~acceptable[np.arange(len(changing)), np.where(changing > 0, 0, 1)]
        going = np.where((changing != 0) & before_line & lost, 0, going)
    room = np.where(wish > 0, (lanes_fast > 0) & acceptable[:, 0], (lanes_slow > 0) & acceptable[:, 1])
    if may_begin is not None:
        room &= may_begin
    begins = (changing == 0) | ((going == 0) & (wish == changing))
    return np.where(begins & (wish != 0) & room, wish, going)


def lane_clear(traffic: LaneTraffic, column: int, lateral: LaneDriving) -> np.ndarray:
    """[N] bool: the leader in a neighbour lane (`column` of the traffic's slots) would not come
    within `look_ahead` for `keep_right_catch_up_s`, at the speed the car wants (a driver does not
    change lanes only to be held up again). Judged at the car's own speed, a car slowed down behind
    a leader found the lane beside free as soon as that leader dropped back past the look-ahead,
    and moved back and forth across the line (on the A10KW, a third of overtakers' changes came
    within 4 s of the one before, the other way)."""
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


def zipper_reach(closing: np.ndarray, courtesy: CarFollowing) -> np.ndarray:
    """[N] metres within which a car in a lane that ends is let in (`letting_in`) beyond the look-ahead:
    what dropping back behind it at the comfortable deceleration takes, closing at `closing` m/s,
    to `courtesy`'s standing gap. Within the look-ahead alone (60 m at 72 km/h) a car standing at the
    end of a dropped lane asked more than `safe_decel` of every car coming up beside it at that speed:
    each passed it for the next one back, and none let it in (`make ramp`'s work zone, half the cars
    learned: a car of SUMO's stood there 57 s)."""
    return closing**2 / (2.0 * courtesy.comfortable_decel) + courtesy.min_gap


def letting_in(
    traffic: LaneTraffic, lane_leads_on: np.ndarray, lateral: LaneDriving, asking: np.ndarray | None = None
) -> np.ndarray:
    """[N] the acceleration that lets a car merge in front, zip fashion (+inf where there is none):
    the nearest car ahead in a neighbour lane that ends within max(`ending_lane_m`, `ending_lane_s`
    at speed), and sooner than the own lane, or that asks to come over (`asking` [N, 2], fast side
    and slow side; None: nobody), as a car bound for an exit does, is followed as a leader where it is within
    `look_ahead` (one in a lane that ends, within `zipper_reach` too), would fit in front of the own
    leader (or, its lane ending, is being passed by an own leader faster by more than `pass_margin`),
    and is not being closed on so fast that keeping clear of it takes more than `safe_decel`. A car
    slowing to a stop at the end of a lane that drops was let in only once the own leader had passed
    it, by then too near to brake for: on `make ramp`'s work zone, half the cars learned, an agent
    SUMO drove stopped at its lane's end with its body 0.34 m over the line, a car of SUMO's passed
    it, and the agent behind, left with it as its leader, stopped 2.3 m behind it, nearer than the
    2.5 m SUMO's driver wants behind before it moves over: both stood 258 s, and 91 vehicles stood
    30 s or more. The gap opens at the full headway (SUMO's
    drivers, who take the cars whose lane ends, move over only into a gap safe at their own 1 s),
    braking no harder than the law's comfortable deceleration unless keeping clear takes more. A car
    nearer than the standing gap, or alongside, is passed, as is one that would take harder
    braking: the next car back lets it in, so a through lane and an ending lane take turns. One
    alongside that asks, its front ahead of the car's, is dropped back for unless the car is closing
    on it: on the dense motorway's weave an agent held alongside a car bound for the exit for 8 s at
    the same speed, and it began its two changes too late, stood at its lane's end over the line,
    and both lanes behind it broke down (SUMO's own drivers, asked, drop back). Letting
    in only a car within a few metres came too late at speed: nobody could brake for it, the merging
    car reached the end of its lane and stood there, and the lane beside it queued behind the cars
    that stopped for it at last. `lane_leads_on` [N, 3] metres (own, fast side, slow side)."""
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


def falling_in(traffic: LaneTraffic, waiting: np.ndarray, lateral: LaneDriving) -> np.ndarray:
    """[N] the acceleration of a car that must leave its ending lane (`waiting` [N]: +1 to the fast
    side, -1 to the slow side, 0 not waiting) and has no gap yet: it falls in behind the nearest car
    ahead of or alongside it in that lane, as the car the through lane lets in does, braking no harder
    than `safe_decel` (+inf where it is not waiting). Without this a car matched its speed to the
    platoon beside it and reached the end of its lane still alongside, where it stood."""
    t = traffic
    rows = np.arange(len(t.speed))
    column = np.where(waiting > 0, 2, 4)
    leader_gap, leader_speed = t.gap[rows, column], t.other_speed[rows, column]
    applies = (waiting != 0) & np.isfinite(leader_speed) & np.isfinite(leader_gap)
    courtesy = replace(lateral.following, time_headway=lateral.let_in_headway)
    return yielding(t.free, leader_gap, t.known_speed[rows, column], applies, courtesy, lateral)


def reaching_over(
    traffic: LaneTraffic, lane_offset: np.ndarray, lateral_speed: np.ndarray, lane_width: np.ndarray,
    car_width: float,
) -> np.ndarray:  # fmt: skip
    """[N] m/s^2: behind the leader of each neighbour lane the car's body reaches into while it is not
    moving away from that lane (np.inf where there is none, or nobody ahead there). A car that gives
    up a lane change drifts on sideways while its lateral speed comes down: it keeps behind that
    lane's leader until it turns back (on the highway at 29 veh/lane-km, shield off, an overtaker
    gave up a change 0.5 m short of the line when a car was put down 3 m ahead in the lane it was
    moving into, went on accelerating behind its own lane's leader, drifted over the line and ran
    into it). A car moving away from a lane, as one that has just passed into the next lane beside a
    slower car, does not: bound by that car too, every pass slowed down and a queue of agents
    discharged 7% slower. A car alongside there (gap 0) is no leader: moving back is the answer to
    it, not full braking; where there is no lane, the gap is 0 too."""
    half_room = (lane_width - car_width) / 2
    over = np.stack([
        (lane_offset > half_room) & (lateral_speed >= 0.0),
        (lane_offset < -half_room) & (lateral_speed <= 0.0),
    ], 1)  # fmt: skip
    ahead = traffic.gap[:, [2, 4]] > 0
    return np.min(np.where(over & ahead, traffic.lead_accel[:, 1:], np.inf), axis=1)


def lateral_profile(
    error: np.ndarray,
    lateral_speed: np.ndarray,
    lateral_accel: np.ndarray,
    speed: np.ndarray,
    dt: float,
    lateral: LaneDriving,
) -> tuple[np.ndarray, np.ndarray]:
    """New lateral speed and acceleration [N] towards a target `error` metres away (+ = fast side):
    the speed from which the target is reached decelerating at `arrival_decel`, capped at
    `max_lateral_speed` and at `max_slip` of the forward speed or `crawl_lateral_speed`, whichever is
    more (a car at walking pace edges over; at speed the slip bounds it), followed with acceleration
    and jerk limits. The acceleration carried to the next step is the comfort limit at most: where
    the cap cuts the speed at once (a car SUMO gave back crawling, at SUMO's 0.9 m/s sideways, with
    a reach of 0.3), the cut's -3 m/s^2 carried on swung the car the other way, off the road."""
    reach = np.minimum(
        lateral.max_lateral_speed, np.maximum(lateral.max_slip * speed, lateral.crawl_lateral_speed)
    )
    profile = np.sign(error) * np.minimum(reach, np.sqrt(2.0 * lateral.arrival_decel * np.abs(error)))
    wanted = np.clip(
        (profile - lateral_speed) / lateral.response_time,
        -lateral.max_lateral_accel,
        lateral.max_lateral_accel,
    )
    jerk = lateral.max_lateral_jerk * dt
    accel = lateral_accel + np.clip(wanted - lateral_accel, -jerk, jerk)
    new_speed = np.clip(lateral_speed + accel * dt, -reach, reach)
    carried = np.clip((new_speed - lateral_speed) / dt, -lateral.max_lateral_accel, lateral.max_lateral_accel)
    return new_speed, carried


@dataclass(frozen=True)
class LaneHabits:
    """How each agent uses the lanes, beyond the rules every car keeps: its driving behaviour."""

    overtakes: np.ndarray  # [N] bool: held up, moves to the fast side unasked, and back to a free
    # slow-side lane after (the law's keep-right); the others keep their lane
    pass_margin: np.ndarray  # [N] m/s: a leader this much slower than the car wants is a reason to pass
    patience: np.ndarray  # [N] s: held up this long before it passes


@dataclass(frozen=True)
class LaneCommand:
    """The traffic driver's actuation and the per-agent state it carries to the next step."""

    actuation: Actuation
    changing: np.ndarray  # [N] int, see `lane_intent`
    lateral_accel: np.ndarray  # [N] m/s^2, + = fast side
    held_for: np.ndarray  # [N] s the car has been held up (`held_up`) without a break


def _rule_wishes(
    traffic: LaneTraffic,
    lateral: LaneDriving,
    lane_leads_on: np.ndarray | None,
    habits: LaneHabits | None,
    held_for: np.ndarray | None,
    steer: np.ndarray,
    dt: float,
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray, np.ndarray]:
    """(slow side free, held up, seconds held up, steer) as the rules of the road and the habits
    make them: keeping right where the slow side is free, passing a slower leader once patience
    runs out, and (with habits) the slow side the rules' alone."""
    rules = lateral.rules
    free = slow_side_free(traffic, lateral, lane_leads_on) if rules.keep_right else None
    if free is not None and habits is not None:
        free &= habits.overtakes
    margin, patient = (None, None) if habits is None else (habits.pass_margin, ~habits.overtakes)
    held = held_up(traffic, lateral, margin, patient) if rules.speed_gain else None
    waited = np.zeros(len(steer))
    if held is not None:
        waited = np.where(held, (0.0 if held_for is None else held_for) + dt, 0.0)
    if habits is not None and rules.keep_right:  # the slow side is the rules' alone
        steer = np.maximum(steer, 0.0)
    if habits is not None and held is not None:
        if free is not None:  # waiting to pass is no time to move right
            free &= ~held
        held = held & (waited >= habits.patience - 1e-9)
        steer = np.where(habits.overtakes & held, 1.0, steer)
    if rules.any:  # the rules judge the lanes: none is free or a reason where its rule is off
        free = np.zeros(len(steer), bool) if free is None else free
        held = np.ones(len(steer), bool) if held is None else held
    return free, held, waited, steer


def actuate_lanes(
    actions: np.ndarray,
    speed: np.ndarray,
    desired_speed: np.ndarray,
    gap: np.ndarray,
    other_speed: np.ndarray,
    lateral_speed: np.ndarray,
    lateral_accel: np.ndarray,
    changing: np.ndarray,
    lane_offset: np.ndarray,
    lane_width: np.ndarray,
    lanes_fast: np.ndarray,
    lanes_slow: np.ndarray,
    offset: np.ndarray,
    half_width: np.ndarray,
    speed_limit: np.ndarray,
    dt: float,
    car: CarModel,
    lateral: LaneDriving,
    side_limit: np.ndarray | None = None,
    speed_cap: np.ndarray | None = None,
    lane_leads_on: np.ndarray | None = None,
    may_begin: np.ndarray | None = None,
    habits: LaneHabits | None = None,
    far_fast_leader: tuple[np.ndarray, np.ndarray] | None = None,
    held_for: np.ndarray | None = None,
    lane_followers: tuple[np.ndarray, np.ndarray] | None = None,
    asking: np.ndarray | None = None,
    time_headway: np.ndarray | None = None,
    lane_bias: np.ndarray | None = None,
) -> LaneCommand:
    """One control step of the traffic driver for all agents.

    Everything sideways is signed as SUMO's lane indices and `changeSublane` are: + towards
    the fast side (the left in keep-right nets, the right in left-hand ones, which SUMO
    mirrors); `offset` and `half_width` are the carriageway's. `gap`/`other_speed` [N, 6]: the
    neighbours in lanes.NEIGHBOUR_SLOTS order (gap +inf where none, 0 alongside or no lane). `angle` in
    the result is atan(lateral speed / speed). A car that heads for a neighbour lane also
    follows that lane's leader, as a driver who moves over does. No change begins where
    `may_begin` [N] bool is false (None: everywhere). `habits` (None: all keep right, pass as
    `lateral` says and go to the slow side when the policy asks) tell who passes a slower leader
    unasked and keeps right after; with them, only the rules move a car to the slow side;
    `far_fast_leader` ([N] gap, [N] speed; None: none) is the nearest leader in a lane beyond the
    fast-side one, which is not passed on its slow side either; `held_for` [N] (None: 0) the
    seconds each car has been held up so far, which its habits' patience must reach before it
    passes (the result carries it on); `lane_followers` ([N, 2] gap, speed; None: none) the nearest
    followers with their centres in the fast-side and slow-side lanes (`gap_acceptable`); `asking`
    ([N, 2] bool; None: nobody) whether the fast-side and slow-side leader wants to come over
    (`letting_in`). A car that wants more than the
    limit (`desired_speed` above `speed_limit`) drives at what it wants, as a share of real
    drivers and of SUMO's do. `time_headway` [N] s (None: the law's) is the headway each car follows
    its leaders at; `lane_bias` [N] m (None: 0) where in its lane each car holds itself, from the
    centre line towards the fast side (people do not drive on the centre line).
    """
    steer = np.clip(actions[:, 0], -1.0, 1.0)
    traffic = lane_traffic(speed, desired_speed, gap, other_speed, lateral.following)
    if time_headway is not None:  # the car's own following; its new followers keep the law's
        own_law = replace(lateral.following, time_headway=time_headway)  # type: ignore[arg-type]
        leaders = behind_leader(
            traffic.free, gap[:, [0, 2, 4]].T, traffic.known_speed[:, [0, 2, 4]].T, own_law
        )
        traffic = replace(traffic, lead_accel=leaders.T)
    rules = lateral.rules
    leave: np.ndarray | None = None
    leaving: np.ndarray | None = None
    lanes_go_on: np.ndarray | bool = True
    if lane_leads_on is not None and rules.leave_ending_lane:
        soon = ends_soon(speed, lateral)
        leave_within = np.maximum(lateral.leave_ending_m, lateral.leave_ending_s * speed)
        ending = lane_leads_on[:, 0] < leave_within  # out of the own lane, if it ends, early on
        leave = np.where(ending & (lane_leads_on[:, 1] >= soon), 1, 0)
        leave = np.where(ending & (leave == 0) & (lane_leads_on[:, 2] >= soon), -1, leave)
        leaving = leave[:, None] == np.array([1, -1])  # [N, 2]: fast, slow side
    if lane_leads_on is not None and rules.avoid_ending_lanes:
        soon = ends_soon(speed, lateral)
        # no change into a lane that ends before long, nor, unless the own lane ends, into one that
        # ends well before it (a weave's, an exit's)
        shorter = lane_leads_on[:, 1:] < lane_leads_on[:, :1] - lateral.shorter_lane_m
        lanes_go_on = (lane_leads_on[:, 1:] >= soon[:, None]) & (
            ~shorter | (False if leaving is None else leaving)
        )
    acceptable = gap_acceptable(traffic, lateral, leaving, lane_followers) & lanes_go_on
    free: np.ndarray | None
    held: np.ndarray | None
    if lateral.network_chooses:  # no rule wishes for a lane: the envelope only forbids
        free, held, waited = np.zeros(len(steer), bool), np.ones(len(steer), bool), np.zeros(len(steer))
    else:
        free, held, waited, steer = _rule_wishes(traffic, lateral, lane_leads_on, habits, held_for, steer, dt)
    heading = lane_intent(
        steer,
        changing,
        lane_offset,
        lane_width,
        lanes_fast,
        lanes_slow,
        acceptable,
        lateral,
        free,
        held,
        leave,
        may_begin,
    )
    follow = traffic.lead_accel[:, 0]
    reaching = np.full(len(steer), np.inf)
    if rules.reaching_over or not rules.any:
        reaching = reaching_over(traffic, lane_offset, lateral_speed, lane_width, car.width)
        follow = np.minimum(follow, reaching)
    into = traffic.lead_accel[np.arange(len(steer)), np.where(heading > 0, 1, np.where(heading < 0, 2, 0))]
    accel = np.clip(actions[:, 1], 0.0, 1.0)
    brake = np.clip(actions[:, 2], 0.0, 1.0)
    if lateral.network_chooses:  # its accel chose the headway (`time_headway`); brake brakes harder
        adjust = -car.max_brake * brake
    else:
        adjust = 2.0 * lateral.accel_span * (accel - 0.5) - car.max_brake * brake
    if rules.any:  # the named limits bound the policy's push too
        bound = np.full(len(steer), np.inf)
        if rules.target_leader:
            bound = np.minimum(bound, np.where(heading != 0, into, np.inf))
        if rules.reaching_over:
            bound = np.minimum(bound, reaching)
        if rules.no_undertaking:
            bound = np.minimum(bound, not_undertaking(traffic, lateral, far_fast_leader))
        if lane_leads_on is not None and rules.letting_in:
            # a car on its way to another lane leaves letting in to the next one back
            bound = np.minimum(
                bound, np.where(heading == 0, letting_in(traffic, lane_leads_on, lateral, asking), np.inf)
            )
        if leave is not None and rules.falling_in:
            waiting = np.where(heading == 0, leave, 0)
            bound = np.minimum(bound, falling_in(traffic, waiting, lateral))
        if rules.no_tailgating:
            closest = replace(lateral.following, time_headway=lateral.min_time_headway)
            bound = np.minimum(
                bound, behind_leader(traffic.free, gap[:, 0], traffic.known_speed[:, 0], closest)
            )
        command = np.minimum(follow + adjust, bound)  # closest >= follow: it only limits a push
    else:
        command = np.minimum(follow, into) + adjust
    command = np.clip(command, -car.max_brake, car.max_accel)
    new_speed = np.clip(speed + command * dt, 0.0, np.maximum(speed_limit, desired_speed))
    speed_cut = np.zeros(len(new_speed), bool)
    if speed_cap is not None:
        speed_cut = new_speed > speed_cap
        new_speed = np.where(speed_cut, np.maximum(speed_cap, 0.0), new_speed)
    error = heading * lane_width - lane_offset
    if lane_bias is not None:
        error = error + lane_bias
    new_lateral, new_accel = lateral_profile(error, lateral_speed, lateral_accel, new_speed, dt, lateral)
    move = new_lateral * dt
    side_cut = np.zeros(len(move), bool)
    if side_limit is not None:
        limited = np.clip(move, -side_limit[:, 1], side_limit[:, 0])
        side_cut = limited != move
        move = limited
        new_lateral = np.where(side_cut, move / dt, new_lateral)
        new_accel = np.where(side_cut, 0.0, new_accel)
        heading = np.where(side_cut, 0, heading)  # a blocked change is given up: back to the own lane
    move, off_track = clamp_to_road(offset, move, half_width, car)
    angle = np.arctan2(new_lateral, np.maximum(new_speed, 0.1))
    result = Actuation(new_speed, angle, new_speed, move, off_track, side_cut, speed_cut, new_lateral)
    return LaneCommand(result, heading, new_accel, waited)
