"""The realism report's measures over `prepare`'s records: lateral acceleration and jerk, lane changes
(and whether the route asked for them), lane-centre offsets, headways and time-to-collision, passes,
and the like-for-like comparison of two groups on the trips both made.

Lateral acceleration and jerk are centred differences over DERIVATIVE_S, on the lateral track.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from behaviors.report.realism_tracks import shifted

if TYPE_CHECKING:
    from collections.abc import Mapping

DERIVATIVE_S = 0.4
"""Lateral acceleration and jerk are differences over at least this span: FCD rounds posLat to
1 cm, and second differences over a 0.2 s step would turn the rounding into up to 0.5 m/s^2."""
SIDEWAYS_SPEED = 0.05
"""m/s: a record moving sideways slower than this is not part of a lane change (its duration)."""
FOLLOW_MIN_SPEED = 5.0  # m/s: headways of slower cars are queueing, not following
LEADER_RANGE = 250.0  # m
PASS_MARGIN = 10.0
"""m beyond a car length within which pairs are tracked for passes; widened to 25 m/s x step for
coarse steps, so that no pass can jump over the window between two records."""


def lateral_motion(tr: pd.DataFrame) -> pd.DataFrame:
    """Lateral acceleration and jerk of every record: centred differences of `track` over
    n steps (n * step >= DERIVATIVE_S); NaN where the span leaves the record's segment."""
    k = max(1, round(DERIVATIVE_S / tr.attrs["step"]))
    seg, u, t = tr["seg"].to_numpy(), tr["track"].to_numpy(), tr["time"].to_numpy()
    u_next, u_prev = shifted(u, seg, -k), shifted(u, seg, k)
    t_next, t_prev = shifted(t, seg, -k), shifted(t, seg, k)
    accel = 2 * ((u_next - u) / (t_next - t) - (u - u_prev) / (t - t_prev)) / (t_next - t_prev)
    jerk = (shifted(accel, seg, -k) - shifted(accel, seg, k)) / (t_next - t_prev)
    return pd.DataFrame({"accel": accel, "jerk": jerk})


