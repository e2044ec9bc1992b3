"""Rewards against the paper's formulas, computed by hand on made-up states (no SUMO)."""

from __future__ import annotations

import numpy as np
import pytest

from behaviors.traffic.rewards import (
    COLLISION_PENALTY,
    NO_PROGRESS_PENALTY,
    OFF_TRACK_PENALTY,
    TERM_NAMES,
    race_positions,
    step_rewards,
)


def test_race_positions_rank_by_progress_and_ties_share_the_better_rank():
    np.testing.assert_array_equal(race_positions(np.array([10.0, 30.0, 20.0, 30.0])), [4, 1, 3, 1])


def test_every_term_equals_its_formula():
    speed = np.array([25.0, 10.0, 30.0])  # m/s
    angle = np.array([0.0, 0.2, -0.3])
    behaviour = np.array([0.0, 1.0, 1.0])
    race = np.array([3, 1, 2])
    collided = np.array([False, True, False])
    off_track = np.array([False, False, True])
    no_progress = np.array([True, False, False])
    deviation = np.array([0.0, 0.5, 1.0])
    terms = step_rewards(speed, angle, behaviour, race, 5, collided, off_track, no_progress, deviation, 0.5)

    kmh = speed * 3.6
    # R_lk = v (cos - |sin|): a heading to the right is penalised like one to the left
    expected_progress = [90.0, 36 * (np.cos(0.2) - np.sin(0.2)), 108 * (np.cos(0.3) - np.sin(0.3))]
    np.testing.assert_allclose(terms.progress, expected_progress)
    np.testing.assert_allclose(terms.race, [0.0, 100 * (5 - 1), 100 * (5 - 2)])  # keepers get no race term
    np.testing.assert_allclose(terms.lane, [0.0, -0.5 * kmh[1] * 0.5, -0.5 * kmh[2] * 1.0])
    np.testing.assert_array_equal(terms.collision, [0.0, COLLISION_PENALTY, 0.0])
    np.testing.assert_array_equal(terms.off_track, [0.0, 0.0, OFF_TRACK_PENALTY])
    np.testing.assert_array_equal(terms.no_progress, [NO_PROGRESS_PENALTY, 0.0, 0.0])
    by_name = terms.as_dict()
    assert tuple(by_name) == TERM_NAMES
    np.testing.assert_allclose(terms.total, sum(by_name.values()))


@pytest.mark.parametrize("deviation", [None, np.array([0.9])])
def test_without_a_lane_weight_the_reward_is_the_papers(deviation):
    terms = step_rewards(
        np.array([20.0]), np.array([0.1]), np.array([0.0]), np.array([1]), 1,
        np.zeros(1, bool), np.zeros(1, bool), np.zeros(1, bool), deviation,
    )  # fmt: skip
    assert terms.lane[0] == 0.0
    assert terms.total[0] == pytest.approx(72 * (np.cos(0.1) - np.sin(0.1)))
