"""Rewards of the paper (section III-A), as named terms for all agents at once.

One formula serves every behaviour, as parameter sharing requires:

    R = R_lk + id * 100 * (n - racePos) + extra conditions
    R_lk = v (cos(angle) - |sin(angle)|),   v in km/h

The paper prints `sin` without the bars; that would reward drifting to one
side, so the absolute value is used. id is 0 for lane keeping, 1 for
overtaking; the extra conditions (collision, off-track, no progress) are added
on the step they happen, which also ends the agent's episode.

Optional, off by default (the paper has no such term): a lane-discipline term
-w v |lane offset| / (lane width / 2), the lane-level cousin of the
-v |trackPos| term of the common DDPG-TORCS code. The paper's reward leaves a
car's lateral place free, and DDPG then parks cars astride lane lines, which
also makes SUMO's sublane model work harder for everyone around them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

COLLISION_PENALTY = -1000.0
OFF_TRACK_PENALTY = -1000.0
NO_PROGRESS_PENALTY = -500.0
RACE_BONUS = 100.0
NO_PROGRESS_SPEED = 1.0
"""m/s: below this for NO_PROGRESS_SECONDS in a row counts as no progress."""
NO_PROGRESS_SECONDS = 5.0

TERM_NAMES = ("progress", "lane", "race", "collision", "off_track", "no_progress")


@dataclass(frozen=True)
class RewardTerms:
    """Per-agent reward terms of one step; `total` is their sum."""

    progress: np.ndarray
    lane: np.ndarray
    race: np.ndarray
    collision: np.ndarray
    off_track: np.ndarray
    no_progress: np.ndarray

    @property
    def total(self) -> np.ndarray:
        return self.progress + self.lane + self.race + self.collision + self.off_track + self.no_progress

    def as_dict(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in TERM_NAMES}


def lanekeeping_reward(speed: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """R_lk = v (cos(angle) - |sin(angle)|) with v in km/h."""
    return speed * 3.6 * (np.cos(angle) - np.abs(np.sin(angle)))


def race_positions(progress: np.ndarray) -> np.ndarray:
    """1-based rank by progress along the route (1 = furthest ahead; ties share the better rank)."""
    order = np.sort(progress)[::-1]
    return np.searchsorted(-order, -progress, side="left") + 1


def step_rewards(
    speed: np.ndarray,
    angle: np.ndarray,
    behaviour_id: np.ndarray,
    race_pos: np.ndarray,
    n_cars: int,
    collided: np.ndarray,
    off_track: np.ndarray,
    no_progress: np.ndarray,
    lane_deviation: np.ndarray | None = None,
    lane_weight: float = 0.0,
) -> RewardTerms:
    """`lane_deviation`: |offset from the lane centre| / half the lane width (0 centre, 1 on a line)."""
    lane = np.zeros(len(speed)) if lane_deviation is None else -lane_weight * speed * 3.6 * lane_deviation
    return RewardTerms(
        progress=lanekeeping_reward(speed, angle),
        lane=lane,
        race=behaviour_id * RACE_BONUS * (n_cars - race_pos),
        collision=np.where(collided, COLLISION_PENALTY, 0.0),
        off_track=np.where(off_track, OFF_TRACK_PENALTY, 0.0),
        no_progress=np.where(no_progress, NO_PROGRESS_PENALTY, 0.0),
    )
