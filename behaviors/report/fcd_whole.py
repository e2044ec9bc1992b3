"""SUMO's FCD output checked whole and moved into place (`seal_fcd`), or cut back to its last whole step
where SUMO stopped in the middle of a run (`last_whole_step`)."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from behaviors.errors import BehaveError
from behaviors.files import atomic_path
from behaviors.report.fcd_read import fcd_format, fcd_is_geo

TIMESTEP = re.compile(rb'<timestep time="([^"]*)"')


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
    fmt = fcd_format(path)
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
    last = {"xml": _xml_last_time, "csv": _csv_last_time, "parquet": _parquet_last_time}[fcd_format(path)]
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
