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

from dataclasses import dataclass

import numpy as np

from behaviors.geometry import wrap_angle


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
class LaneDriving:
    """Lateral limits of the `traffic` driver model: steer sets a lateral speed, not a heading.

    SUMO's sublane model has no heading: `changeSublane(0)` follows the lane, so in the
    traffic model steer 0 holds the car's place in its lane (on curves too) and steer +-1
    asks for `max_lateral_speed` towards the fast/slow side, reached at most at
    `max_lateral_accel` (a firm lane change; SUMO's own drivers default to 1 m/s^2 with
    `lcAccelLat`). The paper's heading model (`actuate`) stays for the paper's policies.
    """

    max_lateral_speed: float = 1.5  # m/s: 3.5 m lane in about 3 s at full steer
    max_lateral_accel: float = 2.0  # m/s^2
    max_slip: float = 0.25  # lateral speed at most this fraction of the forward speed


def actuate_lanes(
    actions: np.ndarray,
    speed: np.ndarray,
    lateral_speed: np.ndarray,
    offset: np.ndarray,
    half_width: np.ndarray,
    speed_limit: np.ndarray,
    dt: float,
    car: CarModel,
    lateral: LaneDriving,
    side_limit: np.ndarray | None = None,
    speed_cap: np.ndarray | None = None,
) -> Actuation:
    """One control step of the traffic model for all agents.

    Everything sideways is signed as SUMO's lane indices and `changeSublane` are: + towards
    the fast side (the left in keep-right nets, the right in left-hand ones, which SUMO
    mirrors). `angle` in the result is atan(lateral speed / speed).
    """
    steer = np.clip(actions[:, 0], -1.0, 1.0)
    new_speed, speed_cut = longitudinal(actions, speed, speed_limit, dt, car, speed_cap)
    reach = np.minimum(lateral.max_lateral_speed, lateral.max_slip * new_speed)
    wanted = steer * reach
    step = lateral.max_lateral_accel * dt
    new_lateral = np.clip(lateral_speed + np.clip(wanted - lateral_speed, -step, step), -reach, reach)
    move = new_lateral * dt
    side_cut = np.zeros(len(move), bool)
    if side_limit is not None:
        limited = np.clip(move, -side_limit[:, 1], side_limit[:, 0])
        side_cut = limited != move
        move = limited
        new_lateral = np.where(side_cut, move / dt, new_lateral)
    move, off_track = clamp_to_road(offset, move, half_width, car)
    angle = np.arctan2(new_lateral, np.maximum(new_speed, 0.1))
    return Actuation(new_speed, angle, new_speed, move, off_track, side_cut, speed_cut, new_lateral)
