"""A bar on a user's own roads (`make ramp`, writes docs/ramp.md).

Builds, with netconvert from plain XML as a SUMO user would in an afternoon, two scenarios:

* `ramp`: a 3-lane motorway (120 km/h) with an on-ramp (a 250 m acceleration lane) and, 450 m
  after it, a work zone: the right lane closed (80 km/h, 2 lanes for `--zone` m), then 3 lanes again.
  2,900 cars/h, 300 lorries/h (vClass truck, 16.5 m) and 100 vans/h (9 m, no vClass: SUMO's
  passenger class, left to SUMO by `--share` as not car-sized), a sixth of each from the ramp, as
  random (Bernoulli) flows for the whole run.
* `lorries`: a straight 3-lane motorway (4 km, 120 km/h) with 2,700 cars/h, 450 lorries/h (vClass
  truck, 16.5 m, 90 km/h) and 150 coaches/h (vClass coach, 13.5 m, 100 km/h).

Every run has its own sumocfg (steps of 0.2 s, the policies' step, and SUMO's sublane model at 0.8 m,
which behave's agents drive in: so `--share 0` is SUMO alone under the same options) with a
collision-output, and runs `behave populate --sumocfg ... --share S --seed K`. Per run: collisions
(SUMO's collision output, every vehicle; populate's count of agents' in brackets), agents off the
track, agents and SUMO's vehicles that stood 30 s or more at a time, the longest standstill, mean
speeds (populate's: agents, SUMO's vehicles), and the vehicles that passed the work zone (reached the
edge after it; on `lorries` the road's last 500 m) per hour.

The bar: 0 collisions, 0 off-tracks, no more than 2 agents or SUMO vehicles standing 30 s at
shares 0.5, 0.7 and 1.0 on `ramp` and 1.0 on `lorries`; SUMO alone: none.

    python benchmarks/ramp_bars.py [--seeds 0,1] [--shares 0,0.5,0.7,1] [--duration 900]
        [--scenarios ramp,lorries] [--zone 400] [--out runs/ramp] [--doc docs/ramp.md] [--jobs 1]
        [--label "On the code as it is"]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import pyarrow.parquet as pq
from ablation import commit
from highway_anchor import cpu_model

from behaviors.files import atomic_write_text
from sumo_scenarios.sumo_home import sumo_binary

STEP_S = 0.2
SUBLANE_M = 0.8
MOTORWAY = 120 / 3.6
ZONE_SPEED = 80 / 3.6
LANE_WIDTH = 3.75
STANDING_S = 30
BAR_STANDING = 2
CAR = 'vClass="passenger"'  # SUMO's defaults otherwise: Krauss, sigma 0.5, speedDev 0.1, 5 m
LORRY = 'vClass="truck" length="16.5"'
VAN = 'length="9"'
COACH = 'vClass="coach" length="13.5" maxSpeed="27.78"'
LORRY_90 = 'vClass="truck" length="16.5" maxSpeed="25"'


@dataclass(frozen=True)
class Scenario:
    name: str
    label: str
    past: str  # the edge whose vehicles have passed the work zone (or the road's end)
    bar_shares: tuple[float, ...]  # shares the bar is judged at (0 is SUMO alone, always judged)


SCENARIOS = {
    "ramp": Scenario("ramp", "ramp and work zone", "after", (0.5, 0.7, 1.0)),
    "lorries": Scenario("lorries", "3 lanes, lorries and coaches", "end", (1.0,)),
}


def netconvert(folder: Path, name: str, nodes: str, edges: str, connections: str = "") -> Path:
    """A net built from plain XML by netconvert, as a user builds one."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.nod.xml").write_text(f"<nodes>\n{nodes}</nodes>\n")
    (folder / f"{name}.edg.xml").write_text(f"<edges>\n{edges}</edges>\n")
    (folder / f"{name}.con.xml").write_text(f"<connections>\n{connections}</connections>\n")
    net = folder / f"{name}.net.xml"
    subprocess.run(
        [sumo_binary("netconvert"), "-n", f"{name}.nod.xml", "-e", f"{name}.edg.xml", "-x", f"{name}.con.xml",
         "-o", net.name, "--no-turnarounds"],
        cwd=folder, check=True, capture_output=True,
    )  # fmt: skip
    return net


def edge(name: str, start: str, end: str, lanes: int, speed: float) -> str:
    return (
        f'    <edge id="{name}" from="{start}" to="{end}" numLanes="{lanes}" speed="{speed:.2f}" '
        f'width="{LANE_WIDTH:g}"/>\n'
    )


