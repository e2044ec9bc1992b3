"""The keep-right measure of `make dense` (benchmarks/dense_bars.py) counts only through lanes: a
weave's auxiliary lane from an on-ramp to an exit is not where keeping right sends a car."""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from dense_bars import OVERTAKERS, rightmost_while_free, through_ranks

from behaviors.report.realism_tracks import read_lanes
from sumo_scenarios import get_scenario


def test_the_weave_lane_is_no_through_lane_and_the_lane_beside_it_is_the_rightmost():
    net = get_scenario("motorway").net
    ranks = through_ranks(net, read_lanes(net))
    assert ranks["m2_0"] == -1  # on-ramp to exit
    assert [ranks[f"m2_{k}"] for k in (1, 2, 3)] == [0, 1, 2]
    assert [ranks[f"m1_{k}"] for k in range(3)] == [0, 1, 2]


def test_an_overtaker_beside_a_free_weave_lane_in_the_rightmost_through_lane_keeps_right():
    net = get_scenario("motorway").net
    ranks = through_ranks(net, read_lanes(net))
    records = pd.DataFrame({
        "id": ["o1", "o1", "o2", "o2", "s1", "s1"],
        "type": ["behave_overtaker"] * 4 + ["behave_background"] * 2,
        "time": [0.0, 20.0, 0.0, 20.0, 0.0, 20.0],
        "lane": ["m2_1", "m2_1", "m2_2", "m2_2", "m2_0", "m2_0"],
        "pos": [100.0, 100.0, 400.0, 400.0, 100.0, 400.0],
    })  # fmt: skip
    # at 20 s: o1 in the rightmost through lane (free there), o2 one lane over with m2_1 free beside it;
    # the SUMO car in the weave lane beside either does not make the through lane busy
    assert rightmost_while_free(records, ranks, OVERTAKERS) == 0.5
