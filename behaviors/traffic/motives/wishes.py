"""Each car's lane wish as the motives, the rules' switches and the habits make it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.traffic.motives.keep_right import slow_side_free
from behaviors.traffic.motives.speed_gain import held_up
from behaviors.traffic.scene import Scene
from behaviors.traffic.settings import LaneHabits


@dataclass(frozen=True)
class LaneWishes:
    """What the motives make of the policy's steer: the steer they leave, and what the lane choice
    (`intent.lane_wish`) weighs. `slow_side_free`/`held_up` None: no rule judges the lanes."""

    steer: np.ndarray  # [N] in [-1, 1]
    slow_side_free: np.ndarray | None  # [N] bool: keeping right moves the car there
    held_up: np.ndarray | None  # [N] bool: a wish for the fast side counts
    held_for: np.ndarray  # [N] s each car has been held up without a break


def lane_wishes(steer: np.ndarray, scene: Scene, habits: LaneHabits | None) -> LaneWishes:
    """The wishes as the rules of the road and the habits make them: keeping right where the slow
    side is free, passing a slower leader once patience runs out, and (with habits) the slow side
    the rules' alone. Where the network chooses, no rule wishes for a lane: every lane may be
    wished for and none is kept to."""
    n = len(steer)
    lateral = scene.lateral
    if lateral.network_chooses:
        return LaneWishes(steer, np.zeros(n, bool), np.ones(n, bool), np.zeros(n))
    rules, traffic = lateral.rules, scene.traffic
    free = slow_side_free(traffic, lateral, scene.place.lane_leads_on) if rules.keep_right else None
    if free is not None and habits is not None:
        free &= habits.overtakes
    margin, patient = (None, None) if habits is None else (habits.pass_margin, ~habits.overtakes)
    held = held_up(traffic, lateral, margin, patient) if rules.speed_gain else None
    waited = np.zeros(n)
    if held is not None:
        held_for = scene.motion.held_for
        waited = np.where(held, (0.0 if held_for is None else held_for) + scene.driver.dt, 0.0)
    if habits is not None and rules.keep_right:  # the slow side is the rules' alone
        steer = np.maximum(steer, 0.0)
    if habits is not None and held is not None:
        if free is not None:  # waiting to pass is no time to move right
            free &= ~held
        held = held & (waited >= habits.patience - 1e-9)
        steer = np.where(habits.overtakes & held, 1.0, steer)
    if rules.any:  # the rules judge the lanes: none is free or a reason where its rule is off
        free = np.zeros(n, bool) if free is None else free
        held = np.ones(n, bool) if held is None else held
    return LaneWishes(steer, free, held, waited)
