"""SUMO floating car data (FCD) converted for other simulators (ns2, omnet, gpx, kml, ipg).

Conversion goes through SUMO's own `tools/traceExporter.py`, whose omnet and kml writers emit XML
that does not parse: the outputs are fixed up here and checked before they are shipped. Recording
and reading FCD are fcd_read.py's.
"""

from __future__ import annotations

import gzip
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

from behaviors.errors import BehaveError
from behaviors.files import check_output_path, temp_dir
from behaviors.report.fcd_read import check_fcd_root, fcd_format, fcd_is_geo, read_fcd
from behaviors.sumo.sumo_home import sumo_home, sumo_tool

if TYPE_CHECKING:
    from io import BufferedIOBase

    import pandas as pd

EXPORT_FORMATS = ("ns2", "omnet", "gpx", "kml", "ipg")
GEO_FORMATS = ("gpx", "kml")
OMNET_BOGUS_LINE = re.compile(r"^<xmlns:xsi=[^\n]*>\n", re.MULTILINE)
OMNET_ROOT_ATTRS = (
    ' xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"'
    ' xsi:noNamespaceSchemaLocation="mobility_trace.xsd"'
)
KML_GX = "http://www.google.com/kml/ext/2.2"
KML_DOC_HEADER = (
    "\t<name>SUMO FCD</name>\n\t<open>1</open>\n\t<description>traces of SUMO FCD output</description>\n"
)
GPX_NAMESPACE = "http://www.topografix.com/GPX/1/0"
GPX_TIME = re.compile(r"<time>([^<]*)</time>")
GPX_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)
"""The date and time of an FCD's time 0 in GPX, unless given (`behave export --start-time`): SUMO's
seconds are no date."""
IPG_HEADER = "# Time tx ty tz rx ry rz"


def export_fcd(
    fcd: Path, fmt: str, *, net: Path | None, out: Path, start: datetime | None = None
) -> list[Path]:
    """Convert FCD (xml, csv or parquet) with traceExporter (ipg: behave's own writer, see `write_ipg`);
    returns the files written.

    `out` is the main file; ns2 adds `<stem>.config<suffix>` and `<stem>.activity<suffix>`. `start`:
    the date and time of the FCD's time 0 in gpx's ISO times (None: GPX_EPOCH).
    gpx and kml need lon/lat: an FCD recorded with geo output (used as it is, `net` or not),
    or `net` with a projection. ns2, omnet and ipg need metres: a geo FCD is projected back
    with `net`. Files appear complete or not at all (temp dir beside `out`, then os.replace).
    """
    fcd, out = Path(fcd), Path(out)
    if fmt not in EXPORT_FORMATS:
        raise BehaveError(f"unknown export format {fmt!r}: choose one of {', '.join(EXPORT_FORMATS)}")
    if not fcd.is_file():
        raise BehaveError(f"FCD file not found: {fcd}")
    source_format = fcd_format(fcd)
    projection = _projection_needed(fcd, fmt, net)
    for name in _output_names(fmt, out.name).values():
        check_output_path(out.with_name(name))  # creates missing parent directories
    work = temp_dir(out)
    try:
        source = _traceable_fcd(fcd, source_format, work / "input.fcd.xml", net, projection)
        if fmt == "ipg":
            written = [write_ipg(read_fcd(source), work / out.name)]
        else:
            written = _run_trace_exporter(source, fmt, out.name, work)
        for path in written:
            if fmt == "gpx":
                _fix_gpx(path, start or GPX_EPOCH)
            else:
                _FIXES.get(fmt, _unchanged)(path)
        finals = [out.with_name(path.name) for path in written]
        for path, final in zip(written, finals, strict=True):
            os.replace(path, final)
        return finals
    except OSError as err:
        raise BehaveError(f"cannot write {out}: {err.strerror or err}") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _projection_needed(fcd: Path, fmt: str, net: Path | None) -> str | None:
    """`to_geo`, `from_geo` or None: how x/y must be converted for `fmt` (refused if impossible)."""
    geo = fcd_is_geo(fcd)
    if (fmt in GEO_FORMATS) == geo:
        return None  # lon/lat for gpx/kml, metres for the others: never projected twice
    if geo:
        if net is None:
            raise BehaveError(
                f"{fcd} holds lon/lat but {fmt} needs metres: give --net (the net it was recorded on)"
            )
        require_projection(net, f"projecting {fcd} back to metres for {fmt}")
        return "from_geo"
    require_projection(net, f"{fmt} needs lon/lat: record the FCD with geo output or give a net")
    return "to_geo"


