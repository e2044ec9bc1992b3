"""Like people? Per-vehicle figures through a 420 m window, beside real drivers'.

highD (Krajewski et al., ITSC 2018) films German Autobahn stretches of about 420 m from a drone and
publishes, per vehicle, what it did while seen: its closest time headway to the leader in its lane,
whether it changed lane, its mean speed. Its licence forbids redistributing the trajectories, so the
reference here is built from the published per-vehicle aggregates of highD location 2 (a 2+2-lane
Autobahn near Cologne, no speed limit, free flow; docs/people.md):

* cars (1,548): closest headway median about 1.4 s, about a third closer than 1 s, about 8% closer
  than 0.5 s; about 16% change lane; mean speed about 33 m/s (p5 ~25, p95 ~42); |offset from the lane
  centre| about 0.3 m on average;
* lorries (413): closest headway median about 2.2 s, about a sixth closer than 1 s, about 1% closer
  than 0.5 s; well under 1% change lane; about 24 m/s; about 0.2 m off the centre.

How each simulated figure is compared (`compare`):

* shares (closer than 1 s, closer than 0.5 s, changing lane): directly, in percentage points;
* the closest-headway distribution: the KS distance of the simulated closest headways to a
  lognormal fitted to the published median and share under 1 s (`lognormal`: median 1.4 s and
  P(< 1 s) = 1/3 give sigma 0.78, which puts 9.4% under 0.5 s where highD counts about 8%). This is a
  comparison against a distribution fitted to published figures, not against the data;
* the mean-speed distribution: highD's location has no limit, our road 130 km/h (36.1 m/s), so the
  location of the distribution cannot be compared and is reported beside it (median, and the
  published 33 m/s). Its shape is: each car's mean speed over the group's median, against the normal
  fitted to the published p5 25 / p95 42 (mean 33.5, sd 5.17) over its median, i.e. N(1, 0.154). The
  KS distance of that scaled sample measures the spread between drivers (coefficient of variation
  about 0.15), not how fast they drive;
* lane keeping: the mean over vehicles of each vehicle's mean |posLat| while not changing lanes,
  against the bar's 0.15-0.45 m.

Everything is pandas/numpy over an FCD table (`behaviors.report.fcd_read.read_fcd`), through the realism
report's own pieces (`behaviors.report.realism_tracks.prepare`, `realism_measures.headways`,
`lane_changes`, `lane_offsets`): the
same gaps (leader's rear to own front, own speed > 5 m/s, leader within 250 m), lane changes and
lane-centre offsets as `behave report`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
import pandas as pd

from behaviors.errors import BehaveError
from behaviors.report.realism_measures import headways, lane_changes, lane_offsets, lateral_motion
from behaviors.report.realism_tracks import REQUIRED, Lanes, prepare

WINDOW_M = 420.0
"""highD's stretch: about 420 m, some 12 s of a car at 33 m/s."""
MIN_COVER = 0.9
"""A vehicle counts if its records in the window span at least this share of it (a whole pass: the
warm-up's and the run's end cut passes short)."""
KS_LIMIT = 0.12
SHARE_POINTS = 0.05
"""How close a share must come to highD's: 5 percentage points."""
OFFSET_RANGE = (0.15, 0.45)
"""m: mean |offset from the lane centre| of people holding a lane (highD's cars: about 0.3 m)."""
CARS, LORRIES = "cars", "lorries"
COLUMNS = ("id", "type", "group", "closest_thw", "changed_lane", "lane_changes", "mean_speed", "mean_offset")


@dataclass(frozen=True)
class Reference:
    """What real drivers of one group did through the window (published per-vehicle aggregates)."""

    group: str
    vehicles: int  # how many highD counted
    thw_median: float  # s: median of the closest time headways
    below_1s: float  # share of vehicles closer than 1 s at some point
    below_half_s: float  # ... closer than 0.5 s
    changed_lane: float  # share that changed lane while seen
    speed_mean: float  # m/s
    speed_p5: float | None  # m/s; None: no spread published
    speed_p95: float | None
    offset_mean: float  # m: |offset from the lane centre|

    def thw(self) -> NormalDist:
        """The lognormal fitted to the median and the share under 1 s, as the normal of log(thw)."""
        return lognormal(self.thw_median, 1.0, self.below_1s)

    def relative_speed(self) -> NormalDist | None:
        """The normal fitted to p5 / p95 of the mean speeds, over its median (None: no spread)."""
        if self.speed_p5 is None or self.speed_p95 is None:
            return None
        fitted = normal_from_percentiles(self.speed_p5, self.speed_p95)
        return NormalDist(1.0, fitted.stdev / fitted.mean)


