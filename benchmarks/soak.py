"""Memory of long `behave populate` runs: does the process grow with simulated time?

Each case runs `behaviors.run.populate.populate` twice, each in a fresh process: with learned agents
among `behave_background` cars (`--keep-count`, FCD on: what `behave populate` runs), and SUMO
alone with the same number of vehicles (all `behave_background`, same net, seed and FCD). Each
process reads its own resident memory (VmRSS in /proc/self/status) every `--every` simulated
seconds, with its children's (populate's parquet reader is a process of its own). Growth: the
least-squares slope of RSS against simulated time after the first `--warmup` simulated seconds
(10 minutes), in MB per simulated hour.

Cases (`--cases`, comma-separated):
  light          the bundled 3 km highway, 80 agents + 20 SUMO cars, 1 h (FCD xml)
  dense          the bundled highway, 150 agents + 150 SUMO cars (33 cars per lane-km), 1 h
  light-parquet  as light, 2 h, FCD in parquet: SUMO writes csv into a pipe, behaviors/sumo/fcd_parquet.py
                 writes the row groups (SUMO's own parquet writer grew 100-260 MB per simulated hour)
  day            a 30 km straight 3-lane motorway, 20 agents + 20 SUMO cars, 24 h
Bar (light, dense, light-parquet): populate grows <= 20 MB per simulated hour, and no more than SUMO
alone where SUMO alone grows (more than 1 MB per simulated hour).

Results go to runs/soak/<case>.json (one file per case, so cases can run apart or at once) and the
table of every case measured so far to docs/benchmarks.md, section "Long runs" (between its
markers; notes below them stay).

Usage: python benchmarks/soak.py [--cases light,dense,day] [--jobs 1] [--every 60] [--warmup 600]
                                 [--seed 3] [--scale 1.0] [--load TEXT] [--no-doc | --doc-only]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import re
import subprocess
import tempfile
import textwrap
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from common import print_table
from rich.console import Console

from behaviors.files import atomic_write_text

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "benchmarks.md"
RESULTS = ROOT / "runs" / "soak"
SECTION = "## Long runs: memory over simulated time (`make soak`, benchmarks/soak.py)"
BEGIN, END = "<!-- soak: begin (written by benchmarks/soak.py) -->", "<!-- soak: end -->"
BAR_MB_PER_H = 20.0
ALONE_GROWS_MB_PER_H = 1.0
"""SUMO alone "grows" above this (RSS is read in kB; a flat process moves by a few tenths of a MB)."""
BARRED = ("light", "dense", "light-parquet")


@dataclass(frozen=True)
class Case:
    name: str
    agents: int
    background: int
    hours: float
    fcd: str = "xml"
    road_km: float | None = None  # None: the bundled 3 km highway; else a straight road built here
    note: str = ""


CASES = {
    "light": Case("light", 80, 20, 1.0, note="1 simulated hour"),
    "dense": Case("dense", 150, 150, 1.0, note="33 cars per lane-km"),
    "light-parquet": Case("light-parquet", 80, 20, 2.0, fcd="parquet", note="parquet FCD (fcd_parquet.py)"),
    "day": Case("day", 20, 20, 24.0, road_km=30.0, note="a simulated day"),
}


@dataclass(frozen=True)
class Run:
    case: Case
    alone: bool  # SUMO alone: every vehicle behave_background
    seed: int
    every: float  # simulated s between RSS readings
    load: str  # what else ran on the machine (for the wall times)


def rss_mb(field: str = "VmRSS", pid: str = "self") -> float:
    """A process's resident set size (or its peak, VmHWM) in MB, as the kernel reports it."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no {field} in /proc/{pid}/status (Linux only)")


def children_rss_mb() -> float:
    """The resident set size of this process's children: populate's parquet reader
    (behaviors/sumo/fcd_parquet.py, a process of its own) is part of what a run holds."""
    me, total = os.getpid(), 0.0
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                if int(Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()[1]) == me:
                    total += rss_mb(pid=entry)
            except (OSError, RuntimeError, ValueError, IndexError):
                continue  # gone meanwhile
    return total


def measure(run: Run) -> dict:
    """One populate run in this (fresh) process: RSS every `run.every` simulated seconds."""
    import torch

    from behaviors.run.populate import populate
    from behaviors.run.populate_config import PopulateConfig
    from behaviors.run.precision import POLICY_THREADS
    from sumo_scenarios import get_scenario

    torch.set_num_threads(POLICY_THREADS)  # as populate() sets it
    c = run.case
    with tempfile.TemporaryDirectory(prefix="behave_soak_") as tmp_name:
        tmp = Path(tmp_name)
        net = get_scenario("highway").net if c.road_km is None else build_road(tmp, c.road_km)
        config = PopulateConfig(
            net=net, overtakers=c.agents // 2, keepers=c.agents - c.agents // 2, background=c.background,
            duration=c.hours * 3600.0, seed=run.seed, fcd=tmp / f"fcd.{c.fcd}", keep_count=True,
        )  # fmt: skip
        if run.alone:
            config = replace(config, overtakers=0, keepers=0, background=c.agents + c.background)
        every = max(1, round(run.every / config.step_length))
        samples: list[tuple[float, float, float]] = []
        start = time.perf_counter()
        steps = 0

        def on_step(simulated_s: float) -> None:
            nonlocal steps
            steps += 1
            if steps % every == 0:
                samples.append(
                    (round(simulated_s, 3), rss_mb() + children_rss_mb(), time.perf_counter() - start)
                )

        summary = populate(config, on_step=on_step)
        fcd_mb = config.fcd.stat().st_size / 2**20
    return {
        "case": asdict(c),
        "alone": run.alone,
        "seed": run.seed,
        "step_length": config.step_length,
        "samples": samples,
        "peak_mb": rss_mb("VmHWM"),
        "wall_s": time.perf_counter() - start,
        "fcd_mb": fcd_mb,
        "vehicles": summary.vehicles,
        "collisions": summary.collisions,
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "load": run.load,
    }


