"""Capacity bars: flow and mean speed against density, SUMO alone against learned fleets.

For each road and target density (vehicles per lane-km of its multi-lane edges) three fleets of
the same size, held by `--keep-count`: SUMO's own cars alone, 50% learned and 100% learned
(keepers and overtakers 1:1, the bundled `traffic` policy, shield on as users run it). Each run
is `behave populate` through the library for WARMUP_S + MEASURE_S simulated seconds; flow,
density and speed are Edie's over the whole road (every multi-lane edge) and the measured window
(behaviors/report/flow.py). Roads:

* `highway`: the bundled straight 3-lane highway, 3 km, 3.5 m lanes;
* `curved4`: a curved 4-lane motorway no policy trained on, 3 km, 3.75 m lanes, no bottleneck
  (netconvert from plain XML here);
* `motorway4`: a curved 4-lane motorway with a bottleneck: an on-ramp joining through an
  acceleration lane, then the right lane dropping (4 -> 3 lanes);
* `carriageway2`: a curved 2-lane carriageway of 3.2 m lanes (SUMO's default width).

Queue discharge: on the bundled highway a car stands in each lane (a SUMO car with a stop) until
RELEASE_S while the fleet queues behind it; then they move on and the discharge flow is the rate
at which the queued cars pass a point DETECTOR_M downstream (veh/h/lane).

    python benchmarks/flow.py [--seed 0] [--jobs 2] [--quick]

Prints the tables and writes docs/flow.md (atomically).
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import time
import xml.etree.ElementTree as ET
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import pandas as pd
from common import write_measured_doc

from behaviors.report.fcd_read import read_fcd
from behaviors.report.flow import ALL, RoadEdges, edie_cells, region, road_from_net
from behaviors.report.realism import THW_LIMIT
from behaviors.report.realism_measures import headways
from behaviors.report.realism_tracks import group_names, prepare, read_lanes
from behaviors.run.populate import populate
from behaviors.run.populate_config import DEFAULT_POLICY, PopulateConfig
from sumo_scenarios import get_scenario
from sumo_scenarios.build import write_xml
from sumo_scenarios.osm_like import Chain, run_netconvert, write_plain

DENSITIES = (7.0, 13.0, 20.0, 27.0)
FLEETS = {"SUMO alone": 0.0, "50% learned": 0.5, "100% learned": 1.0}
WARMUP_S = 120.0
MEASURE_S = 300.0
CELL_M = 300.0
WINDOW_S = 60.0
RELEASE_S = 120.0
"""s: the blocking cars stand until then (the queue forms behind them)."""
DISCHARGE_END_S = 300.0
BLOCK_EDGE, BLOCK_POS = "e6", 250.0  # on the highway: 2,050 m from its start
DETECTOR_M = 300.0
DISCHARGE_DENSITY = 27.0
STARTUP_PER_LANE = 3
"""The first queued cars per lane to pass are left out of the discharge rate (start-up loss)."""
AGENT_GROUPS = ("keepers", "overtakers")
"""realism_tracks.group_names' names for the learned cars."""
STAND_SPEED = 0.1
STAND_S = 30.0
PAST_BOTTLENECK = {"motorway4": "m4"}
"""The edge past a road's bottleneck: its flow is what the bottleneck lets through."""
QUEUE_DISCHARGE_REAL = (1800, 2000)
"""veh/h/lane: real queues discharge at this, some 5-15% below the capacity before breakdown (Hall
and Agyemang-Duah 1991; Cassidy and Bertini 1999)."""


# --- the roads -------------------------------------------------------------------------------