HIGHD_CARS = Reference(CARS, 1548, 1.4, 1 / 3, 0.08, 0.16, 33.0, 25.0, 42.0, 0.3)
HIGHD_LORRIES = Reference(LORRIES, 413, 2.2, 1 / 6, 0.01, 0.005, 24.0, None, None, 0.2)
"""Lorries: "well under 1%" change lane, taken as 0.5%."""
REFERENCES = {CARS: HIGHD_CARS, LORRIES: HIGHD_LORRIES}


def lognormal(median: float, at: float, share_below: float) -> NormalDist:
    """The lognormal with this median and P(X < at) = share_below, as the normal its log follows."""
    if not (median > 0 and at > 0 and 0 < share_below < 1 and at != median):
        raise BehaveError(f"no lognormal has median {median} and P(< {at}) = {share_below}")
    sigma = (math.log(at) - math.log(median)) / NormalDist().inv_cdf(share_below)
    if sigma <= 0:
        raise BehaveError(f"no lognormal has median {median} and P(< {at}) = {share_below}")
    return NormalDist(math.log(median), sigma)


def normal_from_percentiles(p5: float, p95: float) -> NormalDist:
    """The normal whose 5th and 95th percentiles are these."""
    if not p95 > p5:
        raise BehaveError(f"p95 ({p95}) must exceed p5 ({p5})")
    return NormalDist((p5 + p95) / 2, (p95 - p5) / (2 * NormalDist().inv_cdf(0.95)))


def ks_distance(samples: Sequence[float] | np.ndarray, cdf: NormalDist, *, log: bool = False) -> float:
    """One-sample Kolmogorov-Smirnov distance sup |F_n(x) - F(x)| of the finite samples to the normal
    `cdf` (of log(x) with `log`: a lognormal); NaN without samples."""
    x = np.sort(np.asarray(samples, float))
    x = x[np.isfinite(x)]
    if log:
        x = x[x > 0]
        x = np.log(x)
    n = len(x)
    if not n:
        return math.nan
    f = np.array([cdf.cdf(v) for v in x])
    above = np.arange(1, n + 1) / n - f
    below = f - np.arange(n) / n
    return float(max(above.max(), below.max()))


def _base_type(types: pd.Series) -> pd.Series:
    """SUMO names a type it copied for one vehicle `<type>@<vehicle>`: the type it came from."""
    return types.astype(str).str.split("@", n=1).str[0]


@dataclass(frozen=True)
class Window:
    """Where and when vehicles are watched: positions [start, start + length] along `edge` (None:
    every normal edge), times `since` (the warm-up before it is skipped) to `until`; a vehicle counts
    when it drove over at least `min_cover` of the window."""

    start: float
    length: float = WINDOW_M
    edge: str | None = None
    since: float = 0.0
    until: float = math.inf
    min_cover: float = MIN_COVER


