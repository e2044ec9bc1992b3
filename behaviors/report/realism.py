"""Realism report: how human-like the traces of an FCD are, per group of vehicles.

The measures and the naturalistic figures they are compared with are those of the project's
realism notes (lane use, lane changes, lateral acceleration and jerk, lane-change peak and
duration, time headway and time-to-collision, passes and their side, speed, losses). Everything
here is vectorised numpy/pandas over the whole table: a million FCD records take seconds.

Conventions (checked against netconvert and SUMO 1.28):
* Lateral positions are metres from the edge's outer border (the widths of the lanes with a
  lower index + half the own lane's width + posLat). SUMO numbers lanes from the outer side and
  posLat points towards higher indices in both keep-right and left-hand (`--lefthand`) nets, so
  a larger lateral position is always towards the overtaking lanes: left in keep-right nets,
  right in left-hand nets.
* A junction's internal lane counts as the lane the car came from (lane use, lane changes).
* Lateral acceleration and jerk are centred differences over DERIVATIVE_S, on a lateral track
  that stays continuous across edges (see `prepare`).
"""

from __future__ import annotations

import csv
import io
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from behaviors.errors import BehaveError
from behaviors.files import atomic_path, atomic_write_text, ensure_writable_dir
from behaviors.report.agents_table import LONG_STANDSTILL_S, REPORTED

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from matplotlib.figure import Figure

ASSUMED_LANE_WIDTH = 3.2  # SUMO's default; used for lanes the net does not name (or without a net)
DEFAULT_LENGTH = 5.0  # metres; SUMO's passenger car, and every behave vType
SKIP_S = 10.0  # each car's first seconds are left out: insertion is no behaviour
DERIVATIVE_S = 0.4
"""Lateral acceleration and jerk are differences over at least this span: FCD rounds posLat to
1 cm, and second differences over a 0.2 s step would turn the rounding into up to 0.5 m/s^2."""
SIDEWAYS_SPEED = 0.05
"""m/s: a record moving sideways slower than this is not part of a lane change (its duration)."""
LAT_ACCEL_LIMIT = 1.5  # m/s^2
FOLLOW_MIN_SPEED = 5.0  # m/s: headways of slower cars are queueing, not following
LEADER_RANGE = 250.0  # m
THW_LIMIT = 1.0  # s
OFF_CENTRE_LIMIT = 0.5  # m from the lane centre
RUN_GAP_S = 3600.0
"""s between stacked runs (`stack_runs`): no car of one run is seen beside a car of another."""
TTC_LIMIT = 3.0  # s
PASS_MARGIN = 10.0
"""m beyond a car length within which pairs are tracked for passes; widened to 25 m/s x step for
coarse steps, so that no pass can jump over the window between two records."""
GROUP_BY = ("type", "id-prefix")
KEEPERS, OVERTAKERS = "keepers", "overtakers"
GROUPS_OF_TYPE = {"behave_keeper": KEEPERS, "behave_overtaker": OVERTAKERS}
OTHER_GROUP = "sumo"
REQUIRED = ("id", "time", "lane", "pos", "speed")


class NothingToMeasure(BehaveError):
    """No car drove longer than the seconds left out at its start."""


@dataclass(frozen=True)
class Lanes:
    """What the net says of its lanes (empty: every lane ASSUMED_LANE_WIDTH wide, indices as ranks)."""

    centre: dict[str, float] = field(default_factory=dict)  # lane id -> centre, metres from the outer border
    width: dict[str, float] = field(default_factory=dict)
    rank: dict[str, int] = field(
        default_factory=dict
    )  # lane id -> index among car lanes, from the outer side
    lefthand: bool = False
    from_net: bool = False
    next_lanes: dict[str, frozenset[str]] = field(default_factory=dict)
    """Normal lane id -> the normal lanes its connections lead into (a lane that ends: none)."""


