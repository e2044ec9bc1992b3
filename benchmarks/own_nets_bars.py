"""Bars on motorway nets nobody here drew, with the shipped policy and the nets' own demand.

Nets: A10KW (the SUMO wheel's OSM net near Berlin with its `osm.passenger_mw.rou.xml` demand) and
the OSM-like nets of `sumo_scenarios.osm_like` (netconvert from plain XML: a 3-lane motorway whose
right lane drops into an exit, a 2-lane carriageway of 3.2 m lanes, a 3 -> 2 lane drop, and a
left-hand copy of the motorway), each with flows through, off at the exit and on from the ramp.
Each net is run as a user's scenario: `behave populate --sumocfg NET.sumocfg --share 0.2
--no-shield`, so a fifth of its passenger cars, on the same routes as SUMO's, are driven by the
policy. Measured per run from the summary, the per-agent table and the FCD: losses per
agent-hour, agents and SUMO's cars standing still for 30 s or more, the share of vehicles that
departed in the run's first half and reached the end of their route, handovers to SUMO. A
second table holds benchmarks/traffic_bars.py's driving bars (`behave report` on each run's FCD),
so that the left-hand copy is compared with its keep-right original: there passes belong on the right.
Prints the tables and writes them to docs/own_nets.md with the commit measured.

    python benchmarks/own_nets_bars.py --seeds 0,1 --duration 300
"""

from __future__ import annotations

import argparse
import subprocess
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from dataclasses import fields as dataclass_fields
from pathlib import Path

import numpy as np
import pandas as pd
from common import write_measured_doc
from traffic_bars import DRIVING_BARS, bars_table

from behaviors.report.agents_table import LONG_STANDSTILL_S, agents_path
from behaviors.report.fcd_read import read_fcd
from behaviors.report.realism import Report, measure, read_agents
from behaviors.report.realism_tracks import read_lanes
from behaviors.run.populate import populate
from behaviors.run.populate_config import DEFAULT_POLICY, config_from
from behaviors.sumo.sim import STANDSTILL_SPEED
from behaviors.sumo.sumo_home import sumo_home
from sumo_scenarios.build import write_xml
from sumo_scenarios.osm_like import OSM_LIKE_NAMES, build_osm_like

SHARE = 0.2
ARRIVAL_MARGIN = 0.05
"""Agents reach their route ends "as often" as SUMO's cars if their share is at most this much lower."""


def a10kw_sumocfg(folder: Path) -> Path:
    """A sumocfg for the wheel's A10KW net with its motorway passenger demand (absolute paths)."""
    a10 = sumo_home() / "tools" / "game" / "A10KW"
    root = ET.Element("configuration")
    inputs = ET.SubElement(root, "input")
    ET.SubElement(inputs, "net-file", value=str(a10 / "osm.net.xml"))
    ET.SubElement(inputs, "route-files", value=str(a10 / "osm.passenger_mw.rou.xml"))
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "A10KW.sumocfg"
    write_xml(root, path)
    return path


def scenarios(folder: Path, names: list[str]) -> dict[str, Path]:
    """Net name -> sumocfg for the names given, the OSM-like nets built afresh into `folder`."""
    return {
        name: a10kw_sumocfg(folder / name) if name == "A10KW" else build_osm_like(name, folder / name).sumocfg
        for name in names
    }


@dataclass(frozen=True)
class Facts:
    """What one run says about the bars."""

    agents: int
    agent_hours: float
    losses: int  # collisions + off-tracks
    no_progress: int
    agents_standing: int  # agents that stood still LONG_STANDSTILL_S or more at a time
    agents_standing_alone: int  # ... of them where no SUMO vehicle stood that long on that lane then
    cars: int  # SUMO's vehicles (never agents)
    cars_standing: int
    agents_cohort: tuple[int, int]  # (departed in the run's first half, of them reached their route end)
    cars_cohort: tuple[int, int]
    handovers: int

    @property
    def agents_arrived(self) -> float:
        return share(self.agents_cohort)

    @property
    def cars_arrived(self) -> float:
        return share(self.cars_cohort)


def share(cohort: tuple[int, int]) -> float:
    return cohort[1] / cohort[0] if cohort[0] else float("nan")


def pooled(runs: list[Facts]) -> Facts:
    """All runs together: counts and agent-hours added, shares over the pooled cohorts."""

    def cohort(name: str) -> tuple[int, int]:
        return sum(getattr(f, name)[0] for f in runs), sum(getattr(f, name)[1] for f in runs)

    names = [f.name for f in dataclass_fields(Facts) if not f.name.endswith("_cohort")]
    counts = {name: sum(getattr(f, name) for f in runs) for name in names}
    return Facts(**counts, agents_cohort=cohort("agents_cohort"), cars_cohort=cohort("cars_cohort"))