def build_motorway4(folder: Path) -> Path:
    """Curved 4 lanes of 3.75 m; an on-ramp joins through an acceleration lane (5 lanes for 250 m),
    then the right lane ends (4 -> 3)."""
    c = Chain()
    m0 = c.way("m0", 4, [(600.0, 0.0), (500.0, 900.0)], 3.75)
    m1 = c.way("m1", 4, [(400.0, 0.0)], 3.75)
    ramp = c.on_ramp(m1, "ramp")
    m2 = c.way("m2", 5, [(250.0, 0.0)], 3.75)
    m3 = c.way("m3", 4, [(500.0, -800.0), (300.0, 0.0)], 3.75)
    c.way("m4", 3, [(400.0, 700.0), (500.0, 0.0)], 3.75)
    connections = [
        *((m0.id, m1.id, i, i) for i in range(4)),
        (ramp.id, m2.id, 0, 0), *((m1.id, m2.id, i, i + 1) for i in range(4)),
        (m2.id, m3.id, 0, 0), *((m2.id, m3.id, i + 1, i) for i in range(4)),
        *((m3.id, "m4", i + 1, i) for i in range(3)),
    ]  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    write_plain(folder, "motorway4", c.ways, connections)
    return run_netconvert(folder, "motorway4", lefthand=False)


def build_curved4(folder: Path) -> Path:
    """Curved 4 lanes of 3.75 m, 3 km, no bottleneck: the capacity bar's motorway."""
    c = Chain()
    c.way("k0", 4, [(600.0, 0.0), (500.0, 900.0)], 3.75)
    c.way("k1", 4, [(500.0, -800.0), (700.0, 0.0)], 3.75)
    c.way("k2", 4, [(700.0, 0.0)], 3.75)
    folder.mkdir(parents=True, exist_ok=True)
    write_plain(folder, "curved4", c.ways, [])
    return run_netconvert(folder, "curved4", lefthand=False)


def build_carriageway2(folder: Path) -> Path:
    """Curved 2 lanes of SUMO's default 3.2 m, 3 km."""
    c = Chain()
    c.way("c0", 2, [(700.0, 0.0), (500.0, 800.0)], None)
    c.way("c1", 2, [(600.0, 0.0), (500.0, -700.0)], None)
    c.way("c2", 2, [(700.0, 0.0)], None)
    folder.mkdir(parents=True, exist_ok=True)
    write_plain(folder, "carriageway2", c.ways, [])
    return run_netconvert(folder, "carriageway2", lefthand=False)


def roads(folder: Path) -> dict[str, Path]:
    return {
        "highway": get_scenario("highway").net,
        "curved4": build_curved4(folder / "curved4"),
        "motorway4": build_motorway4(folder / "motorway4"),
        "carriageway2": build_carriageway2(folder / "carriageway2"),
    }


def main_road(net: Path) -> RoadEdges:
    """The multi-lane edges (where agents drive and where flow is measured)."""
    road = road_from_net(net)
    keep = {e for e, n in road.lanes.items() if n >= 2}
    return RoadEdges({e: road.length[e] for e in keep}, {e: road.lanes[e] for e in keep})


def lane_km(road: RoadEdges) -> float:
    return sum(road.length[e] * road.lanes[e] for e in road.length) / 1000.0


# --- one run ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Run:
    road: str
    net: Path
    fleet: str
    density: float
    seed: int
    policy: Path
    out: Path
    population: str | None = None  # a styled policy's --population
    warmup: float = WARMUP_S
    measure: float = MEASURE_S
    discharge: bool = False

    def counts(self, lane_km: float) -> tuple[int, int, int]:
        """(keepers, overtakers, SUMO cars) for the target density."""
        total = round(self.density * lane_km)
        learned = round(total * FLEETS[self.fleet])
        keepers = learned // 2
        return keepers, learned - keepers, total - learned


def blockers(path: Path, lanes: int) -> Path:
    """A SUMO car standing in each lane of BLOCK_EDGE until RELEASE_S."""
    root = ET.Element("routes")
    ET.SubElement(root, "vType", id="flow_blocker", vClass="passenger", length="5", sigma="0")
    ET.SubElement(root, "route", id="flow_block_route", edges=" ".join(f"e{i}" for i in range(6, 10)))
    for lane in range(lanes):
        vehicle = ET.SubElement(root, "vehicle", id=f"blocker_{lane}", type="flow_blocker",
                                route="flow_block_route", depart="0", departLane=str(lane),
                                departPos=str(BLOCK_POS), departSpeed="0")  # fmt: skip
        ET.SubElement(vehicle, "stop", lane=f"{BLOCK_EDGE}_{lane}", endPos=str(BLOCK_POS + 1),
                      until=str(RELEASE_S))  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    write_xml(root, path)
    return path