def read_lanes(net: Path) -> Lanes:
    """Lane layout of a SUMO net (.net.xml or .net.xml.gz), internal lanes included (through
    sumo_scenarios.net, the one net reader).

    Ranks count only lanes that allow passenger cars (a sidewalk or bus lane is not lane 0).
    """
    import gzip
    import zlib

    from sumo_scenarios.net import DEFAULT_LANE_WIDTH, net_elements

    net = Path(net)
    if not net.is_file():
        raise BehaveError(f"net file not found: {net}")
    centre: dict[str, float] = {}
    width: dict[str, float] = {}
    rank: dict[str, int] = {}
    next_lanes: dict[str, set[str]] = {}
    lefthand, root = False, False
    try:
        for elem in net_elements(net):
            if elem.tag == "net":
                root, lefthand = True, elem.get("lefthand") == "true"
            elif elem.tag == "edge" and root and elem.get("function", "") in EDGE_FUNCTIONS:
                _add_edge(elem, centre, width, rank, DEFAULT_LANE_WIDTH)
            elif elem.tag == "connection" and root and not elem.get("from", ":").startswith(":"):
                lane_id = f"{elem.get('from')}_{elem.get('fromLane')}"
                next_lanes.setdefault(lane_id, set()).add(f"{elem.get('to')}_{elem.get('toLane')}")
    except (ET.ParseError, ValueError, KeyError, OSError, EOFError, gzip.BadGzipFile, zlib.error) as err:
        raise BehaveError(f"{net} is not a SUMO net ({err})") from None
    if not root:
        raise BehaveError(f"{net} is not a SUMO net (its root element is not <net>)")
    if not centre:
        raise BehaveError(f"{net} is not a SUMO net (no lanes)")
    normal = {lane: frozenset(next_lanes.get(lane, ())) for lane in centre if not lane.startswith(":")}
    return Lanes(centre, width, rank, lefthand, from_net=True, next_lanes=normal)


EDGE_FUNCTIONS = ("", "internal", "crossing", "walkingarea")
"""The edges whose lanes count: normal ones (no function) and a junction's (not macro connectors)."""


def _add_edge(
    elem: ET.Element, centre: dict[str, float], width: dict[str, float], rank: dict[str, int], default: float
) -> None:
    """One edge's lanes from its outer border: centre, width, and rank among the car lanes."""
    from sumo_scenarios.net import allows_car

    lanes = list(elem.iter("lane"))
    order = sorted(range(len(lanes)), key=lambda k: int(lanes[k].get("index") or k))
    border, cars = 0.0, 0
    for k in order:
        lane = lanes[k]
        lane_id, lane_width = lane.get("id", ""), float(lane.get("width", default))
        width[lane_id] = lane_width
        centre[lane_id] = border + lane_width / 2
        rank[lane_id] = cars
        border += lane_width
        cars += allows_car(lane.get("allow"), lane.get("disallow"))


def group_names(ids: pd.Series, types: pd.Series | None, group_by: str) -> pd.Series:
    """Group of each vehicle: by vType (learned keepers, overtakers, everyone else is SUMO's) or
    by the id without its trailing number (`keeper_3` -> `keeper`, `flow.12` -> `flow`).

    SUMO names a type it copied for one vehicle (when that vehicle's parameters are changed)
    `<type>@<vehicle>`: the copy belongs to the type's group."""
    if group_by == "type":
        if types is None:
            raise BehaveError("the FCD has no type column: use --group-by id-prefix")
        base = types.astype(str).str.split("@", n=1).str[0]
        return base.map(GROUPS_OF_TYPE).fillna(OTHER_GROUP).astype(str)
    if group_by == "id-prefix":
        return ids.astype(str).str.replace(r"[._#-]?\d+$", "", regex=True).replace("", "vehicles")
    raise BehaveError(f"unknown grouping {group_by!r}: choose one of {', '.join(GROUP_BY)}")


def _per_unique(values: pd.Series) -> tuple[np.ndarray, pd.Index]:
    codes, uniques = pd.factorize(values)
    return codes, pd.Index(uniques)


def _shift(values: np.ndarray, seg: np.ndarray, k: int) -> np.ndarray:
    """values[i - k] where that row lies in the same segment as row i, else NaN (k may be < 0)."""
    out = np.full(len(values), np.nan)
    if k == 0 or abs(k) >= len(values):
        return values.astype(float) if k == 0 else out
    if k > 0:
        same = seg[k:] == seg[:-k]
        out[k:] = np.where(same, values[:-k], np.nan)
    else:
        same = seg[:k] == seg[-k:]
        out[:k] = np.where(same, values[-k:], np.nan)
    return out


