"""Turn the traffic driver's (steer, accel, brake) into SUMO commands (the paper's heading model is
paper/heading.py). Its steer chooses a lane, and its accel and brake adjust a car-following law:
`actuate_lanes` composes the motives (motives/), the lane choice (intent.py), the limits
(limits.py) and the lateral profile (lateral.py). Pure numpy; `SumoSim.command_agents` writes the
result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.car.model import NO_SHIELD, Actuation, CarModel, ShieldBounds, capped, clamp_to_road
from behaviors.traffic.intent import lane_intent, lane_wish
from behaviors.traffic.lateral import sideways
from behaviors.traffic.limits import SPEED_BOUNDS, bounded, lane_room, reaching_accel, toward
from behaviors.traffic.motives.strategic import leaving_lane
from behaviors.traffic.motives.wishes import lane_wishes
from behaviors.traffic.scene import (
    SETTINGS_STYLE,
    AgentStyle,
    LaneNeighbours,
    Motion,
    RoadPlace,
    Scene,
    own_lane_traffic,
)
from behaviors.traffic.settings import DriverSettings, LaneDriving


@dataclass(frozen=True)
class LaneCommand:
    """The traffic driver's actuation, the per-agent state it carries to the next step, and which
    agents each named limit vetoed or bound."""

    actuation: Actuation
    changing: np.ndarray  # [N] int, see `intent.lane_intent`
    lateral_accel: np.ndarray  # [N] m/s^2, + = fast side
    held_for: np.ndarray  # [N] s the car has been held up (`speed_gain.held_up`) without a break
    limited: dict[str, np.ndarray]  # limits.LIMIT_NAMES -> [N] bool: the agents it vetoed or bound


def policy_push(actions: np.ndarray, lateral: LaneDriving, car: CarModel) -> np.ndarray:
    """[N] m/s^2 the policy adds to the law: accel 0.5 and brake 0 add nothing, accel 1 (0) adds
    (takes) `accel_span`, brake takes up to the car's max_brake. Where the network chooses, its accel
    chose the headway (`AgentStyle.time_headway`) and only its brake counts."""
    accel = np.clip(actions[:, 1], 0.0, 1.0)
    brake = np.clip(actions[:, 2], 0.0, 1.0)
    if lateral.network_chooses:
        return -car.max_brake * brake
    return 2.0 * lateral.accel_span * (accel - 0.5) - car.max_brake * brake


def acceleration(
    actions: np.ndarray, scene: Scene, heading: np.ndarray
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """[N] m/s^2 each car accelerates at: the law behind its leader (and behind the leader of a lane
    its body reaches into) with the policy's push, under the speed bounds where any rule is on (with
    none, behind the leader of the lane it heads for too), within the car's limits; and per bound
    the agents whose push it cut."""
    car, lateral = scene.driver.car, scene.lateral
    follow = np.minimum(scene.traffic.lead_accel[:, 0], scene.reaching)
    push = policy_push(actions, lateral, car)
    if lateral.rules.any:
        command, cut = bounded(follow + push, scene, heading)
    else:
        command = np.minimum(follow, toward(scene.traffic, heading)) + push
        cut = {limit.name: np.zeros(len(push), bool) for limit in SPEED_BOUNDS}
    return np.clip(command, -car.max_brake, car.max_accel), cut


def actuate_lanes(
    actions: np.ndarray,
    motion: Motion,
    place: RoadPlace,
    neighbours: LaneNeighbours,
    driver: DriverSettings,
    style: AgentStyle = SETTINGS_STYLE,
    shield: ShieldBounds = NO_SHIELD,
) -> LaneCommand:
    """One control step of the traffic driver for all agents: the motives turn the policy's steer
    into a lane wish, the limits' vetoes leave the lanes a change may go into, the lane choice heads
    for one, the law with the policy's accel and brake under the limits' bounds gives the speed,
    and the lateral profile the move towards that lane's centre.

    Everything sideways is signed as SUMO's lane indices and `changeSublane` are: + towards the fast
    side (the left in keep-right nets, the right in left-hand ones, which SUMO mirrors). `angle` in
    the result is atan(lateral speed / speed). A car that wants more than the limit (`desired_speed`
    above `speed_limit`) drives at what it wants, as a share of real drivers and of SUMO's do. A
    change the shield blocks is given up: the car heads back to its own lane's centre.
    """
    lateral, car, dt = driver.lateral, driver.car, driver.dt
    traffic = own_lane_traffic(motion, neighbours, lateral.following, style.time_headway)
    reaching = reaching_accel(traffic, motion, place, driver)
    scene = Scene(traffic, motion, place, neighbours, driver, leaving_lane(motion, place, lateral), reaching)
    wishes = lane_wishes(np.clip(actions[:, 0], -1.0, 1.0), scene, style.habits)
    wish = lane_wish(wishes, place, lateral, scene.leave)
    room = lane_room(scene, wish)
    heading = lane_intent(wish, motion.changing, place, room.open, room.give_up, lateral)
    accel, cut = acceleration(actions, scene, heading)
    top = np.maximum(place.speed_limit, motion.desired_speed)
    new_speed, speed_cut = capped(np.clip(motion.speed + accel * dt, 0.0, top), shield.speed_cap)
    side = sideways(heading, motion, place, new_speed, lateral, dt, style.lane_bias, shield.side_limit)
    heading = np.where(side.side_cut, 0, heading)
    move, off_track = clamp_to_road(place.offset, side.move, place.half_width, car)
    angle = np.arctan2(side.lateral_speed, np.maximum(new_speed, 0.1))
    result = Actuation(
        new_speed, angle, new_speed, move, off_track, side.side_cut, speed_cut, side.lateral_speed
    )
    return LaneCommand(result, heading, side.lateral_accel, wishes.held_for, {**room.vetoed, **cut})
