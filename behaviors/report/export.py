"""SUMO floating car data (FCD): record it, read it back, convert it for other simulators.

SUMO writes the FCD itself (see `fcd_options`); conversion goes through SUMO's own
`tools/traceExporter.py`, whose omnet and kml writers emit XML that does not parse: the
outputs are fixed up here and checked before they are shipped.
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
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

from behaviors.errors import BehaveError
from behaviors.files import atomic_path, check_output_path, temp_dir
from behaviors.sumo.fcd_parquet import precision_options
from behaviors.sumo.sumo_home import sumo_home, sumo_tool

if TYPE_CHECKING:
    from collections.abc import Iterator
    from io import BufferedIOBase

    import pandas as pd
    import xmlschema

FCD_SUFFIXES = (".xml", ".csv", ".parquet")
# SUMO 1.28 names; `lon`/`lat` are rejected (geo output reuses x/y), and an unknown name is
# only logged as an error while SUMO carries on with exit code 0.
# `distance` is SUMO's linear referencing (kilometrage of the edges, else the position on the
# edge); `odometer` is the distance driven since insertion.
FCD_ATTRIBUTES: tuple[str, ...] = ("x", "y", "angle", "type", "speed", "pos", "lane", "posLat")
FCD_ATTRIBUTES += ("acceleration", "distance", "odometer")
TEXT_COLUMNS = ("id", "type", "lane")
COLUMNS: tuple[str, ...] = ("time", "id", "x", "y", "angle", "type", "speed", "pos", "lane", "posLat")
COLUMNS += ("acceleration", "distance", "odometer")
GEO_COLUMNS = tuple({"x": "lon", "y": "lat"}.get(c, c) for c in COLUMNS)
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
GEO_HEADER = re.compile(r'<fcd-output\.geo value="true"|<!-- behave populate:[^\n]* geo=true')
TIMESTEP = re.compile(rb'<timestep time="([^"]*)"')


def fcd_options(path: Path, *, geo: bool, precise: bool = False) -> list[str]:
    """SUMO options writing FCD to `path`; its suffix picks the format (xml, csv, parquet). `precise`:
    every decimal SUMO's parquet keeps (for the csv behaviors.sumo.fcd_parquet streams into parquet), in
    each of SUMO's outputs: `--precision` is SUMO's for all of them."""
    _fcd_format(path)
    options = ["--fcd-output", str(path), "--fcd-output.attributes", ",".join(FCD_ATTRIBUTES)]
    options += ["--fcd-output.acceleration", "--fcd-output.distance"]
    options += precision_options() if precise else []
    return [*options, "--fcd-output.geo"] if geo else options


def _fcd_format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FCD_SUFFIXES:
        raise BehaveError(f"{path}: FCD file name must end in one of {', '.join(FCD_SUFFIXES)}")
    return suffix[1:]


def read_fcd(path: Path, *, geo: bool = False) -> pd.DataFrame:
    """One row per vehicle and time step, the same columns and dtypes for xml, csv and parquet.

    Coordinates are named lon/lat when the file says it holds them (see `fcd_is_geo`) or
    `geo` is given: SUMO's geo output keeps calling them x/y, and its csv/parquet carry no
    header that would tell.
    """
    path = Path(path)
    reader = {"xml": _read_xml, "csv": _read_csv, "parquet": _read_parquet}[_fcd_format(path)]
    if not path.is_file():
        raise BehaveError(f"FCD file not found: {path}")
    df = reader(path)
    if geo or (not {"lon", "lat"} & set(df.columns) and fcd_is_geo(path)):
        df = df.rename(columns={"x": "lon", "y": "lat"})
    return _normalise(df)


def fcd_is_geo(path: Path) -> bool:
    """Whether an FCD file says it holds lon/lat: SUMO's or behave's XML header, behave's columns."""
    path = Path(path)
    fmt = _fcd_format(path)
    if fmt == "xml":
        with open(path, encoding="utf-8", errors="replace") as f:
            header = f.read(65536).split("<fcd-export", 1)[0]
        return GEO_HEADER.search(header) is not None
    if fmt == "csv":
        with open(path, encoding="utf-8", errors="replace") as f:
            columns = f.readline().strip().split(";")
    else:
        import pyarrow.parquet as pq

        try:
            columns = pq.ParquetFile(path).schema_arrow.names
        except Exception:  # pyarrow raises several types on files that are not parquet
            return False
    return "vehicle_lon" in columns


def seal_fcd(partial: Path, final: Path, *, header: str, geo: bool, last_time: float, step: float) -> None:
    """Check SUMO's FCD at `partial` is whole, then move it to `final` (atomically).

    SUMO writes its outputs without reporting write errors: on a full disk it leaves a
    CSV cut mid-row, an empty Parquet file or XML without its end, and exits normally. A
    file is whole when it parses to its end and its last time step is `last_time`. XML gets
    `header` in place of SUMO's (equal seeds give equal bytes); geo csv/parquet name their
    coordinate columns lon/lat, so the file says what it holds.
    """
    try:
        _check_last_time(_last_time(partial), last_time, step)
    except CutShort as err:
        raise BehaveError(
            f"SUMO's FCD output was cut short, {final} not written (disk full?): {err}"
        ) from None
    if final.suffix == ".xml":
        with atomic_path(final) as tmp:
            _copy_with_header(partial, tmp, header)
    elif geo and (final.suffix == ".csv" or not fcd_is_geo(partial)):  # a streamed parquet says lon/lat
        with atomic_path(final) as tmp:
            (_geo_csv if final.suffix == ".csv" else _geo_parquet)(partial, tmp)
    else:
        os.replace(partial, final)


