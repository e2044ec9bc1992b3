"""Nothing lost, nothing silent: full disks, geo round trips, SUMO's errors, bad numbers, signals.

Real SUMO, real files, real signals; the full disk is a 200 kB tmpfs (skipped where mounting
is not permitted).
"""

from __future__ import annotations

import gzip
import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from helpers import BEHAVE, behave

from behaviors.cli.main import main
from behaviors.errors import BehaveError
from behaviors.files import atomic_write_text
from behaviors.learn.ddpg.checkpoint import save_checkpoint
from behaviors.learn.ddpg.networks import Actor
from behaviors.report.export import export_fcd
from behaviors.report.fcd_read import fcd_is_geo, read_fcd
from behaviors.report.plot import plot_fcd
from behaviors.run.populate import populate
from behaviors.run.populate_config import PopulateConfig
from sumo_scenarios import get_scenario

HIGHWAY = get_scenario("highway").net
TINY = get_scenario("tiny").net
META = {
    "algorithm": "ps-ddpg", "behaviour": "multi", "behaviours": ["multi"], "obs_dim": 66,
    "observation_layout": "test", "normalisation": "test", "hidden": [256, 256], "training_steps": 0,
}  # fmt: skip
GPX = "{http://www.topografix.com/GPX/1/0}trkpt"


def one_error_line(stderr: str) -> str:
    """The one error line, last on stderr (progress lines may come before it), no traceback."""
    lines = stderr.strip().splitlines()
    errors = [line for line in lines if line.startswith("behave: error: ")]
    assert errors == lines[-1:] and "Traceback" not in stderr, stderr
    return lines[-1]


def hidden(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.startswith("."))


@pytest.fixture
def full_disk(tmp_path: Path):
    """A 200 kB file system of its own: SUMO and every writer hit ENOSPC on it."""
    mount = tmp_path / "full"
    mount.mkdir()
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=200k", "tmpfs", str(mount)], capture_output=True
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "--lazy", str(mount)], check=False)  # even if a killed writer holds it


# 1. full disk ---------------------------------------------------------------------------------


@pytest.mark.sumo
@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".xml"])
def test_full_disk_fails_populate_keeps_the_old_file_and_leaves_no_temp(full_disk: Path, suffix: str):
    out = full_disk / f"out{suffix}"
    out.write_text("good\n")
    done = behave("populate", "--duration", "60", "--fcd", str(out))
    assert done.returncode != 0
    assert "not written" in one_error_line(done.stderr)
    assert out.read_text() == "good\n"
    assert hidden(full_disk) == []


@pytest.mark.sumo
def test_full_disk_fails_every_other_writer_in_one_error(full_disk: Path, tmp_path: Path):
    fcd = tmp_path / "fcd.csv"
    populate(PopulateConfig(duration=4, fcd=fcd))
    writes = {
        "metrics.csv": lambda p: atomic_write_text(p, "episode,reward\n" + "1,2.0\n" * 20_000),
        "last.pt": lambda p: save_checkpoint(p, actor_state=Actor(66, (256, 256)).state_dict(), meta=META),
        "traces.png": lambda p: plot_fcd(read_fcd(fcd), p),
        "trace.gpx": lambda p: export_fcd(fcd, "gpx", net=HIGHWAY, out=p),
    }
    for name in writes:
        (full_disk / name).write_text("good")
    room = os.statvfs(full_disk)
    (full_disk / "filler").write_bytes(b"x" * (room.f_bavail * room.f_frsize - 8192))  # less than any output
    for name, write in writes.items():
        target = full_disk / name
        with pytest.raises(BehaveError, match="No space left on device"):
            write(target)
        assert target.read_text() == "good", name
        assert hidden(full_disk) == [], name


# 2. geo FCD round trip, 3. gzipped nets -------------------------------------------------------


@pytest.fixture(scope="module")
def geo_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("geo")
    runs = {}
    for suffix in (".xml", ".csv", ".parquet"):
        runs[suffix] = root / f"geo{suffix}"
        populate(PopulateConfig(duration=5, geo=True, fcd=runs[suffix], background=4))
    return runs


