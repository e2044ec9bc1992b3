"""The traffic driver's settings: the car, the car-following law's parameters, how lanes are
driven, the rules each switchable alone, and each agent's lane habits. Plain frozen dataclasses."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from behaviors.car.model import CarModel
from sumo_scenarios.build import PASSENGER_MIN_GAP


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


@dataclass(frozen=True)
class LaneHabits:
    """How each agent uses the lanes, beyond the rules every car keeps: its driving behaviour."""

    overtakes: np.ndarray  # [N] bool: held up, moves to the fast side unasked, and back to a free
    # slow-side lane after (the law's keep-right); the others keep their lane
    pass_margin: np.ndarray  # [N] m/s: a leader this much slower than the car wants is a reason to pass
    patience: np.ndarray  # [N] s: held up this long before it passes


@dataclass(frozen=True)
class DriverSettings:
    """What every agent of the traffic driver shares in a step: its car, how it drives in lanes and
    the step's length."""

    lateral: LaneDriving
    dt: float  # s
    car: CarModel = field(default_factory=CarModel)