def run_one(run: Run) -> dict:
    """Populate, then measure its FCD (in a worker process: one SUMO each)."""
    road = main_road(run.net)
    keepers, overtakers, cars = run.counts(lane_km(road))
    folder = run.out / run.road / f"{run.fleet.split()[0].replace('%', '')}_{run.density:g}"
    fcd = folder / "fcd.parquet"
    config = PopulateConfig(
        net=run.net, keepers=keepers, overtakers=overtakers, background=cars, policy=run.policy,
        population=run.population, seed=run.seed, fcd=fcd,
        duration=DISCHARGE_END_S if run.discharge else run.warmup + run.measure,
        keep_count=True, shield=True,
        routes=blockers(folder / "blockers.rou.xml", road.lanes[BLOCK_EDGE]) if run.discharge else None,
    )  # fmt: skip
    start = time.perf_counter()
    summary = populate(config)
    wall = time.perf_counter() - start
    df = read_fcd(fcd)
    row = {"road": run.road, "fleet": run.fleet, "target_density": run.density, "keepers": keepers,
           "overtakers": overtakers, "sumo_cars": cars, "collisions": summary.collisions,
           "off_tracks": summary.off_tracks, "wall_s": wall}  # fmt: skip
    if run.discharge:
        row.update(discharge(df, road))
        row["agents_standing_30s"] = summary.long_standstills
        return row
    groups = group_names(df["id"], df["type"], "type")
    cells = edie_cells(df, road, groups, cell_m=CELL_M, window_s=WINDOW_S, start_s=run.warmup,
                       end_s=run.warmup + run.measure)  # fmt: skip
    whole = region(cells)
    row.update(density=whole.loc[ALL, "density"], flow=whole.loc[ALL, "flow"], speed=whole.loc[ALL, "speed"])
    if run.road in PAST_BOTTLENECK:
        past = region(cells[cells["edge"] == PAST_BOTTLENECK[run.road]])
        row.update(past_flow=past.loc[ALL, "flow"], past_speed=past.loc[ALL, "speed"])
    row["agents_standing_30s"] = agents_standing(df, groups, run.warmup)
    row.update(agents_headways(df, run.net))
    return row


def agents_headways(df: pd.DataFrame, net: Path) -> dict:
    """The learned agents' (keepers and overtakers pooled) median time headway and share of
    following time below THW_LIMIT, by the realism report's rules (the headway bar)."""
    follow = headways(prepare(df, read_lanes(net)))
    agents = follow.loc[follow["group"].isin(AGENT_GROUPS), "thw"]
    if agents.empty:
        return {"agents_thw": math.nan, "agents_thw_short": math.nan}
    return {"agents_thw": float(agents.median()), "agents_thw_short": float((agents < THW_LIMIT).mean())}


def agents_standing(df: pd.DataFrame, groups: pd.Series, after_s: float) -> int:
    """Agents that stood (speed < STAND_SPEED) STAND_S or more at a time after `after_s`."""
    agents = df[groups.isin(AGENT_GROUPS).to_numpy() & (df["time"] >= after_s).to_numpy()]
    if agents.empty:
        return 0
    agents = agents.sort_values(["id", "time"])
    step = float(np.median(np.diff(np.unique(df["time"].to_numpy(float)))))
    standing = (agents["speed"] < STAND_SPEED).to_numpy()
    ids = agents["id"].to_numpy()
    longest: dict[str, float] = {}
    run, last = 0.0, None
    for vid, still in zip(ids, standing, strict=True):
        run = (run + step if still else 0.0) if vid == last else (step if still else 0.0)
        last = vid
        longest[vid] = max(longest.get(vid, 0.0), run)
    return sum(v >= STAND_S for v in longest.values())