def prepare(
    df: pd.DataFrame,
    lanes: Lanes,
    *,
    skip_s: float = SKIP_S,
    group_by: str = "type",
    lengths: Mapping[str, float] | None = None,
) -> pd.DataFrame:
    """One row per FCD record, sorted by vehicle and time, with what every measure needs.

    `seg` numbers runs of records of one car without a time gap; `lat` is the lateral position
    from the outer border; `pos_lat` the offset from the lane centre (NaN if the FCD has no
    posLat); `track` a lateral position continuous across edges (`_track`);
    `road_edge`/`road_rank` carry the last normal lane through junctions; `settled` is false
    during a car's first `skip_s`; `lane_id` the lane's name.
    """
    missing = [c for c in REQUIRED if c not in df.columns or df[c].isna().all()]
    if missing:
        needs = ", ".join(REQUIRED)
        raise BehaveError(f"the FCD lacks {', '.join(missing)}: the realism report needs {needs}")
    df = df.dropna(subset=list(REQUIRED))
    if df.empty:
        raise BehaveError("the FCD holds no vehicle records")
    vehicle, vehicle_ids = _per_unique(df["id"])
    order = np.lexsort((df["time"].to_numpy(float), vehicle))
    df, vehicle = df.iloc[order].reset_index(drop=True), vehicle[order]
    time = df["time"].to_numpy(float)
    new = np.ones(len(df), bool)
    new[1:] = vehicle[1:] != vehicle[:-1]
    dt = np.where(new, np.nan, time - np.roll(time, 1))
    step = float(np.nanmedian(dt)) if (~new).any() else 1.0
    gap = ~new & (dt > 1.5 * step)
    seg = np.cumsum(new | gap)
    dt[gap] = np.nan

    lane, lane_ids = _per_unique(df["lane"])
    lane_names = pd.Index(lane_ids.astype(str))
    layout = _lane_layout(lane_names, lanes).iloc[lane]
    internal, rank = layout["internal"].to_numpy(), layout["rank"].to_numpy()
    edge = layout["edge"].to_numpy()
    offset = df["posLat"].to_numpy(float) if "posLat" in df.columns else np.full(len(df), np.nan)
    pos_lat = np.nan_to_num(offset)
    lat = layout["centre"].to_numpy() + pos_lat
    by_vehicle = pd.Series(vehicle)
    first = np.flatnonzero(new)
    group, length = _vehicle_table(df, first, pd.Index(vehicle_ids.astype(str)), group_by, lengths)
    out = pd.DataFrame({
        "vehicle": vehicle, "seg": seg, "time": time, "dt": dt,
        "speed": df["speed"].to_numpy(float), "pos": df["pos"].to_numpy(float),
        "lane": lane, "lat": lat, "pos_lat": offset, "internal": internal,
        "track": _track(seg, edge, lat, pos_lat, layout["width"].to_numpy()),
        "road_edge": pd.Series(np.where(internal, np.nan, edge)).groupby(by_vehicle).ffill().to_numpy(),
        "road_rank": pd.Series(np.where(internal, np.nan, rank)).groupby(by_vehicle).ffill().to_numpy(),
        "settled": time - time[first][np.cumsum(new) - 1] >= skip_s,
        "lane_id": pd.Categorical.from_codes(lane, categories=lane_names),
        "group": group[vehicle], "length": length[vehicle],
    })  # fmt: skip
    out.attrs["step"] = step
    return out


def _lane_layout(lane_ids: pd.Index, lanes: Lanes) -> pd.DataFrame:
    """Per lane id: its edge (a number), whether it is a junction lane, its centre, width and rank;
    lanes the net does not name are ASSUMED_LANE_WIDTH wide and ranked by their index."""
    edge_id = pd.Series([x.rpartition("_")[0] for x in lane_ids])
    index = pd.to_numeric(pd.Series([x.rpartition("_")[2] for x in lane_ids]), errors="coerce").fillna(0)
    width = ASSUMED_LANE_WIDTH
    return pd.DataFrame({
        "edge": pd.factorize(edge_id)[0].astype(float),
        "internal": lane_ids.str.startswith(":"),
        "centre": [lanes.centre.get(x, (i + 0.5) * width) for x, i in zip(lane_ids, index, strict=True)],
        "width": [lanes.width.get(x, ASSUMED_LANE_WIDTH) for x in lane_ids],
        "rank": [float(lanes.rank.get(x, i)) for x, i in zip(lane_ids, index, strict=True)],
    })  # fmt: skip