def open_net(net: Path) -> BufferedIOBase:
    """A SUMO net file for reading, gzip-compressed (.net.xml.gz) or not."""
    with open(net, "rb") as f:
        compressed = f.read(2) == b"\x1f\x8b"
    return gzip.open(net, "rb") if compressed else open(net, "rb")


def require_projection(net: Path | None, need: str) -> None:
    """A BehaveError saying `need` unless `net` is a SUMO net with a geo projection."""
    if net is None:
        raise BehaveError(need)
    if not Path(net).is_file():
        raise BehaveError(f"net file not found: {net}")
    try:
        with open_net(net) as f:
            location = next((e for _, e in ET.iterparse(f) if e.tag == "location"), None)
    except (ET.ParseError, OSError, EOFError) as err:
        raise BehaveError(f"{net} is not a SUMO net ({err})") from None
    if location is None or location.get("projParameter", "!") == "!":
        raise BehaveError(f"{need} ({net} has no projection)")


def _traceable_fcd(
    fcd: Path, source_format: str, tmp: Path, net: Path | None, projection: str | None
) -> Path:
    """An FCD XML file traceExporter can read: converted from csv/parquet or projected."""
    if source_format == "xml" and projection is None:
        check_fcd_root(fcd)  # traceExporter would die with a traceback on it
        return fcd
    df = read_fcd(fcd)
    if "lon" in df.columns:  # traceExporter reads lon/lat from x/y
        df = df.rename(columns={"lon": "x", "lat": "y"})
    if projection is not None:
        assert net is not None
        df = _project(df, net, tmp.parent, from_geo=projection == "from_geo")
    _write_fcd_xml(df, tmp)
    return tmp


def _project(df: pd.DataFrame, net: Path, work: Path, *, from_geo: bool) -> pd.DataFrame:
    """x/y to lon/lat (or back) with SUMO's own PROJ (pyproj is not installed) through libsumo,
    in a child process: libsumo allows one simulation per process and the caller may run one."""
    source, target = work / "source.txt", work / "target.txt"
    source.write_text("".join(f"{x!r} {y!r}\n" for x, y in zip(df["x"], df["y"], strict=True)))
    code = "import sys; from behaviors.report.export import _project_main; _project_main(*sys.argv[1:])"
    command = [sys.executable, "-c", code, str(net), str(source), str(target), str(int(from_geo))]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        lines = done.stderr.strip().splitlines() or ["no output"]
        raise BehaveError(f"projecting coordinates with {net} failed: {lines[-1]}")
    pairs = [line.split() for line in target.read_text().splitlines()]
    return df.assign(x=[float(p[0]) for p in pairs], y=[float(p[1]) for p in pairs])


def _project_main(net: str, source: str, target: str, from_geo: str) -> None:
    """Child side of `_project`."""
    import libsumo

    libsumo.start(["sumo", "-n", net, "--no-step-log", "--no-warnings"])
    try:
        with open(source) as points, open(target, "w") as out:
            for line in points:
                a, b = libsumo.simulation.convertGeo(*map(float, line.split()), fromGeo=from_geo == "1")
                out.write(f"{a!r} {b!r}\n")
    finally:
        libsumo.close()


def _write_fcd_xml(df: pd.DataFrame, path: Path) -> None:
    """Minimal FCD XML with the attributes traceExporter's writers use."""
    import pandas as pd

    names = ("id", "x", "y", "angle", "type", "speed", "pos", "lane")
    with open(path, "w", encoding="utf-8") as f:
        f.write('<?xml version="1.0" encoding="UTF-8"?>\n<fcd-export>\n')
        for time, step in df.groupby("time", sort=True):
            f.write(f'    <timestep time="{time!r}">\n')
            for row in step[list(names)].itertuples(index=False):
                attrs = " ".join(
                    f"{name}={quoteattr(str(value))}"
                    for name, value in zip(names, row, strict=True)
                    if not pd.isna(value)
                )
                f.write(f"        <vehicle {attrs}/>\n")
            f.write("    </timestep>\n")
        f.write("</fcd-export>\n")


def _output_names(fmt: str, name: str) -> dict[str, str]:
    """traceExporter option per file; the ns2 config names its siblings as given, hence cwd."""
    if fmt != "ns2":
        return {f"--{fmt}-output": name}
    stem, suffix = os.path.splitext(name)
    return {
        "--ns2mobility-output": name,
        "--ns2config-output": f"{stem}.config{suffix}",
        "--ns2activity-output": f"{stem}.activity{suffix}",
    }


