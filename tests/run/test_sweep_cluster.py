"""`behave sweep --ray-address` on a two-node Ray cluster on this machine, set up as
docs/manual/cli.md's recipe says (token authentication: `ray get-auth-token --generate`, RAY_AUTH_MODE
and the token on every node and on the driver): the runs read only the files the sweep sends them, and
a node that leaves mid-sweep costs only its runs, which the same command runs again.

Each node is a `ray start` in a session of its own with its own temporary folder; killing the session's
process group ends the node (and is the teardown): no `ray stop`, which would end every Ray on the
machine.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from helpers import BEHAVE, behave

from behaviors.run.sweep import FAILED, OK, Grid, check_grid, compared, gather, read_row, row_path, run_point
from sumo_scenarios.osm_like import Demand, build_osm_like

pytest.importorskip("ray", reason="ray is not installed (the distributed extra)")

RAY = str(Path(sys.executable).parent / "ray")
DETECTOR = (
    '<additional><inductionLoop id="loop" lane="exit_0" pos="5" period="10" file="out/loop.xml"/>'
    "</additional>"
)
SWEEP = ("sweep", "--share", "0.5", "--duration", "20")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass
class Cluster:
    """A head and a worker node on this machine, with the environment a driver needs to join them."""

    folder: Path
    env: dict[str, str]
    address: str = ""
    groups: dict[str, int] = field(default_factory=dict)  # node -> its `ray start`'s process group

    def start(self, node: str, cpus: int, *args: str) -> None:
        ports = ("--node-manager-port", "--object-manager-port", "--dashboard-agent-listen-port",
                 "--dashboard-agent-grpc-port", "--runtime-env-agent-port",
                 "--metrics-export-port")  # fmt: skip
        options = [f"{name}={free_port()}" for name in ports]
        command = [RAY, "start", *args, f"--num-cpus={cpus}", f"--temp-dir={self.folder / node}",
                   "--node-ip-address=127.0.0.1", "--disable-usage-stats", *options]  # fmt: skip
        started = subprocess.Popen(command, env=self.env, start_new_session=True, stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, text=True)  # fmt: skip
        self.groups[node] = started.pid
        output, _ = started.communicate(timeout=120)
        assert started.returncode == 0, output

    def kill(self, node: str) -> None:
        """The node's every process, at once (a machine that fails)."""
        with contextlib.suppress(ProcessLookupError, KeyError):
            os.killpg(self.groups.pop(node), signal.SIGKILL)

    def processes(self, node: str, title: bytes) -> list[int]:
        """The node's processes (its `ray start`'s group and theirs below) whose command line (a Ray
        worker's title) starts with `title`."""
        parents, groups, titles = {}, {}, {}
        for entry in filter(str.isdigit, os.listdir("/proc")):
            try:
                stat = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
                titles[int(entry)] = Path(f"/proc/{entry}/cmdline").read_bytes()
            except (OSError, IndexError):
                continue
            parents[int(entry)], groups[int(entry)] = int(stat[1]), int(stat[2])

        def on_node(pid: int) -> bool:
            while pid > 1:
                if groups.get(pid) == self.groups.get(node):
                    return True
                pid = parents.get(pid, 0)
            return False

        return [pid for pid, text in titles.items() if text.startswith(title) and on_node(pid)]


@pytest.fixture
def cluster(request) -> Iterator[Cluster]:
    """A two-node cluster with token authentication: the head with `head_cpus` CPUs (0: runs go to the
    worker node only), the worker node with one; both torn down whatever the test did."""
    head_cpus = getattr(request, "param", 0)
    folder = Path(tempfile.mkdtemp(prefix="rc", dir="/tmp"))  # short: Ray's socket paths must fit
    generated = subprocess.run([RAY, "get-auth-token", "--generate"], env=os.environ | {"HOME": str(folder)},
                               capture_output=True, text=True, check=True)  # fmt: skip
    token = folder / ".ray" / "auth_token"
    assert token.read_text().strip() == generated.stdout.strip()
    env = os.environ | {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(token)}
    env.pop("RAY_AUTH_TOKEN", None)
    made = Cluster(folder, env)
    try:
        port = free_port()
        made.start("head", head_cpus, "--head", f"--port={port}", "--include-dashboard=false",
                   f"--dashboard-port={free_port()}", f"--ray-client-server-port={free_port()}")  # fmt: skip
        made.address = f"127.0.0.1:{port}"
        made.start("worker", 1, f"--address={made.address}")
        yield made
    finally:
        for node in list(made.groups):
            made.kill(node)
        shutil.rmtree(folder, ignore_errors=True)


