"""Per-step cost of `behave populate --connect` (behave as a TraCI client of a SUMO in another process)
against the libsumo mode (SUMO inside behave's process), on the same scenario, machine and settings.

Each row is a straight 3-lane road whose N passenger cars all depart at t=0, spread over its lanes
40 m apart, and a sumocfg at the bundled policy's 0.2 s step with sublanes; `--share 1` makes every
car an agent, so N agents drive. Each (mode, round) runs in a fresh process:
- libsumo: `Population` over the sumocfg as `behave populate --sumocfg CFG --share 1` runs it;
- connect: `sumo -c CFG --remote-port P --num-clients 1` with the options behave's own run passes
  SUMO (its vtypes file, so the agents' 1 s action step is the same in both, the collision options,
  the Euler update, the seed), and `Population` joined to it as `--connect` joins (`JoinedSim`).
No FCD in either. After warm-up (every car an agent, then 20 steps) `--steps` whole
`Population.step()` calls are timed: wall ms per step, and CPU ms per step (behave's process, plus
SUMO's process in the connect mode: what the machine spends). Modes alternate round by round so the
shared machine's drift falls on both; the table gives each mode's median over rounds and the ratio.

Usage: python benchmarks/bench_connect.py [--rows 100,1000] [--steps 200] [--rounds 3] [--csv PATH]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import print_table, write_csv
from rich.console import Console

WARMUP_STEPS = 20
SPACING_M = 40.0
LANES = 3
RUN_AHEAD_M = 2500.0  # road beyond the last car: nobody reaches the end within warm-up and timing
TARGET_RATIO_100 = 2.0  # the aim: --connect at most 2x libsumo at 100 agents


def build(folder: Path, cars: int) -> Path:
    """The row's road, demand and sumocfg in `folder`."""
    from sumo_scenarios.build import build_straight

    per_lane = math.ceil(cars / LANES)
    length = per_lane * SPACING_M + RUN_AHEAD_M
    edges = max(2, round(length / 500.0))
    scenario = build_straight(folder, name="road", length=length, edge_length=length / edges, lanes=LANES,
                              lane_width=3.5, description="bench_connect road")  # fmt: skip
    edge = length / edges
    routes = "".join(
        f'<route id="r{j}" edges="{" ".join(f"e{k}" for k in range(j, edges))}"/>' for j in range(edges)
    )
    vehicles = []
    for k in range(cars):  # a route from the edge each car starts on (departPos counts on the first edge)
        at = (per_lane - k // LANES) * SPACING_M
        first = min(int(at // edge), edges - 1)
        place = f'departLane="{k % LANES}" departPos="{at - first * edge:.1f}" departSpeed="max"'
        vehicles.append(f'<vehicle id="car{k:05d}" type="car" route="r{first}" depart="0" {place}/>')
    (folder / "demand.rou.xml").write_text(
        f'<routes><vType id="car" vClass="passenger" sigma="0.5"/>{routes}{"".join(vehicles)}</routes>'
    )
    cfg = folder / "road.sumocfg"
    cfg.write_text(
        f'<configuration><input><net-file value="{scenario.net.name}"/><route-files value="demand.rou.xml"/>'
        '</input><time><begin value="0"/><step-length value="0.2"/></time>'
        '<processing><lateral-resolution value="0.8"/></processing></configuration>'
    )
    return cfg


def sumo_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a process has used, from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        return int(s.getsockname()[1])


def child(mode: str, cfg: Path, cars: int, steps: int) -> dict[str, float]:
    """One timed run in this (fresh) process."""
    import torch

    from behaviors.learn.traffic_env import VTYPES
    from behaviors.run.populate import joinable
    from behaviors.run.populate_config import config_from
    from behaviors.run.population import Population
    from behaviors.run.precision import POLICY_THREADS
    from behaviors.sumo.joined import JoinedSim
    from behaviors.sumo.scenario_config import read_sumocfg, unrandom
    from behaviors.sumo.sim import COLLISION_OPTIONS
    from behaviors.sumo.sumo_home import sumo_binary
    from behaviors.sumo.traci_connection import Address

    torch.set_num_threads(POLICY_THREADS)
    sumo = None
    if mode == "libsumo":
        population = Population(config_from(cfg, share=1.0, seed=0))
        population.start(None)
    else:
        port = free_port()
        command = [sumo_binary("sumo"), "-c", str(cfg), "--remote-port", str(port), "--num-clients", "1",
                   "--additional-files", str(VTYPES), "--seed", "0", "--step-method.ballistic", "false",
                   "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true",
                   *COLLISION_OPTIONS, *unrandom(read_sumocfg(cfg))]  # fmt: skip
        sumo = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        sim = JoinedSim(Address("localhost", port), 1)
        config = joinable(sim, config_from(None, connect=f"localhost:{port}", share=1.0, seed=0), None)
        population = Population(config, joined=sim)
        sim.check_net(population.geometry.edges)
        population.start(None)
    try:
        for _ in range(50):  # every car departs at once (they all fit): all agents after a step or two
            population.step()
            if population.summary.scenario_agents >= cars:
                break
        for _ in range(WARMUP_STEPS):
            population.step()
        agents = len(population.fleet)
        sumo_before = sumo_cpu_s(sumo.pid) if sumo is not None else 0.0
        cpu, start = time.process_time(), time.perf_counter()
        for _ in range(steps):
            population.step()
        wall = time.perf_counter() - start
        cpu = time.process_time() - cpu
        sumo_cpu = sumo_cpu_s(sumo.pid) - sumo_before if sumo is not None else 0.0
    finally:
        population.close()
        if sumo is not None:
            sumo.wait(timeout=60)
    return {
        "agents": agents, "wall_ms": 1e3 * wall / steps, "behave_cpu_ms": 1e3 * cpu / steps,
        "sumo_cpu_ms": 1e3 * sumo_cpu / steps, "cpu_ms": 1e3 * (cpu + sumo_cpu) / steps,
    }  # fmt: skip


def run_child(mode: str, cfg: Path, cars: int, steps: int) -> dict[str, float]:
    out = subprocess.run(
        [sys.executable, __file__, "--child", mode, str(cfg), str(cars), str(steps)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if out.returncode != 0:
        raise SystemExit(f"{mode} run with {cars} cars failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rows", default="100,1000", help="agent counts, comma-separated")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--csv", type=Path, default=None)
    parser.add_argument("--child", nargs=4, metavar=("MODE", "CFG", "CARS", "STEPS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        mode, cfg, cars, steps = args.child
        print(json.dumps(child(mode, Path(cfg), int(cars), int(steps))))
        return
    console = Console()
    rows, csv_rows = [], []
    load = []
    with tempfile.TemporaryDirectory(prefix="bench-connect-") as tmp:
        for cars in (int(n) for n in args.rows.split(",")):
            folder = Path(tmp) / f"n{cars}"
            folder.mkdir()
            cfg = build(folder, cars)
            runs: dict[str, list[dict[str, float]]] = {"libsumo": [], "connect": []}
            for r in range(args.rounds):
                for mode in ("libsumo", "connect") if r % 2 == 0 else ("connect", "libsumo"):
                    load.append(os.getloadavg()[0])
                    result = run_child(mode, cfg, cars, args.steps)
                    runs[mode].append(result)
                    said = f"{result['wall_ms']:.2f} ms/step, {result['cpu_ms']:.2f} CPU ms/step"
                    console.print(f"[dim]{cars} cars, round {r + 1}, {mode}: {said}[/dim]")
            med = {
                mode: {k: statistics.median(x[k] for x in res) for k in res[0]} for mode, res in runs.items()
            }
            lib, con = med["libsumo"], med["connect"]
            row = [
                f"{round(lib['agents']):,}", f"{lib['wall_ms']:.2f}", f"{con['wall_ms']:.2f}",
                f"{con['wall_ms'] / lib['wall_ms']:.2f}", f"{lib['cpu_ms']:.2f}",
                f"{con['behave_cpu_ms']:.2f} + {con['sumo_cpu_ms']:.2f}",
                f"{con['cpu_ms'] / lib['cpu_ms']:.2f}",
            ]  # fmt: skip
            rows.append(row)
            values = (lib["wall_ms"], con["wall_ms"], lib["cpu_ms"], con["behave_cpu_ms"], con["sumo_cpu_ms"])
            csv_rows.append([str(round(lib["agents"])), *(f"{v:.3f}" for v in values)])
    header = ["agents", "libsumo ms/step", "--connect ms/step", "ratio", "libsumo CPU ms/step",
              "--connect CPU ms/step (behave + SUMO)", "CPU ratio"]  # fmt: skip
    title = f"--connect against libsumo (median of {args.rounds} rounds, {args.steps} steps)"
    print_table(console, title, header, rows)
    console.print(
        f"load average (1 min) at the runs' starts: {min(load):.1f}-{max(load):.1f} on {os.cpu_count()} CPUs"
    )
    first = rows[0]
    if first[0] == "100":
        met = float(first[3]) <= TARGET_RATIO_100
        console.print(
            f"aim <= {TARGET_RATIO_100:g}x libsumo at 100 agents (wall): {'met' if met else 'missed'}"
        )
    if args.csv is not None:
        write_csv(args.csv, ["agents", "libsumo_wall_ms", "connect_wall_ms", "libsumo_cpu_ms",
                             "connect_behave_cpu_ms", "connect_sumo_cpu_ms"], csv_rows)  # fmt: skip


if __name__ == "__main__":
    main()