def _vehicle_table(
    df: pd.DataFrame, first: np.ndarray, ids: pd.Index, group_by: str, lengths: Mapping[str, float] | None
) -> tuple[np.ndarray, np.ndarray]:
    """Group name and length of each vehicle (rows `first` are each vehicle's first record).

    The group is the vType of a vehicle's last record: `populate --share` makes a scenario's car
    an agent after SUMO wrote its first record with the scenario's type."""
    last = np.r_[first[1:] - 1, len(df) - 1]
    types = df["type"].iloc[last].reset_index(drop=True) if "type" in df.columns else None
    group = group_names(pd.Series(ids), types, group_by).to_numpy()
    known = dict(lengths or {})
    if types is None:
        return group, np.full(len(ids), DEFAULT_LENGTH)
    return group, np.array([known.get(t, DEFAULT_LENGTH) for t in types.astype(object)], float)


def _track(
    seg: np.ndarray, edge: np.ndarray, lat: np.ndarray, pos_lat: np.ndarray, width: np.ndarray
) -> np.ndarray:
    """Lateral position continuous along each segment: within an edge it moves as `lat`; from one
    edge (or junction lane) to the next as posLat, unwrapped by a lane width if the car's centre
    crossed a line in that same step (a sideways move of half a lane in one record is no motion)."""
    same_edge = _shift(edge, seg, 1) == edge
    across = pos_lat - np.roll(pos_lat, 1)
    mean_width = (width + np.roll(width, 1)) / 2
    across -= mean_width * np.round(across / mean_width)
    step = np.where(same_edge, lat - np.roll(lat, 1), across)
    step[np.isnan(_shift(lat, seg, 1))] = 0.0
    track = np.cumsum(step)
    starts = np.flatnonzero(np.diff(seg, prepend=0))
    return track - np.repeat(track[starts], np.diff(np.append(starts, len(seg))))


def lateral_motion(tr: pd.DataFrame) -> pd.DataFrame:
    """Lateral acceleration and jerk of every record: centred differences of `track` over
    n steps (n * step >= DERIVATIVE_S); NaN where the span leaves the record's segment."""
    k = max(1, round(DERIVATIVE_S / tr.attrs["step"]))
    seg, u, t = tr["seg"].to_numpy(), tr["track"].to_numpy(), tr["time"].to_numpy()
    u_next, u_prev = _shift(u, seg, -k), _shift(u, seg, k)
    t_next, t_prev = _shift(t, seg, -k), _shift(t, seg, k)
    accel = 2 * ((u_next - u) / (t_next - t) - (u - u_prev) / (t - t_prev)) / (t_next - t_prev)
    jerk = (_shift(accel, seg, -k) - _shift(accel, seg, k)) / (t_next - t_prev)
    return pd.DataFrame({"accel": accel, "jerk": jerk})


def _sideways_runs(tr: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Per record: its sideways direction (-1, 0 or 1; still below SIDEWAYS_SPEED) and the number
    of its run (consecutive records of one segment moving the same way)."""
    seg, track, dt = tr["seg"].to_numpy(), tr["track"].to_numpy(), tr["dt"].to_numpy()
    sideways = (track - _shift(track, seg, 1)) / dt
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
    prev_rank = _shift(rank, seg, 1)
    same_edge = _shift(road_edge, seg, 1) == road_edge
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


def read_agents(path: Path) -> pd.DataFrame | None:
    """The per-agent table if the file exists (None if not): how and when each agent ended."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        agents = pd.read_csv(
            path, dtype={c: str for c in ("id", "behaviour", "vtype", "policy", "end_reason")}
        )
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise BehaveError(f"{path} is not a per-agent table ({err})") from None
    missing = [c for c in REPORTED if c not in agents.columns]
    if missing:
        raise BehaveError(f"{path} is not a per-agent table (no {', '.join(missing)} column)")
    return agents


