"""`behave sweep`: a grid of populate runs (share of learned drivers x seeds x policies x scenarios),
run in parallel on Ray, gathered into one table and one plot.

Layout of a sweep folder (`--out`):
* `runs/<point id>.json`: one finished run's row (its settings, its summary, its figures), written
  atomically when the run ends. A sweep started again skips every point whose row says `ok`, so a
  killed sweep resumes where it stopped; a failed run's row holds its error and is run again.
* `fcd/<point id>.csv` and `.agents.csv`: the run's FCD, only with `keep_fcd`.
* `outputs/<point id>/`: every output the run's scenario names (its detectors', summary, tripinfo, ...),
  at their places relative to the sumocfg's folder; SUMO writes them into the run's own temporary
  folder (`scenario_config.redirect_outputs`), never beside the scenario, where parallel runs would
  write the same files.
* `sweep.csv`, `sweep.parquet`, `sweep.png`: every row in `runs/`, gathered, and the main figures
  against the share with the spread over seeds.

Everything but `run_sweep` is plain Python, testable without Ray: grid expansion (`expand`), one
point's run (`run_point`: populate into a temporary folder, then the figures of its FCD, measured in
sweep_figures.py), row building (`ok_row`, `failed_row`) and gathering (`gather`). A row depends on
its point only (populate is seeded: same seed, same FCD), never on the worker or on the other runs;
wall-clock figures are kept apart in WALL_COLUMNS. On a cluster each run takes its files along
(ship.py, `run_shipped`) and a node that leaves costs only the runs it had.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import itertools
import json
import math
import os
import shutil
import signal
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from behaviors.errors import BehaveError
from behaviors.files import atomic_path, atomic_write_text, disk_full, ensure_writable_dir
from behaviors.report.agents_table import agents_path
from behaviors.run.ship import POLICY_DIR, SCENARIO_DIR, Package, pack_policy, pack_scenario, unpack
from behaviors.run.sweep_figures import OK, fcd_figures, plot_table

if TYPE_CHECKING:
    import pandas as pd

RUNS_DIR = "runs"
FCD_DIR = "fcd"
OUTPUTS_DIR = "outputs"
FCD_SUFFIX = ".csv"
"""Each run's FCD: SUMO writes csv as it goes (a parquet trace it keeps in memory until the end)."""
TABLE = "sweep"
FAILED = "failed"
WALL_COLUMNS = ("wall_s", "real_time_factor", "host")
"""Columns that depend on the machine and the moment: left out when rows are compared."""
SETTING_COLUMNS = ("id", "scenario", "scenario_path", "kind", "policy", "share", "seed", "overtakers",
                   "keepers", "background", "overtaker_fraction", "duration_s", "step_length_s",
                   "shield")  # fmt: skip


@dataclass(frozen=True)
class Point:
    """One populate run of a sweep, in plain values (it travels to Ray workers and into its row).

    `kind` "sumocfg": `scenario` is a sumocfg whose passenger cars become agents by `share`;
    "net": `scenario` is a net with `keepers` + `overtakers` agents among `background` SUMO cars."""

    scenario: str  # absolute path
    kind: str
    policy: str
    share: float
    seed: int
    overtakers: int
    keepers: int
    background: int
    overtaker_fraction: float = 0.5
    duration: float | None = None  # None: populate's default (180 s, or the sumocfg's end - begin)
    step_length: float | None = None
    shield: bool = True
    agent_settings: bool = (
        False  # without agents, run as with agents (populate_config.config_from): a share 0 baseline
    )

    @property
    def id(self) -> str:
        """A readable name that is unique to every setting (a hash of them all; `agent_settings` only
        where set, so the points of sweeps before it keep their ids)."""
        settings = asdict(self)
        if not self.agent_settings:
            del settings["agent_settings"]
        digest = hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:10]
        what = f"share{self.share:g}" if self.kind == "sumocfg" else f"o{self.overtakers}k{self.keepers}"
        name = Path(self.scenario).name.split(".")[0]
        return f"{name}-{Path(self.policy).stem}-{what}-seed{self.seed}-{digest}"

    def settings(self) -> dict[str, Any]:
        """The row's setting columns."""
        return {
            "id": self.id, "scenario": Path(self.scenario).name, "scenario_path": self.scenario,
            "kind": self.kind, "policy": self.policy,
            "share": self.share if self.kind == "sumocfg" else math.nan, "seed": self.seed,
            "overtakers": self.overtakers, "keepers": self.keepers, "background": self.background,
            "overtaker_fraction": self.overtaker_fraction,
            "duration_s": math.nan if self.duration is None else self.duration,
            "step_length_s": math.nan if self.step_length is None else self.step_length,
            "shield": self.shield,
        }  # fmt: skip

    def config(self, fcd: Path, notes: list[str] | None = None, outputs: Path | None = None) -> Any:
        """populate's PopulateConfig of this point, writing its FCD to `fcd` (and a sumocfg's own outputs
        into `outputs`; None: where the scenario names them); `notes` as config_from."""
        from behaviors.run.populate_config import config_from

        given: dict[str, Any] = {
            "overtakers": self.overtakers, "keepers": self.keepers, "background": self.background,
            "policy": Path(self.policy), "duration": self.duration, "step_length": self.step_length,
            "seed": self.seed, "fcd": fcd, "shield": self.shield,
        }  # fmt: skip
        if self.kind == "sumocfg":
            given |= {"share": self.share, "overtaker_fraction": self.overtaker_fraction, "outputs": outputs}
            return config_from(Path(self.scenario), notes, self.agent_settings, **given)
        return config_from(None, notes, net=Path(self.scenario), **given)


