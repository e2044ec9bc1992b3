"""Like people? The bar on a highD-like road (`make people`, writes docs/people.md).

Builds, with netconvert from plain XML, a straight 2-lane motorway (3.75 m lanes, 130 km/h = 36.1 m/s,
3 km, one carriageway) and its demand: passenger cars (a vType with SUMO's defaults: Krauss, sigma
0.5, speedDev 0.1) and lorries (vClass truck, 16.5 m, maxSpeed 25 m/s = 90 km/h, accel 1.0), a fifth
of the vehicles, both as random (Bernoulli) flows, `--flow` vehicles an hour in all (free flow as in
highD). The sumocfg steps 0.2 s (the policies' step) in every run. Then, per seed, through
`behave populate --sumocfg`:

* `SUMO`: SUMO's default drivers alone (`--share 0`: the scenario as `sumo -c` runs it, no sublanes,
  LC2013's instant lane changes);
* `SUMO sublanes`: the same with SUMO's sublane model (lateral resolution 0.8 m: SL2015), the model
  SUMO's cars drive by beside agents;
* one run per `--policies` entry with every car learned (`--share 1.0`: each passenger car becomes an
  agent as it departs, half keepers and half overtakers; lorries stay SUMO's, since `--share` draws
  only car-sized vehicles), and with `+lorries` every vehicle (`--share-lorries`: the lorries become
  the styled policy's learned lorries, at their own size).

Each run's FCD is measured by behaviors.report.people through the 420 m window `--window-start` +420 m,
after `--warmup` s: per group (cars, lorries), the closest time headways, the share changing lane,
the mean speeds and the lane-centre offset beside highD's published figures; seeds pooled. Every
collision SUMO sees (its collision-output: SUMO's vehicles and agents alike) is counted.

    python benchmarks/people.py [--seeds 0,1,2] [--duration 900] [--warmup 180] [--flow 1800]
        [--policies traffic,behaviors/pretrained/styled.pt] [--out runs/people] [--doc docs/people.md]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import pandas as pd
from common import write_measured_doc
from highway_anchor import cpu_model

from behaviors.learn.policy import PRETRAINED
from behaviors.report.fcd_read import read_fcd
from behaviors.report.people import (
    CARS,
    KS_LIMIT,
    LORRIES,
    OFFSET_RANGE,
    REFERENCES,
    SHARE_POINTS,
    WINDOW_M,
    Figure,
    Window,
    compare,
    like_people,
    per_vehicle,
)
from sumo_scenarios.build import LORRY_SIZE
from sumo_scenarios.osm_like import Way, run_netconvert, write_plain

ROAD = "autobahn2"
EDGE = "road"
ROAD_M = 3000.0
LANE_WIDTH = 3.75
LIMIT = 130 / 3.6
LORRY = {"length": 16.5, "maxSpeed": 25.0, "accel": 1.0}
STEP_S = 0.2
SUBLANE_M = 0.8
LENGTHS = {"lorry": LORRY["length"], "behave_lorry": LORRY_SIZE[0]}
"""vType -> length; every other type (car, behave's keepers and overtakers) is 5 m. A learned lorry
of the scenario's keeps its length in a copy of behave's type (`behave_lorry@ID`)."""
GROUPS = {"lorry": LORRIES, "behave_lorry": LORRIES}
"""vType -> group; every other type is a car (SUMO's `car`, behave's keepers and overtakers)."""
STYLED = PRETRAINED / "styled.pt"
BAR_PARTS = {
    "thw_ks": f"closest headways within KS {KS_LIMIT:g} of the fitted lognormal",
    "below_1s": f"share closer than 1 s within {100 * SHARE_POINTS:.0f} points",
    "below_half_s": f"share closer than 0.5 s within {100 * SHARE_POINTS:.0f} points",
    "changed_lane": f"share changing lane within {100 * SHARE_POINTS:.0f} points",
    "speed_ks": f"mean speeds' shape within KS {KS_LIMIT:g}",
    "offset_mean": f"mean lane-centre offset {OFFSET_RANGE[0]:g}-{OFFSET_RANGE[1]:g} m",
    "thw_ks closer than SUMO's": "closest headways closer to people's than SUMO's (KS)",
    "speed_ks closer than SUMO's": "mean speeds' shape closer to people's than SUMO's (KS)",
    "changed_lane closer than SUMO's": "share changing lane closer to people's than SUMO's",
    "no collision": "no collision (SUMO's collision output, every vehicle; agents' by populate)",
}


@dataclass(frozen=True)
class Variant:
    key: str  # folder name
    label: str
    share: float
    policy: str | None = None
    sublanes: bool = False
    population: str | None = None  # a styled policy's --population
    lorries: bool = False  # the lorries learned too (--share-lorries)


def variants(policies: list[str]) -> list[Variant]:
    """SUMO alone, with and without sublanes, and each policy (`POLICY`, `POLICY@POPULATION`: a styled
    policy's agents drawn from that population; `+lorries` at the end: the lorries learned too) with
    every car learned."""
    out = [Variant("sumo", "SUMO", 0.0), Variant("sumo-sublanes", "SUMO sublanes", 0.0, sublanes=True)]
    for entry in policies:
        lorries = entry.endswith("+lorries")
        policy, _, population = entry.removesuffix("+lorries").partition("@")
        name = Path(policy).stem if policy.endswith(".pt") or "/" in policy else policy
        name += f"@{Path(population).stem}" if population else ""
        key, label = f"learned-{name}", f"all cars {name}"
        if lorries:
            key, label = f"{key}+lorries", f"every vehicle {name}"
        out.append(Variant(key, label, 1.0, policy, population=population or None, lorries=lorries))
    return out


# ---- the road, its demand and a sumocfg per run ----


def build_road(folder: Path, flow: float, lorry_share: float, duration: float) -> tuple[Path, Path]:
    """The net and the routes (written once per `--out`)."""
    folder.mkdir(parents=True, exist_ok=True)
    write_plain(folder, ROAD, [Way(EDGE, "n0", "n1", 2, LANE_WIDTH, LIMIT, [(0.0, 0.0), (ROAD_M, 0.0)])], [])
    net = run_netconvert(folder, ROAD, lefthand=False)
    routes = folder / f"{ROAD}.rou.xml"
    cars, lorries = flow * (1 - lorry_share) / 3600, flow * lorry_share / 3600
    lorry = " ".join(f'{k}="{v:g}"' for k, v in LORRY.items())
    routes.write_text(
        "<routes>\n"
        '    <vType id="car" vClass="passenger" sigma="0.5" speedDev="0.1"/>\n'
        f'    <vType id="lorry" vClass="truck" {lorry}/>\n'
        f'    <flow id="car" type="car" begin="0" end="{duration:g}" probability="{cars:.6f}" from="{EDGE}" '
        f'to="{EDGE}" departLane="random" departSpeed="desired"/>\n'
        f'    <flow id="lorry" type="lorry" begin="0" end="{duration:g}" probability="{lorries:.6f}" '
        f'from="{EDGE}" to="{EDGE}" departLane="0" departSpeed="desired"/>\n'
        "</routes>\n"
    )
    return net, routes


def write_sumocfg(run: Path, net: Path, routes: Path, duration: float, sublanes: bool) -> Path:
    """The run's own sumocfg: its collision output lands beside it."""
    run.mkdir(parents=True, exist_ok=True)
    sumocfg = run / f"{ROAD}.sumocfg"
    processing = (
        f'    <processing><lateral-resolution value="{SUBLANE_M:g}"/></processing>\n' if sublanes else ""
    )
    sumocfg.write_text(
        "<configuration>\n"
        f'    <input><net-file value="{os.path.relpath(net, run)}"/>'
        f'<route-files value="{os.path.relpath(routes, run)}"/></input>\n'
        f'    <time><begin value="0"/><end value="{duration:g}"/><step-length value="{STEP_S:g}"/></time>\n'
        + processing
        + '    <output><collision-output value="collisions.xml"/></output>\n'
        "</configuration>\n"
    )
    return sumocfg


def collisions(path: Path) -> int:
    """Collisions in SUMO's collision output (every vehicle's, agents' included)."""
    if not path.is_file():
        return 0
    return sum(1 for _, elem in ET.iterparse(path) if elem.tag == "collision")


@dataclass(frozen=True)
class Run:
    variant: Variant
    seed: int
    vehicles: pd.DataFrame  # behaviors.report.people.per_vehicle's rows
    collisions: int  # SUMO's collision output
    agent_collisions: int  # populate's count of agents' collisions
    agents: int
    cpu_s: float
    wall_s: float


def run_one(variant: Variant, seed: int, args: argparse.Namespace, net: Path, routes: Path) -> Run:
    folder = args.out / variant.key / f"s{seed}"
    sumocfg = write_sumocfg(folder, net, routes, args.duration, variant.sublanes)
    (folder / "collisions.xml").unlink(missing_ok=True)
    fcd = folder / "fcd.parquet"
    behave = Path(sys.executable).with_name("behave")
    command = [str(behave), "populate", "--sumocfg", str(sumocfg), "--share", f"{variant.share:g}",
               "--seed", str(seed), "--duration", f"{args.duration:g}", "--fcd", str(fcd),
               "--json", "--quiet"]  # fmt: skip
    if variant.policy is not None:
        command += ["--policy", variant.policy]
    if variant.population is not None:
        command += ["--population", variant.population]
    if variant.lorries:
        command.append("--share-lorries")
    before, started = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    after, wall = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr.strip()}")
    summary = json.loads(done.stdout)
    (folder / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    window = Window(args.window_start, edge=EDGE, since=args.warmup)
    vehicles = per_vehicle(read_fcd(fcd), window, lengths=LENGTHS, groups=GROUPS, default_group=CARS)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    out = Run(variant, seed, vehicles.assign(variant=variant.key, seed=seed),
              collisions(folder / "collisions.xml"), int(summary["collisions"]),
              int(summary.get("of_them_agents", 0)), cpu, wall)  # fmt: skip
    cars = vehicles[vehicles["group"] == CARS]
    print(f"  {variant.label}, seed {seed}: {len(cars)} cars and {len(vehicles) - len(cars)} lorries through "
          f"the window, {out.agents} agents, {out.collisions} collisions, {cpu:.0f} s CPU, {wall:.0f} s wall",
          flush=True)  # fmt: skip
    return out


def commit() -> str:
    """HEAD's short hash, the code files that differ from it (others' work in the checkout ran too) and
    how many other files do."""
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(
        ["git", "diff", "--name-only", "HEAD"], capture_output=True, text=True
    ).stdout.split()
    code = [f for f in dirty if f.startswith(("behaviors/", "cli/", "sumo_scenarios/")) and f.endswith(".py")]
    text = head.stdout.strip() or "unknown"
    if code:
        text += f" with uncommitted changes to {', '.join(code)}"
    others = len(dirty) - len(code)
    return text + (f" ({others} other files uncommitted: tests, docs, build)" if others else "")


# ---- the tables ----


def fmt_figure(figure: Figure, value: float) -> str:
    if math.isnan(value):
        return "-"
    if figure.kind == "share":
        return f"{100 * value:.1f}%"
    if figure.key in ("vehicles", "with_leader"):
        return f"{value:.0f}"
    return f"{value:.3f}" if figure.kind in ("ks", "range") or figure.key == "speed_cv" else f"{value:.2f}"


def reference_cell(figure: Figure) -> str:
    if figure.kind == "ks":
        return f"<= {KS_LIMIT:g}"
    if figure.kind == "range":
        return f"{figure.reference:g} ({OFFSET_RANGE[0]:g}-{OFFSET_RANGE[1]:g})"
    if figure.key == "changed_lane" and figure.reference < 0.01:
        return "< 1%"
    return fmt_figure(figure, figure.reference)


def cell(figure: Figure) -> str:
    """The simulated value, with its distance to the reference in points for a share."""
    if figure.kind == "ks":
        text = fmt_figure(figure, figure.distance)
    else:
        text = fmt_figure(figure, figure.simulated)
    if figure.kind == "share" and not math.isnan(figure.distance):
        text += f" ({100 * figure.distance:.1f} pt)"
    if figure.met is not None and figure.kind != "info":
        text += "" if figure.met else " ✗"
    return text


def group_table(group: str, pooled: dict[str, list[Figure]], labels: dict[str, str]) -> str:
    any_figures = next(iter(pooled.values()))
    header = ["figure", f"highD {group} (fitted)", *labels.values()]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for k, figure in enumerate(any_figures):
        row = [figure.label, reference_cell(figure)]
        row += [cell(pooled[key][k]) for key in labels]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def figures_of(runs: list[Run], group: str) -> list[Figure]:
    vehicles = pd.concat([r.vehicles for r in runs], ignore_index=True)
    return compare(vehicles[vehicles["group"] == group], REFERENCES[group])


def per_seed_table(by_variant: dict[str, list[Run]], labels: dict[str, str]) -> str:
    header = ["run", "seed", "cars", "lorries", "agents", "collisions", "cars' closest-THW KS", "cars < 1 s",
              "cars changing lane", "cars' speed KS", "cars' offset [m]", "CPU s", "wall s"]  # fmt: skip
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for key, runs in by_variant.items():
        for r in runs:
            figs = {f.key: f for f in figures_of([r], CARS)}
            lorries = int((r.vehicles["group"] == LORRIES).sum())
            row = [labels[key], str(r.seed), str(int((r.vehicles["group"] == CARS).sum())), str(lorries),
                   str(r.agents), f"{r.collisions} ({r.agent_collisions} of agents)",
                   fmt_figure(figs["thw_ks"], figs["thw_ks"].distance),
                   fmt_figure(figs["below_1s"], figs["below_1s"].simulated),
                   fmt_figure(figs["changed_lane"], figs["changed_lane"].simulated),
                   fmt_figure(figs["speed_ks"], figs["speed_ks"].distance),
                   fmt_figure(figs["offset_mean"], figs["offset_mean"].simulated),
                   f"{r.cpu_s:.0f}", f"{r.wall_s:.0f}"]  # fmt: skip
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def bar_table(by_variant: dict[str, list[Run]], labels: dict[str, str]) -> str:
    sumo = figures_of(by_variant["sumo"], CARS)
    learned = [key for key in by_variant if key.startswith("learned-")]
    if not learned:
        return "(no learned run)"
    bars = {}
    for key in learned:
        hits = sum(r.collisions + r.agent_collisions for r in by_variant[key])
        bars[key] = like_people(figures_of(by_variant[key], CARS), sumo, hits)
    parts = list(next(iter(bars.values())).parts)
    header = ["part of the bar (cars, seeds pooled)", *(labels[k] for k in learned)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for part in parts:
        cells = ("yes" if bars[k].parts[part] else "no" for k in learned)
        lines.append("| " + " | ".join([BAR_PARTS.get(part, part), *cells]) + " |")
    lines.append(
        "| "
        + " | ".join(["**the bar**", *("**met**" if bars[k].met else "**not met**" for k in learned)])
        + " |"
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--duration", type=float, default=900.0, help="simulated seconds per run")
    parser.add_argument("--warmup", type=float, default=180.0, help="seconds left out at the start")
    parser.add_argument("--flow", type=float, default=1800.0, help="vehicles an hour, lorries included")
    parser.add_argument("--lorry-share", type=float, default=0.2)
    parser.add_argument("--window-start", type=float, default=1500.0, help="m along the road")
    parser.add_argument(
        "--policies", default=None,
        help="comma-separated --policy values for the all-learned runs [default: traffic, and "
        "behaviors/pretrained/styled.pt when it exists]",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("runs/people"))
    parser.add_argument("--doc", type=Path, default=Path("docs/people.md"))
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    if args.policies is None:
        styled = os.path.relpath(STYLED)
        policies = [
            "traffic",
            *([styled, f"{styled}@highd", f"{styled}@highd+lorries"] if STYLED.is_file() else []),
        ]
    else:
        policies = [p for p in args.policies.split(",") if p]
    if not args.window_start + WINDOW_M <= ROAD_M or not 0 <= args.warmup < args.duration:
        parser.error("the window must lie on the 3 km road and the warm-up end before the run")
    started = time.perf_counter()
    net, routes = build_road(args.out / "road", args.flow, args.lorry_share, args.duration)
    chosen = variants(policies)
    labels = {v.key: v.label for v in chosen}
    by_variant: dict[str, list[Run]] = {}
    for variant in chosen:
        by_variant[variant.key] = [run_one(variant, seed, args, net, routes) for seed in seeds]
    wall = time.perf_counter() - started
    cpu = sum(r.cpu_s for runs in by_variant.values() for r in runs)
    pd.concat([r.vehicles for runs in by_variant.values() for r in runs], ignore_index=True).to_csv(
        args.out / "vehicles.csv", index=False
    )
    tables = []
    for group in (CARS, LORRIES):
        pooled = {key: figures_of(runs, group) for key, runs in by_variant.items()}
        tables += [f"### {group.capitalize()}, seeds {args.seeds} pooled", group_table(group, pooled, labels)]
    text = "\n\n".join([
        *tables,
        "### The like-people bar", bar_table(by_variant, labels),
        "### Per run", per_seed_table(by_variant, labels),
    ])  # fmt: skip
    print(text)
    command = " ".join(["python benchmarks/people.py", *sys.argv[1:]])
    now = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    setting = " ".join([
        f"A straight 2-lane motorway, {ROAD_M / 1000:g} km, lanes {LANE_WIDTH:g} m, limit 130 km/h",
        f"({LIMIT:.1f} m/s), built by netconvert from plain XML; {args.flow:g} vehicles/h,",
        f"{100 * args.lorry_share:g}% lorries (vClass truck, {LORRY['length']:g} m,",
        f"maxSpeed {LORRY['maxSpeed']:g} m/s, accel {LORRY['accel']:g}), cars a vType with SUMO's defaults",
        f"(sigma 0.5, speedDev 0.1); steps of {STEP_S:g} s, {args.duration:g} s per run, the first",
        f"{args.warmup:g} s left out; the window {args.window_start:g}-{args.window_start + WINDOW_M:g} m,",
        "vehicles that drove through it whole. `SUMO`: SUMO's default drivers alone (no sublanes);",
        f"`SUMO sublanes`: the same with lateral resolution {SUBLANE_M:g} m (SL2015); `all cars <policy>`:",
        "`--share 1.0`, every passenger car an agent (half keepers, half overtakers), the lorries SUMO's;",
        "`every vehicle <policy>`: the lorries learned too (`--share-lorries`). The reference is highD",
        "location 2's published per-vehicle aggregates (the shared realism notes): the closest-headway",
        "distribution is a lognormal fitted to median 1.4 s and P(< 1 s) = 1/3 (cars; lorries 2.2 s and",
        "1/6), a distribution fitted to published figures, not the data; mean speeds are compared in shape",
        "only, each car's mean speed over the group's median against N(33.5, 5.17) over its median (p5 25,",
        "p95 42; highD's road has no limit, ours 130 km/h), the medians shown beside. Shares are judged",
        f'within {100 * SHARE_POINTS:.0f} points, distributions within KS',
        f"{KS_LIMIT:g}; ✗ marks a figure outside. Definitions: behaviors/report/people.py.",
    ])  # fmt: skip
    doc = (
        "# Like people: closest headways, lane changes, speeds and lane keeping through a 420 m window\n\n"
        f"Written by `{command}` (`make people`) on commit {commit()}, {now}; CPU: {cpu_model()} (`lscpu`); "
        f"the {sum(map(len, by_variant.values()))} runs took {cpu / 60:.1f} min of CPU ({wall / 60:.1f} min "
        f"wall, the machine shared).\n\n{setting}\n\n{text}\n"
    )
    write_measured_doc(args.doc, doc)
    print(f"wrote {args.doc}")


if __name__ == "__main__":
    main()
