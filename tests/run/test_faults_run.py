"""Faults during a run: SUMO failing mid-run, a Ray worker dying mid-sweep, a full
disk during a sweep. Real SUMO, real Ray workers killed by signal, a real (tmpfs) full disk.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from helpers import BEHAVE, behave

from behaviors.report.agents_table import agents_path
from behaviors.report.fcd_read import read_fcd, validate_fcd_xml
from behaviors.run.populate import PopulateStopped, populate
from behaviors.run.populate_config import PopulateConfig
from behaviors.run.sweep import FAILED, OK, Point, RunResult, disk_full_error, failed_row, gather, keep_result
from behaviors.sumo.fcd_parquet import METADATA_KEY

BAD_AT_10 = (
    '<routes><vehicle id="ghost" depart="10" departLane="0" departSpeed="1000">'
    '<route edges="e0 e1"/></vehicle></routes>'
)
"""A vehicle SUMO refuses when it inserts it, at t=10 s: "Departure speed ... is too high"."""
SMALL = ("--keepers", "2", "--overtakers", "2", "--background", "6")


def one_error_line(stderr: str) -> str:
    """The one error line, last on stderr (progress lines may come before it), no traceback."""
    lines = stderr.strip().splitlines()
    errors = [line for line in lines if line.startswith("behave: error: ")]
    assert errors == lines[-1:] and "Traceback" not in stderr, stderr
    return lines[-1]


def hidden(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.rglob(".*"))


# a. SUMO failing mid-run ----------------------------------------------------------------------


@pytest.mark.sumo
@pytest.mark.parametrize("suffix", [".xml", ".csv", ".parquet"])
def test_sumo_failing_mid_run_leaves_a_whole_fcd_cut_short_and_one_line(tmp_path: Path, suffix: str):
    routes = tmp_path / "bad.rou.xml"
    routes.write_text(BAD_AT_10)
    fcd = tmp_path / f"run{suffix}"
    done = behave("populate", *SMALL, "--duration", "30", "--routes", str(routes), "--fcd", str(fcd))
    assert done.returncode == 2
    line = one_error_line(done.stderr)
    assert line.startswith("behave: error: SUMO stopped: Departure speed for vehicle 'ghost' is too high")
    assert line.endswith(f"{fcd} and its agents table hold the run up to t=9.8 s (cut short)")
    df = read_fcd(fcd)  # whole: it parses to its end
    assert df["time"].min() == 0 and df["time"].max() == pytest.approx(9.8) and df["id"].nunique() >= 10
    assert agents_path(fcd).is_file() and hidden(tmp_path) == []
    if suffix == ".xml":
        validate_fcd_xml(fcd)
        assert "cut-short-after=10 -->" in fcd.read_text()[:1000]
    if suffix == ".parquet":
        assert pq.ParquetFile(fcd).metadata.metadata[METADATA_KEY].endswith(b" cut-short-after=10")


@pytest.mark.sumo
@pytest.mark.parametrize("suffix", [".xml", ".parquet"])
def test_a_simulation_closed_under_the_run_keeps_what_was_simulated(tmp_path: Path, suffix: str):
    """libsumo closed from outside at t=5 s: every call into it fails (libsumo's FatalTraCIError)."""
    import libsumo

    def close_at_5(simulated_s: float) -> None:
        if abs(simulated_s - 5.0) < 1e-6:
            libsumo.close()

    fcd = tmp_path / f"run{suffix}"
    config = PopulateConfig(keepers=2, overtakers=2, background=6, duration=20.0, fcd=fcd)
    with pytest.raises(PopulateStopped, match=r"^SUMO stopped: .*hold the run up to t=4\.8 s \(cut short\)$"):
        populate(config, on_step=close_at_5)
    assert read_fcd(fcd)["time"].max() == pytest.approx(4.8) and agents_path(fcd).is_file()


# b. a Ray worker dying mid-sweep --------------------------------------------------------------


def descendants_titled(root: int, title: bytes) -> list[int]:
    """Processes below `root` whose command line (Ray's worker title) starts with `title`."""
    parents, titles = {}, {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
                titles[int(entry)] = Path(f"/proc/{entry}/cmdline").read_bytes()
            except OSError:
                continue
            parents[int(entry)] = int(stat.rsplit(")", 1)[1].split()[1])

    def below(pid: int) -> bool:
        while pid > 1:
            pid = parents.get(pid, 0)
            if pid == root:
                return True
        return False

    return [pid for pid, text in titles.items() if text.startswith(title) and below(pid)]


SWEEP = ("sweep", "--net", "highway", "--overtakers", "1", "--keepers", "1", "--background", "4",
         "--seeds", "0,1,2", "--duration", "30", "--workers", "1")  # fmt: skip


@pytest.mark.sumo
def test_a_worker_killed_mid_sweep_loses_only_its_run_and_a_rerun_picks_it_up(tmp_path: Path):
    pytest.importorskip("ray", reason="ray is not installed (the distributed extra)")
    out = tmp_path / "sweep"
    sweep = subprocess.Popen([*BEHAVE, *SWEEP, "--out", str(out)], stderr=subprocess.PIPE, text=True)
    killed: list[int] = []
    deadline = time.monotonic() + 240
    while not killed and sweep.poll() is None and time.monotonic() < deadline:
        if len(list((out / "runs").glob("*.json"))) == 1:  # the first run done: kill the second's worker
            workers = descendants_titled(sweep.pid, b"ray::run_point")
            for pid in workers[:1]:
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
        time.sleep(0.2)
    _, stderr = sweep.communicate(timeout=300)
    assert killed, stderr
    assert sweep.returncode == 1 and "behave: 1 of 3 runs failed" in stderr and "Traceback" not in stderr
    table = gather(out)
    assert sorted(table["status"]) == [FAILED, OK, OK]
    lost = table[table["status"] == FAILED].iloc[0]
    assert "died" in lost["error"] or "crash" in lost["error"].lower(), lost["error"]
    again = behave(*SWEEP, "--out", str(out), timeout=300)
    assert again.returncode == 0, again.stderr
    assert "3 runs: 2 finished before, 1 to run on 1 workers" in again.stderr
    assert list(gather(out)["status"]) == [OK, OK, OK]


# c. a full disk during a sweep ----------------------------------------------------------------


@pytest.fixture
def small_disk(tmpfs: Callable[[int], Path]) -> Path:
    """A 160 kB file system of its own."""
    return tmpfs(160)


@pytest.mark.sumo
def test_a_full_disk_stops_a_sweep_cleanly_and_a_rerun_finishes_it(small_disk: Path):
    """The sweep folder on a disk that holds one run's kept FCD (~90 kB) and not two."""
    pytest.importorskip("ray", reason="ray is not installed (the distributed extra)")
    out = small_disk / "sweep"
    done = behave(*SWEEP, "--keep-fcd", "--out", str(out), timeout=600)
    assert done.returncode == 2
    line = one_error_line(done.stderr)
    assert "disk full, the sweep stopped" in line and "No space left on device" in line
    assert line.endswith(
        "1 of 3 runs finished, their rows kept in "
        f"{out / 'runs'}; make room and run the same sweep again for the other 2"
    )
    (row,) = (out / "runs").glob("*.json")
    kept = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    assert kept == {f"runs/{row.name}", f"fcd/{row.stem}.csv", f"fcd/{row.stem}.agents.csv"}  # nothing half
    subprocess.run(["mount", "-o", "remount,size=4m", str(small_disk)], check=True)  # room made
    again = behave(*SWEEP, "--keep-fcd", "--out", str(out), timeout=600)
    assert again.returncode == 0, again.stderr
    assert "3 runs: 1 finished before, 2 to run on 1 workers" in again.stderr
    assert list(gather(out)["status"]) == [OK, OK, OK]


def test_a_run_failed_for_a_full_disk_stops_the_sweep(tmp_path: Path):
    """A run whose own files hit a full disk (its FCD on the worker) fails with that error: the sweep
    keeps its failed row and stops instead of failing every other point the same way."""
    point = Point(str(tmp_path / "n.net.xml"), "net", "traffic", 0.0, 0, 1, 1, 4)
    error = "SUMO's FCD output was cut short, fcd.csv not written (disk full?): CSV ends mid-row"
    assert keep_result(tmp_path, RunResult(failed_row(point, error))) == error
    assert gather(tmp_path)["status"].tolist() == [FAILED]
    assert keep_result(tmp_path, RunResult(failed_row(point, "SUMO stopped: unknown edge"))) is None
    assert disk_full_error("cannot write x: No space left on device") and not disk_full_error("bad edge")
