"""The learned car: its physical limits (`CarModel`), the shield's bounds on a step (`ShieldBounds`),
what a step of actuation commands (`Actuation`), and the speed and sideways-move arithmetic both
drivers' actuations share. Pure numpy."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
class ShieldBounds:
    """What the safety shield (shield.py) allows each agent this step; None: no bound."""

    side_limit: np.ndarray | None = None  # [N, 2] m: the sideways move to the fast and slow side
    speed_cap: np.ndarray | None = None  # [N] m/s


NO_SHIELD = ShieldBounds()
"""No bound: the bare policy."""


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
    limits: dict[str, int] = field(default_factory=dict)  # agents each named limit vetoed or bound
    # (limits.LIMIT_NAMES; traffic model only)


def capped(speed: np.ndarray, speed_cap: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """`speed` under the shield's `speed_cap` (None: none), and where the cap cut it."""
    if speed_cap is None:
        return speed, np.zeros(len(speed), bool)
    speed_cut = speed > speed_cap
    return np.where(speed_cut, np.maximum(speed_cap, 0.0), speed), speed_cut


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
    return capped(new_speed, speed_cap)


def clamp_to_road(
    offset: np.ndarray, move: np.ndarray, half_width: np.ndarray, car: CarModel
) -> tuple[np.ndarray, np.ndarray]:
    """The sideways move cut to the room left on the carriageway, and where it would have left it."""
    room = half_width - car.width / 2
    target = offset + move
    return np.clip(target, -room, room) - offset, np.abs(target) > room