def stack_runs(
    runs: Sequence[tuple[pd.DataFrame, pd.DataFrame | None]],
) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """Several runs (FCD, per-agent table or None) as one to measure together: ids get the run's
    number (`3:agent_0`) and each run's clock starts RUN_GAP_S after the previous run ended, so
    that no car is another run's leader or pass. The agent tables are kept only if every run has one."""
    fcds, tables, start = [], [], 0.0
    for k, (fcd, agents) in enumerate(runs):
        shift = start - float(fcd["time"].min())
        fcds.append(fcd.assign(id=f"{k}:" + fcd["id"].astype(str), time=fcd["time"] + shift))
        if agents is not None:
            moved = {"depart_s": agents["depart_s"] + shift, "end_s": agents["end_s"] + shift}
            tables.append(agents.assign(id=f"{k}:" + agents["id"].astype(str), **moved))
        start = float(fcds[-1]["time"].max()) + RUN_GAP_S
    if not fcds:
        raise BehaveError("no runs to measure")
    both = len(tables) == len(fcds)
    return pd.concat(fcds, ignore_index=True), pd.concat(tables, ignore_index=True) if both else None


def losses(agents: pd.DataFrame, group_by: str = "type") -> pd.DataFrame:
    """Per group: collisions, off-tracks and removals without progress per agent-hour (over the
    agents' whole runs), and how many agents stood still LONG_STANDSTILL_S or longer."""
    group = group_names(agents["id"], agents["vtype"], group_by)
    hours = (agents["end_s"] - agents["depart_s"]).clip(lower=0) / 3600
    table = pd.DataFrame({
        "group": group, "hours": hours,
        "collision": agents["end_reason"] == "collision", "off_track": agents["end_reason"] == "off_track",
        "no_progress": agents["end_reason"] == "no_progress",
        "standing": agents["longest_standstill_s"] >= LONG_STANDSTILL_S,
    }).groupby("group").sum()  # fmt: skip
    rate = table[["collision", "off_track", "no_progress"]].div(
        table["hours"].where(table["hours"] > 0), axis=0
    )
    rate.columns = ["collisions_per_agent_hour", "off_tracks_per_agent_hour", "no_progress_per_agent_hour"]
    return rate.assign(agents_standing=table["standing"].astype(float))


@dataclass(frozen=True)
class Metric:
    key: str
    label: str
    reference: str = "-"
    share: bool = False  # shown as a percentage


METRICS = (
    Metric("vehicles", "vehicles"),
    Metric("vehicle_km", "vehicle-km (after each car's first seconds)"),
    Metric("mean_speed", "mean speed [m/s]"),
    Metric("lane_changes_per_km", "lane changes per vehicle-km", "0.12 (highD) - 0.22 (VTTI)"),
    Metric("discretionary_lane_changes_per_km", "lane changes per vehicle-km the route did not ask for"),
    Metric("lane_changes_per_min", "lane changes per vehicle-minute"),
    Metric("lat_accel_over_limit", f"time with |lateral accel| > {LAT_ACCEL_LIMIT} m/s^2", "~0", share=True),
    Metric("lat_accel_p95", "|lateral accel| p95 [m/s^2]"),
    Metric("lat_jerk_p95", "|lateral jerk| p95 [m/s^3]"),
    Metric("lc_peak_accel_median", "peak |lateral accel| per lane change, median [m/s^2]", "0.5-1"),
    Metric("lc_duration_median", "lane-change duration, median [s]", "5-6 (VTTI mean 6.28)"),
    Metric("lane_offset_mean", "|offset from the lane centre| outside lane changes, mean [m]"),
    Metric(
        "off_centre_share",
        f"time > {OFF_CENTRE_LIMIT:g} m off the lane centre (outside lane changes)",
        share=True,
    ),
    Metric("thw_median", "time headway, median [s]", "1-2 (freeway rush hour)"),
    Metric("thw_p5", "time headway, 5th percentile [s]", "~1 (lower limit)"),
    Metric(
        "thw_below_limit", f"following time with headway < {THW_LIMIT:g} s", "small (< 0.9 s fined, DE)", True
    ),
    Metric("ttc_below_limit", f"following time with time-to-collision < {TTC_LIMIT:g} s", share=True),
    Metric("passes_per_km", "passes made per vehicle-km"),
    Metric("passes_overtaking_side", "passes made on the left", "~100% (right: illegal, StVO 5)", True),
    Metric("collisions_per_agent_hour", "collisions per agent-hour", "0"),
    Metric("off_tracks_per_agent_hour", "off-tracks per agent-hour", "0"),
    Metric("no_progress_per_agent_hour", "agents removed without progress per agent-hour", "0"),
    Metric("agents_standing", f"agents that stood still >= {LONG_STANDSTILL_S:.0f} s"),
)
LOSS_KEYS: tuple[str, ...] = (
    "collisions_per_agent_hour",
    "off_tracks_per_agent_hour",
    "no_progress_per_agent_hour",
)
LOSS_KEYS += ("agents_standing",)


