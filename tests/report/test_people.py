"""behaviors.report.people on small FCD tables whose figures are worked out by hand (no SUMO)."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pandas as pd
import pytest

from behaviors.errors import BehaveError
from behaviors.report.people import (
    CARS,
    HIGHD_CARS,
    HIGHD_LORRIES,
    LORRIES,
    Figure,
    Window,
    compare,
    ks_distance,
    like_people,
    lognormal,
    normal_from_percentiles,
    per_vehicle,
)

LENGTHS = {"lorry": 16.5}
GROUPS = {"lorry": LORRIES, "car": CARS}
STEP = 0.5


def track(vid: str, vtype: str, times: np.ndarray, pos: np.ndarray, speed: float, lane, pos_lat=0.0):
    n = len(times)
    lanes = [lane] * n if isinstance(lane, str) else list(lane)
    lat = np.broadcast_to(np.asarray(pos_lat, float), (n,))
    return pd.DataFrame({"time": times, "id": vid, "type": vtype, "speed": speed, "pos": pos,
                         "lane": lanes, "posLat": lat})  # fmt: skip


def table(*parts: pd.DataFrame) -> pd.DataFrame:
    df = pd.concat(parts, ignore_index=True).sort_values(["time", "id"], kind="stable")
    for column in ("id", "type", "lane"):
        df[column] = df[column].astype(pd.StringDtype())
    return df.reset_index(drop=True)


def following() -> pd.DataFrame:
    """A 16.5 m lorry (type copied for it by SUMO: `lorry@a`) at 20 m/s, its front 76.5 m ahead of a
    car at 25 m/s at t = 0, both in lane e_0, records every 0.5 s from 0 to 12 s. The gap (lorry's
    rear to the car's front) is 60 - 5 t; the car's front is in the window [100, 200] for t in [4, 8],
    where the gap shrinks from 40 m (1.6 s) to 20 m: its closest headway in the window is 20 / 25 =
    0.8 s (at t = 9, past the window, it would be 0.6 s). The car holds 0.25 m right of its lane's
    centre, the lorry 0.1 m left."""
    t = np.arange(0, 12.01, STEP)
    lorry = track("a", "lorry@a", t, 76.5 + 20 * t, 20.0, "e_0", 0.1)
    car = track("b", "car", t, 25 * t, 25.0, "e_0", -0.25)
    return table(lorry, car)


def test_closest_headway_speed_and_offset_in_the_window() -> None:
    out = per_vehicle(following(), Window(100, 100), lengths=LENGTHS, groups=GROUPS).set_index("id")
    assert list(out.index) == ["a", "b"]
    assert out.loc["b", "closest_thw"] == pytest.approx(0.8)
    assert math.isnan(out.loc["a", "closest_thw"])  # no leader
    assert out.loc["b", "group"] == CARS and out.loc["a", "group"] == LORRIES
    assert out.loc["a", "type"] == "lorry@a"
    assert out.loc["b", "mean_speed"] == pytest.approx(25.0)
    assert out.loc["b", "mean_offset"] == pytest.approx(0.25)
    assert out.loc["a", "mean_offset"] == pytest.approx(0.1)
    assert not out["changed_lane"].any()


def test_the_leaders_length_comes_from_its_type() -> None:
    """Taken for 5 m (its type not named), the lorry leaves a gap of 71.5 - 5 t: 31.5 m at t = 8,
    1.26 s."""
    out = per_vehicle(following(), Window(100, 100), lengths={}, groups=GROUPS).set_index("id")
    assert out.loc["b", "closest_thw"] == pytest.approx(31.5 / 25)


def test_groups_and_unknown_types() -> None:
    df = following()
    only_lorries = per_vehicle(df, Window(100, 100), lengths=LENGTHS, groups={"lorry": LORRIES})
    assert list(only_lorries["id"]) == ["a"]  # `car` is in no group and no default: left out
    both = per_vehicle(df, Window(100, 100), lengths=LENGTHS, groups={"lorry": LORRIES}, default_group=CARS)
    assert list(both["group"]) == [LORRIES, CARS]


def test_warm_up_and_partial_passes_are_left_out() -> None:
    """From t = 6 on the car is seen at 150-200 m only (half the window): not a whole pass; the lorry,
    seen from 196.5 m, no more."""
    df = following()
    assert per_vehicle(df, Window(100, 100, since=6.0), lengths=LENGTHS, groups=GROUPS).empty
    cut = per_vehicle(df, Window(100, 100, since=6.0, min_cover=0.5), lengths=LENGTHS, groups=GROUPS)
    assert list(cut["id"]) == ["b"]
    # the car's headway only counts from t = 6 (gap 30 m, 1.2 s) to t = 8 (0.8 s)
    assert cut["closest_thw"].iloc[0] == pytest.approx(0.8)
    assert cut["mean_speed"].iloc[0] == pytest.approx(25.0)


def test_slow_cars_have_no_headway() -> None:
    """Below 5 m/s following is queueing: no closest headway."""
    t = np.arange(0, 40.01, STEP)
    df = table(track("a", "car", t, 20 + 4 * t, 4.0, "e_0"), track("b", "car", t, 4 * t, 4.0, "e_0"))
    out = per_vehicle(df, Window(40, 100), lengths=LENGTHS, groups=GROUPS).set_index("id")
    assert math.isnan(out.loc["b", "closest_thw"])
    assert out.loc["b", "mean_speed"] == pytest.approx(4.0)


def test_lane_changes_inside_and_outside_the_window() -> None:
    """Two cars alone on their lanes at 30 m/s: c moves from e_0 to e_1 at 150 m (inside [100, 200]),
    d from e_1 to e_0 at 240 m (past it). c holds 0.2 m off its lane's centre before and after; the
    record of its change (the one sideways step) does not count in its offset."""
    t = np.arange(0, 10.01, STEP)
    pos = 30 * t
    c = track("c", "car", t, pos, 30.0, np.where(pos < 150, "e_0", "e_1"), 0.2)
    d = track("d", "car", t + 100, pos, 30.0, np.where(pos < 240, "e_1", "e_0"), 0.0)
    out = per_vehicle(table(c, d), Window(100, 100), lengths=LENGTHS, groups=GROUPS).set_index("id")
    assert bool(out.loc["c", "changed_lane"]) and out.loc["c", "lane_changes"] == 1
    assert not out.loc["d", "changed_lane"] and out.loc["d", "lane_changes"] == 0
    assert out.loc["c", "mean_offset"] == pytest.approx(0.2)
    assert math.isnan(out.loc["c", "closest_thw"])


def test_other_edges_are_not_the_window() -> None:
    df = following()
    df["lane"] = df["lane"].str.replace("e_", "f_").astype(pd.StringDtype())
    assert per_vehicle(df, Window(100, 100, edge="e"), lengths=LENGTHS, groups=GROUPS).empty
    assert len(per_vehicle(df, Window(100, 100, edge="f"), lengths=LENGTHS, groups=GROUPS)) == 2


def test_the_fitted_references() -> None:
    cars = HIGHD_CARS.thw()  # the normal of log(thw)
    assert math.exp(cars.mean) == pytest.approx(1.4)
    assert cars.cdf(0.0) == pytest.approx(1 / 3)
    assert cars.stdev == pytest.approx(math.log(1.4) / 0.43072729929545756, rel=1e-6)  # 0.781
    assert cars.cdf(math.log(0.5)) == pytest.approx(0.0938, abs=5e-4)  # highD counts about 8%
    lorries = HIGHD_LORRIES.thw()
    assert math.exp(lorries.mean) == pytest.approx(2.2) and lorries.cdf(0.0) == pytest.approx(1 / 6)
    speed = normal_from_percentiles(25, 42)
    assert speed.mean == pytest.approx(33.5) and speed.stdev == pytest.approx(17 / (2 * 1.6448536), rel=1e-6)
    relative = HIGHD_CARS.relative_speed()
    assert (
        relative is not None and relative.mean == 1.0 and relative.stdev == pytest.approx(5.1674 / 33.5, 1e-4)
    )
    assert HIGHD_LORRIES.relative_speed() is None
    with pytest.raises(BehaveError):
        lognormal(1.0, 2.0, 0.3)  # half the mass lies under the median: P(< 2) cannot be 0.3


def test_ks_distance() -> None:
    """Samples 1 and 2 against N(0, 1): F(1) = 0.841 against the sample's 0 just below 1 is the gap."""
    assert ks_distance([1.0, 2.0], NormalDist()) == pytest.approx(NormalDist().cdf(1.0))
    assert ks_distance([math.e, math.e**2], NormalDist(), log=True) == pytest.approx(NormalDist().cdf(1.0))
    # one sample at the median: 1/2 either side
    assert ks_distance([0.0], NormalDist()) == pytest.approx(0.5)
    assert math.isnan(ks_distance([], NormalDist()))
    many = np.array([NormalDist().inv_cdf((k + 0.5) / 1000) for k in range(1000)])
    assert ks_distance(many, NormalDist()) == pytest.approx(0.0005, abs=1e-6)


def vehicles(thw: list[float], changed: list[bool], speed: list[float], offset: list[float]) -> pd.DataFrame:
    n = len(thw)
    return pd.DataFrame({"id": [str(k) for k in range(n)], "type": "car", "group": CARS, "closest_thw": thw,
                         "changed_lane": changed, "lane_changes": np.asarray(changed, int),
                         "mean_speed": speed, "mean_offset": offset})  # fmt: skip


def test_compare_counts_shares_over_cars_with_a_leader() -> None:
    v = vehicles([0.4, 0.8, 1.2, 2.0, math.nan], [True, False, False, False, False],
                 [30.0, 30.0, 30.0, 30.0, 30.0], [0.1, 0.2, 0.3, 0.4, math.nan])  # fmt: skip
    figures = {f.key: f for f in compare(v, HIGHD_CARS)}
    assert figures["vehicles"].simulated == 5 and figures["with_leader"].simulated == 4
    assert figures["below_1s"].simulated == pytest.approx(0.5)
    assert figures["below_1s"].distance == pytest.approx(0.5 - 1 / 3) and not figures["below_1s"].met
    assert figures["below_half_s"].simulated == pytest.approx(0.25)
    assert figures["changed_lane"].simulated == pytest.approx(0.2)
    assert figures["changed_lane"].distance == pytest.approx(0.04) and figures["changed_lane"].met
    assert figures["thw_median"].simulated == pytest.approx(1.0)
    assert figures["offset_mean"].simulated == pytest.approx(0.25) and figures["offset_mean"].met
    # every car at the median speed: the scaled sample is one point at 1, half the fitted normal off
    assert figures["speed_median"].simulated == 30.0
    assert figures["speed_ks"].distance == pytest.approx(0.5)
    assert figures["thw_ks"].distance == pytest.approx(
        ks_distance([0.4, 0.8, 1.2, 2.0], HIGHD_CARS.thw(), log=True)
    )


def test_the_bar() -> None:
    def fig(key: str, kind: str, distance: float, simulated: float = math.nan) -> Figure:
        return Figure(key, key, simulated, math.nan, distance, 0.12 if kind == "ks" else 0.05, kind)

    good = [fig("thw_ks", "ks", 0.08), fig("speed_ks", "ks", 0.1), fig("changed_lane", "share", 0.02),
            fig("below_1s", "share", 0.03), fig("offset_mean", "range", math.nan, 0.3)]  # fmt: skip
    sumo = [fig("thw_ks", "ks", 0.3), fig("speed_ks", "ks", 0.15), fig("changed_lane", "share", 0.1)]
    assert like_people(good, sumo, collisions=0).met
    assert not like_people(good, sumo, collisions=1).met
    closer_sumo = [fig("thw_ks", "ks", 0.05), *sumo[1:]]
    bar = like_people(good, closer_sumo, collisions=0)
    assert not bar.met and not bar.parts["thw_ks closer than SUMO's"]
    centred = [*good[:4], fig("offset_mean", "range", math.nan, 0.03)]
    assert not like_people(centred, sumo, collisions=0).parts["offset_mean"]
