"""SUMO floating car data (FCD): record it, read it back, convert it for other simulators.

SUMO writes the FCD itself (see `fcd_options`); conversion goes through SUMO's own
`tools/traceExporter.py`, whose omnet and kml writers emit XML that does not parse: the
outputs are fixed up here and checked before they are shipped.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

from behaviors.errors import BehaveError
from behaviors.sumo_home import sumo_home, sumo_tool

if TYPE_CHECKING:
    from collections.abc import Iterator

    import pandas as pd
    import xmlschema

FCD_SUFFIXES = (".xml", ".csv", ".parquet")
# SUMO 1.28 names; `lon`/`lat` are rejected (geo output reuses x/y), and an unknown name is
# only logged as an error while SUMO carries on with exit code 0.
# `distance` is SUMO's linear referencing (kilometrage of the edges, else the position on the
# edge); `odometer` is the distance driven since insertion.
FCD_ATTRIBUTES = ("x", "y", "angle", "type", "speed", "pos", "lane", "posLat")
FCD_ATTRIBUTES += ("acceleration", "distance", "odometer")
TEXT_COLUMNS = ("id", "type", "lane")
COLUMNS = ("time", "id", "x", "y", "angle", "type", "speed", "pos", "lane", "posLat")
COLUMNS += ("acceleration", "distance", "odometer")
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


def fcd_options(path: Path, *, geo: bool) -> list[str]:
    """SUMO options writing FCD to `path`; its suffix picks the format (xml, csv, parquet)."""
    _fcd_format(path)
    options = ["--fcd-output", str(path), "--fcd-output.attributes", ",".join(FCD_ATTRIBUTES)]
    options += ["--fcd-output.acceleration", "--fcd-output.distance"]
    return [*options, "--fcd-output.geo"] if geo else options


def _fcd_format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FCD_SUFFIXES:
        raise BehaveError(f"{path}: FCD file name must end in one of {', '.join(FCD_SUFFIXES)}")
    return suffix[1:]


def read_fcd(path: Path, *, geo: bool = False) -> pd.DataFrame:
    """One row per vehicle and time step, the same columns and dtypes for xml, csv and parquet.

    `geo` names the coordinates lon/lat: SUMO's geo output keeps calling them x/y, and
    csv/parquet carry no header that would tell.
    """
    path = Path(path)
    reader = {"xml": _read_xml, "csv": _read_csv, "parquet": _read_parquet}[_fcd_format(path)]
    if not path.is_file():
        raise BehaveError(f"FCD file not found: {path}")
    df = _normalise(reader(path))
    return df.rename(columns={"x": "lon", "y": "lat"}) if geo else df


def _not_fcd(path: Path, why: object) -> BehaveError:
    return BehaveError(f"{path} is not an FCD file ({why})")


def _read_xml(path: Path) -> pd.DataFrame:
    import pandas as pd

    rows: list[dict[str, str]] = []
    time = ""
    events = ET.iterparse(path, events=("start", "end"))
    try:
        root = _fcd_root(path, events)
        for event, elem in events:
            if event == "start" and elem.tag == "timestep":
                time = elem.get("time", "")
            elif event == "end" and elem.tag == "vehicle":
                rows.append({"time": time, **elem.attrib})
            elif event == "end" and elem.tag == "timestep":
                root.clear()  # keeps memory flat on long traces
    except ET.ParseError as err:
        raise _not_fcd(path, err) from None
    return pd.DataFrame(rows, columns=["time", "id"] if not rows else None)


def _fcd_root(path: Path, events: Iterator[tuple[str, ET.Element]]) -> ET.Element:
    _, root = next(events)
    if root.tag != "fcd-export":
        raise _not_fcd(path, f"root element <{root.tag}>, expected <fcd-export>")
    return root


def _check_fcd_root(path: Path) -> None:
    try:
        _fcd_root(path, ET.iterparse(path, events=("start",)))
    except ET.ParseError as err:
        raise _not_fcd(path, err) from None


def _read_csv(path: Path) -> pd.DataFrame:
    import pandas as pd

    try:
        df = pd.read_csv(path, sep=";", dtype=str, keep_default_na=False, na_values=[""])
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise _not_fcd(path, err) from None
    return _vehicle_columns(path, df)


def _read_parquet(path: Path) -> pd.DataFrame:
    import pandas as pd
    import pyarrow

    try:
        df = pd.read_parquet(path)
    except (pyarrow.ArrowException, OSError) as err:
        raise _not_fcd(path, err) from None
    return _vehicle_columns(path, df)


def _vehicle_columns(path: Path, df: pd.DataFrame) -> pd.DataFrame:
    """SUMO's tables prefix columns by element (timestep_time, vehicle_x, person_x, ...)."""
    if "timestep_time" not in df.columns:
        raise _not_fcd(path, "no timestep_time column")
    if "vehicle_id" not in df.columns:  # no vehicle ever drove
        return df.iloc[0:0, :0].assign(time=[], id=[])
    vehicles = df[df["vehicle_id"].notna()]  # drops empty steps and person rows
    keep = {c: c.removeprefix("vehicle_") for c in df.columns if c.startswith("vehicle_")}
    return vehicles[["timestep_time", *keep]].rename(columns={"timestep_time": "time", **keep})