@dataclass(frozen=True)
class Grid:
    """What a user asks for: every combination of these is one point."""

    sumocfgs: tuple[str, ...] = ()
    nets: tuple[str, ...] = ()
    shares: tuple[float, ...] = (0.0,)
    seeds: tuple[int, ...] = (0,)
    policies: tuple[str, ...] = ("traffic",)
    overtakers: tuple[int, ...] | None = None  # None: populate's default for the scenario's kind
    keepers: tuple[int, ...] | None = None
    background: int | None = None
    overtaker_fraction: float = 0.5
    duration: float | None = None
    step_length: float | None = None
    shield: bool = True


NET_DEFAULTS = {"overtakers": 4, "keepers": 4, "background": 20}
"""populate's counts on a net; on a sumocfg its agents come from the share and it adds no cars."""


def expand(grid: Grid) -> list[Point]:
    """Every point of the grid, in a fixed order (scenario, policy, counts, share, seed); values given
    twice count once."""
    points: list[Point] = []
    common: dict[str, Any] = {"overtaker_fraction": grid.overtaker_fraction, "duration": grid.duration,
                              "step_length": grid.step_length, "shield": grid.shield}  # fmt: skip
    scenarios = [(s, "sumocfg") for s in grid.sumocfgs] + [(n, "net") for n in grid.nets]
    for (scenario, kind), policy in itertools.product(_unique(scenarios), _unique(grid.policies)):
        default = NET_DEFAULTS if kind == "net" else dict.fromkeys(NET_DEFAULTS, 0)
        overtakers = grid.overtakers if grid.overtakers is not None else (default["overtakers"],)
        keepers = grid.keepers if grid.keepers is not None else (default["keepers"],)
        background = grid.background if grid.background is not None else default["background"]
        shares = _unique(grid.shares) if kind == "sumocfg" else [0.0]
        # a sumocfg's runs without agents beside runs with them run as those do (step, sublanes): comparable
        agents = kind == "sumocfg" and (any(shares) or any(overtakers) or any(keepers))
        for o, k, share, seed in itertools.product(_unique(overtakers), _unique(keepers), shares,
                                                   _unique(grid.seeds)):  # fmt: skip
            baseline = agents and share == 0 and o + k == 0
            points.append(Point(scenario, kind, policy, float(share), int(seed), int(o), int(k),
                                int(background), agent_settings=baseline, **common))  # fmt: skip
    return points


def _unique(values: Iterable[Any]) -> list[Any]:
    return list(dict.fromkeys(values))