@dataclass(frozen=True)
class Report:
    """The realism measures per group, and the samples the picture is drawn from."""

    table: pd.DataFrame  # rows: metric keys (METRICS, lane shares after mean_speed); columns: groups
    metrics: tuple[Metric, ...]
    samples: dict[str, dict[str, np.ndarray]]  # "thw", "accel", "speed" -> group -> values
    notes: tuple[str, ...]
    losses_known: bool  # a per-agent table was read: no figure means the group had no agents
    like_for_like: dict[str, float] = field(default_factory=dict)
    """overtakers / keepers on the trips both made (`like_for_like`); empty without both groups."""


def check_options(skip_s: float, group_by: str) -> None:
    """Refuse bad options before a long FCD is read."""
    if not skip_s >= 0:
        raise BehaveError(f"--skip-s must be >= 0, got {skip_s}")
    if group_by not in GROUP_BY:
        raise BehaveError(f"unknown grouping {group_by!r}: choose one of {', '.join(GROUP_BY)}")


def _ordered_groups(groups: pd.Index) -> list[str]:
    known = [g for g in (*GROUPS_OF_TYPE.values(), OTHER_GROUP) if g in groups]
    return known + sorted(g for g in groups if g not in known)


def measure(
    df: pd.DataFrame,
    lanes: Lanes,
    *,
    agents: pd.DataFrame | None = None,
    skip_s: float = SKIP_S,
    group_by: str = "type",
    lengths: Mapping[str, float] | None = None,
) -> Report:
    """Every realism measure of an FCD table (from `read_fcd`), per group of vehicles."""
    check_options(skip_s, group_by)
    tr = prepare(df, lanes, skip_s=skip_s, group_by=group_by, lengths=lengths)
    motion = lateral_motion(tr)
    settled = tr["settled"].to_numpy()
    if not settled.any():
        raise NothingToMeasure(
            f"no vehicle drove longer than {skip_s:g} s: nothing to measure (try a smaller --skip-s)"
        )
    live = tr[settled].assign(accel=motion["accel"].abs()[settled], jerk=motion["jerk"].abs()[settled])
    by = live.groupby("group")
    km = (live["speed"] * live["dt"].fillna(0)).groupby(live["group"]).sum() / 1000
    minutes = live["dt"].fillna(0).groupby(live["group"]).sum() / 60
    changes = lane_changes(tr, motion["accel"].to_numpy(), lanes.next_lanes)
    follow = headways(tr)
    made = passes(tr)
    offsets = lane_offsets(tr, changes)
    n_changes = changes.groupby("group").size().reindex(km.index, fill_value=0)
    rows = {
        "vehicles": by["vehicle"].nunique(),
        "vehicle_km": km,
        "mean_speed": by["speed"].mean(),
        "lane_changes_per_km": n_changes / km.where(km > 0),
        "discretionary_lane_changes_per_km": (
            (~changes["route"]).groupby(changes["group"]).sum().reindex(km.index, fill_value=0)
            / km.where((km > 0) & bool(lanes.next_lanes))
        ),
        "lane_changes_per_min": n_changes / minutes.where(minutes > 0),
        "lat_accel_over_limit": by["accel"].apply(lambda a: (a.dropna() > LAT_ACCEL_LIMIT).mean()),
        "lat_accel_p95": by["accel"].quantile(0.95),
        "lat_jerk_p95": by["jerk"].quantile(0.95),
        "lc_peak_accel_median": changes.groupby("group")["peak_accel"].median(),
        "lc_duration_median": changes.groupby("group")["duration"].median(),
        "lane_offset_mean": offsets.groupby("group")["offset"].mean(),
        "off_centre_share": (offsets["offset"] > OFF_CENTRE_LIMIT).groupby(offsets["group"]).mean(),
        "thw_median": follow.groupby("group")["thw"].median(),
        "thw_p5": follow.groupby("group")["thw"].quantile(0.05),
        "thw_below_limit": (follow["thw"] < THW_LIMIT).groupby(follow["group"]).mean(),
        "ttc_below_limit": (follow["ttc"] < TTC_LIMIT).groupby(follow["group"]).mean(),
        "passes_per_km": made.groupby("group").size().reindex(km.index, fill_value=0) / km.where(km > 0),
        "passes_overtaking_side": made.groupby("group")["overtaking_side"].mean(),
    }
    groups = _ordered_groups(km.index)
    table = pd.DataFrame({key: values.reindex(groups) for key, values in rows.items()}).T
    lane_use = live.groupby(["group", "road_rank"]).size().unstack(fill_value=0)
    lane_use = lane_use.div(lane_use.sum(axis=1), axis=0).reindex(groups).T
    lane_use.index = [f"lane_{int(rank)}_share" for rank in lane_use.index]
    notes = [_lane_note(lanes), f"each car's first {skip_s:g} s left out"]
    if not lanes.next_lanes:
        notes.append("which lane changes the route asked for is unknown without the net's connections")
    if tr["pos_lat"].isna().all():
        notes.append("lane centring unknown: the FCD has no posLat")
    if agents is not None:
        loss = losses(agents, group_by).reindex(groups).T
    else:
        loss = pd.DataFrame(np.nan, index=list(LOSS_KEYS), columns=groups)
        notes.append("losses unknown: no per-agent table (<fcd stem>.agents.csv) beside the FCD")
    at = list(table.index).index("mean_speed") + 1
    table = pd.concat([table.iloc[:at], lane_use, table.iloc[at:], loss])
    metrics = _metrics(lane_use.index, lanes.lefthand)
    samples = {
        "thw": _by_group(follow, "thw"),
        "accel": _by_group(live.dropna(subset=["accel"]), "accel"),
        "speed": _by_group(live, "speed"),
    }
    ratios = {}
    if {OVERTAKERS, KEEPERS} <= set(groups):
        ratios = like_for_like(live, made, trips(tr), OVERTAKERS, KEEPERS)
        notes.append(like_for_like_note(ratios))
    return Report(table.astype(float), metrics, samples, tuple(notes), agents is not None, ratios)