def per_vehicle(
    df: pd.DataFrame,
    window: Window,
    *,
    lengths: Mapping[str, float],
    groups: Mapping[str, str],
    default_group: str | None = None,
    lanes: Lanes | None = None,
) -> pd.DataFrame:
    """One row per vehicle that drove through the window (one straight edge is the road this is made
    for).

    `lengths`: vType -> length in metres (the leader's rear is its front minus its length; types not
    named are 5 m); `groups`: vType -> group (`cars`, `lorries`), types not named go to
    `default_group` or, if None, are left out. A type SUMO copied for one vehicle (`lorry@v3`) is its
    base type. The group is the type of the vehicle's last record in the window (`behave populate
    --share` turns a scenario's car into an agent of its own type as it departs).

    Columns: id, type, group; closest_thw (s: the smallest gap / own speed to the leader in its lane
    while its front was in the window, own speed > 5 m/s, leader within 250 m; NaN: no leader);
    changed_lane and lane_changes (its lane changes whose first record in the new lane is in the
    window); mean_speed (m/s, over its records in the window); mean_offset (m: mean |posLat| over its
    records in the window outside lane changes; NaN without posLat).
    """
    if "type" not in df.columns:
        raise BehaveError("the FCD has no type column: cars and lorries are told apart by their vType")
    start, length, edge, min_cover = window.start, window.length, window.edge, window.min_cover
    if not length > 0 or not 0 < min_cover <= 1:
        raise BehaveError(f"bad window: length {length}, cover {min_cover}")
    df = df[(df["time"] >= window.since) & (df["time"] <= window.until)].dropna(subset=list(REQUIRED))
    if df.empty:
        return pd.DataFrame(columns=list(COLUMNS))
    ids = pd.Index(pd.factorize(df["id"])[1].astype(str))  # prepare's vehicle codes, the same factorize
    known = {t: lengths[b] for t, b in zip(df["type"].unique().astype(str), _base_type(
        pd.Series(df["type"].unique())), strict=True) if b in lengths}  # fmt: skip
    tr = prepare(df, lanes or Lanes(), skip_s=0.0, lengths=known)
    lane_name = tr["lane_id"].astype(str).to_numpy()
    on_road = ~tr["internal"].to_numpy()
    if edge is not None:
        on_road &= np.array([name.rpartition("_")[0] == edge for name in lane_name])
    pos = tr["pos"].to_numpy()
    inside = on_road & (pos >= start) & (pos <= start + length)
    vehicle = tr["vehicle"].to_numpy()

    # each record labels itself: the realism functions return the label of the record they measured
    labelled = tr.assign(group=np.arange(len(tr)))
    thw = headways(labelled)
    thw = thw[inside[thw["group"].to_numpy()]]
    changes = lane_changes(labelled, lateral_motion(tr)["accel"].to_numpy(), (lanes or Lanes()).next_lanes)
    changed_rows = changes["group"].to_numpy(int)
    changed_rows = changed_rows[inside[changed_rows]]
    offsets = lane_offsets(labelled, changes)
    offsets = offsets[inside[offsets["group"].to_numpy(int)]]

    seen = pd.DataFrame(
        {"vehicle": vehicle[inside], "pos": pos[inside], "speed": tr["speed"].to_numpy()[inside]}
    )
    by = seen.groupby("vehicle")
    span = by["pos"].max() - by["pos"].min()
    whole = span.index[span >= min_cover * length - 1e-9]
    if not len(whole):
        return pd.DataFrame(columns=list(COLUMNS))
    out = pd.DataFrame(index=whole)
    out["id"] = ids[whole]
    out["type"] = _last_type_in_window(df, window).reindex(out["id"]).to_numpy()
    base = _base_type(out["type"])
    out["group"] = base.map(lambda t: groups.get(t, default_group)).to_numpy()
    out["closest_thw"] = (
        pd.Series(thw["thw"].to_numpy(), vehicle[thw["group"].to_numpy()])
        .groupby(level=0)
        .min()
        .reindex(whole)
        .to_numpy()
    )
    count = pd.Series(1, vehicle[changed_rows]).groupby(level=0).sum().reindex(whole, fill_value=0)
    out["changed_lane"] = count.to_numpy() > 0
    out["lane_changes"] = count.to_numpy()
    out["mean_speed"] = by["speed"].mean().reindex(whole).to_numpy()
    offset = pd.Series(offsets["offset"].to_numpy(), vehicle[offsets["group"].to_numpy(int)])
    out["mean_offset"] = offset.groupby(level=0).mean().reindex(whole).to_numpy()
    out = out[out["group"].notna()]
    return out.reset_index(drop=True)[list(COLUMNS)]


def _last_type_in_window(df: pd.DataFrame, window: Window) -> pd.Series:
    """Per vehicle id: the vType of its last record in the window."""
    lane = df["lane"].astype(str)
    on_road = ~lane.str.startswith(":")
    if window.edge is not None:
        on_road &= lane.str.rpartition("_")[0] == window.edge
    seen = df[
        on_road & (df["pos"] >= window.start) & (df["pos"] <= window.start + window.length)
    ].sort_values("time", kind="stable")
    return seen.groupby(seen["id"].astype(str))["type"].last().astype(str)


@dataclass(frozen=True)
class Figure:
    """One simulated figure of a group beside real drivers' and how far apart they are."""

    key: str
    label: str
    simulated: float
    reference: float
    distance: float  # KS distance, |points| for shares (as a fraction), or NaN where not judged
    limit: float  # the bar's limit on the distance (NaN: reported only)
    kind: str  # "ks", "share", "range", "info"

    @property
    def met(self) -> bool | None:
        if self.kind == "range":
            low, high = OFFSET_RANGE
            return None if math.isnan(self.simulated) else low <= self.simulated <= high
        if math.isnan(self.limit):
            return None
        return not math.isnan(self.distance) and self.distance <= self.limit


