"""SUMO's floating car data (FCD): the options that have SUMO write it (xml, csv or parquet, by the file's
suffix), reading it back into one table, and checking XML against SUMO's schema."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

from behaviors.errors import BehaveError
from behaviors.sumo.fcd_parquet import precision_options
from behaviors.sumo.sumo_home import sumo_home

if TYPE_CHECKING:
    from collections.abc import Iterator

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
GEO_HEADER = re.compile(r'<fcd-output\.geo value="true"|<!-- behave populate:[^\n]* geo=true')


def fcd_options(path: Path, *, geo: bool, precise: bool = False) -> list[str]:
    """SUMO options writing FCD to `path`; its suffix picks the format (xml, csv, parquet). `precise`:
    every decimal SUMO's parquet keeps (for the csv behaviors.sumo.fcd_parquet streams into parquet), in
    each of SUMO's outputs: `--precision` is SUMO's for all of them."""
    fcd_format(path)
    options = ["--fcd-output", str(path), "--fcd-output.attributes", ",".join(FCD_ATTRIBUTES)]
    options += ["--fcd-output.acceleration", "--fcd-output.distance"]
    options += precision_options() if precise else []
    return [*options, "--fcd-output.geo"] if geo else options


def fcd_format(path: Path) -> str:
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
    reader = {"xml": _read_xml, "csv": _read_csv, "parquet": _read_parquet}[fcd_format(path)]
    if not path.is_file():
        raise BehaveError(f"FCD file not found: {path}")
    df = reader(path)
    if geo or (not {"lon", "lat"} & set(df.columns) and fcd_is_geo(path)):
        df = df.rename(columns={"x": "lon", "y": "lat"})
    return _normalise(df)


def fcd_is_geo(path: Path) -> bool:
    """Whether an FCD file says it holds lon/lat: SUMO's or behave's XML header, behave's columns."""
    path = Path(path)
    fmt = fcd_format(path)
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


def check_fcd_root(path: Path) -> None:
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
