"""The car-following law: the Improved Intelligent Driver Model (Treiber and Kesting 2013), worked
out for all agents at once and for up to ten leaders per car (pure numpy)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.traffic.settings import CarFollowing


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


def new_follower_accel(
    speed: np.ndarray, follower_gap: np.ndarray, follower_speed: np.ndarray, law: CarFollowing
) -> np.ndarray:
    """[N] the acceleration the car behind in a neighbour lane would need were the car to move in
    front of it (0 where nobody is behind), by the same car-following law at its own speed;
    `follower_speed` has no NaN. `follower_gap`/`follower_speed` may be [k, N] (k followers per car)."""
    braking = behind_leader(free_road(follower_speed, follower_speed, law), follower_gap, speed, law)
    return np.where(np.isfinite(follower_gap), braking, 0.0)
