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

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Protocol, TypeVar

import numpy as np

from behaviors.errors import BehaveError

COLLISION_PENALTY = -1000.0
OFF_TRACK_PENALTY = -1000.0
NO_PROGRESS_PENALTY = -500.0
RACE_BONUS = 100.0
NO_PROGRESS_SPEED = 1.0
"""m/s: below this for NO_PROGRESS_SECONDS in a row counts as no progress."""
NO_PROGRESS_SECONDS = 5.0

TERM_NAMES = ("progress", "lane", "race", "collision", "off_track", "no_progress")


class StepTerms(Protocol):
    """What a step's reward terms offer, whichever reward made them (RewardTerms, TrafficTerms)."""

    @property
    def total(self) -> np.ndarray: ...

    @property
    def progress(self) -> np.ndarray: ...

    def as_dict(self) -> dict[str, np.ndarray]: ...


class RewardWeightError(BehaveError):
    """A reward weight for a term the driver's reward does not have, or one that is not finite."""


def check_reward_weights(weights: Mapping[str, float], terms: Sequence[str], driver: str) -> None:
    """RewardWeightError unless every weight names one of `terms` and is a finite number: a
    misspelled term would otherwise be ignored silently."""
    unknown = sorted(set(weights) - set(terms))
    if unknown:
        raise RewardWeightError(
            f"no reward term {', '.join(map(repr, unknown))} in the {driver} driver's reward "
            f"(its terms: {', '.join(terms)})"
        )
    for name, weight in weights.items():
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not math.isfinite(weight):
            raise RewardWeightError(f"reward weight of '{name}' must be a finite number, got {weight!r}")


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

    def weighted(self, weights: Mapping[str, float]) -> RewardTerms:
        """The terms each times its weight (terms not named keep weight 1)."""
        return replace(self, **{name: getattr(self, name) * w for name, w in weights.items()})


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


# --- the traffic reward: driving behaviour as named terms -------------------------------

TRAFFIC_TERM_NAMES = (
    "speed",
    "headway",
    "closing",
    "centre",
    "lane_change",
    "keep_slow_side",
    "pass_slow_side",
    "comfort",
    "collision",
    "off_track",
    "no_progress",
)


@dataclass(frozen=True)
class TrafficWeights:
    """Weights and thresholds of the traffic reward; one step's terms are about [-1, 1].

    Keepers and overtakers share one formula (parameter sharing) and differ only through the
    behaviour id: a lane change costs a keeper much more, and an overtaker is asked to return to
    the slow side when that lane is free. Both are judged against the speed their lane allows:
    following a slower leader costs nothing while the car keeps up with it (within `free_gap` +
    `free_headway` x speed; the car-following law keeps 2.5 m + 1.2 s), and hanging back behind it
    costs as much as driving slower than wanted on a free road. With the leader's speed counting
    out to 1.6 s, and an overtaker judged against its desired speed whatever was ahead, a fine-tuned
    policy learnt to hang back (headways 1.37 s on a curved motorway, 20% less flow at 27 veh/lane-km
    with every car learned); passing is the lane habits' (`TrafficDriver.habits`), not the reward's.
    """

    safe_headway: float = 1.0  # s: following closer than this costs, in proportion (fined below 0.9 s)
    standstill_gap: float = 2.0  # m: added to the safe headway's gap; a standing queue needs no more
    safe_ttc: float = 4.0  # s: closing in faster than this costs, in proportion
    headway: float = 2.0
    closing: float = 1.0
    centre: float = 0.3  # per half lane width off the lane centre
    lane_change_keeper: float = 4.0  # per lane change
    lane_change_overtaker: float = 0.5
    keep_slow_side: float = 0.3  # per step in a lane with a free lane on the slow side
    pass_slow_side: float = 1.0  # per step passing a car on its slow side, at 5 m/s faster
    comfort: float = 0.3  # per (lateral acceleration / 1.5 m/s^2)^2
    comfort_longitudinal: float = 0.05  # per (acceleration / 3 m/s^2)^2
    crash: float = 20.0  # collision or off-track
    no_progress: float = 10.0
    free_headway: float = 1.3  # s: a leader nearer than free_gap + this x speed sets the target speed
    free_gap: float = 3.0  # m
    free_slow_lane: float = 60.0  # m: the slow-side lane counts as free beyond max(this, 3 s at speed)
    passing_zone: float = 20.0  # m: a fast-side leader this close is being passed


