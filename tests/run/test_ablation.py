"""`make ablation` (benchmarks/ablation.py): the bar's arithmetic on made-up figures, the constant
"policies" it drives with, and one tiny run of the whole script."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from ablation import (
    FIGURES,
    GROUPS,
    KEEPERS,
    OVERTAKERS,
    Samples,
    median_action,
    moves,
    moves_at_least,
    seed_noise,
    verdict,
)

from behaviors.learn.policy import RULES_ACTION, constant_act, held_constant, load_policy, rules_policy

ROOT = Path(__file__).resolve().parents[2]


def test_seed_noise_is_the_pooled_sample_std_of_both_variants():
    # var([1, 3]) = 2 and var([2, 2, 2]) = 0 (ddof 1): sqrt((2 + 0) / 2) = 1
    assert seed_noise([1.0, 3.0], [2.0, 2.0, 2.0]) == pytest.approx(1.0)
    assert seed_noise([1.0, math.nan, 3.0], [5.0, 7.0]) == pytest.approx(
        math.sqrt(2.0)
    )  # nan: a seed left out
    assert math.isnan(seed_noise([1.0], [2.0, 3.0]))  # one seed: no noise known


def test_a_figure_moves_beyond_three_times_its_noise_counted_at_least_at_its_floor():
    assert moves(3.1, 1.0) and not moves(3.0, 1.0) and moves(-3.1, 1.0)
    assert not moves(1.0, 0.1, floor=0.4)  # 10x the measured noise, but not 3x the floor
    assert moves(1.3, 0.1, floor=0.4)
    assert moves(1.3, math.nan, floor=0.4)  # noise unknown: the floor alone
    assert not moves(1.3, math.nan)
    assert not moves(math.nan, 0.1, floor=0.4)
    assert moves_at_least(0.5, 0.1, 0.4) and not moves_at_least(0.3, 0.05, 0.4)  # the least move
    assert not moves_at_least(1.0, 0.5, 0.4)  # at least the amount, but within 3x the noise


def samples(policy: dict, median: dict, rules: dict) -> Samples:
    """Per-seed values of every figure: 1.0 in each seed unless given, for the three variants."""
    out: Samples = {}
    for variant, given in (("policy", policy), ("median", median), ("rules", rules)):
        out[variant] = {
            (g, f.key): list(given.get((g, f.key), [1.0, 1.0, 1.0])) for g in GROUPS for f in FIGURES
        }
    return out


def test_the_verdict_counts_moved_figures_and_the_behaviours_gap_without_the_network():
    lc = "lane_changes_per_km"
    policy = {
        (KEEPERS, lc): [0.0, 0.0, 0.0],
        (OVERTAKERS, lc): [1.0, 1.1, 0.9],  # std 0.1
        (KEEPERS, "mean_speed"): [30.0, 30.5, 29.5],  # std 0.5
        (OVERTAKERS, "thw_median"): [1.2, 1.2, 1.2],
    }
    median = {
        (KEEPERS, lc): [0.0, 0.0, 0.0],
        (OVERTAKERS, lc): [0.1, 0.2, 0.0],  # -0.9: > 3 x max(0.1, 0.25)
        (KEEPERS, "mean_speed"): [32.0, 32.5, 31.5],  # +2: > 3 x 0.5, but not 3 x the floor of 1 m/s
        (OVERTAKERS, "thw_median"): [2.5, 2.5, 2.5],  # +1.3: > 3 x the floor of 0.4 s (noise 0)
    }
    rules = {(KEEPERS, lc): [0.2, 0.2, 0.2], (OVERTAKERS, lc): [0.2, 0.2, 0.2]}
    judged = verdict(samples(policy, median, rules))
    moved = {(m.group, m.figure.key) for m in judged.moves if m.moved}
    assert moved == {(OVERTAKERS, lc), (OVERTAKERS, "thw_median")}
    assert judged.moved == 2
    assert judged.moved_measured == 3  # the keepers' speed too, against the measured noise alone
    assert judged.moved_amount == 3  # read as the least move that counts: +2 m/s is at least 1 m/s
    assert judged.gap["policy"] == pytest.approx(1.0)
    assert judged.gap_fraction["median"] == pytest.approx(0.1)
    assert judged.gap_fraction["rules"] == pytest.approx(0.0)
    speed = next(m for m in judged.moves if (m.group, m.figure.key) == (KEEPERS, "mean_speed"))
    assert (speed.policy, speed.median, speed.delta, speed.noise) == pytest.approx((30.0, 32.0, 2.0, 0.5))


def test_the_median_action_is_per_dimension_over_every_agent_step_of_every_run():
    runs = [np.array([[1.0, 1.0, 0.0], [-1.0, 0.9, 0.1]]), np.array([[0.5, 1.0, 0.0]])]
    assert median_action(runs) == pytest.approx([0.5, 1.0, 0.0])


def test_constant_policies_answer_every_observation_with_their_action():
    obs = np.zeros((5, 27), np.float32)
    assert (constant_act((0.2, 0.7, 0.1))(obs, None) == np.float32([0.2, 0.7, 0.1])).all()
    assert constant_act(RULES_ACTION)(obs[:0], None).shape == (0, 3)
    rules = rules_policy()
    assert (rules.label, rules.driver, rules.behaviour, rules.sees_behaviour) == (
        "rules",
        "traffic",
        "multi",
        True,
    )
    assert (rules.act(obs, None) == np.float32(RULES_ACTION)).all()
    shipped = load_policy("traffic")
    held = held_constant(shipped, np.array([-0.94, 1.0, 0.0]))
    assert rules.obs_dim == shipped.obs_dim
    assert (held.driver, held.behaviour, held.obs_dim) == (shipped.driver, shipped.behaviour, shipped.obs_dim)
    assert held.label == "traffic@-0.94,1,0"
    assert (held.act(obs, None) == np.float32([-0.94, 1.0, 0.0])).all()


@pytest.mark.sumo
def test_make_ablation_runs_end_to_end_at_a_tiny_duration(tmp_path):
    doc = tmp_path / "ablation.md"
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "ablation.py"), "--duration", "14", "--seeds", "0,1",
         "--out", str(tmp_path / "runs"), "--doc", str(doc)],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    text = doc.read_text()
    assert text.startswith("# Who drives")
    command = "`python benchmarks/ablation.py --seeds 0,1 --duration 14 --policy"
    assert f"Written by `make ablation` ({command}" in text
    assert "CPU: " in text and "The bar: the network makes the behaviour" in text
    for traffic in ("light", "dense"):
        recorded = np.load(tmp_path / "runs" / traffic / "policy" / "s0" / "actions.npz")
        assert (
            recorded["actions"].shape[1] == 3 and len(recorded["actions"]) == len(recorded["behaviour"]) > 0
        )
        for variant in ("policy", "median", "rules"):
            assert (tmp_path / "runs" / traffic / variant / "s1" / "fcd.parquet").is_file()
    rules_agents = (tmp_path / "runs" / "light" / "rules" / "s0" / "fcd.agents.csv").read_text()
    assert ",rules," in rules_agents