def long_standstills(fcd: pd.DataFrame, step: float) -> pd.DataFrame:
    """Each time a vehicle stood still (speed below STANDSTILL_SPEED) LONG_STANDSTILL_S or more at a
    stretch: its id, the lane it stood on first, and when the stretch began and ended."""
    rows = fcd.sort_values(["id", "time"])
    standing = (rows["speed"] < STANDSTILL_SPEED).to_numpy()
    ids = rows["id"].to_numpy()
    stretch = np.cumsum(np.r_[True, (standing[1:] != standing[:-1]) | (ids[1:] != ids[:-1])])
    still = rows[standing].assign(stretch=stretch[standing])
    runs = still.groupby("stretch").agg(id=("id", "first"), lane=("lane", "first"), start=("time", "min"),
                                        end=("time", "max"))  # fmt: skip
    return runs[runs["end"] - runs["start"] + step >= LONG_STANDSTILL_S].reset_index(drop=True)


def alone(agent_runs: pd.DataFrame, car_runs: pd.DataFrame) -> set[str]:
    """Agents with a long standstill on a lane where no SUMO vehicle stood long at an overlapping time
    (an agent queueing with SUMO's cars at a ramp's end is not stuck where they drive)."""
    out = set()
    for run in agent_runs.itertuples():
        queue = car_runs[(car_runs["lane"] == run.lane) & (car_runs["start"] <= run.end)
                         & (car_runs["end"] >= run.start)]  # fmt: skip
        if queue.empty:
            out.add(run.id)
    return out


def arrivals(depart: pd.Series, arrived: pd.Series, by: float) -> tuple[int, int]:
    """How many vehicles departed by `by`, and how many of them reached the end of their route."""
    cohort = depart <= by
    return int(cohort.sum()), int(arrived[cohort].sum())


def facts_of(fcd: pd.DataFrame, agents: pd.DataFrame, summary, step: float, duration: float) -> Facts:
    is_agent = fcd["id"].isin(agents["id"])
    cars = fcd[~is_agent]
    agent_runs, car_runs = long_standstills(fcd[is_agent], step), long_standstills(cars, step)
    span = cars.groupby("id")["time"].agg(["min", "max"])
    last = float(fcd["time"].max())
    hours = summary.agent_steps * step / 3600
    return Facts(
        agents=len(agents),
        agent_hours=hours,
        losses=summary.collisions + summary.off_tracks,
        no_progress=int((agents["end_reason"] == "no_progress").sum()),
        agents_standing=int((agents["longest_standstill_s"] >= LONG_STANDSTILL_S).sum()),
        agents_standing_alone=len(alone(agent_runs, car_runs)),
        cars=len(span),
        cars_standing=car_runs["id"].nunique(),
        agents_cohort=arrivals(agents["depart_s"], agents["end_reason"] == "arrived", duration / 2),
        cars_cohort=arrivals(span["min"], span["max"] < last, duration / 2),
        handovers=summary.handovers,
    )


def run(sumocfg: Path, seed: int, duration: float, fcd: Path, policy: Path) -> tuple[Facts, Report]:
    """One run's facts and its realism report (groups keepers, overtakers, sumo)."""
    config = config_from(
        sumocfg, share=SHARE, seed=seed, duration=duration, fcd=fcd, shield=False, policy=policy
    )
    summary = populate(config)
    agents = read_agents(agents_path(fcd))
    assert agents is not None  # populate writes it beside the FCD
    trace = read_fcd(fcd)
    report = measure(trace, read_lanes(config.net), agents=agents)
    return facts_of(trace, agents, summary, config.step_length, duration), report


@dataclass(frozen=True)
class Row:
    name: str
    bar: str
    cell: Callable[[Facts], str]
    ok: Callable[[Facts], bool] | None = None  # None: a reference row, no bar


def pct(x: float) -> str:
    return "-" if np.isnan(x) else f"{100 * x:.0f}%"


ROWS = (
    Row("agents (agent-hours)", "", lambda f: f"{f.agents} ({f.agent_hours:.2f} h)"),
    Row("collisions + off-tracks per agent-hour", "<= 1",
        lambda f: f"{f.losses / max(f.agent_hours, 1e-9):.2f} ({f.losses})",
        lambda f: f.losses <= f.agent_hours),
    Row("agents standing still >= 30 s where SUMO's vehicles drive (all agents standing so long)", "0",
        lambda f: f"{f.agents_standing_alone} ({f.agents_standing})", lambda f: f.agents_standing_alone == 0),
    Row("SUMO's vehicles standing still >= 30 s (reference)", "", lambda f: f"{f.cars_standing} of {f.cars}"),
    Row("agents reaching their route end (departed in the first half)", "as often as SUMO's (-5 pts)",
        lambda f: f"{pct(f.agents_arrived)} of {f.agents_cohort[0]}",
        lambda f: f.agents_arrived >= f.cars_arrived - ARRIVAL_MARGIN),
    Row("SUMO's vehicles reaching theirs (reference)", "",
        lambda f: f"{pct(f.cars_arrived)} of {f.cars_cohort[0]}"),
    Row("agents taken out by SUMO (no progress)", "", lambda f: str(f.no_progress)),
    Row("handovers to SUMO (per agent)", "",
        lambda f: f"{f.handovers} ({f.handovers / max(f.agents, 1):.2f})"),
)  # fmt: skip