def discharge(df: pd.DataFrame, road: RoadEdges) -> dict:
    """The rate at which cars queued behind the blockers pass DETECTOR_M beyond them."""
    offset = {f"e{i}": sum(road.length[f"e{j}"] for j in range(i)) for i in range(10)}
    normal = df[~df["lane"].astype(str).str.startswith(":")]
    edge = normal["lane"].astype(str).str.rpartition("_")[0]
    x = edge.map(offset).astype(float) + normal["pos"].to_numpy(float)
    block_x = offset[BLOCK_EDGE] + BLOCK_POS
    frame = pd.DataFrame({"id": normal["id"], "time": normal["time"], "x": x, "speed": normal["speed"]})
    frame = frame[~frame["id"].astype(str).str.startswith("blocker_")]
    at_release = frame[(frame["time"] - RELEASE_S).abs() < 1e-6]
    queued = set(at_release.loc[(at_release["x"] < block_x) & (at_release["speed"] < 1.0), "id"])
    detector = block_x + DETECTOR_M
    passed = frame[frame["id"].isin(queued) & (frame["x"] >= detector)].groupby("id")["time"].min()
    times = np.sort(passed.to_numpy(float))
    lanes = road.lanes[BLOCK_EDGE]
    used = times[STARTUP_PER_LANE * lanes :]
    rate = (len(used) - 1) / (used[-1] - used[0]) * 3600 / lanes if len(used) >= 10 else math.nan
    return {"queued": len(queued), "discharged": len(times), "discharge_flow": rate}


# --- tables ----------------------------------------------------------------------------------


def fmt(value: float, digits: int = 0) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:,.{digits}f}"


def sumo_alone(rows: pd.DataFrame, column: str) -> float:
    """`column` of the SUMO-alone run among `rows` (one setting's fleets), the ratios' base; NaN if none."""
    alone = rows.loc[rows["fleet"] == "SUMO alone", column]
    return float(alone.iloc[0]) if len(alone) else math.nan


def flow_table(rows: pd.DataFrame) -> list[str]:
    header = ["road", "target veh/lane-km", "fleet", "cars (keepers+overtakers+SUMO)", "density",
              "flow veh/h/lane", "speed m/s", "flow / SUMO alone", "agents stood >= 30 s",
              "collisions + off-tracks", "agents' median headway s", f"agents' following < {THW_LIMIT:g} s",
              "bar"]  # fmt: skip
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for (road, target), part in rows.groupby(["road", "target_density"], sort=False):
        base = sumo_alone(part, "flow")
        for _, r in part.iterrows():
            ratio = r["flow"] / base if base > 0 else math.nan
            lines.append("| " + " | ".join([
                road, f"{target:g}", r["fleet"], f"{r['keepers']}+{r['overtakers']}+{r['sumo_cars']}",
                fmt(r["density"], 1), fmt(r["flow"]), fmt(r["speed"], 1),
                fmt(ratio, 2) if r["fleet"] != "SUMO alone" else "1",
                str(int(r["agents_standing_30s"])) if r["fleet"] != "SUMO alone" else "-",
                str(int(r["collisions"] + r["off_tracks"])), fmt(r["agents_thw"], 2),
                fmt(100 * r["agents_thw_short"], 1) + "%" if np.isfinite(r["agents_thw_short"]) else "-",
                bar_mark(r, ratio),
            ]) + " |")  # fmt: skip
    return lines


def bar_mark(r: pd.Series, ratio: float) -> str:
    """The capacity bars for a learned fleet's row (bottleneck-free roads: standing)."""
    if r["fleet"] == "SUMO alone":
        return "-"
    marks = []
    if r["target_density"] == 20:
        marks.append(f"flow >= 90% of SUMO: {'yes' if ratio >= 0.9 else 'no'}")
        within = 1.2 <= r["agents_thw"] <= 2.2 and r["agents_thw_short"] < 0.15
        marks.append(f"headway 1.2-2.2 s, < 15% below 1 s: {'yes' if within else 'no'}")
    if r["target_density"] == 27:
        marks.append(f"flow >= 1,800: {'yes' if r['flow'] >= 1800 else 'no'}")
    if r["road"] != "motorway4":
        marks.append(f"nobody stood 30 s: {'yes' if r['agents_standing_30s'] == 0 else 'no'}")
    return "; ".join(marks)