def _sideways_runs(tr: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Per record: its sideways direction (-1, 0 or 1; still below SIDEWAYS_SPEED) and the number
    of its run (consecutive records of one segment moving the same way)."""
    seg, track, dt = tr["seg"].to_numpy(), tr["track"].to_numpy(), tr["dt"].to_numpy()
    sideways = (track - shifted(track, seg, 1)) / dt
    moving = np.where(np.abs(sideways) > SIDEWAYS_SPEED, np.sign(sideways), 0.0)
    run_start = np.ones(len(tr), bool)
    run_start[1:] = (moving[1:] != moving[:-1]) | (seg[1:] != seg[:-1])
    return moving, np.cumsum(run_start) - 1


def lane_changes(
    tr: pd.DataFrame, accel: np.ndarray, next_lanes: Mapping[str, frozenset[str]] | None = None
) -> pd.DataFrame:
    """One row per lane change of a settled car (its lane rank changes between two records on
    the same edge), with its duration, peak |lateral acceleration|, sideways run, and whether the
    route asked for it (`route_asked`).

    The duration is the run of records moving sideways (faster than SIDEWAYS_SPEED) towards the
    new lane, from the record before the run to its last record; the peak is over that run.
    `run` numbers that run as `_sideways_runs` does (-1: the car did not move towards the lane).
    """
    seg, rank = tr["seg"].to_numpy(), tr["road_rank"].to_numpy()
    time, dt, road_edge = tr["time"].to_numpy(), tr["dt"].to_numpy(), tr["road_edge"].to_numpy()
    prev_rank = shifted(rank, seg, 1)
    same_edge = shifted(road_edge, seg, 1) == road_edge
    change = same_edge & (rank != prev_rank) & ~np.isnan(prev_rank) & tr["settled"].to_numpy()
    direction = np.sign(rank - prev_rank)
    moving, run = _sideways_runs(tr)
    run_start = np.diff(run, prepend=-1) > 0
    starts = np.flatnonzero(run_start)
    ends = np.append(starts[1:], len(tr)) - 1
    begin = time[starts] - dt[starts]
    peak = pd.Series(np.abs(accel)).groupby(run).max().to_numpy()
    idx = np.flatnonzero(change)
    along = moving[idx] == direction[idx]
    runs = run[idx]
    return pd.DataFrame({
        "group": tr["group"].to_numpy()[idx],
        "route": route_asked(tr, idx, next_lanes or {}),
        "duration": np.where(along, time[ends[runs]] - begin[runs], np.nan),
        "peak_accel": np.where(along, peak[runs], np.nan),
        "run": np.where(along, runs, -1),
    })  # fmt: skip


def route_asked(
    tr: pd.DataFrame, changes: np.ndarray, next_lanes: Mapping[str, frozenset[str]]
) -> np.ndarray:
    """Per lane change (the record index where the car is first seen in the new lane): whether the
    route asked for it, as a mandatory change: the lane left could not take the car, through the
    net's connections, as far along the edges it drove on afterwards as the lane it moved into
    (an acceleration lane, a dropped lane, a lane that leads only onto an exit, or onto the exit
    it takes). False where the net's connections are not known."""
    out = np.zeros(len(changes), bool)
    if not len(changes) or not next_lanes:
        return out
    lane = tr["lane_id"].astype(str).to_numpy()
    normal = np.flatnonzero(~tr["internal"].to_numpy())
    seg = tr["seg"].to_numpy()[normal]
    edge = np.array([name.rpartition("_")[0] for name in lane[normal]])
    starts = np.r_[True, (edge[1:] != edge[:-1]) | (seg[1:] != seg[:-1])]
    run_edge, run_seg = edge[starts], seg[starts]
    run_of = np.full(len(tr), -1)
    run_of[normal] = np.cumsum(starts) - 1
    for k, i in enumerate(changes.tolist()):
        left, run = lane[i - 1], run_of[i]
        if left.startswith(":") or run < 0:
            continue
        end = run + 1
        while end < len(run_seg) and run_seg[end] == run_seg[run]:
            end += 1
        route = list(run_edge[run + 1 : end])
        out[k] = _reach(left, route, next_lanes) < _reach(lane[i], route, next_lanes)
    return out


def _reach(lane: str, route: list[str], next_lanes: Mapping[str, frozenset[str]]) -> int:
    """How many edges of `route` a car in `lane` can drive on without changing lanes."""
    current = {lane}
    for count, edge in enumerate(route):
        current = {n for c in current for n in next_lanes.get(c, ()) if n.rpartition("_")[0] == edge}
        if not current:
            return count
    return len(route)


def lane_offsets(tr: pd.DataFrame, changes: pd.DataFrame) -> pd.DataFrame:
    """|offset from the lane centre| (posLat) of every settled record on a normal lane outside the
    sideways runs of lane changes (junction lanes join lanes of other widths; a lane change
    leaves the centre on purpose)."""
    _, run = _sideways_runs(tr)
    offset = np.abs(tr["pos_lat"].to_numpy())
    keep = tr["settled"].to_numpy() & ~tr["internal"].to_numpy() & ~np.isin(run, changes["run"])
    keep &= ~np.isnan(offset)
    return pd.DataFrame({"group": tr["group"].to_numpy()[keep], "offset": offset[keep]})


def headways(tr: pd.DataFrame) -> pd.DataFrame:
    """Time headway and time-to-collision of settled cars following a leader in the same lane.

    Gap = leader's pos - leader's length - own pos (pos is the front bumper); kept where the own
    speed exceeds FOLLOW_MIN_SPEED and the gap is at most LEADER_RANGE. TTC is infinite unless
    the follower is faster.
    """
    time, lane, pos = tr["time"].to_numpy(), tr["lane"].to_numpy(), tr["pos"].to_numpy()
    order = np.lexsort((pos, lane, time))
    own, lead = order[:-1], order[1:]
    paired = (time[lead] == time[own]) & (lane[lead] == lane[own])
    own, lead = own[paired], lead[paired]
    speed, length = tr["speed"].to_numpy(), np.broadcast_to(tr["length"].to_numpy(), len(tr))
    gap = pos[lead] - length[lead] - pos[own]
    keep = tr["settled"].to_numpy()[own] & (speed[own] > FOLLOW_MIN_SPEED) & (gap <= LEADER_RANGE)
    own, lead, gap = own[keep], lead[keep], gap[keep]
    closing = speed[own] - speed[lead]
    with np.errstate(divide="ignore"):
        ttc = np.where(closing > 0, gap / np.where(closing > 0, closing, 1.0), np.inf)
    return pd.DataFrame({"group": tr["group"].to_numpy()[own], "thw": gap / speed[own], "ttc": ttc})


def _neighbour_pairs(tr: pd.DataFrame, window: float) -> tuple[np.ndarray, np.ndarray]:
    """Row pairs (i, j) of two cars at the same time on the same road edge, pos[j] - pos[i] <= window."""
    road_edge = np.nan_to_num(tr["road_edge"].to_numpy(), nan=-1.0)
    time, pos = tr["time"].to_numpy(), tr["pos"].to_numpy()
    order = np.lexsort((pos, road_edge, time))
    t, e, p = time[order], road_edge[order], pos[order]
    rows_i, rows_j = [], []
    for s in range(1, len(order)):
        near = (t[s:] == t[:-s]) & (e[s:] == e[:-s]) & (p[s:] - p[:-s] <= window) & (e[s:] >= 0)
        if not near.any():
            break
        hits = np.flatnonzero(near)
        rows_i.append(order[hits])
        rows_j.append(order[hits + s])
    if not rows_i:
        return np.zeros(0, int), np.zeros(0, int)
    return np.concatenate(rows_i), np.concatenate(rows_j)


def passes(tr: pd.DataFrame) -> pd.DataFrame:
    """One row per pass made by a settled car (its group and vehicle code), with the side it passed on.

    A passes B when A's front goes from more than a car length (their mean length) behind B's
    front to more than a car length ahead while both stay on the same edge. The side is where
    A was, laterally, while the two were alongside (the mean over those records; the record that
    completed the pass if it jumped over them): `overtaking_side` is true for larger lateral
    positions, i.e. a pass on the left in keep-right nets (on the right in left-hand nets).
    """
    length = np.broadcast_to(tr["length"].to_numpy(), len(tr))
    window = float(length.max()) + max(PASS_MARGIN, 25.0 * tr.attrs["step"])
    i, j = _neighbour_pairs(tr, window)
    vehicle = tr["vehicle"].to_numpy()
    a = np.where(vehicle[i] < vehicle[j], i, j)  # each pair in one orientation: lower vehicle code first
    b = np.where(vehicle[i] < vehicle[j], j, i)
    pos, lat = tr["pos"].to_numpy(), tr["lat"].to_numpy()
    ahead = pos[a] - pos[b]
    reach = (length[a] + length[b]) / 2
    state = np.where(ahead > reach, 1, np.where(ahead < -reach, -1, 0))
    order = np.lexsort((tr["time"].to_numpy()[a], vehicle[b], vehicle[a]))
    a, b, state = a[order], b[order], state[order]
    beside = np.cumsum(np.where(state == 0, lat[a] - lat[b], 0.0))
    count = np.cumsum(state == 0)
    marked = np.flatnonzero(state != 0)
    prev, cur = marked[:-1], marked[1:]
    road_edge = tr["road_edge"].to_numpy()
    done = (
        (vehicle[a[prev]] == vehicle[a[cur]]) & (vehicle[b[prev]] == vehicle[b[cur]])
        & (state[prev] == -state[cur]) & (road_edge[a[prev]] == road_edge[a[cur]])
    )  # fmt: skip
    prev, cur = prev[done], cur[done]
    alongside = count[cur] - count[prev]
    side_ab = np.where(
        alongside > 0, (beside[cur] - beside[prev]) / np.maximum(alongside, 1), lat[a[cur]] - lat[b[cur]]
    )
    a_passed = state[cur] == 1
    passer = np.where(a_passed, a[cur], b[cur])
    settled = tr["settled"].to_numpy()[passer]
    side = np.where(a_passed, side_ab, -side_ab)[settled]
    return pd.DataFrame({
        "group": tr["group"].to_numpy()[passer][settled], "vehicle": vehicle[passer][settled],
        "overtaking_side": side > 0,
    })  # fmt: skip


def trips(tr: pd.DataFrame) -> np.ndarray:
    """Per vehicle code: its trip, the first and the last normal edge it was seen on (one number)."""
    edge = pd.Series(tr["road_edge"].to_numpy()).groupby(tr["vehicle"].to_numpy())
    first, last = edge.first(), edge.last()
    n_edges = np.nanmax(tr["road_edge"].to_numpy(), initial=0) + 1
    out = np.full(int(tr["vehicle"].max()) + 1, np.nan)
    out[first.index.to_numpy()] = first.to_numpy() * n_edges + last.to_numpy()
    return out


def like_for_like(
    live: pd.DataFrame, made: pd.DataFrame, trip: np.ndarray, over: str, under: str
) -> dict[str, float]:
    """`over` / `under` mean speed and passes per km with the mix of trips taken out: on each trip
    (`trips`) both groups made, each group's value, the trips weighted by the two groups' time
    (speed) or km (passes) on them. Which cars a share draws is chance: on a net with an exit, one
    behaviour may draw more cars onto the slower ramp routes, and the pooled means compare routes
    rather than behaviours. `trips`: how many trips both made (0: every ratio NaN); `km_share`: the
    two groups' km on those trips, of all their km."""
    trip_of = trip[live["vehicle"].to_numpy()]
    on = live.assign(trip=trip_of, km=live["speed"] * live["dt"].fillna(0) / 1000)
    by = on.groupby(["trip", "group"])
    speed = by["speed"].mean().unstack()
    time = by["dt"].sum().unstack()
    km = by["km"].sum().unstack()
    shared = km.index[(km[over] > 0) & (km[under] > 0)] if {over, under} <= set(km.columns) else km.index[:0]
    if not len(shared):
        return {"trips": 0.0, "km_share": 0.0, "mean_speed": math.nan, "passes_per_km": math.nan}
    count = made.assign(trip=trip[made["vehicle"].to_numpy()]).groupby(["trip", "group"]).size()
    rate = count.unstack().reindex(index=km.index, columns=km.columns).fillna(0) / km

    def weighted(values: pd.DataFrame, weights: pd.DataFrame) -> float:
        w = weights.loc[shared, over] + weights.loc[shared, under]
        top = float((w * values.loc[shared, over]).sum())
        bottom = float((w * values.loc[shared, under]).sum())
        return top / bottom if bottom > 0 else (math.inf if top > 0 else math.nan)

    both = km[[over, under]].fillna(0)
    return {
        "trips": float(len(shared)),
        "km_share": float(both.loc[shared].to_numpy().sum() / both.to_numpy().sum()),
        "mean_speed": weighted(speed, time),
        "passes_per_km": weighted(rate, km),
    }