def _normalise(df: pd.DataFrame) -> pd.DataFrame:
    """Canonical column order and dtypes; absent attributes become missing values."""
    import pandas as pd

    extra = [c for c in df.columns if c not in COLUMNS]
    df = df.reindex(columns=[*COLUMNS, *extra]).reset_index(drop=True)
    for column in df.columns:
        if column in TEXT_COLUMNS:
            df[column] = df[column].astype(pd.StringDtype())
        else:
            df[column] = pd.to_numeric(df[column], errors="coerce").astype("float64")
    return df


@cache
def _fcd_schema() -> xmlschema.XMLSchema:
    """Built once: parsing the XSD costs more than validating a small file."""
    import xmlschema

    return xmlschema.XMLSchema(sumo_home() / "data" / "xsd" / "fcd_file.xsd")


def validate_fcd_xml(path: Path) -> None:
    """Check an FCD XML file against SUMO's schema; the first violation becomes the error."""
    import xmlschema

    if not Path(path).is_file():
        raise BehaveError(f"FCD file not found: {path}")
    try:
        error = next(_fcd_schema().iter_errors(str(path)), None)
    except (ET.ParseError, xmlschema.XMLSchemaException) as err:
        raise BehaveError(f"{path} is not valid FCD XML: {err}") from None
    if error is not None:
        where = f" at {error.path}" if error.path else ""
        raise BehaveError(f"{path} is not valid FCD XML{where}: {error.reason}")


def export_fcd(fcd: Path, fmt: str, *, net: Path | None, out: Path) -> list[Path]:
    """Convert FCD (xml, csv or parquet) with traceExporter; returns the files written.

    `out` is the main file; ns2 adds `<stem>.config<suffix>` and `<stem>.activity<suffix>`.
    gpx and kml need lon/lat: an FCD recorded with geo output, or `net` with a projection.
    Files appear complete or not at all (temp dir beside `out`, then os.replace).
    """
    fcd, out = Path(fcd), Path(out)
    if fmt not in EXPORT_FORMATS:
        raise BehaveError(f"unknown export format {fmt!r}: choose one of {', '.join(EXPORT_FORMATS)}")
    if not fcd.is_file():
        raise BehaveError(f"FCD file not found: {fcd}")
    source_format = _fcd_format(fcd)
    geo = fmt in GEO_FORMATS and not (source_format == "xml" and _recorded_geo(fcd))
    if geo:
        _require_projection(net, fmt)
    work = _temp_dir(out)
    try:
        source = _traceable_fcd(fcd, source_format, work / "input.fcd.xml", net if geo else None)
        written = _run_trace_exporter(source, fmt, out.name, work)
        for path in written:
            _FIXES.get(fmt, _unchanged)(path)
        finals = [out.with_name(path.name) for path in written]
        for path, final in zip(written, finals, strict=True):
            os.replace(path, final)
        return finals
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _temp_dir(out: Path) -> Path:
    if not out.parent.is_dir():
        raise BehaveError(f"output directory does not exist: {out.parent}")
    try:
        return Path(tempfile.mkdtemp(prefix=".behave-export-", dir=out.parent))
    except OSError as err:
        raise BehaveError(f"output directory is not writable: {out.parent} ({err.strerror})") from None


