"""When SUMO's own driver takes a learned agent, and when it gives the car back.

The policies learn on roads where every lane goes on and no light turns red. SUMO knows where each
route needs to be and stops at the line, so its strategic layer takes an agent whose lane stops
leading on soon while another lane of its edge goes on (an exit or a lane drop ahead), that is on
a one-lane road or about to leave the carriageway for one, whose body reaches into a lane that
ends, or that has a red or yellow signal ahead; and hands it back once none of that holds and the
car is inside a lane that leads on. Deciding is pure numpy (`decide`); the fleet sends the
commands to SUMO in a phase of their own, after sensing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.road.routes import LANE_END_MARGIN

HANDOVER_DISTANCE = 250.0
HANDOVER_SECONDS = 10.0
"""SUMO takes an agent whose lane ends within max(250 m, 10 s at its speed) while another lane goes on."""
HANDBACK_MARGIN = 100.0
"""m: the policy gets the car back only when its lane leads on this much beyond that reach."""
HANDBACK_INSIDE = 0.2
"""m: and only when its body is also this far inside its lane's lines: SUMO may carry a car it took
over a line into a lane that then drops, which leaves it on the carriageway's edge."""
SIGNAL_DISTANCE = 100.0
SIGNAL_SECONDS = 5.0
"""SUMO also takes an agent with a red or yellow signal within max(100 m, 5 s at its speed) on its
route (the policies never saw a traffic light), and gives it back once none is."""


@dataclass(frozen=True)
class LaneEnds:
    """Per agent, where its own and neighbouring lanes stop leading on, in lane coordinates."""

    own_fast_slow: np.ndarray  # [N, 3] lane position where the own/fast/slow lane stops leading on
    best: np.ndarray  # [N] the same for the edge's farthest-leading lane
    one_lane_at: np.ndarray  # [N] lane position of the route's next road of one car lane (inf: none)


@dataclass(frozen=True)
class LanePlace:
    """Per agent, where it is in its lane: `lane_pos`/`lateral_pos` in lane `lane_number` of `lanes`;
    `half_room` is how far a centre may move before the body meets a line; `lateral_speed` [N]
    (None: 0) the agents' own sideways speed, + = fast side."""

    lane_pos: np.ndarray
    lateral_pos: np.ndarray
    lane_number: np.ndarray
    lanes: np.ndarray
    half_room: np.ndarray
    lateral_speed: np.ndarray | None = None


@dataclass(frozen=True)
class Handover:
    """Which agents SUMO takes this step (`give`) and which it gives back (`take`)."""

    give: np.ndarray
    take: np.ndarray


def handover_reach(speed: np.ndarray) -> np.ndarray:
    return np.maximum(HANDOVER_DISTANCE, HANDOVER_SECONDS * speed)


def straddling_an_ending_lane(ends: LaneEnds, place: LanePlace, reach: np.ndarray) -> np.ndarray:
    """Agents whose body reaches over the line into a neighbouring lane that ends within `reach`:
    where that lane drops, the road narrows under them. One moving away from that lane (`lateral_speed`;
    None: nobody moves) is on its way out of it, as a car that has just left it
    is: taken for a step or two and given back, its sideways motion jumped at both ends."""
    lateral_pos, half_room, lane_number = place.lateral_pos, place.half_room, place.lane_number
    leads = ends.own_fast_slow - place.lane_pos[:, None]
    short = (leads < reach[:, None]) & (ends.own_fast_slow < ends.best[:, None] - LANE_END_MARGIN)
    away = np.zeros(len(lateral_pos)) if place.lateral_speed is None else place.lateral_speed
    over_fast = (lateral_pos > half_room) & (lane_number < place.lanes - 1) & short[:, 1] & (away >= 0.0)
    over_slow = (lateral_pos < -half_room) & (lane_number > 0) & short[:, 2] & (away <= 0.0)
    return over_fast | over_slow


def decide(
    ends: LaneEnds,
    place: LanePlace,
    handed: np.ndarray,
    speed: np.ndarray,
    normal: np.ndarray,
    signal: np.ndarray,
) -> Handover:
    """Who SUMO takes and who it gives back, for agents at `place` (`normal`: on a normal edge, not
    inside a junction), with a red or yellow `signal` ahead."""
    lane_pos, lanes = place.lane_pos, place.lanes
    own_end = ends.own_fast_slow[:, 0]
    own_left = own_end - lane_pos
    reach = handover_reach(speed)
    one_lane_left = ends.one_lane_at - lane_pos
    # a ramp usually leaves from lane 0: SUMO gets the reach once per lane it has to cross
    ramp_reach = reach * (1 + np.maximum(place.lane_number, 0))
    ending = (own_left < reach) & (ends.best > own_end + LANE_END_MARGIN)
    ending |= one_lane_left < ramp_reach  # leaving the carriageway: SUMO takes the car to the ramp
    straddling = straddling_an_ending_lane(ends, place, reach)
    ending |= straddling
    needs_sumo = (normal & (ending | (lanes < 2))) | signal
    free = (
        normal
        & (lanes >= 2)
        & ~((own_left < reach + HANDBACK_MARGIN) & (ends.best > own_end))
        & (one_lane_left >= ramp_reach + HANDBACK_MARGIN)
        & ~straddling
        & ~signal
        & (np.abs(place.lateral_pos) <= place.half_room - HANDBACK_INSIDE)
    )
    return Handover(give=needs_sumo & ~handed, take=handed & free)