def scenario(folder: Path) -> tuple[Path, list[Path]]:
    """A sumocfg in `folder`/scenario/cfg that names its net by a relative path out of its folder, its
    routes by an absolute path, an additional (a detector writing out/loop.xml) beside it and a summary
    output; and the folders that hold its files."""
    net = build_osm_like("motorway3", folder / "shared", Demand(end=62.0, scale=1.0, sigma=0.5))
    cfg = folder / "scenario" / "cfg"
    cfg.mkdir(parents=True)
    (cfg / "loop.add.xml").write_text(DETECTOR)
    sumocfg = cfg / "cluster.sumocfg"
    sumocfg.write_text(
        f'<configuration><input><net-file value="../../shared/{net.net.name}"/>'
        f'<route-files value="{net.routes}"/><additional-files value="loop.add.xml"/></input>'
        '<output><summary-output value="summary.xml"/></output></configuration>'
    )
    return sumocfg, [folder / "shared", folder / "scenario"]


def sweep_lines(args: list[str], env: dict[str, str], on_line, timeout: float = 300) -> tuple[int, list[str]]:
    """`behave sweep ARGS`, `on_line(line)` called with each line of its stderr as it comes; its exit
    code and stderr lines."""
    process = subprocess.Popen([*BEHAVE, *args], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                               text=True)  # fmt: skip
    lines: queue.Queue[str | None] = queue.Queue()
    threading.Thread(target=lambda: [*map(lines.put, process.stderr), lines.put(None)], daemon=True).start()  # type: ignore[arg-type]
    seen, deadline = [], time.monotonic() + timeout
    try:
        while (line := lines.get(timeout=max(deadline - time.monotonic(), 0.1))) is not None:
            seen.append(line.rstrip("\n"))
            on_line(seen[-1])
        return process.wait(timeout=60), seen
    finally:
        if process.poll() is None:
            process.kill()


def as_text(row: dict) -> str:
    """A row without its wall-clock columns, as the sweep stores it (nan equal to nan)."""
    return json.dumps(compared(json.loads(json.dumps(row))), sort_keys=True)