def _recorded_geo(fcd: Path) -> bool:
    """SUMO's FCD XML header repeats its options, so a geo recording says so."""
    with open(fcd, encoding="utf-8", errors="replace") as f:
        header = f.read(65536).split("<fcd-export", 1)[0]
    return re.search(r'<fcd-output\.geo value="true"', header) is not None


def _require_projection(net: Path | None, fmt: str) -> None:
    need = f"{fmt} needs lon/lat: record the FCD with geo output or give a net with a projection"
    if net is None:
        raise BehaveError(need)
    if not Path(net).is_file():
        raise BehaveError(f"net file not found: {net}")
    try:
        location = next((e for _, e in ET.iterparse(net) if e.tag == "location"), None)
    except ET.ParseError as err:
        raise BehaveError(f"{net} is not a SUMO net ({err})") from None
    if location is None or location.get("projParameter", "!") == "!":
        raise BehaveError(f"{need} ({net} has no projection)")


def _traceable_fcd(fcd: Path, source_format: str, tmp: Path, net: Path | None) -> Path:
    """An FCD XML file traceExporter can read: converted from csv/parquet or to lon/lat."""
    if source_format == "xml" and net is None:
        _check_fcd_root(fcd)  # traceExporter would die with a traceback on it
        return fcd
    df = read_fcd(fcd)
    if net is not None:
        df = _to_lonlat(df, net, tmp.parent)
    _write_fcd_xml(df, tmp)
    return tmp


def _to_lonlat(df: pd.DataFrame, net: Path, work: Path) -> pd.DataFrame:
    """Project x/y with SUMO's own PROJ (pyproj is not installed) through libsumo, in a child
    process: libsumo allows one simulation per process and the caller may be running one."""
    xy, lonlat = work / "xy.txt", work / "lonlat.txt"
    xy.write_text("".join(f"{x!r} {y!r}\n" for x, y in zip(df["x"], df["y"], strict=True)))
    code = "import sys; from behaviors.export import _lonlat_main; _lonlat_main(*sys.argv[1:])"
    command = [sys.executable, "-c", code, str(net), str(xy), str(lonlat)]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        lines = done.stderr.strip().splitlines() or ["no output"]
        raise BehaveError(f"projecting x/y to lon/lat with {net} failed: {lines[-1]}")
    pairs = [line.split() for line in lonlat.read_text().splitlines()]
    return df.assign(x=[float(p[0]) for p in pairs], y=[float(p[1]) for p in pairs])


def _lonlat_main(net: str, xy: str, lonlat: str) -> None:
    """Child side of `_to_lonlat`."""
    import libsumo

    libsumo.start(["sumo", "-n", net, "--no-step-log", "--no-warnings"])
    try:
        with open(xy) as source, open(lonlat, "w") as target:
            for line in source:
                lon, lat = libsumo.simulation.convertGeo(*map(float, line.split()))
                target.write(f"{lon!r} {lat!r}\n")
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


def _fix_gpx(path: Path) -> None:
    """Well-formed already, but GPX 1.0 readers need its namespace and a creator."""
    text = path.read_text(encoding="utf-8")
    root = f'<gpx version="1.0" creator="behave (SUMO traceExporter)" xmlns="{GPX_NAMESPACE}">'
    _ship_xml(path, text.replace('<gpx version="1.0">', root, 1))


def _ship_xml(path: Path, text: str) -> None:
    try:
        ET.fromstring(text.encode("utf-8"))
    except ET.ParseError as err:
        raise BehaveError(f"traceExporter wrote unparsable XML ({path.name}: {err})") from None
    path.write_text(text, encoding="utf-8")


def _unchanged(path: Path) -> None:
    """ns2 and ipg are plain text."""


_FIXES = {"omnet": _fix_omnet, "kml": _fix_kml, "gpx": _fix_gpx}