def flows(per_hour: list[tuple[str, str, str, float]], duration: float) -> str:
    """Random (Bernoulli) flows, one a second at most: (id, vType, route, vehicles an hour)."""
    return "".join(
        f'    <flow id="{name}" type="{kind}" route="{route}" begin="0" end="{duration:g}" '
        f'probability="{rate / 3600:.6f}" departLane="best" departSpeed="max"/>\n'
        for name, kind, route, rate in per_hour
    )


def build_ramp(folder: Path, duration: float, zone: float = 400.0) -> tuple[Path, Path]:
    """The motorway with its on-ramp and work zone: net and routes. Main road 1.5 km, the ramp's 250 m
    acceleration lane, 450 m of 3 lanes, the work zone (the right lane closed: its lane 0 has no
    connection, as a closed lane has none), then 1 km of 3 lanes."""
    x_zone = 1500 + 250 + 450
    nodes = (
        '    <node id="a" x="0" y="0"/>\n    <node id="b" x="1500" y="0"/>\n'
        '    <node id="r" x="1200" y="-60"/>\n    <node id="c" x="1750" y="0"/>\n'
        f'    <node id="d" x="{x_zone}" y="0"/>\n    <node id="e" x="{x_zone + zone:g}" y="0"/>\n'
        f'    <node id="f" x="{x_zone + zone + 1000:g}" y="0"/>\n'
    )
    edges = (
        edge("in", "a", "b", 3, MOTORWAY) + edge("ramp", "r", "b", 1, MOTORWAY)
        + edge("merge", "b", "c", 4, MOTORWAY) + edge("before", "c", "d", 3, MOTORWAY)
        + edge("zone", "d", "e", 2, ZONE_SPEED) + edge("after", "e", "f", 3, MOTORWAY)
    )  # fmt: skip
    links = [("in", "merge", k, k + 1) for k in range(3)] + [("ramp", "merge", 0, 0)]
    links += [("merge", "before", k + 1, k) for k in range(3)]  # the acceleration lane ends
    links += [("before", "zone", k + 1, k) for k in range(2)]  # the right lane is closed
    links += [("zone", "after", k, k + 1) for k in range(2)]
    connections = "".join(
        f'    <connection from="{a}" to="{b}" fromLane="{i}" toLane="{j}"/>\n' for a, b, i, j in links
    )
    net = netconvert(folder, "ramp", nodes, edges, connections)
    routes = folder / "ramp.rou.xml"
    main, ramp = "in merge before zone after", "ramp merge before zone after"
    demand = [("car", "car", 2900), ("lorry", "lorry", 300), ("van", "van", 100)]
    per_hour = [(f"{name}_main", kind, "main", rate * 5 / 6) for name, kind, rate in demand]
    per_hour += [(f"{name}_ramp", kind, "ramp", rate / 6) for name, kind, rate in demand]
    routes.write_text(
        "<routes>\n"
        f'    <vType id="car" {CAR}/>\n    <vType id="lorry" {LORRY}/>\n    <vType id="van" {VAN}/>\n'
        f'    <route id="main" edges="{main}"/>\n    <route id="ramp" edges="{ramp}"/>\n'
        + flows(per_hour, duration)
        + "</routes>\n"
    )
    return net, routes


def build_lorries(folder: Path, duration: float) -> tuple[Path, Path]:
    """A straight 3-lane motorway, 4 km in two edges (the last 500 m its own, to count what passes)."""
    nodes = "".join(f'    <node id="{n}" x="{x}" y="0"/>\n' for n, x in (("a", 0), ("b", 3500), ("c", 4000)))
    net = netconvert(
        folder, "lorries", nodes, edge("road", "a", "b", 3, MOTORWAY) + edge("end", "b", "c", 3, MOTORWAY)
    )
    routes = folder / "lorries.rou.xml"
    per_hour = [("car", "car", "r", 2700), ("lorry", "lorry", "r", 450), ("coach", "coach", "r", 150)]
    routes.write_text(
        "<routes>\n"
        f'    <vType id="car" {CAR}/>\n    <vType id="lorry" {LORRY_90}/>\n    <vType id="coach" {COACH}/>\n'
        '    <route id="r" edges="road end"/>\n' + flows(per_hour, duration) + "</routes>\n"
    )
    return net, routes


BUILDERS = {"ramp": build_ramp, "lorries": build_lorries}


def write_sumocfg(run: Path, net: Path, routes: Path, duration: float) -> Path:
    """The run's own sumocfg: its collision output lands beside it."""
    run.mkdir(parents=True, exist_ok=True)
    sumocfg = run / "scenario.sumocfg"
    sumocfg.write_text(
        "<configuration>\n"
        f'    <input><net-file value="{os.path.relpath(net, run)}"/>'
        f'<route-files value="{os.path.relpath(routes, run)}"/></input>\n'
        f'    <time><begin value="0"/><end value="{duration:g}"/><step-length value="{STEP_S:g}"/></time>\n'
        f'    <processing><lateral-resolution value="{SUBLANE_M:g}"/></processing>\n'
        '    <output><collision-output value="collisions.xml"/></output>\n'
        "</configuration>\n"
    )
    return sumocfg