def like_for_like_note(ratios: dict[str, float]) -> str:
    """`like_for_like`'s ratios in words: `1.23x`, or what an infinite or undefined ratio means."""
    if not ratios["trips"]:
        return "overtakers / keepers: no trip both made (first to last edge), so no like-for-like ratios"

    def times(value: float, what: str) -> str:
        if math.isfinite(value):
            return f"{value:.2f}x"
        if math.isinf(value):
            return f"only the overtakers had any {what}"
        return f"neither had any {what}"

    return (
        f"overtakers / keepers on the trips both made ({ratios['trips']:.0f}, first to last edge; "
        f"{100 * ratios['km_share']:.0f}% of their km): mean speed {times(ratios['mean_speed'], 'speed')}, "
        f"passes per km {times(ratios['passes_per_km'], 'passes')}"
    )


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


def _lane_note(lanes: Lanes) -> str:
    if not lanes.from_net:
        return f"no net: every lane assumed {ASSUMED_LANE_WIDTH} m wide, lanes counted by their index"
    side = "left (left-hand net)" if lanes.lefthand else "right"
    return f"lane widths from the net; lanes counted from the {side} among lanes cars may use"


def _metrics(lane_rows: pd.Index, lefthand: bool) -> tuple[Metric, ...]:
    outer = "left" if lefthand else "right"
    lanes = [
        Metric(row, f"time in lane {row.split('_')[1]} (from the {outer})", "-", True) for row in lane_rows
    ]  # fmt: skip
    if lanes:
        lanes[0] = Metric(lanes[0].key, lanes[0].label, "most at low density", True)
    out: list[Metric] = []
    for metric in METRICS:
        if metric.key == "passes_overtaking_side" and lefthand:
            metric = Metric(metric.key, "passes made on the right (left-hand net)", metric.reference, True)
        out.append(metric)
        if metric.key == "mean_speed":
            out += lanes
    return tuple(out)


def _by_group(frame: pd.DataFrame, column: str) -> dict[str, np.ndarray]:
    return {str(g): part[column].to_numpy(float) for g, part in frame.groupby("group")}


def format_value(value: float, metric: Metric, *, losses_known: bool = True) -> str:
    if np.isnan(value):
        return "unknown" if metric.key in LOSS_KEYS and not losses_known else "-"
    if metric.share:
        return f"{100 * value:.1f}%"
    if metric.key in ("vehicles", "agents_standing"):
        return f"{value:.0f}"
    return f"{value:.2f}" if abs(value) < 100 else f"{value:,.0f}"


