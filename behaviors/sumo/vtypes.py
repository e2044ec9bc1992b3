"""Vehicle sizes and classes by vType, for drawing an FCD (`behave animate`): FCD records each
vehicle's vType id but not its size.

A vType's length, width and vClass come from the files that define it (a scenario's route and
additional files, behave's own vTypes) where they can be found; what a vType leaves out, and a type
no file defines, takes SUMO's defaults for its vClass (a type no file defines: the class its id names,
`lorry_eu` a truck, else a passenger car).
"""

from __future__ import annotations

import gzip
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class VehicleKind:
    length: float  # m, front bumper to rear bumper
    width: float  # m
    vclass: str  # SUMO's vClass


VCLASS_SIZES: dict[str, tuple[float, float]] = {
    "passenger": (5.0, 1.8), "private": (5.0, 1.8), "taxi": (5.0, 1.8), "evehicle": (5.0, 1.8),
    "authority": (5.0, 1.8), "army": (5.0, 1.8), "vip": (5.0, 1.8), "hov": (5.0, 1.8),
    "emergency": (6.5, 2.16), "delivery": (6.5, 2.16), "truck": (7.1, 2.4), "trailer": (16.5, 2.55),
    "bus": (12.0, 2.5), "coach": (14.0, 2.6), "motorcycle": (2.2, 0.9), "moped": (2.1, 0.8),
    "bicycle": (1.6, 0.65), "scooter": (1.2, 0.5), "pedestrian": (0.215, 0.478), "tram": (22.0, 2.4),
    "rail_urban": (36.5, 3.0), "rail": (67.0, 2.84), "rail_electric": (25.0, 2.95),
    "rail_fast": (25.0, 2.95), "ship": (17.0, 4.0),
}  # fmt: skip
"""(length, width) in metres of SUMO's vType defaults per vClass (SUMO's "Vehicle Type Parameter
Defaults"); a class not listed is drawn as a passenger car."""
PASSENGER = "passenger"
SUMO_TYPES = {
    "DEFAULT_VEHTYPE": "passenger", "DEFAULT_PEDTYPE": "pedestrian", "DEFAULT_BIKETYPE": "bicycle",
    "DEFAULT_TAXITYPE": "taxi", "DEFAULT_RAILTYPE": "rail", "DEFAULT_CONTAINERTYPE": "passenger",
}  # fmt: skip
"""SUMO's built-in vTypes and their classes."""
NAME_CLASSES = {
    "lorry": "truck", "truck": "truck", "hgv": "truck", "trailer": "trailer", "semitrailer": "trailer",
    "bus": "bus", "coach": "coach", "van": "delivery", "delivery": "delivery", "motorcycle": "motorcycle",
    "motorbike": "motorcycle", "moped": "moped", "bicycle": "bicycle", "bike": "bicycle", "tram": "tram",
}  # fmt: skip
"""Words of a vType id no file defines, and the vClass they name."""


def class_kind(vclass: str) -> VehicleKind:
    """A vClass's default size (a passenger car's for a class not in VCLASS_SIZES)."""
    length, width = VCLASS_SIZES.get(vclass, VCLASS_SIZES[PASSENGER])
    return VehicleKind(length, width, vclass)


def read_vtypes(files: Iterable[Path]) -> dict[str, VehicleKind]:
    """vType id -> its kind, from every <vType> in `files` (plain or gzip XML); a file that cannot be
    read is skipped. A later file's definition of the same id wins, as SUMO loads them."""
    kinds: dict[str, VehicleKind] = {}
    for path in files:
        try:
            with _open(Path(path)) as f:
                for _, elem in ET.iterparse(f):
                    if elem.tag == "vType" and elem.get("id"):
                        kinds[str(elem.get("id"))] = _kind(elem)
                    elem.clear()
        except (OSError, ET.ParseError, EOFError):
            continue
    return kinds


def _open(path: Path):  # type: ignore[no-untyped-def]
    with open(path, "rb") as f:
        compressed = f.read(2) == b"\x1f\x8b"
    return gzip.open(path, "rb") if compressed else open(path, "rb")


def _kind(elem: ET.Element) -> VehicleKind:
    vclass = elem.get("vClass") or PASSENGER
    default = class_kind(vclass)
    return VehicleKind(
        _size(elem.get("length"), default.length), _size(elem.get("width"), default.width), vclass
    )


def _size(text: str | None, default: float) -> float:
    try:
        value = float(text) if text is not None else default
    except ValueError:
        return default
    return value if value > 0 else default


def kind_of(vtype: str, known: dict[str, VehicleKind]) -> VehicleKind:
    """The kind of an FCD record's vType: SUMO's copy for one vehicle, `lorry@v3`, is its base type's;
    a type no file defined is the class its id names (NAME_CLASSES), else a passenger car."""
    base = vtype.split("@", 1)[0]
    if base in known:
        return known[base]
    if base in SUMO_TYPES:
        return class_kind(SUMO_TYPES[base])
    if base in VCLASS_SIZES:
        return class_kind(base)
    for word in re.split(r"[^a-z]+", base.lower()):
        if word in NAME_CLASSES:
            return class_kind(NAME_CLASSES[word])
    return class_kind(PASSENGER)


HEADER_FILES = re.compile(r'<(route-files|additional-files|configuration-file) value="([^"]*)"')
BEHAVE_SUMOCFG = re.compile(r"<!-- behave populate:[^\n]* sumocfg=(\S+)")


def files_named_by(fcd: Path) -> list[Path]:
    """The route, additional and sumocfg files an XML FCD's header names (SUMO's option comment, or
    behave's `sumocfg=`) that exist as written or beside the FCD; a sumocfg stands for its route and
    additional files."""
    from behaviors.errors import BehaveError
    from behaviors.sumo.scenario_config import read_sumocfg

    if fcd.suffix.lower() != ".xml":
        return []
    with open(fcd, encoding="utf-8", errors="replace") as f:
        head = f.read(65536).split("<fcd-export", 1)[0]
    names = [name for _, listed in HEADER_FILES.findall(head) for name in listed.split(",") if name.strip()]
    names += BEHAVE_SUMOCFG.findall(head)
    out: list[Path] = []
    for name in names:
        path = next((p for p in (Path(name.strip()), fcd.parent / name.strip()) if p.is_file()), None)
        if path is None:
            continue
        if path.suffix == ".sumocfg":
            try:
                scenario = read_sumocfg(path)
            except BehaveError:
                continue
            out += [*scenario.routes, *scenario.additional]
        else:
            out.append(path)
    return out
