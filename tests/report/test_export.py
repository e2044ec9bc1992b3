"""FCD recording, reading, validation, export and plotting against a real SUMO run."""

from __future__ import annotations

import os
import re
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd
import pytest

from behaviors.errors import BehaveError
from behaviors.report.export import EXPORT_FORMATS, export_fcd
from behaviors.report.fcd_read import fcd_options, read_fcd, validate_fcd_xml
from behaviors.report.plot import (
    ALONG_LABELS,
    _along_column,
    _lane_widths,
    _lateral_lanes,
    plot_fcd,
    trace_styles,
)
from behaviors.sumo.sumo_home import sumo_binary

UTM32 = "+proj=utm +zone=32 +ellps=WGS84 +datum=WGS84 +units=m +no_defs"
NODES = f"""<nodes>
  <location netOffset="0.00,0.00" convBoundary="0.00,0.00,1000.00,0.00"
            origBoundary="0,0,1000,0" projParameter="{UTM32}"/>
  <node id="a" x="0" y="0"/>
  <node id="b" x="1000" y="0"/>
</nodes>"""
EDGES = """<edges>
  <edge id="e" from="a" to="b" numLanes="2" speed="33.33" width="3.5" spreadType="center"/>
</edges>"""
ROUTES = """<routes>
  <vType id="behave_keeper" lcModel="SL2015" maxSpeed="25"/>
  <vType id="behave_overtaker" lcModel="SL2015" maxSpeed="33"/>
  <vType id="behave_background" lcModel="SL2015" maxSpeed="20"/>
  <route id="r" edges="e"/>
  <vehicle id="k0" type="behave_keeper" route="r" depart="1" departLane="0" departSpeed="0"/>
  <vehicle id="b0" type="behave_background" route="r" depart="1" departLane="1"
           departPos="30" departSpeed="0"/>
  <vehicle id="o0" type="behave_overtaker" route="r" depart="3" departLane="0" departSpeed="0"/>
</routes>"""
NUM = r"-?[\d.]+(?:e-?\d+)?"  # geo input gives lat like 1.6e-05
NS2_PLACE = re.compile(rf"^\$node_\((\d+)\) set [XYZ]_ {NUM}$")
NS2_SETDEST = re.compile(rf'^\$ns_ at {NUM} "\$node_\((\d+)\) setdest {NUM} {NUM} {NUM}"$')


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 2-lane straight with a projection, 30 s of 3 cars recorded in every FCD format."""
    root = tmp_path_factory.mktemp("fcd")
    (root / "n.nod.xml").write_text(NODES)
    (root / "n.edg.xml").write_text(EDGES)
    (root / "r.rou.xml").write_text(ROUTES)
    netconvert = [sumo_binary("netconvert"), "-n", "n.nod.xml", "-e", "n.edg.xml"]
    subprocess.run([*netconvert, "-o", "n.net.xml", "--no-turnarounds"], cwd=root, check=True)
    sumo = [sumo_binary("sumo"), "-n", "n.net.xml", "-r", "r.rou.xml", "--end", "30"]
    sumo += ["--lateral-resolution", "0.4", "--no-step-log"]
    recordings = {"run.xml": False, "run.csv": False, "run.parquet": False}
    for name, geo in {**recordings, "geo.xml": True, "geo.csv": True}.items():
        subprocess.run([*sumo, *fcd_options(root / name, geo=geo)], cwd=root, check=True)
    return root


def test_fcd_options_name_sumo_attributes(tmp_path: Path) -> None:
    options = fcd_options(tmp_path / "f.csv", geo=True)
    assert options[:2] == ["--fcd-output", str(tmp_path / "f.csv")]
    assert "--fcd-output.geo" in options
    assert "--fcd-output.geo" not in fcd_options(tmp_path / "f.xml", geo=False)
    with pytest.raises(BehaveError, match=r"\.json.*must end in"):
        fcd_options(tmp_path / "f.json", geo=False)


@pytest.mark.sumo
def test_three_formats_read_the_same(run: Path) -> None:
    xml, csv, parquet = (read_fcd(run / f"run.{ext}") for ext in ("xml", "csv", "parquet"))
    assert list(xml.columns[:13]) == [
        *("time", "id", "x", "y", "angle", "type", "speed", "pos", "lane", "posLat"),
        *("acceleration", "distance", "odometer"),
    ]
    assert len(xml) > 60 and set(xml["type"]) >= {"behave_keeper", "behave_overtaker"}
    assert xml[["distance", "acceleration", "odometer"]].notna().all().all()
    # the odometer counts from insertion: 0 on each vehicle's first step, then the metres driven
    first = xml.groupby("id")["odometer"].first()
    assert (first == 0).all() and (xml.groupby("id")["odometer"].diff().dropna() >= 0).all()
    # xml and csv are rounded to SUMO's 2 decimals; parquet keeps float32
    pd.testing.assert_frame_equal(xml, csv)
    pd.testing.assert_frame_equal(xml, parquet, check_exact=False, atol=0.006)


@pytest.mark.sumo
def test_xml_validates_against_sumo_schema(run: Path) -> None:
    validate_fcd_xml(run / "run.xml")
    validate_fcd_xml(run / "geo.xml")
    bad = run / "bad.fcd.xml"
    bad.write_text('<fcd-export><timestep time="x"/></fcd-export>')
    with pytest.raises(BehaveError, match="not valid FCD XML"):
        validate_fcd_xml(bad)


@pytest.mark.sumo
def test_geo_output_has_lon_lat(run: Path) -> None:
    for name in ("geo.xml", "geo.csv"):
        df = read_fcd(run / name, geo=True)
        assert {"lon", "lat"} <= set(df.columns) and "x" not in df.columns
        # the net's origin is UTM 32 easting 0 at the equator: about 4.5 E, 0 N
        assert df["lon"].between(4.4, 4.6).all() and df["lat"].abs().max() < 0.001


@pytest.mark.sumo
@pytest.mark.parametrize("source", ["run.xml", "run.parquet", "geo.xml"])
def test_every_export_format_parses(run: Path, tmp_path: Path, source: str) -> None:
    for fmt in EXPORT_FORMATS:
        written = export_fcd(run / source, fmt, net=run / "n.net.xml", out=tmp_path / f"t.{fmt}")
        assert written and all(path.stat().st_size > 0 for path in written)
        _check_export(fmt, written)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp leftovers


def _check_export(fmt: str, written: list[Path]) -> None:
    main = written[0]
    if fmt == "ns2":
        lines = main.read_text().splitlines()
        assert all(NS2_PLACE.match(line) or NS2_SETDEST.match(line) for line in lines)
        assert {NS2_SETDEST.match(line)[1] for line in lines if NS2_SETDEST.match(line)} == {
            "0",
            "1",
            "2",
        }
        assert "append opt(mf) /t.ns2" in written[1].read_text()
    elif fmt == "ipg":
        assert len(main.read_text().splitlines()) > 60
    else:
        root = ET.parse(main).getroot()
        points = {
            "omnet": "waypoint",
            "gpx": "{http://www.topografix.com/GPX/1/0}trkpt",
            "kml": "{http://www.opengis.net/kml/2.2}coordinates",
        }[fmt]
        assert len(list(root.iter(points))) >= (60 if fmt != "kml" else 3)
        if fmt == "gpx":
            lons = [float(p.get("lon")) for p in root.iter(points)]
            assert min(lons) > 4.4 and max(lons) < 4.6


@pytest.mark.sumo
def test_not_fcd_is_refused(run: Path, tmp_path: Path) -> None:
    files = {
        "random.xml": "hello, not xml",
        "other.xml": "<routes/>",
        "empty.xml": "",
        "random.csv": "a,b\n1,2\n",
        "empty.csv": "",
        "random.parquet": "PAR1 nonsense",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(BehaveError, match=rf"{re.escape(name)} is not an FCD file"):
            read_fcd(tmp_path / name)
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(BehaveError, match=r"other\.xml is not an FCD file"):
        export_fcd(tmp_path / "other.xml", "omnet", net=None, out=out / "t.omnet")
    assert not list(out.iterdir())


@pytest.mark.sumo
def test_bad_requests_are_refused(run: Path, tmp_path: Path) -> None:
    fcd = run / "run.xml"
    with pytest.raises(BehaveError, match=r"unknown export format 'vissim'.*ns2.*omnet"):
        export_fcd(fcd, "vissim", net=None, out=tmp_path / "t.x")
    with pytest.raises(BehaveError, match="FCD file not found"):
        export_fcd(run / "missing.xml", "ns2", net=None, out=tmp_path / "t.tcl")
    with pytest.raises(BehaveError, match="FCD file not found"):
        read_fcd(run / "missing.parquet")
    with pytest.raises(BehaveError, match="gpx needs lon/lat"):
        export_fcd(fcd, "gpx", net=None, out=tmp_path / "t.gpx")


@pytest.mark.sumo
def test_missing_output_directories_are_created(run: Path, tmp_path: Path) -> None:
    out = tmp_path / "traces" / "deeper" / "mobility.tcl"
    written = export_fcd(run / "run.xml", "ns2", net=None, out=out)
    assert out in written and out.stat().st_size > 0


@pytest.mark.sumo
def test_unwritable_output_dir_is_refused(run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    if os.access(locked, os.W_OK):  # root ignores permissions: fail the way the kernel would

        def refuse(**_: object) -> str:
            raise PermissionError(13, "Permission denied")

        monkeypatch.setattr("behaviors.files.tempfile.mkdtemp", refuse)
    with pytest.raises(BehaveError, match=r"not writable|Permission denied"):
        export_fcd(run / "run.xml", "ns2", net=None, out=locked / "t.tcl")
    assert not list(locked.iterdir())


@pytest.mark.sumo
def test_plot_writes_png(run: Path, tmp_path: Path) -> None:
    out = tmp_path / "trace.png"
    plot_fcd(read_fcd(run / "run.parquet"), out, title="test", lane_width=3.5)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000
    assert [p.name for p in tmp_path.iterdir()] == ["trace.png"]


@pytest.mark.sumo
def test_plot_uses_the_net_lane_widths(run: Path, tmp_path: Path) -> None:
    out = tmp_path / "trace.png"
    df = read_fcd(run / "run.xml")
    plot_fcd(df, out, title="test", net=run / "n.net.xml")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    widths = _lane_widths(run / "n.net.xml")
    assert widths["e_0"] == widths["e_1"] == 3.5
    trace = pd.DataFrame(
        {"lane": pd.array(["e_0", "e_1", "x_1"], dtype="string"), "posLat": [1.75, -0.7, 1.6]}
    )
    assert list(_lateral_lanes(trace, widths, 3.2)) == pytest.approx([0.5, 0.8, 1.5])  # x_1: fallback
    with pytest.raises(BehaveError, match="net file not found"):
        plot_fcd(df, out, net=run / "missing.net.xml")
    with pytest.raises(BehaveError, match=r"r\.rou\.xml is not a SUMO net"):
        plot_fcd(df, out, net=run / "r.rou.xml")


def test_plot_axis_is_road_position_or_odometer() -> None:
    def trace(distance: list[float]) -> pd.DataFrame:
        n = len(distance)
        odometer = [float(i) * 30 for i in range(n)]
        return pd.DataFrame({"id": ["a"] * n, "time": range(n), "distance": distance, "odometer": odometer})

    assert _along_column(trace([100.0, 130.0, 159.99, 159.98, 190.0])) == "distance"  # rounding noise
    assert _along_column(trace([240.0, 270.0, 0.5, 30.5])) == "odometer"  # per-edge sawtooth
    assert _along_column(trace([float("nan")] * 3)) == "odometer"
    # traces are judged one by one: one car's start below another's end is no sawtooth
    two = pd.concat([trace([500.0, 530.0]), trace([0.0, 30.0]).assign(id="b")])
    assert _along_column(two) == "distance"
    assert set(ALONG_LABELS.values()) >= {"road position [m]", "distance driven since insertion [m]"}


def test_plot_colours_a_vehicle_by_its_last_type_as_the_report_groups_it() -> None:
    """A car `--share` made an agent starts with the scenario's type, and SUMO's rows for an agent
    it drives carry its copy `behave_keeper@<id>`: drawn by the first record's exact type, every
    agent of a `--sumocfg` run was a grey SUMO car in the time-space picture."""
    df = pd.DataFrame(
        {
            "time": [0.0, 0.2, 0.0, 0.2, 0.0],
            "id": ["shared", "shared", "handed", "handed", "sumo"],
            "type": ["car", "behave_keeper", "behave_overtaker", "behave_overtaker@handed", "car"],
        }
    )
    styles = trace_styles(df)
    assert styles["shared"][0] == "keeper (learned)"
    assert styles["handed"][0] == "overtaker (learned)"
    assert styles["sumo"][0] == "SUMO car"