def check_grid(grid: Grid, notes: list[str] | None = None) -> list[Point]:
    """The grid's points, or a BehaveError (one line) for anything that would make a run fail at once:
    a missing scenario, a share out of range, a policy that cannot drive what is asked, a duration past
    a sumocfg's end. `notes` gets each line populate would say of how a scenario runs, once."""
    if not grid.sumocfgs and not grid.nets:
        raise BehaveError("nothing to sweep: give --sumocfg or --net")
    if grid.nets and any(share != 0 for share in grid.shares) and not grid.sumocfgs:
        raise BehaveError("--share converts a scenario's own cars: it needs --sumocfg")
    for name, values in (("--share", grid.shares), ("--seeds", grid.seeds), ("--policy", grid.policies)):
        if not values:
            raise BehaveError(f"{name} names no value")
    points = expand(grid)
    from behaviors.learn.policy import load_policy  # torch: only once the options are checked
    from behaviors.run.populate_config import check_fits

    policies = {spec: load_policy(Path(spec)) for spec in _unique(grid.policies)}
    said: list[str] = []
    for point in points:  # every share and count: what the policy must drive, what the config holds
        config = point.config(Path(tempfile.gettempdir()) / f"check{FCD_SUFFIX}", said)
        config.validate()
        check_fits(config, policies[point.policy])
    if notes is not None:
        notes.extend(_unique(said))
    return points


def resolve_net(spec: str) -> str:
    """A bundled scenario's name (`highway`, `tiny`, ...) or a .net.xml path, as an absolute path."""
    path = Path(spec)
    if path.is_file():
        return str(path.resolve())
    from sumo_scenarios import SCENARIO_NAMES, get_scenario

    if spec in SCENARIO_NAMES:
        return str(get_scenario(spec).net.resolve())
    raise BehaveError(f"net not found: {spec} (a .net.xml or one of {', '.join(SCENARIO_NAMES)})")


def resolve_policy(spec: str) -> str:
    """A policy file or run directory as an absolute path (workers run elsewhere); a bundled name as is."""
    return str(Path(spec).resolve()) if Path(spec).exists() else spec


def resolve_sumocfg(spec: str) -> str:
    path = Path(spec)
    if not path.is_file():
        raise BehaveError(f"sumocfg not found: {spec}")
    return str(path.resolve())


# --- one run ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunResult:
    """What a run sends back: its row, and (keep_fcd) its FCD and agents table as bytes, so that a
    worker on another machine needs no shared folder."""

    row: dict[str, Any]
    fcd: bytes | None = None
    agents: bytes | None = None
    outputs: tuple[tuple[str, bytes], ...] = ()  # the scenario's own outputs: (path in the run folder, bytes)


def run_point(
    point: Point, *, keep_fcd: bool = False, workdir: Path | None = None, here: Point | None = None
) -> RunResult:
    """One populate run of `point` in a temporary folder and its row; any failure becomes a failed
    row. The row is the same wherever and beside whatever it runs. `here`: the point with the paths
    its files have on this machine (a shipped run's, `run_shipped`), which the row does not show."""
    here = here or point
    with tempfile.TemporaryDirectory(prefix="behave-sweep-", dir=workdir) as folder:
        fcd, outputs = Path(folder) / f"fcd{FCD_SUFFIX}", Path(folder) / OUTPUTS_DIR
        start = time.perf_counter()
        try:
            from behaviors.run.populate import populate

            config = here.config(fcd, outputs=outputs)
            summary = populate(config)
            row = ok_row(point, summary.as_dict(), fcd_figures(fcd, Path(summary_net(here))))
            row["step_length_s"] = (
                config.step_length
            )  # the step it ran at (given, the policy's, the sumocfg's)
        except Exception as exc:  # a run's failure is its row's, not the sweep's
            return RunResult(failed_row(point, error_line(exc), time.perf_counter() - start))
        written = tuple(
            (path.relative_to(outputs).as_posix(), path.read_bytes())
            for path in sorted(outputs.rglob("*"))
            if path.is_file()
        )
        if not keep_fcd:
            return RunResult(row, outputs=written)
        return RunResult(row, fcd.read_bytes(), agents_path(fcd).read_bytes(), written)


