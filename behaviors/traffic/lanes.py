"""What a driver in lanes needs to see: the `traffic` observation, for all agents at once.

The paper's TORCS state knows the carriageway borders but not the lane lines, and one frame
of opponent distances carries no closing speed: no policy can learn to hold a lane of its
choice or to follow a slower car from it. This observation gives, per agent, its own lane
(offset, width, lanes beside it, how far each lane leads on along the route), its speed
against a desired speed, and for the leader and follower in its own and the two adjacent
lanes their gap and relative speed.

Sides are lane-index sides, not geometric ones: "fast" is towards higher lane indices (the
left in keep-right nets, the right in left-hand nets), "slow" towards lane 0. A policy
that passes on the fast side and keeps to the slow side thus drives correctly in both kinds
of net. Pure numpy: no SUMO here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.road.geometry import NEXT_LANES_SEEN, RoadGeometry, road_coordinates
from behaviors.road.neighbours import Neighbours, nearest_per_slot, neighbours, within
from behaviors.sumo.sim import STANDSTILL_SPEED
from behaviors.traffic.bodies import Bodies
from behaviors.traffic.law import nan_as
from behaviors.traffic.shield import PASSING_ROOM

SPEED_SCALE = 40.0
"""m/s: speeds are divided by this."""
GAP_RANGE = 150.0
"""m: neighbours farther than this along the road are not seen (gap 1 after scaling)."""
RELATIVE_SPEED_SCALE = 15.0
LANE_END_RANGE = 500.0
"""m: how far a lane leads on is seen up to this distance (1 = at least that far)."""
MAX_LANES_SEEN = 3


def search_radius(longest: float) -> float:
    """m between front bumpers: the farthest a neighbour within GAP_RANGE can be when the longest
    vehicle (agents included) is `longest` metres long."""
    return GAP_RANGE + longest


NEIGHBOUR_SLOTS = ("leader", "follower", "fast_leader", "fast_follower", "slow_leader", "slow_follower")
"""Order of the six neighbours: own lane, the fast-side lane, the slow-side lane."""
SLOTS_KEPT = 9
"""The six, the nearest leader beyond the fast-side lane and two followers by their centres."""

TRAFFIC_LAYOUT = (
    ("speed", 1),
    ("desired_speed", 1),
    ("speed_error", 1),
    ("speed_limit", 1),
    ("lateral_speed", 1),
    ("lane_change", 1),
    ("lane_offset", 1),
    ("lane_width", 1),
    ("lanes_fast_side", 1),
    ("lanes_slow_side", 1),
    ("curvature", 1),
    ("lane_leads_on", 3),
    ("gap", 6),
    ("relative_speed", 6),
    ("behaviour", 1),
)
"""Names and sizes in order (see the README's table)."""

TRAFFIC_SLICES: dict[str, slice] = {}
_start = 0
for _name, _size in TRAFFIC_LAYOUT:
    TRAFFIC_SLICES[_name] = slice(_start, _start + _size)
    _start += _size
TRAFFIC_OBS_SIZE = _start
del _start, _name, _size


@dataclass(frozen=True)
class LaneAgents:
    """The controlled agents in one step, in their lanes (row i = agent i).

    Lateral quantities are signed towards the fast side (+ = towards higher lane indices).
    """

    front: np.ndarray  # [N, 2] front bumper centre, metres (SUMO's position)
    lane_row: np.ndarray  # [N] the own lane's row in the RoadGeometry
    shape_pos: np.ndarray  # [N] metres of the front along the own lane's shape
    curvature: np.ndarray  # [N] 1/m of the road axis, + = turning to the geometric left
    speed: np.ndarray  # [N] m/s along the road
    lateral_speed: np.ndarray  # [N] m/s, + = towards the fast side
    changing: np.ndarray  # [N] the lane change under way: +1 to the fast side, -1 to the slow, 0 none
    desired_speed: np.ndarray  # [N] m/s
    speed_limit: np.ndarray  # [N] m/s
    lane_offset: np.ndarray  # [N] metres from the own lane's centre, + = fast side
    lane_width: np.ndarray  # [N] metres
    lane_number: np.ndarray  # [N] own lane index (0 = slow side)
    lanes: np.ndarray  # [N] lanes of the carriageway
    lane_leads_on: np.ndarray  # [N, 3] metres the own, fast-side and slow-side lane lead on along the route
    behaviour_id: np.ndarray  # [N] 0 keeper, 1 overtaker
    fast_side_sign: float = 1.0  # +1 when the fast side is the geometric left (keep-right nets)


@dataclass(frozen=True)
class Surroundings:
    """Leaders and followers around each agent, in metres and m/s (not normalised).

    `gap` is bumper to bumper, +inf when nobody is within GAP_RANGE and 0 where the lane does
    not exist (a wall); `other_speed` is the neighbour's speed (nan when there is none).
    Columns follow NEIGHBOUR_SLOTS. `far_fast_gap`/`far_fast_speed`: the nearest leader in any
    lane beyond the fast-side one (not observed: the rule against passing on the slow side reads
    it, since a car two lanes over is passed on the wrong side too).
    """

    gap: np.ndarray  # [N, 6]
    other_speed: np.ndarray  # [N, 6]
    far_fast_gap: np.ndarray  # [N]
    far_fast_speed: np.ndarray  # [N]
    lane_follower_gap: np.ndarray  # [N, 2] the nearest follower whose centre is in the fast-side and
    lane_follower_speed: np.ndarray  # [N, 2] slow-side lane, as the slots where there is no lane (not
    # observed: a car across the line nearer behind fills the follower slot and hides it, and a lane
    # change must not)
    side_leader_row: np.ndarray  # [N, 2] int: the fast-side and slow-side leaders' rows among all
    # vehicles, -1 where none (not observed: the driver asks SUMO whether they want to come over)

    @property
    def lead_gap(self) -> np.ndarray:
        return self.gap[:, 0]

    @property
    def lead_speed(self) -> np.ndarray:
        return self.other_speed[:, 0]


def lane_coordinates(
    geometry: RoadGeometry,
    lane_row: np.ndarray,
    shape_pos: np.ndarray,
    front: np.ndarray,
    pairs: np.ndarray,
    offset: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(along, across) of world `offset`s from cars' fronts (car `pairs[k]` for offset k), in the
    frame of each car's own lane.

    `along` runs along the lane's centre line from the car's front, `across` is the distance
    from that line (+ geometric left). A lane is a polyline and SUMO places cars on it, so
    the point is projected onto the polyline itself: a car in the same lane beyond a vertex
    where the road turns 12 degrees stays in that lane. Beyond the lane's end the car's lane
    goes on as the lane it leads into, where that is one (`RoadGeometry.lane_next`: through the
    junction and into the next edge), else with the end's curvature; behind its start, as the
    lane a car came on from, where that is one (`RoadGeometry.lane_prev`). A segment is
    straight, so a projection that stays on the car's own segment is exact at once; only the
    others (beyond a vertex, off the lane's ends) are projected once more, unless the lane is one
    straight segment, which goes on straight.
    """
    car = geometry.lane_pose(lane_row, shape_pos, with_curvature=False)
    # each target from its car's point on the lane, x and y apart: gathers and products on
    # contiguous columns, not on strided views of [K, 2] (a third less time at 12,000 pairs)
    front_from_lane = front - car.point
    x = offset[:, 0] + front_from_lane[:, 0][pairs]
    y = offset[:, 1] + front_from_lane[:, 1][pairs]
    cos, sin = np.cos(car.angle)[pairs], np.sin(car.angle)[pairs]
    along = x * cos + y * sin
    across = y * cos - x * sin
    bends = geometry.lane_segments[lane_row] > 1
    if bends.any():  # a lane of one straight segment (a motorway's often are) needs no second look
        at = shape_pos[pairs] + along
        beyond = bends[pairs] & ((at < car.segment_start[pairs]) | (at > car.segment_end[pairs]))
        if beyond.any():
            k = np.flatnonzero(beyond)
            own, target = pairs[k], front[pairs[k]] + offset[k]
            along[k], across[k] = _project(geometry, lane_row[own], shape_pos[own], target, along[k])
    for ahead in (True, False):  # beyond the lane's end, then behind its start
        departs = geometry.lane_next_departs if ahead else geometry.lane_prev_departs
        chained = departs(lane_row)
        if not chained.any():
            continue
        edge = geometry.lane_shape_length[lane_row] - shape_pos if ahead else -shape_pos
        outside = along > edge[pairs] if ahead else along < edge[pairs]
        k = np.flatnonzero(chained[pairs] & outside)
        if len(k):
            target = front[pairs[k]] + offset[k]
            along[k], across[k] = _along_chained_lanes(
                geometry, lane_row[pairs[k]], edge[pairs[k]], target, along[k], ahead
            )
    return along, across


def _along_chained_lanes(
    geometry: RoadGeometry,
    lane_row: np.ndarray,
    edge: np.ndarray,
    target: np.ndarray,
    along: np.ndarray,
    ahead: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """(along, across) of `target`s beyond the end of lanes that lead into one lane (`ahead`) or
    behind the start of lanes a car came on from one lane (`edge`: metres from the car to that end
    or start, negative behind): measured along the lanes that chain on from there (`lane_next`,
    `lane_prev`), as the car will drive or came. Extrapolating the own lane misplaced cars where
    the lanes shift sideways through a junction: at a lane drop, the queue in the lane ahead read
    as the slow-side lane's; on `motorway4`, past the lanes the on-ramp adds, a car coming up at 28
    m/s in the lane that leads into the fast-side lane read as two lanes over, and an agent moved
    out in front of it at 7 m/s."""
    chain, sign = (geometry.lane_next, 1.0) if ahead else (geometry.lane_prev, -1.0)
    out_along, out_across = along.copy(), np.zeros(len(along))
    todo = np.arange(len(along))
    row, past = lane_row, along - edge  # metres past the edge, signed as `along`
    for hop in range(NEXT_LANES_SEEN):
        row = chain[row]
        length = geometry.lane_shape_length[row]
        # where on this lane the chain comes in (near) and goes on (far)
        near, far = (np.zeros(len(row)), length) if ahead else (length, np.zeros(len(row)))
        at, across = _project(geometry, row, np.zeros(len(row)), target, near + past)
        past = at - far
        further = (sign * past > 0.0) & (chain[row] >= 0) & (hop + 1 < NEXT_LANES_SEEN)
        done = ~further
        out_along[todo[done]] = (edge + (at - near))[done]
        out_across[todo[done]] = across[done]
        todo, row, target = todo[further], row[further], target[further]
        edge, past = (edge + (far - near))[further], past[further]
        if not len(todo):
            break
    return out_along, out_across


def _project(
    geometry: RoadGeometry, lane_row: np.ndarray, shape_pos: np.ndarray, target: np.ndarray, along: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One Newton step of the projection onto the lane polyline from a first guess `along` (the
    guess lands within a few metres of the foot even 150 m round a 300 m bend), with the
    segment's curvature carrying on beyond the lane's ends."""
    pose = geometry.lane_pose(lane_row, shape_pos + along)
    r = target - pose.point
    ahead, across = road_coordinates(r[:, 0], r[:, 1], pose.angle, pose.curvature)
    return pose.pos - shape_pos + ahead, across


def surroundings(
    agents: LaneAgents,
    positions: np.ndarray,
    speeds: np.ndarray,
    agent_rows: np.ndarray,
    geometry: RoadGeometry,
    near: Neighbours | None = None,
    bodies: Bodies | None = None,
) -> Surroundings:
    """Nearest leader and follower in the own, fast-side and slow-side lane of every agent.

    A vehicle counts in every lane its body overlaps (a car mid-change blocks both lanes);
    one alongside counts as a leader or follower with gap 0. `positions`/`speeds` cover all
    vehicles (SUMO's too); `agent_rows[i]` is agent i's own row there. `bodies`: every vehicle's
    size (None: all of the agents' size). Gaps are bumper to bumper: to a leader's rear, from a
    follower's front to the agent's rear. `near`: the pairs of a neighbour search already made with
    at least `search_radius(bodies.longest)` (one search serves the shield too).
    """
    n = len(agents.speed)
    bodies = Bodies.cars(len(positions)) if bodies is None else bodies
    radius = search_radius(bodies.longest)
    # NEIGHBOUR_SLOTS, the nearest leader beyond the fast-side lane, the nearest followers whose centres
    # are in the fast-side and in the slow-side lane
    gap = np.full((n, SLOTS_KEPT), np.inf)
    other = np.full((n, SLOTS_KEPT), np.nan)
    who = np.full((n, SLOTS_KEPT), -1, np.int64)
    if near is None:
        near = neighbours(agents.front, positions, radius, exclude=agent_rows)
    q, m, dx, dy, square = within(near, radius)
    if len(q):
        along, across = lane_coordinates(
            geometry, agents.lane_row, agents.shape_pos, agents.front, q, np.stack([dx, dy], axis=1)
        )
        behind = along < 0
        # the body between the two front bumpers: the leader's, or the agent's own for a follower
        own_length, own_width = (np.broadcast_to(size, q.shape) for size in bodies.own_size(q))
        body = np.where(behind, own_length, bodies.length[m])
        seen = square < (GAP_RANGE + body) ** 2
        if not seen.all():  # only where some vehicle is longer than another
            k = np.flatnonzero(seen)
            q, m, along, across, behind, body, own_width = (
                q[k],
                m[k],
                along[k],
                across[k],
                behind[k],
                body[k],
                own_width[k],
            )
        # the other car's lateral place in own-lane widths, 0 = own lane centre
        width = agents.lane_width[q]
        lane_units = across * agents.fast_side_sign / width
        other_width = bodies.width[m]
        half = other_width / 2 / width
        slow_edge, fast_edge = lane_units - half, lane_units + half  # worked out once for all lanes
        distance = np.abs(along) - body
        row_slot = q * SLOTS_KEPT + behind  # + a lane's leader column: its leader, or the follower beside it
        slots, pairs = [], []
        for side, column in ((0, 0), (1, 2), (-1, 4)):
            k = np.flatnonzero((fast_edge > side - 0.5) & (slow_edge < side + 0.5))
            if side == 0:
                # a car standing alongside with its body over the line and room to drive past it
                # leads nobody: else, at a lane drop's end, it and an agent waiting beside it
                # would hold each other up
                standing = (distance[k] <= 0) & (speeds[m[k]] < STANDSTILL_SPEED)
                if standing.any():
                    s = k[standing]
                    centres = np.abs(lane_units[s] * width[s] - agents.lane_offset[q[s]])
                    room = centres - (own_width[s] + other_width[s]) / 2
                    standing[standing] = room >= PASSING_ROOM
                    k = k[~standing]
            slots.append(row_slot[k] + column)
            pairs.append(k)
        k = np.flatnonzero((slow_edge > 1.5) & ~behind)
        slots.append(row_slot[k] + 6)
        pairs.append(k)
        beside = np.flatnonzero(behind & (np.abs(lane_units) > 0.5) & (np.abs(lane_units) < 1.5))
        slots.append(q[beside] * SLOTS_KEPT + np.where(lane_units[beside] > 0, 7, 8))
        pairs.append(beside)
        slot, pair = np.concatenate(slots), np.concatenate(pairs)
        found, nearest = nearest_per_slot(n * SLOTS_KEPT, slot, distance[pair])
        gap.ravel()[found] = distance[pair[nearest]]
        other.ravel()[found] = speeds[m[pair[nearest]]]
        who.ravel()[found] = m[pair[nearest]]
    gap = np.maximum(gap, 0.0)
    far_gap, far_speed = gap[:, 6], other[:, 6]
    behind_gap, behind_speed = gap[:, 7:], other[:, 7:]
    gap, other = gap[:, :6], other[:, :6]
    fast_missing = agents.lane_number >= agents.lanes - 1
    slow_missing = agents.lane_number <= 0
    for missing, columns, follower in ((fast_missing, slice(2, 4), 0), (slow_missing, slice(4, 6), 1)):
        gap[missing, columns], other[missing, columns] = 0.0, np.nan
        behind_gap[missing, follower], behind_speed[missing, follower] = 0.0, np.nan
        who[missing, columns.start] = -1
    return Surroundings(gap, other, far_gap, far_speed, behind_gap, behind_speed, who[:, [2, 4]])


def observe_lanes(agents: LaneAgents, around: Surroundings) -> np.ndarray:
    """float32 [N, TRAFFIC_OBS_SIZE] observations, normalised to about [-1, 1]."""
    n = len(agents.speed)
    obs = np.empty((n, TRAFFIC_OBS_SIZE), np.float32)
    put = _writer(obs)
    put("speed", agents.speed / SPEED_SCALE)
    put("desired_speed", agents.desired_speed / SPEED_SCALE)
    put("speed_error", np.clip((agents.speed - agents.desired_speed) / 10.0, -1.0, 1.0))
    put("speed_limit", agents.speed_limit / SPEED_SCALE)
    put("lateral_speed", agents.lateral_speed / 2.0)
    put("lane_change", agents.changing)
    put("lane_offset", np.clip(agents.lane_offset / (agents.lane_width / 2), -1.5, 1.5))
    put("lane_width", agents.lane_width / 4.0)
    put("lanes_fast_side", np.minimum(agents.lanes - 1 - agents.lane_number, MAX_LANES_SEEN) / MAX_LANES_SEEN)
    put("lanes_slow_side", np.minimum(agents.lane_number, MAX_LANES_SEEN) / MAX_LANES_SEEN)
    put("curvature", np.clip(agents.curvature * agents.fast_side_sign * 100.0, -1.0, 1.0))
    put("lane_leads_on", np.clip(agents.lane_leads_on / LANE_END_RANGE, 0.0, 1.0))
    put("gap", np.minimum(around.gap / GAP_RANGE, 1.0))
    relative = nan_as(around.other_speed - agents.speed[:, None], 0.0)  # speeds are finite
    put("relative_speed", np.clip(relative / RELATIVE_SPEED_SCALE, -1.0, 1.0))
    put("behaviour", agents.behaviour_id)
    return obs


def _writer(obs: np.ndarray):
    def put(name: str, values: np.ndarray) -> None:
        values = np.asarray(values)
        obs[:, TRAFFIC_SLICES[name]] = values if values.ndim == 2 else values[:, None]

    return put