def last_whole_step(partial: Path) -> float | None:
    """The time of the last whole step in an FCD SUMO stopped writing in the middle of a run (None: no
    step), the file cut back to it where it ends inside one: a csv row without its newline, XML
    without its end (closed after its last whole <timestep>). A parquet file is whole or unreadable."""
    path = Path(partial)
    fmt = _fcd_format(path)
    if fmt == "csv":
        with open(path, "rb+") as f:
            size = f.seek(0, os.SEEK_END)
            f.seek(max(0, size - 65536))
            tail = f.read()
            f.truncate(size - len(tail) + tail.rfind(b"\n") + 1)
    elif fmt == "xml":
        try:
            _xml_last_time(path)
        except CutShort:  # not well-formed: SUMO stopped inside it
            _close_xml(path)
    try:
        return _last_time(path)
    except CutShort:
        return None


def _close_xml(path: Path) -> None:
    """XML FCD cut back to its last </timestep> and closed (a run SUMO left unclosed)."""
    end = b"</timestep>"
    with open(path, "rb+") as f:
        at = f.seek(0, os.SEEK_END)
        while at > 0:
            start = max(0, at - (1 << 20))
            f.seek(start)
            block = f.read(at - start + len(end))
            found = block.rfind(end)
            if found >= 0:
                f.seek(start + found + len(end))
                f.truncate()
                f.write(b"\n</fcd-export>\n")
                return
            at = start


def _last_time(path: Path) -> float:
    """The last time step of a whole FCD file (CutShort if it is not whole or holds none)."""
    last = {"xml": _xml_last_time, "csv": _csv_last_time, "parquet": _parquet_last_time}[_fcd_format(path)]
    return _read_time(last(path))


class CutShort(Exception):
    """An output file that does not reach its end."""


def _read_time(time: str | float | None) -> float:
    try:
        return float(time)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise CutShort(f"last time step {time!r} unreadable") from None


def _check_last_time(seen: float, last_time: float, step: float) -> None:
    if abs(seen - last_time) > step / 2:
        raise CutShort(f"last time step {seen:g} s, expected {last_time:g} s")


def _xml_last_time(path: Path) -> str | None:
    """Well-formed to its closing tag (expat in C, 1 MB blocks); the last <timestep> time."""
    import xml.parsers.expat

    parser = xml.parsers.expat.ParserCreate()
    last, tail = None, b""
    try:
        with open(path, "rb") as f:
            while block := f.read(1 << 20):
                parser.Parse(block, False)
                seen = tail + block
                found = TIMESTEP.match(seen, max(seen.rfind(b"<timestep "), 0))
                last = found[1] if found else last
                tail = block[-200:]
            parser.Parse(b"", True)
    except xml.parsers.expat.ExpatError as err:
        raise CutShort(f"XML {err}") from None
    return last.decode() if last else None


def _csv_last_time(path: Path) -> str:
    """The last row ends with a newline and has the header's fields; its time is the last step."""
    with open(path, "rb") as f:
        header = f.readline()
        f.seek(max(f.tell(), os.fstat(f.fileno()).st_size - 65536))
        end = f.read()
    if not header.endswith(b"\n") or not end.endswith(b"\n"):
        raise CutShort("CSV ends mid-row")
    row = (end.rstrip(b"\n").rsplit(b"\n", 1)[-1] or header).split(b";")
    if len(row) != header.count(b";") + 1:
        raise CutShort("CSV last row has missing fields")
    return row[0].decode(errors="replace")


def _parquet_last_time(path: Path) -> float | None:
    """Parquet's footer is written last: a cut file does not open; then the last time step."""
    import pyarrow.parquet as pq

    try:
        table = pq.ParquetFile(path)
        groups = table.metadata.num_row_groups
        times = table.read_row_group(groups - 1, columns=["timestep_time"]).column(0) if groups else []
    except Exception as err:  # pyarrow raises several types on a cut file
        raise CutShort(str(err)) from None
    return times[-1].as_py() if len(times) else None


def _copy_with_header(source: Path, target: Path, header: str) -> None:
    """SUMO's XML with its option comment replaced by `header`."""
    with open(source, encoding="utf-8") as src, open(target, "w", encoding="utf-8") as dst:
        in_comment = False
        for line in src:
            if not in_comment and line.startswith("<!-- generated on"):
                in_comment = True
                dst.write(header)
            if in_comment:
                in_comment = "-->" not in line
                continue
            dst.write(line)
            if line.startswith("<fcd-export"):
                break
        shutil.copyfileobj(src, dst, 1 << 20)


def _geo_csv(source: Path, target: Path) -> None:
    with open(source, "rb") as src, open(target, "wb") as dst:
        dst.write(_geo_names(src.readline().decode()).encode())
        shutil.copyfileobj(src, dst, 1 << 20)


def _geo_parquet(source: Path, target: Path) -> None:
    """Row group by row group, so memory stays bounded on long traces."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.ParquetFile(source)
    names = _geo_names(";".join(table.schema_arrow.names)).split(";")
    schema = pa.schema([f.with_name(n) for f, n in zip(table.schema_arrow, names, strict=True)])
    with pq.ParquetWriter(target, schema) as writer:
        for k in range(table.metadata.num_row_groups):
            writer.write_table(table.read_row_group(k).rename_columns(names))


def _geo_names(header: str) -> str:
    return re.sub(r"\bvehicle_x\b", "vehicle_lon", re.sub(r"\bvehicle_y\b", "vehicle_lat", header))


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

    columns = GEO_COLUMNS if "lon" in df.columns else COLUMNS
    extra = [c for c in df.columns if c not in columns]
    df = df.reindex(columns=[*columns, *extra]).reset_index(drop=True)
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
    source_format = _fcd_format(fcd)
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
        _check_fcd_root(fcd)  # traceExporter would die with a traceback on it
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