def run_shipped(
    point: Point, scenario: Package, policy: Package | None, *, keep_fcd: bool = False
) -> RunResult:
    """`run_point` on a cluster's worker, of a point whose files came with it (`ship.pack_scenario`,
    `ship.pack_policy`): unpacked into a temporary folder and run from there, its row as the sweep's
    machine would give it."""
    with tempfile.TemporaryDirectory(prefix="behave-shipped-") as folder:
        try:
            here = replace(
                point, scenario=str(unpack(scenario, Path(folder) / SCENARIO_DIR)),
                policy=point.policy if policy is None else str(unpack(policy, Path(folder) / POLICY_DIR)),
            )  # fmt: skip
        except OSError as exc:
            return RunResult(
                failed_row(point, f"cannot unpack the run's files on its worker: {error_line(exc)}")
            )
        return run_point(point, keep_fcd=keep_fcd, workdir=Path(folder), here=here)


def packages(ray: Any, points: Sequence[Point], say: Callable[[str], None]) -> dict[str, tuple[Any, Any]]:
    """Each point's scenario and policy packages in Ray's object store (each file read and sent once),
    by the point's id; `say` gets what goes."""
    scenarios = {key: pack_scenario(*key) for key in _unique((p.scenario, p.kind) for p in points)}
    policies = {spec: pack_policy(spec) for spec in _unique(p.policy for p in points)}
    files = [package for package in (*scenarios.values(), *policies.values()) if package is not None]
    size, count = sum(package.size for package in files), sum(len(package.files) for package in files)
    amount = f"{size / 2**20:.1f} MB" if size >= 2**20 else f"{size / 2**10:.0f} kB"
    say(f"sending each run its files: {count} file{'s' * (count != 1)}, {amount}, put once in the "
        "cluster's object store")  # fmt: skip
    scenario_refs = {key: ray.put(package) for key, package in scenarios.items()}
    policy_refs = {spec: ray.put(package) for spec, package in policies.items()}
    return {p.id: (scenario_refs[p.scenario, p.kind], policy_refs[p.policy]) for p in points}


def summary_net(point: Point) -> str:
    """The net the point's cars drive on (a sumocfg's own)."""
    if point.kind == "net":
        return point.scenario
    from behaviors.sumo.scenario_config import read_sumocfg

    return str(read_sumocfg(Path(point.scenario)).net)


def error_line(exc: BaseException) -> str:
    """An error as one line: a BehaveError's message, anything else with its type."""
    text = " ".join(str(exc).split())
    return text if isinstance(exc, BehaveError) else f"{type(exc).__name__}: {text}"


# --- rows and the table ----------------------------------------------------------------------------


SUMMARY_FILL = {"scenario_passenger_cars": 0, "of_them_agents": 0, "left_to_sumo_not_car_sized": 0,
                "keeper_mean_speed": math.nan, "overtaker_mean_speed": math.nan,
                "sumo_mean_speed": math.nan}  # fmt: skip
"""Summary figures populate leaves out when they do not apply: every row has them."""


def ok_row(point: Point, summary: dict[str, Any], figures: dict[str, float]) -> dict[str, Any]:
    """A finished run's row: settings, status, populate's summary (wall-clock figures apart, at the
    end), its FCD's flow and realism figures."""
    summary = SUMMARY_FILL | dict(summary)
    wall: dict[str, Any] = {key: summary.pop(key) for key in ("wall_s", "real_time_factor") if key in summary}
    summary.pop("phases", None)
    return {**point.settings(), "status": OK, "error": "", **summary, **figures, **wall,
            "host": socket.gethostname()}  # fmt: skip


def failed_row(point: Point, error: str, wall_s: float = math.nan) -> dict[str, Any]:
    return {**point.settings(), "status": FAILED, "error": error, "wall_s": wall_s,
            "host": socket.gethostname()}  # fmt: skip


def compared(row: dict[str, Any]) -> dict[str, Any]:
    """A row without its wall-clock columns: what equal points must give equally."""
    return {key: value for key, value in row.items() if key not in WALL_COLUMNS}


def row_path(out: Path, point_id: str) -> Path:
    return Path(out) / RUNS_DIR / f"{point_id}.json"


def write_row(out: Path, row: dict[str, Any]) -> Path:
    path = row_path(out, row["id"])
    ensure_writable_dir(path.parent)
    atomic_write_text(path, json.dumps(row, indent=1, allow_nan=True) + "\n")
    return path


def read_row(path: Path) -> dict[str, Any] | None:
    """A row file, or None if it cannot be read (a run of an older behave, a damaged file)."""
    try:
        row = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return row if isinstance(row, dict) and "id" in row and "status" in row else None