def bottleneck_table(rows: pd.DataFrame) -> list[str]:
    """Per bottleneck road, density and fleet: the flow on the edge past the bottleneck."""
    header = ["road", "target veh/lane-km", "fleet", "edge past the bottleneck", "flow there veh/h/lane",
              "speed there m/s", "/ SUMO alone"]  # fmt: skip
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    bottlenecks = rows[rows["road"].isin(PAST_BOTTLENECK)]
    for (road, target), part in bottlenecks.groupby(["road", "target_density"], sort=False):
        base = sumo_alone(part, "past_flow")
        for _, r in part.iterrows():
            lines.append("| " + " | ".join([
                road, f"{target:g}", r["fleet"], f"`{PAST_BOTTLENECK[road]}`", fmt(r["past_flow"]),
                fmt(r["past_speed"], 1), fmt(r["past_flow"] / base, 2) if base > 0 else "-",
            ]) + " |")  # fmt: skip
    return lines


def discharge_table(rows: pd.DataFrame) -> list[str]:
    header = ["fleet", "cars (keepers+overtakers+SUMO)", "queued at release", "passed the detector",
              "discharge flow veh/h/lane", "/ SUMO alone", "bar: >= 1,700"]  # fmt: skip
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    base = sumo_alone(rows, "discharge_flow")
    for _, r in rows.iterrows():
        rate = r["discharge_flow"]
        lines.append("| " + " | ".join([
            r["fleet"], f"{r['keepers']}+{r['overtakers']}+{r['sumo_cars']}", str(int(r["queued"])),
            str(int(r["discharged"])), fmt(rate), fmt(rate / base, 2) if base > 0 else "-",
            ("yes" if rate >= 1700 else "no") if np.isfinite(rate) else "-",
        ]) + " |")  # fmt: skip
    return lines


def commit() -> str:
    done = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return done.stdout.strip() or "unknown"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, default=DEFAULT_POLICY)
    parser.add_argument("--population", default=None, help="a styled policy's --population")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2, help="populate runs at a time (one SUMO each)")
    parser.add_argument("--out", type=Path, default=Path("runs/flow"))
    parser.add_argument("--doc", type=Path, default=Path("docs/flow.md"))
    parser.add_argument(
        "--quick", action="store_true", help="the highway at one density, 60 s (a smoke test)"
    )
    args = parser.parse_args()
    start = time.perf_counter()
    nets = roads(args.out / "nets")
    runs = [Run(road, net, fleet, density, args.seed, args.policy, args.out, args.population)
            for road, net in nets.items() for density in DENSITIES for fleet in FLEETS]  # fmt: skip
    queue_runs = [Run("highway", nets["highway"], fleet, DISCHARGE_DENSITY, args.seed, args.policy,
                      args.out / "discharge", args.population, discharge=True)
                  for fleet in FLEETS]  # fmt: skip
    if args.quick:
        runs = [
            replace(r, warmup=20.0, measure=60.0) for r in runs if r.road == "highway" and r.density == 13
        ]
        queue_runs = []
    work = queue_runs + sorted(runs, key=lambda r: -r.density)  # the longest first
    with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn"), max_tasks_per_child=1) as pool:
        results = dict(zip(work, pool.map(run_one, work), strict=True))
    wall = time.perf_counter() - start
    queue_rows = pd.DataFrame([results[r] for r in queue_runs])
    flow_rows = pd.DataFrame([results[r] for r in runs])
    args.out.mkdir(parents=True, exist_ok=True)
    flow_rows.to_csv(args.out / "flow_runs.csv", index=False)
    if len(queue_rows):
        queue_rows.to_csv(args.out / "discharge_runs.csv", index=False)
    text = document(runs, flow_rows, queue_rows, args, wall)
    print(text)
    if not args.quick:
        write_measured_doc(args.doc, text)


