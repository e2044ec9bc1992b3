"""Does each agent drive as its style asks? (`make styles`, writes docs/styles.md)

The styled driver's agents each draw a style (desired speed, time headway, eagerness to pass, place
in the lane; behaviors/traffic/styles.py), which the agents table records. On the bundled highway, every
agent styled, this runs `behave populate` (seeds 0 and 1 by default, the shield on as users run it),
measures each agent from the FCD and sets what it did against what it asked:

- its median time headway while following (own speed > 5 m/s, leader within 250 m in its lane)
  against its style's headway;
- its mean speed as a share of the limit against its style's speed factor;
- its lane changes per km against its eagerness;
- its mean |offset from the lane centre| outside lane changes against its style's place.

Each with Spearman's rank correlation over the agents and the medians per third of the asked value.

    python benchmarks/style_response.py [--policy PATH] [--seeds 0,1] [--duration 600]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from common import write_measured_doc
from highway_anchor import cpu_model

from behaviors.learn.policy import PRETRAINED
from behaviors.report.agents_table import agents_path
from behaviors.report.fcd_read import read_fcd
from behaviors.report.realism_measures import FOLLOW_MIN_SPEED, LEADER_RANGE
from behaviors.report.realism_tracks import REQUIRED, prepare, read_lanes
from behaviors.road.geometry_build import load_geometry
from behaviors.run.populate import populate
from behaviors.run.populate_config import PopulateConfig
from sumo_scenarios import get_scenario

PAIRS = (
    ("style_time_headway_s", "median_thw", "time headway, s"),
    ("style_speed_factor", "speed_share", "speed / limit"),
    ("style_eagerness", "lane_changes_per_km", "eagerness -> lane changes per km"),
    ("style_lane_bias_m", "mean_offset", "lane place, m (|offset| against |bias|)"),
)


def per_agent(fcd: Path, net: Path, limit: float) -> pd.DataFrame:
    """What each agent did, by vehicle id."""
    lanes = read_lanes(net)
    df = read_fcd(fcd)
    tr = prepare(df, lanes)
    ids = pd.factorize(df.dropna(subset=list(REQUIRED))["id"])[1].astype(str)  # prepare's vehicle codes
    time_, lane, pos = tr["time"].to_numpy(), tr["lane"].to_numpy(), tr["pos"].to_numpy()
    speed, length = tr["speed"].to_numpy(), tr["length"].to_numpy()
    order = np.lexsort((pos, lane, time_))
    own, lead = order[:-1], order[1:]
    paired = (time_[lead] == time_[own]) & (lane[lead] == lane[own])
    own, lead = own[paired], lead[paired]
    gap = pos[lead] - length[lead] - pos[own]
    keep = tr["settled"].to_numpy()[own] & (speed[own] > FOLLOW_MIN_SPEED) & (gap <= LEADER_RANGE)
    thw = pd.Series(gap[keep] / speed[own][keep], index=tr["vehicle"].to_numpy()[own][keep])
    settled = tr[tr["settled"]]
    km = (settled["speed"] * settled["dt"].fillna(0)).groupby(settled["vehicle"]).sum() / 1000
    # a lane change: the lane rank changes between two records of one car on one edge (realism_measures.py's
    # definition; the highway's one edge asks for none)
    same = (tr["seg"].shift() == tr["seg"]) & (tr["road_edge"].shift() == tr["road_edge"])
    changed = same & (tr["road_rank"].shift() != tr["road_rank"]) & tr["settled"]
    counted = tr[changed].groupby("vehicle").size()
    out = pd.DataFrame({
        "median_thw": thw.groupby(level=0).median(),
        "speed_share": settled.groupby("vehicle")["speed"].mean() / limit,
        "lane_changes_per_km": counted.reindex(km.index).fillna(0) / km.where(km > 0.5),
        "mean_offset": settled.assign(off=settled["pos_lat"].abs()).groupby("vehicle")["off"].mean(),
    })  # fmt: skip
    out.index = ids[out.index.to_numpy()]
    return out


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 5:
        return float("nan")
    ra, rb = pd.Series(a[ok]).rank().to_numpy(), pd.Series(b[ok]).rank().to_numpy()
    return float(np.corrcoef(ra, rb)[0, 1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--policy", type=Path, default=PRETRAINED / "styled.pt")
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--agents", type=int, default=40, help="keepers and as many overtakers")
    parser.add_argument("--background", type=int, default=40)
    parser.add_argument("--out", type=Path, default=Path("runs/styles"))
    parser.add_argument("--doc", type=Path, default=Path("docs/styles.md"))
    args = parser.parse_args(argv)
    highway = get_scenario("highway")
    limit = float(load_geometry(highway.net).lane_speed.max())
    tables = []
    start = time.perf_counter()
    for seed in (int(s) for s in args.seeds.split(",")):
        fcd = args.out / f"s{seed}" / "fcd.xml"
        populate(PopulateConfig(policy=args.policy, keepers=args.agents, overtakers=args.agents,
                                background=args.background, duration=args.duration, seed=seed, fcd=fcd,
                                keep_count=True))  # fmt: skip
        agents = pd.read_csv(agents_path(fcd)).set_index("id")
        did = per_agent(fcd, highway.net, limit)
        tables.append(agents.join(did, how="inner").assign(seed=seed))
    both = pd.concat(tables)
    wall = time.perf_counter() - start
    lines = [
        "# Do agents drive as their style asks?",
        "",
        f"Written by `python benchmarks/style_response.py --policy {args.policy} --seeds {args.seeds} "
        f"--duration {args.duration:g}` on {time.strftime('%Y-%m-%d')}, commit {git_commit()}, "
        f"{cpu_model()}, {wall / 60:.1f} min wall. The bundled highway, {args.agents} keepers and "
        f"{args.agents} overtakers kept in count among {args.background} SUMO cars; {len(both)} agent runs.",
        "",
        "| asked | Spearman's rho | done, by third of the asked value (low / middle / high) |",
        "|---|---|---|",
    ]
    for asked, done, label in PAIRS:
        a = both[asked].to_numpy(float)
        d = both[done].to_numpy(float)
        if asked == "style_lane_bias_m":
            a = np.abs(a)
        rho = spearman(a, d)
        thirds = pd.qcut(pd.Series(a).rank(method="first"), 3, labels=False).to_numpy()
        medians = [np.nanmedian(d[thirds == k]) for k in range(3)]
        lines.append(f"| {label} | {rho:+.2f} | {' / '.join(f'{m:.2f}' for m in medians)} |")
    write_measured_doc(args.doc, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


def git_commit() -> str:
    out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False)
    return out.stdout.strip() or "unknown"


if __name__ == "__main__":
    sys.exit(main())