def table(columns: dict[str, Facts]) -> str:
    """One row per bar, a column per run and one for all runs pooled, on which the bar is judged."""
    everything = pooled(list(columns.values()))
    header = ["", "bar", *columns, "all runs", "met"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in ROWS:
        met = "" if row.ok is None else ("yes" if row.ok(everything) else "no")
        cells = [row.name, row.bar, *(row.cell(f) for f in (*columns.values(), everything)), met]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def commit() -> str:
    """The commit measured, marked when behave's code differs from it in the working tree."""
    head = subprocess.run(["git", "log", "-1", "--format=%h"], capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "behaviors"], capture_output=True, text=True
    ).stdout
    return head + (" + uncommitted changes under behaviors/" if dirty.strip() else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, default=DEFAULT_POLICY)
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--out", type=Path, default=Path("runs/own_nets"))
    parser.add_argument("--doc", type=Path, default=Path("docs/own_nets.md"))
    parser.add_argument("--nets", default=",".join(("A10KW", *OSM_LIKE_NAMES)), help="comma-separated subset")
    args = parser.parse_args()
    measured = commit()
    columns: dict[str, Facts] = {}
    driving: dict[str, tuple[pd.DataFrame, dict]] = {}
    for name, sumocfg in scenarios(args.out / "nets", args.nets.split(",")).items():
        for seed in (int(s) for s in args.seeds.split(",")):
            facts, report = run(
                sumocfg, seed, args.duration, args.out / name / f"s{seed}" / "fcd.parquet", args.policy
            )
            columns[f"{name} s{seed}"] = facts
            driving[f"{name} s{seed}"] = (report.table, {"like_for_like": report.like_for_like})
            print(f"{name} seed {seed}: {facts}", flush=True)
    text = table(columns)
    driving_text = bars_table(DRIVING_BARS, driving)
    print(text, driving_text, sep="\n\n")
    command = f"python benchmarks/own_nets_bars.py --seeds {args.seeds} --duration {args.duration:g}"
    if args.nets != parser.get_default("nets"):
        command += f" --nets {args.nets}"
    if args.policy != DEFAULT_POLICY:
        command += f" --policy {args.policy}"
    doc = (
        "# The shipped policy on nets nobody here drew\n\n"
        f"`{command}` (`make own-nets`), measured at commit {measured}.\n\n"
        f"Each net runs as a user's scenario with its own demand: `behave populate --sumocfg NET.sumocfg "
        f"--share {SHARE:g} --no-shield --duration {args.duration:g} --seed S` with the bundled traffic "
        "policy, so a fifth of the passenger cars, on the routes the demand gives them (through, off at "
        "the exit, on from the ramp), are agents. A10KW: the SUMO wheel's `tools/game/A10KW/osm.net.xml` "
        "with `osm.passenger_mw.rou.xml`. The others are built by `sumo_scenarios/osm_like.py` with "
        "netconvert from plain XML (curves of 600-1000 m drawn with a point every 5 m): `motorway3` 3 "
        "lanes of 3.5 m whose right lane drops into the exit, the ramp adding it back; `carriageway2` 2 "
        "lanes of SUMO's default 3.2 m with a deceleration lane to the exit and an acceleration lane from "
        "the ramp; `lanedrop` 3 lanes becoming 2, then an exit and a ramp, all connections netconvert's "
        "guesses; `motorway3_lefthand` `motorway3` mirrored and built with `--lefthand`. Flows: 1,400 "
        "cars/h through, 300 off at the exit, 300 on from the ramp, 160 lorries/h.\n\n"
        "Standing still: SUMO speed below 0.1 m/s for 30 s or more at a stretch (agents: the per-agent "
        "table; SUMO's vehicles: their FCD rows). Reaching the route end: of the vehicles that departed "
        "in the first half of the run, the share that arrived before it ended. `met`: the bar judged on all "
        "runs pooled (losses over all agent-hours, shares over all cohorts).\n\n" + text + "\n\n"
        "How the agents drive there: the driving bars, measured by `behave report` on the same "
        "runs' FCD (each car's first 10 s left out; keepers and overtakers as the share drew them). On "
        "the left-hand net the overtaking side is the right, and the rightmost-lane row reads the "
        "outer (slow) lane, lane 0. `met`: every run meets the bar.\n\n" + driving_text + "\n"
    )
    write_measured_doc(args.doc, doc)


if __name__ == "__main__":
    main()