def compare(vehicles: pd.DataFrame, reference: Reference) -> list[Figure]:
    """The group's figures (rows of `per_vehicle` of that group) beside the reference's."""
    thw = vehicles["closest_thw"].to_numpy(float)
    thw = thw[np.isfinite(thw)]
    speed = vehicles["mean_speed"].to_numpy(float)
    speed = speed[np.isfinite(speed)]
    offset = vehicles["mean_offset"].to_numpy(float)
    offset = offset[np.isfinite(offset)]
    fitted = reference.thw()
    nan = math.nan

    def quantile(values: np.ndarray, q: int) -> float:
        return float(np.percentile(values, q)) if len(values) else nan

    def share(values: np.ndarray, below: float) -> float:
        return float((values < below).mean()) if len(values) else nan

    def points(key: str, label: str, simulated: float, ref: float) -> Figure:
        return Figure(key, label, simulated, ref, abs(simulated - ref), SHARE_POINTS, "share")

    median_speed = float(np.median(speed)) if len(speed) else nan
    relative = reference.relative_speed()
    figures = [
        Figure("vehicles", "vehicles through the window", float(len(vehicles)), float(reference.vehicles),
               nan, nan, "info"),
        Figure("with_leader", "... with a leader (a closest headway)", float(len(thw)), nan, nan, nan,
               "info"),
        Figure("thw_median", "closest time headway, median [s]", float(np.median(thw)) if len(thw) else nan,
               reference.thw_median, nan, nan, "info"),
        *(Figure(f"thw_p{q}", f"closest time headway, p{q} [s]", quantile(thw, q),
                 math.exp(fitted.inv_cdf(q / 100)), nan, nan, "info") for q in (10, 90)),
        Figure("thw_ks", "closest time headway: KS distance to the fitted lognormal", nan, nan,
               ks_distance(thw, fitted, log=True), KS_LIMIT, "ks"),
        points("below_1s", "closer than 1 s", share(thw, 1.0), reference.below_1s),
        points("below_half_s", "closer than 0.5 s", share(thw, 0.5), reference.below_half_s),
        points("changed_lane", "changed lane in the window",
               float(vehicles["changed_lane"].mean()) if len(vehicles) else nan, reference.changed_lane),
        Figure("speed_median", "mean speed, median [m/s] (reference: no limit)", median_speed,
               reference.speed_mean, nan, nan, "info"),
    ]  # fmt: skip
    if relative is not None:
        scaled = speed / median_speed if len(speed) else speed
        sd = float(np.std(scaled)) if len(scaled) else nan
        bounds = {5: reference.speed_p5, 95: reference.speed_p95}
        figures += [
            *(Figure(f"speed_p{q}", f"mean speed, p{q} [m/s] (reference: no limit)", quantile(speed, q),
                     float(bound or nan), nan, nan, "info") for q, bound in bounds.items()),
            Figure("speed_cv", "mean speed / its median: standard deviation", sd, relative.stdev, nan, nan,
                   "info"),
            Figure("speed_ks", "mean speed / its median: KS distance to the fitted normal's", nan, nan,
                   ks_distance(scaled, relative), KS_LIMIT, "ks"),
        ]  # fmt: skip
    figures.append(
        Figure("offset_mean", "|offset from the lane centre|, mean [m]",
               float(offset.mean()) if len(offset) else nan, reference.offset_mean, nan, nan, "range")
    )  # fmt: skip
    return figures


JUDGED_AGAINST_SUMO = ("thw_ks", "speed_ks", "changed_lane")
"""The figures the learned cars must match more closely than SUMO's default drivers."""


@dataclass(frozen=True)
class Bar:
    """The like-people bar for the cars (`compare`), each part met or not."""

    parts: dict[str, bool]

    @property
    def met(self) -> bool:
        return all(self.parts.values())


def like_people(learned: list[Figure], sumo: list[Figure], collisions: int) -> Bar:
    """Cars' figures with every car learned against SUMO's default drivers on the same road: the
    distributions within KS_LIMIT, the shares within SHARE_POINTS, each of JUDGED_AGAINST_SUMO closer
    than SUMO's, the lane-centre offset in OFFSET_RANGE, and no collision."""
    mine = {f.key: f for f in learned}
    theirs = {f.key: f for f in sumo}
    parts = {f.key: bool(f.met) for f in learned if f.kind in ("ks", "share", "range")}
    for key in JUDGED_AGAINST_SUMO:
        if key in mine and key in theirs:
            a, b = mine[key].distance, theirs[key].distance
            parts[f"{key} closer than SUMO's"] = not math.isnan(a) and (math.isnan(b) or a < b)
    parts["no collision"] = collisions == 0
    return Bar(parts)
