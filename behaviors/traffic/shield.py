"""Safety shield for `behave populate`: learned agents neither steer into a car alongside
nor run into the car ahead.

The policies were trained among a handful of cars, all at the speed limit. Dropped
into dense mixed traffic they drift sideways into neighbours and keep full speed
behind slower SUMO cars: without the shield, 89% of the collisions SUMO reports on
the 1,000-agent benchmark are side contacts, and on the bundled highway nearly all
are agents at the limit running into slower cars. The shield sits between the
policy and SUMO and only ever takes something away:

* sideways: each agent may move at most half the free room beside it (among cars
  overlapping it lengthwise) minus a margin; half, because the car beside may be
  an agent moving towards it in the same step;
* lengthwise: each agent's speed is capped so that it could still stop behind the
  car ahead if that car braked as hard as the agent can (Gipps' safe speed),
  with no harder braking than an emergency stop.

Steering and throttle stay the policy's everywhere else. Training never uses it,
evaluation only when asked (`behave evaluate --shield`): they measure the bare
policy. Pure numpy; `Fleet` calls it with the same vehicle positions the sensors use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.car.model import CarModel
from behaviors.road.neighbours import Neighbours, nearest_per_slot, neighbours
from behaviors.traffic.bodies import Bodies

SIDE_MARGIN = 0.3
"""Metres of lateral clearance kept between two cars side by side (a pair ends up twice this apart)."""

PASSING_ROOM = 2 * SIDE_MARGIN
"""Metres between the bodies of two cars side by side that let one drive on past the other: the
clearance each keeps, on both sides."""

LENGTHWISE_SLACK = 1.0
"""Metres added at both ends of a car when deciding whether two cars are alongside each other."""

PATH_MARGIN = 0.8
"""Metres: a car ahead less than this far off sideways counts as in the agent's way (its leader).
More than the side margin, because the agent may move up to a metre sideways in the step."""

STANDSTILL_GAP = 1.0
"""Metres left to the car ahead when both have stopped."""

EMERGENCY_DECEL = 9.0
"""m/s^2: the hardest the shield brakes (SUMO's default emergency deceleration for cars)."""


@dataclass(frozen=True)
class Surroundings:
    """What the shield needs around each agent (row i = agent i)."""

    side_room: np.ndarray  # [N, 2] free metres (left, right) beside the agent; inf = nobody alongside
    leader: np.ndarray  # [N] row (in the vehicle arrays) of the nearest car ahead in the agent's way, -1 none
    leader_gap: np.ndarray  # [N] metres from the agent's front bumper to that car's rear bumper; inf = none


def surroundings(
    front: np.ndarray,
    axis: np.ndarray,
    points: np.ndarray,
    self_rows: np.ndarray,
    car: CarModel,
    reach: float,
    near: Neighbours | None = None,
    bodies: Bodies | None = None,
) -> Surroundings:
    """Side room and leader of every agent, from front bumpers (SUMO's vehicle positions).

    SUMO's sublane model checks contact on unrotated boxes: a car covers its lane from its front
    bumper one length back, and its width around its lateral position (which is its front's).
    So everything here is measured between front bumpers, along and across `axis`, the direction
    of the road at each agent (not its heading: a swerving car's frame would tilt the gaps to the
    cars beside it). `points` holds every vehicle's front, row `self_rows[i]` being agent i; the
    agents are `car`-sized and the others as `bodies` says (None: `car`-sized too). `reach` bounds
    the search, in metres; `near`, if given, holds the pairs of a search already made with at least
    that radius.
    """
    n = len(front)
    room = np.full((n, 2), np.inf)
    leader = np.full(n, -1, np.int64)
    gap_ahead = np.full(n, np.inf)
    q, m, dx, dy, square = near if near is not None else neighbours(front, points, reach, self_rows)
    if len(q) == 0:
        return Surroundings(room, leader, gap_ahead)
    close = square < reach**2  # the pairs within reach (`within`), masked: not copied out of `near`
    cos, sin = np.cos(axis)[q], np.sin(axis)[q]
    ahead = dx * cos + dy * sin  # the other's front, along the road and across it (positive = left)
    left = dy * cos - dx * sin
    own_length: np.ndarray | float
    own_width: np.ndarray | float
    if bodies is None:
        other_length, other_width = np.full(len(m), car.length), np.full(len(m), car.width)
        own_length, own_width = car.length, car.width
    else:
        other_length, other_width = bodies.length[m], bodies.width[m]
        own_length, own_width = bodies.own_size(q)
    # overlapping lengthwise: the other's front ahead of the agent's rear, its rear behind the front
    alongside = close & (ahead < other_length + LENGTHWISE_SLACK) & (ahead > -(own_length + LENGTHWISE_SLACK))
    side_gap = np.abs(left) - (own_width + other_width) / 2
    beside = alongside & (side_gap > 0)  # overlapping sideways already: ahead or behind, not beside
    for side, mask in ((0, beside & (left > 0)), (1, beside & (left < 0))):
        np.minimum.at(room[:, side], q[mask], side_gap[mask])
    # cars ahead in the agent's way; not one beside it with room to pass, which the side limit keeps
    # clear (capped to the speed of a car standing beside it, an agent would stand for good)
    passable = beside & (side_gap >= PASSING_ROOM)
    path = np.flatnonzero(close & (side_gap < PATH_MARGIN) & (ahead > 0) & ~passable)
    q, m, gap = q[path], m[path], ahead[path] - other_length[path]
    agent, first = nearest_per_slot(n, q, gap)
    leader[agent] = m[first]
    gap_ahead[agent] = gap[first]
    return Surroundings(room, leader, gap_ahead)


def search_reach(
    top_speed: float, dt: float, car: CarModel, longest: float | None = None, own_longest: float | None = None
) -> float:
    """Metres within which a car ahead can limit an agent at `top_speed` (a stopped one at that):
    its front is up to the `longest` vehicle's length (None: `car`'s) beyond its rear, and the agent
    up to `own_longest` (None: `car`'s) long."""
    brake = car.max_brake
    stopping = ((top_speed + brake * dt) ** 2) / (2 * brake)
    other = car.length if longest is None else max(longest, car.length)
    own = car.length if own_longest is None else max(own_longest, car.length)
    return stopping + STANDSTILL_GAP + (own + other) + 2 * car.width


def side_limits(room: np.ndarray) -> np.ndarray:
    """[N, 2] largest sideways move (left, right) this step: half the room on that side, minus the margin."""
    return np.maximum(room / 2 - SIDE_MARGIN, 0.0)


def safe_speed(
    gap: np.ndarray, leader_speed: np.ndarray, speed: np.ndarray, dt: float, car: CarModel
) -> np.ndarray:
    """[N] highest speed for the next step: Gipps' bound, kept above an emergency stop.

    Driving at most -b dt + sqrt((b dt)^2 + u^2 + 2 b g) leaves room to stop behind a
    leader at speed u, `gap` g ahead, should it brake at b (the agent's own max_brake).
    """
    b = car.max_brake
    room = np.maximum(gap - STANDSTILL_GAP, 0.0)
    bound = -b * dt + np.sqrt((b * dt) ** 2 + leader_speed**2 + 2 * b * room)
    return np.maximum(bound, speed - EMERGENCY_DECEL * dt)