@dataclass(frozen=True)
class TrafficStep:
    """What the traffic reward needs of one step, per agent (m, m/s, s); the style's headway and
    eagerness only the styled driver's reward reads (None for the others)."""

    speed: np.ndarray
    desired_speed: np.ndarray
    acceleration: np.ndarray  # along the road, m/s^2
    lateral_acceleration: np.ndarray  # m/s^2
    lane_deviation: np.ndarray  # |offset from the lane centre| / half the lane width
    lane_changed: np.ndarray  # bool: crossed a lane line this step
    behaviour_id: np.ndarray  # 0 keeper, 1 overtaker
    gap: np.ndarray  # [N, 6] as lanes.Surroundings.gap
    other_speed: np.ndarray  # [N, 6] as lanes.Surroundings.other_speed
    collided: np.ndarray
    off_track: np.ndarray
    no_progress: np.ndarray
    time_headway: np.ndarray | None = None  # s: the headway the driver's style asks for
    eagerness: np.ndarray | None = None  # in [0, 1]: how readily the style passes


@dataclass(frozen=True)
class TrafficTerms:
    """Per-agent terms of one step; `total` is their sum."""

    values: dict[str, np.ndarray]

    @property
    def total(self) -> np.ndarray:
        return np.sum([self.values[name] for name in TRAFFIC_TERM_NAMES], axis=0)

    @property
    def progress(self) -> np.ndarray:
        """The speed term: what training logs as progress for the traffic driver."""
        return self.values["speed"]

    def as_dict(self) -> dict[str, np.ndarray]:
        return dict(self.values)

    def weighted(self, weights: Mapping[str, float]) -> TrafficTerms:
        """The terms each times its weight (terms not named keep weight 1)."""
        return TrafficTerms({name: value * weights.get(name, 1.0) for name, value in self.values.items()})