def finished(out: Path, points: Sequence[Point]) -> set[str]:
    """Ids of the points whose row says they ran to the end."""
    done = set()
    for point in points:
        row = read_row(row_path(out, point.id))
        if row is not None and row["status"] == OK:
            done.add(point.id)
    return done


def gather(out: Path) -> pd.DataFrame:
    """Every row in the sweep folder as one table: settings, status and error first, wall-clock
    columns last, rows sorted by their settings."""
    import pandas as pd

    rows = [row for path in sorted((Path(out) / RUNS_DIR).glob("*.json")) if (row := read_row(path))]
    table = pd.DataFrame(rows)
    if table.empty:
        return pd.DataFrame(columns=[*SETTING_COLUMNS, "status", "error"])
    first = [c for c in (*SETTING_COLUMNS, "status", "error") if c in table.columns]
    last = [c for c in WALL_COLUMNS if c in table.columns]
    table = table[first + [c for c in table.columns if c not in first + last] + last]
    order = ["scenario", "kind", "policy", "overtakers", "keepers", "share", "seed", "id"]
    return table.sort_values(order, kind="stable", na_position="first").reset_index(drop=True)


def write_table(out: Path, table: pd.DataFrame) -> list[Path]:
    """sweep.csv and sweep.parquet, each complete or absent."""
    csv, parquet = Path(out) / f"{TABLE}.csv", Path(out) / f"{TABLE}.parquet"
    atomic_write_text(csv, table.to_csv(index=False))
    with atomic_path(parquet) as tmp:
        table.to_parquet(tmp, index=False)
    return [csv, parquet]


def keep_signal_handlers(start: Callable[[], Any]) -> Any:
    """`start()` with this process's SIGTERM and SIGINT handlers kept: Ray's driver installs its own,
    which print a stack dump and end the process; behave's stop cleanly (exit 143 / 130) and the
    finished runs' rows stay."""
    if threading.current_thread() is not threading.main_thread():
        return start()
    kept = {signum: signal.getsignal(signum) for signum in (signal.SIGTERM, signal.SIGINT)}
    try:
        return start()
    finally:
        for signum, handler in kept.items():
            if handler is not None:
                signal.signal(signum, handler)


NO_SPACE = os.strerror(errno.ENOSPC)
"""How a write on a full disk is reported ("No space left on device"); populate's FCD check says
"disk full?" where SUMO could not tell."""


def disk_full_error(text: str, out: Path | None = None) -> bool:
    """Whether an error is a full disk's: its text says so, or the disk of `out` has no room left."""
    return NO_SPACE in text or "disk full" in text or (out is not None and disk_full(Path(out)))


def keep_result(out: Path, result: RunResult) -> str | None:
    """A run's files and row into the sweep folder; the error if the disk is full, with nothing of the
    run left behind (a run without its row is run again), or if the run itself failed for a full disk
    (its failed row kept where it fits)."""
    try:
        save_files(out, result)
        write_row(out, result.row)
    except BehaveError as err:
        if not disk_full_error(str(err), out):
            raise
        discard_files(out, result.row["id"])
        return str(err)
    if result.row["status"] != OK and disk_full_error(str(result.row.get("error", ""))):
        return str(result.row["error"])
    return None


def discard_files(out: Path, point_id: str) -> None:
    """A run's row and files, removed (where saving them failed part of the way)."""
    shutil.rmtree(Path(out) / OUTPUTS_DIR / point_id, ignore_errors=True)
    for path in (row_path(out, point_id), *(Path(out) / FCD_DIR).glob(f"{point_id}.*")):
        with contextlib.suppress(OSError):
            path.unlink()


def save_files(out: Path, result: RunResult) -> None:
    """A run's scenario outputs into `outputs/<id>/` (the folder cleared first: a run again replaces
    them) and a kept run's FCD and agents table into `fcd/`."""
    run_folder = Path(out) / OUTPUTS_DIR / result.row["id"]
    if run_folder.is_dir():
        shutil.rmtree(run_folder)
    for name, content in result.outputs:
        target = run_folder / name
        ensure_writable_dir(target.parent)
        with atomic_path(target) as tmp:
            tmp.write_bytes(content)
    if result.fcd is None:
        return
    folder = Path(out) / FCD_DIR
    ensure_writable_dir(folder)
    for name, data in ((f"{result.row['id']}{FCD_SUFFIX}", result.fcd), (f"{result.row['id']}.agents.csv",
                                                                      result.agents)):  # fmt: skip
        if data is not None:
            with atomic_path(folder / name) as tmp:
                tmp.write_bytes(data)