def sumo_collisions(path: Path) -> int:
    """Collisions in SUMO's collision output (every vehicle's, agents' included)."""
    if not path.is_file():
        return 0
    return sum(1 for _, elem in ET.iterparse(path) if elem.tag == "collision")


def passed(fcd: Path, edge_id: str) -> int:
    """Vehicles seen on `edge_id` (its lanes) in the FCD."""
    table = pq.read_table(fcd, columns=["vehicle_id", "vehicle_lane"]).to_pandas()
    return int(
        table.loc[table["vehicle_lane"].str.rsplit("_", n=1).str[0] == edge_id, "vehicle_id"].nunique()
    )


@dataclass(frozen=True)
class Run:
    scenario: str
    share: float
    seed: int
    summary: dict[str, float]
    collisions: int  # SUMO's collision output
    passed_per_h: float
    wall_s: float

    @property
    def standing(self) -> tuple[int, int]:
        s = self.summary
        return int(s.get(f"agents_standing_{STANDING_S}s", 0)), int(s.get(f"sumo_standing_{STANDING_S}s", 0))

    @property
    def longest(self) -> float:
        return max(
            float(self.summary.get("longest_standstill_s", 0)),
            float(self.summary.get("sumo_longest_standstill_s", 0)),
        )

    @property
    def met(self) -> bool:
        agents, sumo = self.standing
        limit = 0 if self.share == 0 else BAR_STANDING
        clean = (
            self.collisions == 0
            and int(self.summary["collisions"]) == 0
            and int(self.summary["off_tracks"]) == 0
        )
        return clean and agents + sumo <= limit


def run_one(
    scenario: Scenario, share: float, seed: int, args: argparse.Namespace, built: tuple[Path, Path]
) -> Run:
    folder = args.out / scenario.name / f"share{share:g}" / f"s{seed}"
    sumocfg = write_sumocfg(folder, *built, args.duration)
    (folder / "collisions.xml").unlink(missing_ok=True)
    fcd = folder / "fcd.parquet"
    behave = Path(sys.executable).with_name("behave")
    command = [str(behave), "populate", "--sumocfg", str(sumocfg), "--share", f"{share:g}",
               "--seed", str(seed), "--duration", f"{args.duration:g}", "--fcd", str(fcd),
               "--json", "--quiet"]  # fmt: skip
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr.strip()}")
    summary = json.loads(done.stdout)
    (folder / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    out = Run(scenario.name, share, seed, summary, sumo_collisions(folder / "collisions.xml"),
              passed(fcd, scenario.past) * 3600 / args.duration, wall)  # fmt: skip
    agents, sumo = out.standing
    print(f"  {scenario.name} share {share:g} seed {seed}: {out.collisions} collisions, "
          f"{agents}+{sumo} standing {STANDING_S} s, longest {out.longest:.0f} s, {wall:.0f} s wall",
          flush=True)  # fmt: skip
    return out


def speed(summary: dict[str, float], *keys: str) -> str:
    """Mean speed (km/h) over the keys present, weighted equally (keepers and overtakers are half each)."""
    values = [float(summary[k]) for k in keys if k in summary]
    return f"{3.6 * sum(values) / len(values):.0f}" if values else "-"


HEADER = ["scenario", "share", "seed", "agents", "collisions (of agents)", "off-tracks",
          f"agents standing {STANDING_S} s", f"SUMO's standing {STANDING_S} s", "longest standstill s",
          "agents km/h", "SUMO's km/h", "passed veh/h", "bar"]  # fmt: skip


def row(run: Run) -> list[str]:
    s = run.summary
    agents, sumo = run.standing
    judged = run.share == 0 or run.share in SCENARIOS[run.scenario].bar_shares
    return [SCENARIOS[run.scenario].label, f"{run.share:g}", str(run.seed),
            str(int(s.get("of_them_agents", 0))), f"{run.collisions} ({int(s['collisions'])})",
            str(int(s["off_tracks"])), str(agents), str(sumo), f"{run.longest:.0f}",
            speed(s, "keeper_mean_speed", "overtaker_mean_speed"), speed(s, "sumo_mean_speed"),
            f"{run.passed_per_h:.0f}", ("met" if run.met else "**not met**") if judged else "-"]  # fmt: skip


def table(runs: list[Run]) -> str:
    lines = ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(row(r)) + " |" for r in runs]
    return "\n".join(lines)