@pytest.mark.sumo
def test_a_sweep_on_two_nodes_reads_only_the_files_it_sends(cluster: Cluster, tmp_path: Path) -> None:
    """A driver without the cluster's token is refused in one line. Runs go to the worker node only (the
    head has no CPU); the scenario's folders are deleted once the sweep has packed them, before any run
    starts: the rows come from the files sent alone, and are the rows a run here gives."""
    sumocfg, folders = scenario(tmp_path)
    out = tmp_path / "sweep"
    deleted: list[int] = []  # rows written when the scenario went

    def delete_once_sent(line: str) -> None:
        if "to run on" in line and not deleted:
            deleted.append(len(list((out / "runs").glob("*.json"))))
            for folder in folders:
                shutil.rmtree(folder)

    args = [*SWEEP, "--sumocfg", str(sumocfg), "--seeds", "0,1", "--ray-address", cluster.address,
            "--out", str(out)]  # fmt: skip
    grid = Grid(sumocfgs=(str(sumocfg.resolve()),), shares=(0.5,), seeds=(0, 1), duration=20.0)
    alone = run_point(check_grid(grid)[1])  # seed 1, here, from the scenario's own folder
    start = time.monotonic()
    refused = behave(*args, env=cluster.env | {"RAY_AUTH_TOKEN": "not-the-token"}, timeout=120)
    print(f"a wrong token refused in {time.monotonic() - start:.0f} s")
    (line,) = [line for line in refused.stderr.splitlines() if not line.startswith("sweep: note: ")]
    assert refused.returncode == 2 and "Traceback" not in refused.stderr, refused.stderr
    assert line.startswith(f"behave: error: cannot start or join Ray at {cluster.address}: ")
    assert "(the cluster refused the token: a cluster started with RAY_AUTH_MODE=token" in line
    assert not list(out.rglob("*.json"))
    start = time.monotonic()
    code, stderr = sweep_lines(args, cluster.env, delete_once_sent)
    print(f"two-node sweep of 2 runs: {time.monotonic() - start:.0f} s")
    assert deleted == [0] and not any(folder.exists() for folder in folders), stderr
    assert code == 0 and not any("Traceback" in line for line in stderr), stderr
    assert any(line.startswith("sweep: sending each run its files: 4 files") for line in stderr), stderr
    table = gather(out)
    assert len(table) == 2 and list(table["status"]) == [OK, OK], table[["id", "status", "error"]]
    assert set(table["scenario_path"]) == {str(sumocfg.resolve())} and (table["of_them_agents"] > 0).all()
    shipped = read_row(row_path(out, alone.row["id"]))
    assert shipped is not None and as_text(shipped) == as_text(alone.row)  # the same row as here
    for point in table["id"]:  # the scenario's own outputs, at their places relative to its sumocfg
        assert {p.name for p in (out / "outputs" / point).rglob("*.xml")} == {"summary.xml", "loop.xml"}
        assert (out / "outputs" / point / "out" / "loop.xml").stat().st_size > 0


@pytest.mark.sumo
@pytest.mark.parametrize("cluster", [1], indirect=True)
def test_a_node_lost_mid_sweep_costs_its_runs_only_and_a_rerun_runs_them(cluster: Cluster) -> None:
    """The worker node killed as soon as a run starts on it: the head finishes the others, one line
    names the lost run, and the same command again (the head alone) runs it."""
    args = [*SWEEP[:1], "--net", "tiny", "--overtakers", "1", "--keepers", "1", "--background", "4",
            "--duration", "20", "--seeds", "0,1,2", "--workers", "2", "--ray-address", cluster.address,
            "--out", str(cluster.folder / "sweep")]  # fmt: skip
    killed: list[int] = []

    def kill_when_a_run_starts_there(line: str) -> None:
        deadline = time.monotonic() + 60
        while "to run on" in line and not killed and time.monotonic() < deadline:
            if cluster.processes("worker", b"ray::run_shipped"):
                killed.append(cluster.groups["worker"])
                cluster.kill("worker")
            time.sleep(0.1)

    start = time.monotonic()
    code, stderr = sweep_lines(args, cluster.env, kill_when_a_run_starts_there)
    print(f"sweep losing a node: {time.monotonic() - start:.0f} s")
    assert killed and code == 1 and not any("Traceback" in line for line in stderr), stderr
    table = gather(cluster.folder / "sweep")
    assert list(table["status"]) == [OK, OK] and FAILED not in set(table["status"]), stderr
    (lost,) = {f"seed{s}" for s in (0, 1, 2)} - {i.split("-")[-2] for i in table["id"]}
    assert stderr[-1].startswith("behave: 1 of 3 runs lost with a Ray node that left the cluster (") and (
        stderr[-1].endswith("): the same command again runs them") and lost in stderr[-1]
    ), stderr
    start = time.monotonic()
    again = behave(*args, env=cluster.env, timeout=300)
    print(f"rerun of the lost run: {time.monotonic() - start:.0f} s")
    assert again.returncode == 0, again.stderr
    assert "3 runs: 2 finished before, 1 to run on" in again.stderr
    assert list(gather(cluster.folder / "sweep")["status"]) == [OK, OK, OK]
