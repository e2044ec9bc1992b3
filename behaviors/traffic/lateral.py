"""The lateral profile: how fast a car moves sideways towards the centre of the lane it heads for,
within human comfort, and the sideways move that makes in one step."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.traffic.scene import Motion, RoadPlace
from behaviors.traffic.settings import LaneDriving


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
    the cap cuts the speed at once (a car SUMO gave back crawling, faster sideways than its reach),
    the cut carried on would swing the car the other way, off the road."""
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
class SidewaysMove:
    """One step's sideways motion of each agent (+ = fast side)."""

    lateral_speed: np.ndarray  # [N] m/s
    lateral_accel: np.ndarray  # [N] m/s^2 carried to the next step
    move: np.ndarray  # [N] m this step, before the carriageway's border
    side_cut: np.ndarray  # [N] bool: the shield's `side_limit` cut the move


def sideways(
    heading: np.ndarray,
    motion: Motion,
    place: RoadPlace,
    speed: np.ndarray,
    lateral: LaneDriving,
    dt: float,
    lane_bias: np.ndarray | None,
    side_limit: np.ndarray | None,
) -> SidewaysMove:
    """The move towards the centre of the lane each car heads for (`lane_bias` [N] m towards the
    fast side of it, None: on it) at its new `speed`, cut to `side_limit` [N, 2] (to the fast and
    slow side; None: no cut), where the cut move is the lateral speed and no acceleration is kept."""
    error = heading * place.lane_width - place.lane_offset
    if lane_bias is not None:
        error = error + lane_bias
    new_lateral, new_accel = lateral_profile(
        error, motion.lateral_speed, motion.lateral_accel, speed, dt, lateral
    )
    move = new_lateral * dt
    side_cut = np.zeros(len(move), bool)
    if side_limit is not None:
        limited = np.clip(move, -side_limit[:, 1], side_limit[:, 0])
        side_cut = limited != move
        move = limited
        new_lateral = np.where(side_cut, move / dt, new_lateral)
        new_accel = np.where(side_cut, 0.0, new_accel)
    return SidewaysMove(new_lateral, new_accel, move, side_cut)