# --- Ray ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SweepResult:
    table: pd.DataFrame
    ran: int  # points run now
    skipped: int  # points already finished
    failed: int  # of those run now
    outputs: list[Path]
    lost: tuple[str, ...] = ()  # ids of the runs lost with a Ray node that left the cluster: no row


def run_sweep(
    points: Sequence[Point],
    out: Path,
    *,
    workers: int | None = None,
    address: str | None = None,
    keep_fcd: bool = False,
    on_event: Callable[[str], None] | None = None,
) -> SweepResult:
    """Run the points not finished yet, at most `workers` at a time (None: as many as Ray has CPUs),
    each as a Ray task (its own process, its own SUMO); write each row as it comes back, then the
    table and the plot. On a cluster (`address`) each run's files go with it (`run_shipped`). A worker
    that dies loses its run only (a failed row, run again next time); a node that leaves the cluster
    loses the runs it had (no row: `lost`, run next time). A full disk stops the sweep: the runs under
    way are cancelled, the finished ones' rows stay, and a BehaveError says so (the same call again,
    once there is room, runs the rest)."""
    out = Path(out)
    ensure_writable_dir(out / RUNS_DIR)
    done = finished(out, points)
    todo = [point for point in points if point.id not in done]
    say = on_event or (lambda text: None)
    failures, lost = 0, list[str]()
    full: str | None = None  # why the sweep stopped: the disk is full
    if not todo:
        say(f"{len(points)} runs: all {len(done)} finished before")
    else:
        from behaviors.learn.distributed import start_ray

        local = workers if workers is not None else os.cpu_count() or 1
        ray = keep_signal_handlers(lambda: start_ray(address, local, log_to_driver=False))
        try:
            if workers is None:  # as many at once as the machine or the cluster has CPUs
                workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
            shipped = packages(ray, todo, say) if address is not None else {}
            say(f"{len(points)} runs: {len(done)} finished before, {len(todo)} to run on {workers} workers")
            task = ray.remote(num_cpus=1, max_retries=0)(run_shipped if address is not None else run_point)
            waiting, running = list(todo), dict[Any, Point]()
            while (waiting or running) and full is None:
                while waiting and len(running) < workers:
                    point = waiting.pop(0)
                    running[task.remote(point, *shipped.get(point.id, ()), keep_fcd=keep_fcd)] = point
                ready, _ = ray.wait(list(running), num_returns=1)
                point = running.pop(ready[0])
                try:
                    result = ray.get(ready[0])
                except ray.exceptions.NodeDiedError:  # its node left the cluster: nothing wrong with the run
                    lost.append(point.id)
                    say(f"{point.id}: lost with its Ray node, which left the cluster")
                    continue
                except Exception as exc:  # the worker died (a crash in SUMO, killed): the run failed
                    result = RunResult(failed_row(point, error_line(getattr(exc, "cause", None) or exc)))
                full = keep_result(out, result)
                ok = result.row["status"] == OK
                failures += not ok
                note = "" if row_path(out, point.id).is_file() else " (not kept: the disk is full)"
                say(f"{point.id}: {OK if ok else 'failed: ' + result.row['error']}{note}")
            for ref in running:  # stopped for a full disk: the runs under way would not fit either
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
        finally:
            ray.shutdown()
    if full is not None:
        kept = len(finished(out, points))
        raise BehaveError(
            f"disk full, the sweep stopped ({full}): {kept} of {len(points)} runs finished, their rows kept "
            f"in {out / RUNS_DIR}; make room and run the same sweep again for the other {len(points) - kept}"
        )
    table = gather(out)
    outputs = write_table(out, table)
    picture = plot_table(table, out / f"{TABLE}.png")
    return SweepResult(
        table, len(todo), len(done), failures, outputs + ([picture] if picture else []), tuple(lost)
    )