def build_road(out_dir: Path, km: float) -> Path:
    from sumo_scenarios.build import build_straight

    scenario = build_straight(
        out_dir / "road", name="soak_road", length=km * 1000.0, edge_length=300.0, lanes=3, lane_width=3.5,
        kilometrage=True, description=f"straight 3-lane motorway, {km:g} km (soak benchmark)",
    )  # fmt: skip
    return scenario.net


def growth_per_hour(samples: list[list[float]], warmup: float) -> float:
    """Least-squares slope of RSS (MB) against simulated hours, readings after `warmup` s."""
    t = np.array([s[0] for s in samples if s[0] >= warmup]) / 3600.0
    rss = np.array([s[1] for s in samples if s[0] >= warmup])
    if len(t) < 2:
        return float("nan")
    return float(np.polyfit(t, rss, 1)[0])


def rss_at(samples: list[list[float]], when: float) -> float:
    """RSS at the first reading at or after `when` simulated seconds."""
    return next((s[1] for s in samples if s[0] >= when), samples[-1][1])


def meets(case: str, growth: float, alone: float) -> str:
    if case not in BARRED:
        return "-"
    ok = growth <= BAR_MB_PER_H and (alone <= ALONE_GROWS_MB_PER_H or growth <= alone)
    return "met" if ok else "MISSED"


def cpu_name() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        model = re.search(r"Model name:\s*(.+)", out)
        cores = re.search(r"^CPU\(s\):\s*(\d+)", out, re.MULTILINE)
        return f"{model[1].strip() if model else platform.processor()}, {cores[1] if cores else '?'} cores"
    except (OSError, subprocess.CalledProcessError):
        return platform.processor() or "unknown CPU"


def load_results(folder: Path) -> dict[str, dict]:
    """Every case measured so far: {case: {"populate": result, "alone": result, "command": argv}}."""
    out = {}
    for path in sorted(folder.glob("*.json")):
        out[path.stem] = json.loads(path.read_text())
    return out


ORDER = list(CASES)


def columns(warmup: float) -> list[str]:
    return ["case", "road", "agents", "SUMO cars", "FCD", "simulated h", "seed",
            f"RSS at {warmup / 60:g} min MB", "RSS at end MB", "populate MB per sim h",
            "SUMO alone MB per sim h", "bar", "wall s (populate / alone)", "measured",
            "beside it"]  # fmt: skip


def table_rows(results: dict[str, dict], warmup: float) -> list[list[str]]:
    rows = []
    for name in sorted(results, key=lambda n: ORDER.index(n) if n in ORDER else len(ORDER)):
        r = results[name]
        pop, alone, c = r["populate"], r["alone"], r["populate"]["case"]
        grows, alone_grows = (
            growth_per_hour(pop["samples"], warmup),
            growth_per_hour(alone["samples"], warmup),
        )
        road = "bundled highway (3 km)" if c["road_km"] is None else f"straight {c['road_km']:g} km"
        rows.append([
            name, road, str(c["agents"]), str(c["background"]), c["fcd"], f"{c['hours']:g}", str(pop["seed"]),
            f"{rss_at(pop['samples'], warmup):.1f}", f"{pop['samples'][-1][1]:.1f}", f"{grows + 0.0:.1f}",
            f"{alone_grows + 0.0:.1f}", meets(name, grows, alone_grows),
            f"{pop['wall_s']:.0f} / {alone['wall_s']:.0f}", pop["date"], pop["load"],
        ])  # fmt: skip
    return rows


def trace_rows(result: dict, every_s: float) -> list[list[str]]:
    """The memory trace of a case: RSS of populate and SUMO alone at every `every_s` simulated s."""
    pop, alone = result["populate"]["samples"], result["alone"]["samples"]
    marks = np.arange(every_s, pop[-1][0] + 1e-6, every_s)
    return [[f"{t / 3600:g}", f"{rss_at(pop, t):.1f}", f"{rss_at(alone, t):.1f}"] for t in marks]


def markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows])