def _run_trace_exporter(source: Path, fmt: str, name: str, work: Path) -> list[Path]:
    outputs = _output_names(fmt, name)
    command = [sys.executable, str(sumo_tool("traceExporter.py")), "-i", str(source.resolve())]
    for option, file_name in outputs.items():
        command += [option, file_name]
    env = {**os.environ, "SUMO_HOME": str(sumo_home())}
    done = subprocess.run(command, cwd=work, env=env, capture_output=True, text=True)
    written = [work / file_name for file_name in outputs.values()]
    if done.returncode != 0 or not all(path.is_file() for path in written):
        lines = (done.stderr or done.stdout).strip().splitlines() or ["no output"]
        raise BehaveError(f"traceExporter failed to write {fmt}: {lines[-1]}")
    return written


def _fix_omnet(path: Path) -> None:
    """1.28 writes the root's namespace attributes as a bogus element `<xmlns:xsi=...>`
    above `<mobility_trace>`: move them onto the root."""
    text = path.read_text(encoding="utf-8")
    if OMNET_BOGUS_LINE.search(text):
        text = OMNET_BOGUS_LINE.sub("", text, count=1)
        text = text.replace("<mobility_trace>", f"<mobility_trace{OMNET_ROOT_ATTRS}>", 1)
    _ship_xml(path, text)


def _fix_kml(path: Path) -> None:
    """1.28 uses the gx: prefix undeclared and repeats the Document header per vehicle."""
    text = path.read_text(encoding="utf-8")
    if "xmlns:gx=" not in text:
        text = text.replace("<kml ", f'<kml xmlns:gx="{KML_GX}" ', 1)
    first = text.find(KML_DOC_HEADER) + len(KML_DOC_HEADER)
    text = text[:first] + text[first:].replace(KML_DOC_HEADER, "")
    _ship_xml(path, text)


def _fix_gpx(path: Path, start: datetime) -> None:
    """Well-formed already, but GPX 1.0 readers need its namespace and a creator, and its times to be
    dates (xsd:dateTime): traceExporter writes the FCD's seconds, `<time>0.0</time>`."""
    text = path.read_text(encoding="utf-8")
    root = f'<gpx version="1.0" creator="behave (SUMO traceExporter)" xmlns="{GPX_NAMESPACE}">'
    text = GPX_TIME.sub(lambda m: f"<time>{iso_time(start, float(m[1]))}</time>", text)
    _ship_xml(path, text.replace('<gpx version="1.0">', root, 1))


def iso_time(start: datetime, seconds: float) -> str:
    """`start` + `seconds` as GPX's xsd:dateTime in UTC, to the millisecond: 1970-01-01T00:00:00.200Z."""
    moment = (start.astimezone(timezone.utc) if start.tzinfo else start) + timedelta(seconds=seconds)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{moment.microsecond // 1000:03d}Z"


def write_ipg(df: pd.DataFrame, path: Path) -> Path:
    """IPG trace text with each vehicle's rows together under `# vehicle <id>`, by time (SUMO's
    traceExporter printed every vehicle's rows step by step with no id: 600 vehicles interleaved).
    Columns as SUMO's: time, x, y, z (0 without elevation), the FCD angle, 0, 0."""
    z = df["z"] if "z" in df.columns else None
    with open(path, "w", encoding="utf-8") as f:
        for vid, rows in df.assign(z=0.0 if z is None else z.fillna(0.0)).groupby("id", sort=False):
            f.write(f"# vehicle {vid}\n{IPG_HEADER}\n")
            rows = rows.sort_values("time", kind="stable")
            for t, x, y, height, angle in zip(*(rows[c].tolist() for c in ("time", "x", "y", "z", "angle")),
                                               strict=True):  # fmt: skip
                f.write(f"{t!r} {x!r} {y!r} {height!r} {angle!r} 0 0\n")
    return path


def _ship_xml(path: Path, text: str) -> None:
    try:
        ET.fromstring(text.encode("utf-8"))
    except ET.ParseError as err:
        raise BehaveError(f"traceExporter wrote unparsable XML ({path.name}: {err})") from None
    path.write_text(text, encoding="utf-8")


def _unchanged(path: Path) -> None:
    """ns2 and ipg are plain text."""


_FIXES = {"omnet": _fix_omnet, "kml": _fix_kml}  # gpx: _fix_gpx, with the start time