@pytest.mark.sumo
@pytest.mark.parametrize("suffix", [".xml", ".csv", ".parquet"])
def test_geo_fcd_round_trips_into_every_format(geo_runs: dict[str, Path], tmp_path: Path, suffix: str):
    fcd = geo_runs[suffix]
    assert fcd_is_geo(fcd)
    lonlat = read_fcd(fcd)
    assert lonlat["lon"].between(11.55, 11.6).all() and lonlat["lat"].between(48.14, 48.16).all()
    for net in (None, HIGHWAY):  # never projected a second time, with a net or without
        (gpx,) = export_fcd(fcd, "gpx", net=net, out=tmp_path / "t.gpx")
        lons = sorted(float(p.get("lon")) for p in ET.parse(gpx).getroot().iter(GPX))
        assert lons[0] == pytest.approx(lonlat["lon"].min(), abs=1e-5)
        assert lons[-1] == pytest.approx(lonlat["lon"].max(), abs=1e-5)
    export_fcd(fcd, "kml", net=HIGHWAY, out=tmp_path / "t.kml")
    assert "11.5" in (tmp_path / "t.kml").read_text()
    for fmt in ("ns2", "omnet"):
        with pytest.raises(BehaveError, match=r"holds lon/lat .* needs metres"):
            export_fcd(fcd, fmt, net=None, out=tmp_path / f"t.{fmt}")
    export_fcd(fcd, "omnet", net=HIGHWAY, out=tmp_path / "t.omnet")
    xs = [float(x.text or "nan") for x in ET.parse(tmp_path / "t.omnet").getroot().iter("xpos")]
    assert xs and min(xs) >= 0 and max(xs) <= 3000 and max(xs) - min(xs) > 50  # metres on the 3 km road


def test_geo_on_a_net_without_projection_is_refused_before_running(tmp_path: Path):
    with pytest.raises(BehaveError, match="projection"):
        populate(PopulateConfig(net=TINY, geo=True, fcd=tmp_path / "f.xml", overtakers=1, keepers=1))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.sumo
def test_export_reads_a_gzipped_net(geo_runs: dict[str, Path], tmp_path: Path):
    metric = tmp_path / "m.csv"
    populate(PopulateConfig(duration=3, fcd=metric, background=2))
    net_gz = tmp_path / "highway.net.xml.gz"
    net_gz.write_bytes(gzip.compress(HIGHWAY.read_bytes()))
    (gpx,) = export_fcd(metric, "gpx", net=net_gz, out=tmp_path / "m.gpx")
    assert float(next(ET.parse(gpx).getroot().iter(GPX)).get("lat")) == pytest.approx(48.148, abs=0.01)
    export_fcd(geo_runs[".csv"], "ns2", net=net_gz, out=tmp_path / "g.ns2")


# 4. SUMO's own errors -------------------------------------------------------------------------

UNKNOWN_EDGE = """<routes>
  <route id="r0" edges="nope1 nope2"/>
  <vehicle id="v0" route="r0" depart="0"/>
</routes>"""
MALFORMED = """<routes>
  <vehicle id="v0" depart="0">
    <route edges="a b"/ >
  </vehicle>
</routes>"""


@pytest.mark.sumo
@pytest.mark.parametrize(
    ("text", "named"),
    [
        (UNKNOWN_EDGE, ("unknown.rou.xml", "'v0'", "'nope1'")),
        (MALFORMED, ("malformed.rou.xml", "unterminated", "4/24")),
    ],
    ids=["unknown-edge", "malformed"],
)
def test_sumo_errors_name_the_file_the_vehicle_and_the_edge(
    tmp_path: Path, text: str, named: tuple[str, ...]
):
    routes = tmp_path / named[0]
    routes.write_text(text)
    with pytest.raises(BehaveError) as err:
        populate(PopulateConfig(duration=2, routes=routes, fcd=tmp_path / "f.xml"))
    message = str(err.value)
    assert "\n" not in message and all(word in message for word in named), message


# 5. numeric options ---------------------------------------------------------------------------