def rows(report: Report) -> list[list[str]]:
    """Table rows of formatted values: description, one column per group, naturalistic reference."""
    return [
        [
            m.label,
            *(format_value(v, m, losses_known=report.losses_known) for v in report.table.loc[m.key]),
            m.reference,
        ]
        for m in report.metrics
    ]


def write_report(
    report: Report, out: Path, title: str, *, picture: bool = True, extra: Sequence[str] = ()
) -> list[Path]:
    """realism.csv (raw numbers), realism.md (with the `extra` lines at its end) and (if `picture`:
    it takes ~2 s) realism.png in `out`, each complete or absent."""
    out = Path(out)
    ensure_writable_dir(out)
    groups = list(report.table.columns)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["metric", "description", *groups, "naturalistic"])
    for m in report.metrics:
        values = ["" if np.isnan(v) else f"{v:.6g}" for v in report.table.loc[m.key]]
        writer.writerow([m.key, m.label, *values, m.reference])
    header = ["metric", *groups, "naturalistic"]
    lines = [f"# Realism report: {title}", "", *(f"- {note}" for note in report.notes), ""]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows(report)]
    lines += ["", *extra] if extra else []
    paths = [out / "realism.csv", out / "realism.md"]
    atomic_write_text(paths[0], buffer.getvalue())
    atomic_write_text(paths[1], "\n".join(lines) + "\n")
    if not picture:
        return paths
    with atomic_path(out / "realism.png") as tmp:
        _figure(report, title).savefig(tmp, format="png", dpi=100)
    return [*paths, out / "realism.png"]


def _finite(values: np.ndarray | None) -> np.ndarray:
    return np.zeros(0) if values is None else values[np.isfinite(values)]


COLOURS = {"keepers": "tab:blue", "overtakers": "tab:orange", OTHER_GROUP: "tab:gray"}


def _figure(report: Report, title: str) -> Figure:
    """Lane use per group, and the distributions of time headway, |lateral accel| and speed."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 8), layout="constrained")
    FigureCanvasAgg(figure)
    (lanes, thw), (accel, speed) = figure.subplots(2, 2)
    groups = list(report.table.columns)
    colour = {g: COLOURS.get(g, f"C{k + 3}") for k, g in enumerate(groups)}
    lane_rows = [m.key for m in report.metrics if m.key.startswith("lane_") and m.share]
    bar = 0.8 / max(len(groups), 1)
    for k, g in enumerate(groups):
        shares = report.table.loc[lane_rows, g].fillna(0).to_numpy()
        lanes.bar(np.arange(len(lane_rows)) + k * bar, 100 * shares, bar, label=g, color=colour[g])
    lanes.set_xticks(
        np.arange(len(lane_rows)) + bar * (len(groups) - 1) / 2,
        [f"lane {r.split('_')[1]}" for r in lane_rows],
    )
    lanes.set_ylabel("share of time [%]")
    lanes.set_title("lane use (lane 0 = outermost)")
    accel_bins = np.linspace(0, 3, 31)
    for g in groups:
        for axes, key in ((thw, "thw"), (speed, "speed")):
            values = np.sort(_finite(report.samples[key].get(g)))
            if len(values):
                axes.step(
                    values,
                    np.arange(1, len(values) + 1) / len(values),
                    where="post",
                    label=g,
                    color=colour[g],
                )
        values = _finite(report.samples["accel"].get(g))
        if len(values):
            accel.hist(values, bins=accel_bins, density=True, histtype="step", label=g, color=colour[g])
    thw.set(xlim=(0, 4), xlabel="time headway [s]", ylabel="share of following time below")
    speed.set(xlabel="speed [m/s]", ylabel="share of time below")
    accel.set(xlabel="|lateral acceleration| [m/s^2]", ylabel="density")
    thw.axvline(THW_LIMIT, color="red", linestyle="--", linewidth=0.8)
    accel.axvline(LAT_ACCEL_LIMIT, color="red", linestyle="--", linewidth=0.8)
    accel.set_yscale("log")
    for axes in (lanes, thw, accel, speed):
        axes.grid(alpha=0.3)
        if axes.get_legend_handles_labels()[0]:
            axes.legend()
    figure.suptitle(title)
    return figure
