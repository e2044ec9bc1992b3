"""An FCD table as the realism measures read it (`prepare`): one row per record, sorted by vehicle and
time, with its lane's layout from the net (`read_lanes`), its group (`group_names`) and a lateral track.

Conventions (checked against netconvert and SUMO 1.28):
* Lateral positions are metres from the edge's outer border (the widths of the lanes with a
  lower index + half the own lane's width + posLat). SUMO numbers lanes from the outer side and
  posLat points towards higher indices in both keep-right and left-hand (`--lefthand`) nets, so
  a larger lateral position is always towards the overtaking lanes: left in keep-right nets,
  right in left-hand nets.
* A junction's internal lane counts as the lane the car came from (lane use, lane changes).
* The lateral track stays continuous across edges (`_track`).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from behaviors.errors import BehaveError

if TYPE_CHECKING:
    from collections.abc import Mapping

ASSUMED_LANE_WIDTH = 3.2  # SUMO's default; used for lanes the net does not name (or without a net)
DEFAULT_LENGTH = 5.0  # metres; SUMO's passenger car, and every behave vType
SKIP_S = 10.0  # each car's first seconds are left out: insertion is no behaviour
GROUP_BY = ("type", "id-prefix")
KEEPERS, OVERTAKERS, LORRIES = "keepers", "overtakers", "lorries"
GROUPS_OF_TYPE = {"behave_keeper": KEEPERS, "behave_overtaker": OVERTAKERS, "behave_lorry": LORRIES}
OTHER_GROUP = "sumo"
REQUIRED = ("id", "time", "lane", "pos", "speed")


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


def shifted(values: np.ndarray, seg: np.ndarray, k: int) -> np.ndarray:
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
    same_edge = shifted(edge, seg, 1) == edge
    across = pos_lat - np.roll(pos_lat, 1)
    mean_width = (width + np.roll(width, 1)) / 2
    across -= mean_width * np.round(across / mean_width)
    step = np.where(same_edge, lat - np.roll(lat, 1), across)
    step[np.isnan(shifted(lat, seg, 1))] = 0.0
    track = np.cumsum(step)
    starts = np.flatnonzero(np.diff(seg, prepend=0))
    return track - np.repeat(track[starts], np.diff(np.append(starts, len(seg))))
