"""`behave sweep`: a grid of populate runs on Ray, one row per run, resumable.

One sweep (share {0, 0.25, 0.5} x seeds {0, 1} on a user's sumocfg, 2 workers) is shared by the
tests: before it, one point is run alone (its row written as a finished run's) and another is left
as a failed run, as a sweep killed half-way leaves them; the sweep must run only the other points.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pytest

from behaviors.report.fcd_read import fcd_options
from behaviors.run.sweep import (
    FAILED,
    OK,
    WALL_COLUMNS,
    Grid,
    Point,
    SweepResult,
    check_grid,
    compared,
    expand,
    failed_row,
    finished,
    gather,
    row_path,
    run_point,
    run_sweep,
    save_files,
    write_row,
)
from behaviors.run.sweep_figures import fcd_figures, flow_figures
from behaviors.sumo.sim import COLLISION_OPTIONS
from behaviors.sumo.sumo_home import sumo_binary
from sumo_scenarios.osm_like import Demand, build_osm_like

pytest.importorskip("ray", reason="ray is not installed (the distributed extra)")

SHARES = (0.0, 0.25, 0.5)
SEEDS = (0, 1)
STEP = 0.2  # populate's step where the sumocfg sets none
DEMAND = Demand(end=62.0, scale=1.0, sigma=0.5)  # one whole 60 s window: `report`'s flow summary


def differences(a: dict, b: dict) -> dict:
    """Where two rows differ (nan equal to nan), wall-clock columns left out: {column: (a's, b's)}."""
    a, b = compared(a), compared(b)
    keys = sorted(a.keys() | b.keys())
    return {
        k: (a.get(k, "missing"), b.get(k, "missing"))
        for k in keys
        if k not in a or k not in b or not (a[k] == b[k] or (pd.isna(a[k]) and pd.isna(b[k])))
    }


@pytest.fixture(scope="module")
def scenario(tmp_path_factory) -> Path:
    return build_osm_like("motorway3", tmp_path_factory.mktemp("net"), DEMAND).sumocfg.resolve()


@dataclass(frozen=True)
class Swept:
    result: SweepResult  # of the sweep that finished the grid
    out: Path
    alone: dict  # the row of the point run alone before the sweep
    killed: subprocess.CompletedProcess  # the `behave sweep` stopped by SIGTERM half-way
    before: set[str]  # the points finished when the sweep started again


def sweep_killed_half_way(scenario: Path, out: Path, points: list[Point]) -> subprocess.CompletedProcess:
    """`behave sweep` of the grid, sent SIGTERM once it has finished one run of its own."""
    args = [
        sys.executable,
        "-m",
        "behaviors.cli",
        "sweep",
        "--sumocfg",
        str(scenario),
        "--share",
        ",".join(map(str, SHARES)),
        "--seeds",
        ",".join(map(str, SEEDS)),
        "--workers",
        "2",
        "--out",
        str(out),
    ]
    process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    deadline = time.monotonic() + 120
    while len(finished(out, points)) < 2 and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    process.send_signal(signal.SIGTERM)
    stdout, stderr = process.communicate(timeout=60)
    return subprocess.CompletedProcess(args, process.returncode, stdout, stderr)


@pytest.fixture(scope="module")
def swept(scenario, tmp_path_factory) -> Swept:
    """The shared sweep: one point run alone and one failed run in its folder, then `behave sweep`
    killed half-way, then the sweep started again."""
    out = tmp_path_factory.mktemp("sweep")
    points = check_grid(Grid(sumocfgs=(str(scenario),), shares=SHARES, seeds=SEEDS))
    alone = run_point(points[3])  # share 0.25, seed 1
    write_row(out, alone.row)
    write_row(out, failed_row(points[4], "SUMO crashed"))  # share 0.5, seed 0
    killed = sweep_killed_half_way(scenario, out, points)
    before = finished(out, points)
    return Swept(run_sweep(points, out, workers=2), out, alone.row, killed, before)


@pytest.mark.sumo
def test_the_grid_is_every_combination_once_in_a_fixed_order(scenario):
    grid = Grid(
        sumocfgs=(str(scenario), str(scenario)), shares=(0.5, 0.0, 0.5), seeds=(1, 0), policies=("a", "b")
    )
    points = expand(grid)
    assert len(points) == 2 * 2 * 2
    assert [(p.policy, p.share, p.seed) for p in points[:4]] == [("a", 0.5, 1), ("a", 0.5, 0), ("a", 0.0, 1),
                                                                   ("a", 0.0, 0)]  # fmt: skip
    assert len({p.id for p in points}) == len(points)
    assert points[0].id == expand(grid)[0].id  # the id is the settings', nothing else
    nets = expand(Grid(nets=("n.net.xml",), overtakers=(0, 2), keepers=(4,), seeds=(0,)))
    assert [(p.overtakers, p.keepers, p.background, p.kind) for p in nets] == [
        (0, 4, 20, "net"),
        (2, 4, 20, "net"),
    ]


def test_flow_figures_per_group_from_a_small_fcd():
    """Two SUMO cars and an agent over 4 steps of 1 s: car a leaves after 2 records, b stops once."""
    rows = [  # time, id, type, speed
        (0, "a", "car", 10), (1, "a", "car", 10),
        (0, "b", "car", 5), (1, "b", "car", 0), (2, "b", "car", 0), (3, "b", "car", 4),
        (1, "k", "behave_keeper@k", 20), (2, "k", "behave_keeper", 20), (3, "k", "behave_keeper", 20),
    ]  # fmt: skip
    figures = flow_figures(pd.DataFrame(rows, columns=["time", "id", "type", "speed"]))
    assert figures["sumo_vehicles"] == 2 and figures["agents_vehicles"] == 1 and figures["all_vehicles"] == 3
    assert figures["sumo_left"] == 1 and figures["sumo_travel_time_mean_s"] == 2.0  # a: 0 to 1, plus a step
    assert figures["sumo_throughput_per_h"] == 1 / 4 * 3600  # one car left in 4 s
    assert figures["sumo_stops_per_vehicle"] == 0.5 and figures["agents_stops_per_vehicle"] == 0
    assert figures["sumo_mean_speed"] == 29 / 6 and figures["agents_mean_speed"] == 20
    assert figures["all_vehicle_km"] == (29 + 60) / 1000
    assert figures["agents_share_of_vehicles"] == 1 / 3


@pytest.mark.sumo
def test_a_sweep_of_3_shares_by_2_seeds_on_2_workers_ends_with_6_rows(swept):
    result, out = swept.result, swept.out
    table = result.table
    assert len(table) == 6 and (table["status"] == OK).all(), table[["id", "status", "error"]]
    assert sorted(zip(table["share"], table["seed"], strict=True)) == [(s, k) for s in SHARES for k in SEEDS]
    for name in ("sweep.csv", "sweep.parquet", "sweep.png"):
        assert (out / name).stat().st_size > 0
    pd.testing.assert_frame_equal(pd.read_parquet(out / "sweep.parquet"), table)
    assert len(pd.read_csv(out / "sweep.csv")) == 6
    assert list(table.columns[-len(WALL_COLUMNS) :]) == list(WALL_COLUMNS)
    agents = table.set_index("share")["of_them_agents"]
    assert (agents[0.0] == 0).all() and (agents[0.5] > 0).all()
    columns = {"realism_sumo_thw_median", "realism_keepers_lane_changes_per_km", "sumo_mean_speed",
               "edie_all_flow", "edie_sumo_density", "edie_keepers_max_flow"}  # fmt: skip
    assert columns <= set(table)
    # no FCD unless asked: only rows and the table are left, no temp files
    assert sorted(p.name for p in out.iterdir()) == ["runs", "sweep.csv", "sweep.parquet", "sweep.png"]
    assert len(list((out / "runs").iterdir())) == 6


@pytest.mark.sumo
def test_a_killed_sweep_started_again_runs_only_the_missing_points(swept):
    killed, result, out = swept.killed, swept.result, swept.out
    assert killed.returncode == 143, killed.stderr
    assert killed.stderr.splitlines()[-1] == "behave: error: terminated; nothing was left half-written"
    assert "sweep: 6 runs: 1 finished before, 5 to run on 2 workers" in killed.stderr  # the failed one again
    assert 2 <= len(swept.before) < 6
    assert (result.skipped, result.ran, result.failed) == (len(swept.before), 6 - len(swept.before), 0)
    kept = json.loads(row_path(out, swept.alone["id"]).read_text())
    assert kept["wall_s"] == swept.alone["wall_s"]  # the finished run's row was not run again
    assert sorted(p.name for p in (out / "runs").iterdir()) == sorted(f"{i}.json" for i in result.table["id"])
    points = expand(Grid(sumocfgs=(kept["scenario_path"],), shares=SHARES, seeds=SEEDS))
    again = run_sweep(points, out, workers=2)  # nothing left: no Ray is started
    assert (again.ran, again.skipped) == (0, 6)
    quiet = subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "sweep", "--sumocfg", kept["scenario_path"], "--share",
         ",".join(map(str, SHARES)), "--seeds", ",".join(map(str, SEEDS)), "--out", str(out), "-q"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert (quiet.returncode, quiet.stdout, quiet.stderr) == (0, "", "")


@pytest.mark.sumo
def test_the_share_0_rows_are_a_plain_sumo_runs_figures(swept, scenario, tmp_path):
    table = swept.result.table
    for seed in SEEDS:
        fcd = tmp_path / f"plain{seed}.csv"
        subprocess.run(
            [sumo_binary("sumo"), "-c", str(scenario), "--seed", str(seed), "--step-length", str(STEP),
             "--lateral-resolution", "0.8", "--no-step-log", "true", *COLLISION_OPTIONS,
             *fcd_options(fcd, geo=False)],
            check=True, capture_output=True,
        )  # fmt: skip
        plain = fcd_figures(fcd, Path(str(scenario).replace(".sumocfg", ".net.xml")))
        row = table[(table["share"] == 0.0) & (table["seed"] == seed)].iloc[0].to_dict()
        assert plain["sumo_vehicles"] > 10 and row["agent_steps"] == 0 and row["collisions"] == 0
        assert not differences({k: row[k] for k in plain}, plain)


@pytest.mark.sumo
def test_a_point_run_alone_gives_the_row_it_got_on_a_worker(swept, tmp_path):
    table = swept.result.table
    row = table[(table["share"] == 0.5) & (table["seed"] == 1)].iloc[0]
    point = Point(row["scenario_path"], "sumocfg", "traffic", 0.5, 1, 0, 0, 0)
    assert point.id == row["id"]
    alone = run_point(point, keep_fcd=True)
    stored = json.loads(json.dumps(alone.row))  # through JSON, as the sweep stores its rows
    assert not differences(stored, {k: row[k] for k in stored})
    assert row.drop(list(stored)).isna().all()  # the table's other columns are other rows' (none here)
    # and `behave populate` of the same point writes the FCD those figures came from
    fcd = tmp_path / "populate.csv"
    subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "populate", "--sumocfg", row["scenario_path"],
         "--share", "0.5", "--seed", "1", "--fcd", str(fcd)],
        check=True, capture_output=True, env=os.environ | {"COLUMNS": "200"},
    )  # fmt: skip
    assert fcd.read_bytes() == alone.fcd
    figures = fcd_figures(fcd, Path(row["scenario_path"].replace(".sumocfg", ".net.xml")))
    assert not differences(figures, {k: row[k] for k in figures})
    save_files(tmp_path / "kept", alone)  # --keep-fcd: the run's FCD and agents table in fcd/
    kept = sorted(p.name for p in (tmp_path / "kept" / "fcd").iterdir())
    assert kept == [f"{point.id}.agents.csv", f"{point.id}.csv"]


@pytest.mark.sumo
def test_a_failed_run_is_a_row_with_its_error_and_the_others_go_on(scenario, tmp_path):
    """Through the command line: one scenario SUMO cannot load beside a good one."""
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "demand.rou.xml").write_text(
        '<routes><vehicle id="v" depart="0"><route edges="nowhere"/></vehicle></routes>'
    )
    cfg = bad / "bad.sumocfg"
    cfg.write_text(
        f'<configuration><input><net-file value="{str(scenario).replace(".sumocfg", ".net.xml")}"/>'
        '<route-files value="demand.rou.xml"/></input><time><end value="20"/></time></configuration>'
    )
    out = tmp_path / "sweep"
    result = subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "sweep", "--sumocfg", str(scenario), "--sumocfg", str(cfg),
         "--share", "0.25", "--duration", "15", "--workers", "2", "--out", str(out), "--keep-fcd"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert result.returncode == 1, result.stderr
    assert "1 of 2 runs failed" in result.stderr and "Traceback" not in result.stderr
    table = gather(out)
    assert list(table["status"]) == [FAILED, OK]  # sorted by scenario: bad.sumocfg first
    assert "nowhere" in table["error"].iloc[0] and f"{table['id'].iloc[0]}: failed: " in result.stderr
    assert len(list((out / "fcd").glob("*.agents.csv"))) == 1  # --keep-fcd keeps the finished run's FCD


@pytest.mark.sumo
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--share", "0,1.5"], "--share must be a finite number >= 0 and <= 1"),
        (["--seeds", "0,x"], "--seeds must be a comma-separated list of integers"),
        (["--seeds", "-1"], "--seeds must be a finite number >= 0"),
        (["--workers", "0"], "--workers must be a finite number >= 1"),
        (["--policy", "nothing-like-it"], "nothing-like-it"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(scenario, tmp_path, args, message):
    result = subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "sweep", "--sumocfg", str(scenario), *args, "--out",
         str(tmp_path / "out")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("behave: error: ") and message in lines[0], lines
    assert not (tmp_path / "out").exists()


@pytest.mark.sumo
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--sumocfg", "missing.sumocfg"], "sumocfg not found: missing.sumocfg"),
        (
            ["--net", "highway", "--share", "0.5"],
            "--share converts a scenario's own cars: it needs --sumocfg",
        ),
        ([], "nothing to sweep: give --sumocfg or --net"),
        (["--net", "nowhere"], "net not found: nowhere"),
    ],
)
def test_bad_scenarios_are_one_line_and_exit_2(tmp_path, args, message):
    result = subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "sweep", *args], capture_output=True, text=True, cwd=tmp_path
    )
    assert result.returncode == 2 and result.stderr.startswith(f"behave: error: {message}"), result.stderr
    assert result.stderr.count("\n") == 1


def test_help_loads_nothing_heavy():
    probe = (
        "import sys\nfrom behaviors.cli.main import main\nsys.argv = ['behave', 'sweep', '--help']\n"
        "try:\n    main()\nexcept SystemExit:\n    pass\n"
        "print(*(m for m in ('torch', 'pandas', 'matplotlib', 'libsumo', 'ray') if m in sys.modules))\n"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert "Usage: behave sweep" in result.stdout and result.stdout.splitlines()[-1] == ""
