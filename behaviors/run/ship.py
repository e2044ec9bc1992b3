"""What a sweep's run on a cluster needs, packed on the machine running the sweep and unpacked on the
worker: no shared disk, nothing on the worker that depends on the sweep machine's paths.

A scenario's package holds a sumocfg and every file it reads (each option's existing files: net,
routes, additionals, ...; and the files its additionals name by relative paths), or a net alone; a
policy's package holds the checkpoint a file or training run names (a bundled policy travels by
name: every node has behave). The files keep their places relative to each other, so the names a
sumocfg or an additional gives relative to itself still hold; a sumocfg's absolute names are
rewritten to the unpacked copies. An output the sumocfg names stays a name: the run writes it into
its own folder as on this machine (`scenario_config.redirect_outputs`).
"""

from __future__ import annotations

import gzip
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from behaviors.errors import BehaveError
from behaviors.sumo.scenario_config import ADDITIONAL_OUTPUTS, OUTPUT_NAMES, read_sumocfg

SCENARIO_DIR, POLICY_DIR = "scenario", "policy"


@dataclass(frozen=True)
class Package:
    """Files as bytes at their places under one folder, and the one of them a run is given."""

    files: tuple[tuple[str, bytes], ...]  # (posix path under the folder, content)
    entry: str  # the path under the folder that the run names (the sumocfg, the net, the checkpoint)

    @property
    def size(self) -> int:
        return sum(len(content) for _, content in self.files)


def pack_scenario(path: str, kind: str) -> Package:
    """A sumocfg (`kind` "sumocfg") with every file it reads, or a net alone (`kind` "net")."""
    scenario = Path(os.path.normpath(path))
    if kind == "net":
        return Package(((scenario.name, read(scenario)),), scenario.name)
    named = sumocfg_inputs(scenario)
    for additional in read_sumocfg(scenario).additional:
        named += additional_inputs(Path(os.path.normpath(additional)))
    places = placed([scenario, *named])
    content = {places[scenario]: shipped_sumocfg(scenario, places)}
    content |= {places[file]: read(file) for file in named}
    return Package(tuple(sorted(content.items())), places[scenario])


def pack_policy(spec: str) -> Package | None:
    """The checkpoint a policy file or training run names, at the place that gives the same label
    (a run's folder name, a file's stem); None for a bundled policy's name, which every node has."""
    from behaviors.learn.policy import resolve

    if not Path(spec).exists():
        return None
    checkpoint, _ = resolve(spec)
    if Path(spec).is_dir():
        entry = PurePosixPath(Path(spec).name)
        name = (entry / checkpoint.relative_to(spec).as_posix()).as_posix()
        return Package(((name, read(checkpoint)),), entry.as_posix())
    return Package(((checkpoint.name, read(checkpoint)),), checkpoint.name)


def unpack(package: Package, folder: Path) -> Path:
    """The package's files written under `folder`; the path of its entry."""
    for name, content in package.files:
        target = folder / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(content)
    return folder / package.entry


def read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise BehaveError(f"cannot read {path} to send it to the cluster: {exc.strerror or exc}") from None


def sumocfg_inputs(sumocfg: Path) -> list[Path]:
    """The existing files the sumocfg's options name (outputs aside), relative names resolved against
    its folder as SUMO resolves them."""
    found: list[Path] = []
    for name, value in read_sumocfg(sumocfg).options:
        if name not in OUTPUT_NAMES:
            found += [file for part in parts(value) if (file := beside(sumocfg, part)).is_file()]
    return unique(found)


def additional_inputs(additional: Path) -> list[Path]:
    """The existing files an additional file names by relative paths (its outputs aside), as
    `scenario_config.rewrite_additional` finds them."""
    opener = gzip.open if additional.suffix == ".gz" else open
    try:
        with opener(additional, "rb") as stream:
            tree = ET.parse(stream)
    except (ET.ParseError, OSError) as exc:
        raise BehaveError(f"cannot read additional file {additional}: {exc}") from None
    found = []
    for elem in tree.iter():
        for attribute, value in elem.attrib.items():
            named = additional.parent / value
            if value and ADDITIONAL_OUTPUTS.get(elem.tag) != attribute and not Path(value).is_absolute():
                found += [Path(os.path.normpath(named))] if named.is_file() else []
    return unique(found)


def shipped_sumocfg(sumocfg: Path, places: dict[Path, str]) -> bytes:
    """The sumocfg as it is, or where it names a file by an absolute path, with that name made the
    packed file's place relative to the sumocfg's (an output within the sumocfg's folder: its place
    there, so that it lands in the run folder where it would on this machine)."""
    text = read(sumocfg)
    root = ET.fromstring(text)
    changed = False
    home = PurePosixPath(places[sumocfg]).parent
    for elem in root.iter():
        value = elem.get("value")
        if value is None or not any(Path(part).is_absolute() for part in parts(value)):
            continue
        names = []
        for part in parts(value):
            file = Path(os.path.normpath(part))
            if file in places:
                part = os.path.relpath(places[file], home)
            elif file.is_absolute() and file.is_relative_to(sumocfg.parent):
                part = file.relative_to(sumocfg.parent).as_posix()
            names.append(part)
        elem.set("value", ",".join(names))
        changed = True
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) if changed else text


def placed(files: list[Path]) -> dict[Path, str]:
    """Each file's place in the package: its path relative to the folder all of them are in."""
    common = Path(os.path.commonpath([file.parent for file in files]))
    return {file: file.relative_to(common).as_posix() for file in files}


def parts(value: str) -> list[str]:
    """The names of a comma-separated option, as SUMO splits them."""
    return [part.strip() for part in value.split(",") if part.strip()]


def beside(sumocfg: Path, name: str) -> Path:
    return Path(os.path.normpath(name if Path(name).is_absolute() else sumocfg.parent / name))


def unique(files: list[Path]) -> list[Path]:
    return list(dict.fromkeys(files))