def document(
    runs: list[Run], flow_rows: pd.DataFrame, queue_rows: pd.DataFrame, args: argparse.Namespace, wall: float
) -> str:
    lines = [
        "# Flow against density: SUMO alone and learned fleets",
        "",
        f"Measured on commit {commit()} with `python benchmarks/flow.py --seed {args.seed} --jobs {args.jobs}"
        f"{'' if args.policy == DEFAULT_POLICY else f' --policy {args.policy} --doc {args.doc}'}"
        f"{f' --population {args.population}' if args.population else ''}` "
        f"(`make flow` runs the default policy), policy `{args.policy.name}`"
        f"{f' (population {args.population})' if args.population else ''}, shield on, `--keep-count`, "
        "step 0.2 s; "
        f"{os.cpu_count()} cores, {wall / 60:.1f} min wall time for all "
        f"{len(flow_rows) + len(queue_rows)} runs.",
        "",
        f"Each run: {runs[0].warmup:g} s warm-up, then {runs[0].measure:g} s measured. Density, flow "
        f"and speed are Edie's definitions over every multi-lane edge and the measured window "
        f"({CELL_M:g} m x "
        f"{WINDOW_S:g} s cells, `behaviors/report/flow.py`); the vehicle count is the target density x the "
        "road's lane-km (multi-lane edges), so the measured density differs where cars bunch up "
        "or fail to get in. Fleets: SUMO's cars alone (vType `behave_background`, Krauss + SL2015), "
        "50% learned and 100% learned (keepers:overtakers 1:1). `agents stood >= 30 s`: agents "
        "that stood (< 0.1 m/s) 30 s or more at a time in the measured window; `motorway4` has "
        "a lane drop (a bottleneck), so its standing agents are not held against the bar, and its "
        "flow is held against SUMO's through the same bottleneck. Bars: "
        "at 20 veh/lane-km a learned fleet's flow >= 90% of SUMO alone; at 27 >= "
        "1,800 veh/h/lane; no agent standing 30 s where no bottleneck stops traffic.",
        "",
        "Roads: `highway` the bundled straight 3-lane, 3 km, 3.5 m lanes; `curved4` a curved 4-lane "
        "motorway (3.75 m, 3 km) no policy trained on, without a bottleneck; `motorway4` a curved "
        "4-lane motorway (3.75 m) no policy trained on, an on-ramp with an acceleration lane, then "
        "a lane drop 4 -> 3 (netconvert from plain XML in `benchmarks/flow.py`; the on-ramp carries "
        "no demand of its own: populate routes cars over multi-lane edges only); `carriageway2` a "
        "curved 2-lane carriageway of 3.2 m lanes, 3 km.",
        "",
        *flow_table(flow_rows),
        "",
    ]
    if "past_flow" in flow_rows:
        low, high = QUEUE_DISCHARGE_REAL
        lines += [
            "### Through the bottleneck",
            "",
            "What a bottleneck lets through is its capacity for a study: Edie's flow on the edge past "
            "it, over the same window. Where the road upstream queues, this is the queue's discharge "
            f"through the lane drop; real queues discharge at about {low:,}-{high:,} veh/h/lane, "
            "5-15% below the capacity before breakdown (Hall and Agyemang-Duah 1991; Cassidy and "
            "Bertini 1999).",
            "",
            *bottleneck_table(flow_rows),
            "",
        ]
    if len(queue_rows):
        lines += [
            "### Queue discharge",
            "",
            f"The bundled highway at {DISCHARGE_DENSITY:g} veh/lane-km of cars (`--keep-count`): a SUMO "
            f"car stands in each lane 2,050 m from the start until {RELEASE_S:g} s; the fleet "
            f"queues behind. Discharge flow: the queued cars (standing behind the blockers at "
            f"{RELEASE_S:g} s) passing a point {DETECTOR_M:g} m downstream, the first "
            f"{STARTUP_PER_LANE} per lane left out (start-up), (n - 1) / (last - first passage) per "
            f"lane; the run ends at {DISCHARGE_END_S:g} s. Bar: >= 1,700 veh/h/lane.",
            "",
            *discharge_table(queue_rows),
            "",
        ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