def render(results: dict[str, dict], warmup: float, meta: dict) -> str:
    commands = sorted({r.get("command", "python benchmarks/soak.py") for r in results.values()})
    intro = (
        f"Machine: {meta['cpu']} (`lscpu`). Every case: `behave populate` "
        "(`behaviors.run.populate.populate`, `--keep-count`, FCD on, step 0.2 s) in a fresh process, "
        "and SUMO alone with the same vehicles (all `behave_background`) in another; RSS of the process "
        f"and its children (populate's parquet reader) every {meta['every']:g} simulated s; "
        "growth = least-squares slope after the first "
        f"{warmup / 60:g} simulated minutes. Bar ({', '.join(BARRED)}): "
        f"<= {BAR_MB_PER_H:g} MB per simulated hour, and no more than SUMO alone where SUMO alone grows."
    )
    parts = [
        textwrap.fill(intro, 100),
        "",
        "Commands: " + ", ".join(f"`{c}`" for c in commands),
        "",
        markdown(columns(warmup), table_rows(results, warmup)),
    ]
    if "day" in results:
        parts += [
            "",
            "Memory trace of the simulated day (RSS in MB at each simulated hour):",
            "",
            markdown(["simulated h", "populate", "SUMO alone"], trace_rows(results["day"], 3600.0)),
        ]
    return "\n".join(parts)


def write_doc(text: str) -> None:
    """Replace what lies between the section's markers (the section is added at the end if missing);
    everything else in the file, notes below the markers too, stays as it is."""
    old = DOC.read_text() if DOC.is_file() else ""
    block = f"{BEGIN}\n{text}\n{END}"
    if BEGIN in old and END in old:
        head, rest = old.split(BEGIN, 1)
        new = head + block + rest.split(END, 1)[1]
    else:
        new = old.rstrip("\n") + f"\n\n{SECTION}\n\n{block}\n"
    atomic_write_text(DOC, new)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="light,dense,day", help=f"comma-separated, of {', '.join(CASES)}")
    parser.add_argument("--jobs", type=int, default=1, help="runs at once (each its own process)")
    parser.add_argument("--every", type=float, default=60.0, help="simulated s between RSS readings")
    parser.add_argument("--warmup", type=float, default=600.0, help="simulated s left out of the growth")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument(
        "--scale", type=float, default=1.0, help="multiply every case's duration (quick checks)"
    )
    parser.add_argument("--no-doc", action="store_true", help="do not write docs/benchmarks.md")
    parser.add_argument("--results", type=Path, default=RESULTS, help="folder of the per-case results")
    parser.add_argument(
        "--doc-only", action="store_true", help="run nothing: the doc from the results so far"
    )
    parser.add_argument(
        "--load", default="idle machine", help="what else runs on the machine (noted beside the wall times)"
    )
    args = parser.parse_args(argv)
    args.case_list = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in args.case_list if c not in CASES]
    if unknown or not args.case_list:
        parser.error(f"unknown case(s) {', '.join(unknown)}; choose from {', '.join(CASES)}")
    if args.jobs < 1 or args.every <= 0 or args.warmup < 0 or args.scale <= 0:
        parser.error("--jobs, --every and --scale must be positive, --warmup not negative")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    console = Console(width=max(Console().width, 160))
    cases = [CASES[name] for name in args.case_list]
    cases = [replace(c, hours=c.hours * args.scale) for c in cases]
    kinds = () if args.doc_only else (False, True)
    runs = [Run(c, alone, args.seed, args.every, args.load) for c in cases for alone in kinds]
    # the longest first, so that with --jobs 2 the short ones fill in beside it
    runs.sort(key=lambda r: -(r.case.hours * (r.case.agents + r.case.background) * (1 if r.alone else 5)))
    context = multiprocessing.get_context("spawn")
    args.results.mkdir(parents=True, exist_ok=True)
    done: dict[str, dict] = {}
    command = f"python benchmarks/soak.py --cases {','.join(args.case_list)}" + "".join(
        f" --{name} {getattr(args, name):g}"
        for name, default in (("scale", 1.0), ("seed", 3), ("every", 60.0), ("warmup", 600.0))
        if getattr(args, name) != default
    )
    start = time.perf_counter()
    with context.Pool(args.jobs, maxtasksperchild=1) as pool:
        for result in pool.imap_unordered(measure, runs):
            name = result["case"]["name"]
            kind = "alone" if result["alone"] else "populate"
            console.print(f"[dim]{name} {kind}: {result['wall_s']:.0f} s wall, "
                          f"{time.perf_counter() - start:.0f} s since start[/dim]")  # fmt: skip
            done.setdefault(name, {"command": command})[kind] = result
            if len(done[name]) == 3:
                atomic_write_text(args.results / f"{name}.json", json.dumps(done[name]))
    results = load_results(args.results)
    print_table(console, "memory over simulated time", columns(args.warmup), table_rows(results, args.warmup))
    if "day" in results:
        print_table(console, "the simulated day", ["simulated h", "populate MB", "SUMO alone MB"],
                    trace_rows(results["day"], 3600.0))  # fmt: skip
    if not args.no_doc:
        meta = {"cpu": cpu_name(), "every": args.every}
        write_doc(render(results, args.warmup, meta))
        console.print(f"wrote {DOC.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