def _driving_terms(step: TrafficStep, w: TrafficWeights) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The terms every traffic-type reward shares (closing in, lane centre, passing on the slow side,
    comfort, losses), and whether the slow-side lane is free (what keeping right is judged by)."""
    v = step.speed
    lead_gap, lead_speed = step.gap[:, 0], step.other_speed[:, 0]
    has_lead = np.isfinite(lead_gap) & ~np.isnan(lead_speed)
    closing_speed = np.where(has_lead, v - np.nan_to_num(lead_speed), 0.0)
    ttc = np.where(closing_speed > 0.1, lead_gap / np.maximum(closing_speed, 0.1), np.inf)
    slow_gap, slow_follow_gap = step.gap[:, 4], step.gap[:, 5]
    slow_lane_free = (slow_gap > np.maximum(w.free_slow_lane, 3.0 * v)) & (
        slow_follow_gap > np.maximum(10.0, v)
    )
    fast_gap, fast_speed = step.gap[:, 2], step.other_speed[:, 2]
    passing = (fast_gap < w.passing_zone) & ~np.isnan(fast_speed)
    undertaking = np.where(passing, np.clip((v - np.nan_to_num(fast_speed)) / 5.0, 0.0, 1.0), 0.0)
    terms = {
        "closing": -w.closing * np.clip((w.safe_ttc - ttc) / w.safe_ttc, 0.0, 1.0),
        "centre": -w.centre * np.minimum(step.lane_deviation, 1.0),
        "pass_slow_side": -w.pass_slow_side * undertaking,
        "comfort": -w.comfort * (step.lateral_acceleration / 1.5) ** 2
        - w.comfort_longitudinal * (step.acceleration / 3.0) ** 2,
        "collision": -w.crash * step.collided,
        "off_track": -w.crash * step.off_track,
        "no_progress": -w.no_progress * step.no_progress,
    }
    return terms, slow_lane_free


def traffic_rewards(step: TrafficStep, w: TrafficWeights) -> TrafficTerms:
    v = step.speed
    overtaker = step.behaviour_id > 0.5
    lead_gap, lead_speed = step.gap[:, 0], step.other_speed[:, 0]
    has_lead = np.isfinite(lead_gap) & ~np.isnan(lead_speed)
    target = np.where(
        has_lead & (lead_gap < w.free_gap + w.free_headway * v),
        np.minimum(step.desired_speed, lead_speed),
        step.desired_speed,
    )
    speed = 1.0 - np.abs(v - target) / np.maximum(target, 1.0)
    safe_gap = w.standstill_gap + w.safe_headway * v  # a queue's few metres at a standstill
    shared, slow_lane_free = _driving_terms(step, w)
    change_cost = np.where(overtaker, w.lane_change_overtaker, w.lane_change_keeper)
    values = {
        **shared,
        "speed": np.clip(speed, -1.0, 1.0),
        "headway": -w.headway * np.where(has_lead, np.clip(1.0 - lead_gap / safe_gap, 0.0, 1.0), 0.0),
        "lane_change": -change_cost * step.lane_changed,
        "keep_slow_side": -w.keep_slow_side * (overtaker & slow_lane_free),
    }
    return TrafficTerms({k: np.asarray(x, float) for k, x in values.items()})


SAFETY_HEADWAY = 0.5
"""s: following closer than this costs whatever the style (the styled driver's envelope bound)."""


def styled_rewards(step: TrafficStep, w: TrafficWeights) -> TrafficTerms:
    """The traffic reward's terms judged against each driver's style instead of its behaviour id:
    the speed against the desired speed, a slower leader forgiven as much as the driver is patient
    (1 - eagerness: an eager driver is not content behind it, which is its reason to pass); the
    headway against the style's (a fraction off costs that fraction), closer than SAFETY_HEADWAY
    costing more; a lane change costing less the eagerer the driver; and keeping right asked of
    everyone, as the law asks it. The other terms are the traffic reward's (`_driving_terms`)."""
    assert step.time_headway is not None and step.eagerness is not None
    v, wanted, eager = step.speed, step.time_headway, step.eagerness
    lead_gap, lead_speed = step.gap[:, 0], step.other_speed[:, 0]
    has_lead = np.isfinite(lead_gap) & ~np.isnan(lead_speed)
    following = has_lead & (lead_gap < w.free_gap + 2.0 * wanted * v) & (v > 5.0)
    held_back = np.maximum(step.desired_speed - np.nan_to_num(lead_speed), 0.0)
    target = np.where(following, step.desired_speed - (1.0 - eager) * held_back, step.desired_speed)
    speed = 1.0 - np.abs(v - target) / np.maximum(target, 1.0)
    headway = np.where(following, lead_gap / np.maximum(v, 0.1), np.inf)
    off_style = np.where(following, np.minimum(np.abs(headway - wanted) / wanted, 1.0), 0.0)
    too_close = np.clip(1.0 - headway / SAFETY_HEADWAY, 0.0, 1.0)
    shared, slow_lane_free = _driving_terms(step, w)
    change_cost = w.lane_change_overtaker + (w.lane_change_keeper - w.lane_change_overtaker) * (1.0 - eager)
    values = {
        **shared,
        "speed": np.clip(speed, -1.0, 1.0),
        "headway": -0.5 * w.headway * off_style - w.headway * too_close,
        "lane_change": -change_cost * step.lane_changed,
        "keep_slow_side": -w.keep_slow_side * slow_lane_free,
    }
    return TrafficTerms({k: np.asarray(x, float) for k, x in values.items()})


Terms = TypeVar("Terms", RewardTerms, TrafficTerms)


def weigh(terms: Terms, weights: Mapping[str, float] | None) -> Terms:
    """The terms times their weights (`reward_weights`); without weights the same terms, untouched,
    so that the default reward stays bit for bit what it was."""
    return terms.weighted(weights) if weights else terms
