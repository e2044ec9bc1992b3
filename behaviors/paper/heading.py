"""The paper's heading model: steering turns a car's heading relative to the road axis (a kinematic
bicycle, capped by a lateral-acceleration limit), road curvature turns the road under it (so steer
0 on a curve drifts outward), and the car moves v*cos(angle) along its lane (setSpeed) and
v*sin(angle) across it (changeSublane): SUMO's sublane model has no heading of its own."""

from __future__ import annotations

import numpy as np

from behaviors.car.model import NO_SHIELD, Actuation, CarModel, ShieldBounds, clamp_to_road, longitudinal
from behaviors.road.geometry import wrap_angle


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
    shield: ShieldBounds = NO_SHIELD,
) -> Actuation:
    """One control step of the paper's heading model for all agents.

    `offset` is the car centre's distance from the carriageway centre (positive =
    left), `half_width` half the carriageway width, `curvature` the road axis's
    curvature (1/m, positive = turning left) at the car. The shield's `side_limit` [N, 2], if given,
    caps the sideways move to the left and right, its `speed_cap` [N] the speed (see shield.py);
    a car whose sideways move was cut has its heading turned back to match the move it makes.
    """
    side_limit = shield.side_limit
    steer = np.clip(actions[:, 0], -1.0, 1.0)
    new_speed, speed_cut = longitudinal(actions, speed, speed_limit, dt, car, shield.speed_cap)
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