NUMERIC = [
    ("populate", "--duration", "nan"), ("populate", "--duration", "0"), ("populate", "--step-length", "inf"),
    ("populate", "--background", "-1"), ("populate", "--seed", "-1"), ("populate", "--keepers", "-2"),
    ("train", "--episodes", "0"), ("train", "--checkpoint-every", "0"), ("train", "--max-minutes", "nan"),
    ("train", "--step-length", "-0.2"), ("train", "--lane-weight", "-1"), ("train", "--batch-size", "0"),
    ("evaluate", "--episodes", "0"), ("evaluate", "--max-steps", "-5"), ("evaluate", "--agents", "3,0"),
    ("evaluate", "--seed", "4294967296"),
]  # fmt: skip
NOT_RUN = {"populate": ["--net", "/nonexistent.net.xml"], "train": ["lanekeeping", "--scenario", "nosuch"]}
NOT_RUN["evaluate"] = ["--scenario", "nosuch"]


@pytest.mark.parametrize(("command", "option", "value"), NUMERIC)
def test_numeric_options_are_checked_at_the_edge_in_one_line(
    command: str, option: str, value: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
):
    monkeypatch.setattr(sys, "argv", ["behave", command, *NOT_RUN[command], option, value])
    with pytest.raises(SystemExit) as exit_:
        main()
    assert exit_.value.code == 2
    line = one_error_line(capsys.readouterr().err)
    assert f"{option} must be a finite number" in line and value.split(",")[-1] in line


# 6. output paths checked before SUMO starts ---------------------------------------------------


@pytest.mark.sumo
def test_output_paths_are_checked_before_anything_runs(tmp_path: Path):
    directory = tmp_path / "taken.xml"
    directory.mkdir()
    with pytest.raises(BehaveError, match="it is a directory"):
        populate(PopulateConfig(duration=2, fcd=directory))
    fcd = tmp_path / "fcd.xml"
    done = behave("populate", "--duration", "2", "--fcd", str(fcd), "--plot", str(directory))
    assert "it is a directory" in one_error_line(done.stderr)
    assert not fcd.exists()  # refused before SUMO ran, not after
    (directory.parent / "results.md").mkdir()
    done = behave("evaluate", "--baseline", "sumo", "--agents", "1", "--out", str(directory.parent))
    assert "results.md: it is a directory" in one_error_line(done.stderr)
    assert not (directory.parent / "results.csv").exists()  # refused before the evaluation ran
    (tmp_path / "in.csv").write_text("timestep_time;vehicle_id\n0.00;a\n")
    with pytest.raises(BehaveError, match="it is a directory"):
        export_fcd(tmp_path / "in.csv", "ipg", net=None, out=directory)


# 7. signals and stale temp files --------------------------------------------------------------


@pytest.mark.sumo
def test_sigterm_stops_populate_and_removes_its_temp_files(tmp_path: Path):
    out = tmp_path / "out.xml"
    process = subprocess.Popen([*BEHAVE, "populate", "--duration", "3600", "--fcd", str(out)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    deadline = time.monotonic() + 120
    while not any(p.stat().st_size > 10_000 for p in tmp_path.iterdir()) and time.monotonic() < deadline:
        time.sleep(0.2)  # until SUMO is writing its FCD
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 143
    assert "terminated" in one_error_line(stderr)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.sumo
def test_stale_temp_files_of_dead_runs_are_removed_and_no_others(tmp_path: Path):
    dead = subprocess.Popen(["true"])
    dead.wait()
    alive = os.getpid()
    stale = [
        f".out.csv.{dead.pid}-abc123.tmp.csv",
        f".out.{dead.pid}.partial.csv",
        f".out.csv.{dead.pid}-d.tmp.csv",
    ]
    kept = [
        f".out.csv.{alive}-abc123.tmp.csv",
        ".out.csv.notapid.tmp.csv",
        ".other.csv.1-x.tmp.csv",
        "out.csv",
    ]
    for name in stale + kept:
        (tmp_path / name).write_text("x")
    (tmp_path / stale[2]).unlink()
    (tmp_path / stale[2]).mkdir()  # an export's temp directory
    populate(PopulateConfig(duration=2, fcd=tmp_path / "out.csv"))
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted({*kept, "out.agents.csv"}), left