def write_section(path: Path, intro: str, label: str, section: str) -> None:
    """Write the doc: `intro`, then its `## ` sections as they were, `label`'s replaced by `section`
    (appended if new): the measurement before a change stays beside the one after it."""
    sections: list[tuple[str, str]] = []
    if path.is_file():
        for part in path.read_text().split("\n## ")[1:]:
            sections.append((part.split("\n", 1)[0].strip(), "## " + part.rstrip("\n") + "\n"))
    if label in (name for name, _ in sections):
        sections = [(name, section if name == label else text) for name, text in sections]
    else:
        sections.append((label, section))
    atomic_write_text(path, "\n".join([intro, *(text for _, text in sections)]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--shares", default="0,0.5,0.7,1", help="on the ramp; the lorries' road: 0 and 1")
    parser.add_argument("--duration", type=float, default=900.0, help="simulated seconds per run")
    parser.add_argument("--scenarios", default="ramp,lorries")
    parser.add_argument("--zone", type=float, default=400.0, help="m of the work zone's 2 lanes")
    parser.add_argument("--out", type=Path, default=Path("runs/ramp"))
    parser.add_argument("--doc", type=Path, default=Path("docs/ramp.md"))
    parser.add_argument("--jobs", type=int, default=1, help="runs at once")
    parser.add_argument(
        "--label", default="On the code as it is", help="the doc's section these runs write (others are kept)"
    )
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    shares = [float(s) for s in args.shares.split(",")]
    chosen = [SCENARIOS[name] for name in args.scenarios.split(",")]
    before, started = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    work = []
    for scenario in chosen:
        folder = args.out / scenario.name / "road"
        built = (
            build_ramp(folder, args.duration, args.zone)
            if scenario.name == "ramp"
            else build_lorries(folder, args.duration)
        )
        for share in shares if scenario.name == "ramp" else [s for s in shares if s in (0.0, 1.0)]:
            work += [(scenario, share, seed, built) for seed in seeds]
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        runs = list(pool.map(lambda w: run_one(w[0], w[1], w[2], args, w[3]), work))
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)  # every run's, reaped: --jobs counts once
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    text = table(runs)
    print(text)
    judged = [r for r in runs if r.share == 0 or r.share in SCENARIOS[r.scenario].bar_shares]
    verdict = "met" if all(r.met for r in judged) else "not met"
    command = shlex.join(["python", "benchmarks/ramp_bars.py", *sys.argv[1:]])
    now = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    setting = " ".join([
        "`ramp and work zone`: a 3-lane motorway (120 km/h, lanes 3.75 m) built by netconvert from plain",
        "XML, an on-ramp with a 250 m acceleration lane, 450 m on a work zone closes the right lane",
        f"({args.zone:g} m of 2 lanes at 80 km/h), then 3 lanes again; 2,900 cars/h (SUMO's defaults), 300",
        "lorries/h (vClass truck, 16.5 m) and 100 vans/h (9 m, no vClass), a sixth of each from the ramp,",
        "random flows. `3 lanes, lorries and coaches`: a straight 4 km 3-lane motorway, 2,700 cars/h,",
        "450 lorries/h (16.5 m, 90 km/h), 150 coaches/h (13.5 m, 100 km/h). Each run: its own sumocfg",
        f"(steps of {STEP_S:g} s, lateral resolution {SUBLANE_M:g} m, so share 0 is SUMO alone under the",
        "options the agents' runs have), `behave populate --sumocfg ... --share S --seed K`",
        f"for {args.duration:g} s. Collisions: SUMO's collision output (every vehicle), populate's count",
        f"of agents' in brackets; standing: stood {STANDING_S} s or more at a time (populate's summary);",
        "speeds: populate's means over vehicle-steps (agents: keepers' and overtakers' averaged); passed:",
        "vehicles that reached the edge after the work zone (on the straight road, its last 500 m), per hour",
        f"of the run. The bar: 0 collisions, 0 off-tracks, at most {BAR_STANDING} vehicles",
        f"standing {STANDING_S} s (SUMO alone: none). Definitions: benchmarks/ramp_bars.py.",
    ])  # fmt: skip
    intro = f"# Lane drops, ramps and long vehicles at high shares\n\n{setting}\n"
    section = (
        f"## {args.label}\n\n"
        f"Written by `{command}` (`make ramp`) on commit {commit()}, {now}; CPU: {cpu_model()} (`lscpu`); "
        f"the {len(runs)} runs took {cpu / 60:.1f} min of CPU ({wall / 60:.1f} min wall, the machine "
        f"shared).\n\n{text}\n\n**The bar: {verdict}.**\n"
    )
    write_section(args.doc, intro, args.label, section)
    print(f"wrote {args.doc}")


if __name__ == "__main__":
    main()
