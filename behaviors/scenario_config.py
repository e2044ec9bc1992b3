"""A user's SUMO scenario as its .sumocfg sets it: net, routes, additionals, time and options.

behave runs the scenario through SUMO with the sumocfg itself (`-c`), so every option the
user set holds, and overrides on SUMO's command line only what behave must own (see the
README: collision handling, seed, step length, FCD output, its vehicle types added to the
additionals). The few files and times behave needs to know itself are read
here with the standard library's parser; relative paths are resolved against the sumocfg's
folder, as SUMO does.
"""

from __future__ import annotations

import hashlib
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path

from behaviors.errors import BehaveError
from behaviors.sim import SimOptions

LATERAL_RESOLUTION = 0.8
"""m: SUMO's sublane width behave needs for its agents' sideways moves, where the sumocfg sets none."""


@dataclass(frozen=True)
class ScenarioConfig:
    """What behave needs to know of a sumocfg; everything else SUMO reads from the file itself."""

    path: Path
    net: Path
    routes: tuple[Path, ...] = ()
    additional: tuple[Path, ...] = ()
    begin: float = 0.0
    end: float | None = None
    step_length: float | None = None
    lateral_resolution: float | None = None
    ballistic: bool = False  # step-method.ballistic

    @property
    def duration(self) -> float | None:
        """Simulated seconds from begin to end, if the sumocfg sets an end."""
        return None if self.end is None else self.end - self.begin


def read_sumocfg(path: Path) -> ScenarioConfig:
    """The sumocfg's net, route and additional files (resolved, checked to exist) and its times.

    Options are found by name anywhere in the file (SUMO groups them under <input>, <time>, ...
    but does not require it); a list is split at commas as SUMO does.
    """
    path = Path(path)
    if not path.is_file():
        raise BehaveError(f"sumocfg not found: {path}")
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise BehaveError(f"cannot read sumocfg {path}: {exc}") from None
    values = {elem.tag: elem.get("value", "") for elem in root.iter() if elem.get("value") is not None}
    nets = files(path, values.get("net-file", ""))
    if len(nets) != 1:
        raise BehaveError(f"sumocfg {path} must name one net-file, it names {len(nets)}")
    return ScenarioConfig(
        path=path,
        net=nets[0],
        routes=files(path, values.get("route-files", "")),
        additional=files(path, values.get("additional-files", "")),
        begin=seconds(path, values, "begin") or 0.0,
        end=seconds(path, values, "end"),
        step_length=seconds(path, values, "step-length"),
        lateral_resolution=number(path, values, "lateral-resolution"),
        ballistic=flag(path, values, "step-method.ballistic"),
    )


def files(config: Path, listed: str) -> tuple[Path, ...]:
    """The files of a comma-separated option, relative ones resolved against the sumocfg's folder."""
    out = []
    for name in filter(None, (part.strip() for part in listed.split(","))):
        file = Path(name) if Path(name).is_absolute() else config.parent / name
        if not file.is_file():
            raise BehaveError(f"sumocfg {config} names a file that does not exist: {file}")
        out.append(file)
    return tuple(out)


NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")
CLOCK_UNITS = (1.0, 60.0, 3600.0, 86400.0)
"""Seconds per field of SUMO's clock format, read from the right: [DD:]HH:MM:SS[.S]."""


def number(config: Path, values: dict[str, str], name: str) -> float | None:
    """A plain numeric option of the sumocfg, None if not set."""
    text = values.get(name, "").strip()
    if not text:
        return None
    if not NUMBER.fullmatch(text):
        raise BehaveError(f"sumocfg {config}: {name} must be a number, got '{text}'")
    return float(text)


TRUE_WORDS = ("1", "yes", "true", "on", "x", "t")
FALSE_WORDS = ("0", "no", "false", "off", "-", "f")
"""The spellings of a yes/no option that SUMO reads (in any case)."""


def flag(config: Path, values: dict[str, str], name: str) -> bool:
    """A yes/no option of the sumocfg, False if not set."""
    text = values.get(name, "").strip().lower()
    if text in TRUE_WORDS:
        return True
    if text in FALSE_WORDS or not text:
        return False
    raise BehaveError(f"sumocfg {config}: {name} must be true or false, got '{values[name]}'")


def seconds(config: Path, values: dict[str, str], name: str) -> float | None:
    """A time option of the sumocfg, None if not set: seconds, or SUMO's HH:MM:SS or DD:HH:MM:SS
    (fractions of a second allowed), the forms SUMO itself accepts."""
    text = values.get(name, "").strip()
    if not text:
        return None
    fields = text.split(":")
    if NUMBER.fullmatch(text):
        return float(text)
    if len(fields) in (3, 4) and all(NUMBER.fullmatch(f) for f in fields):
        return sum(float(f) * unit for f, unit in zip(reversed(fields), CLOCK_UNITS, strict=False))
    raise BehaveError(f"sumocfg {config}: {name} must be seconds or HH:MM:SS (DD:HH:MM:SS), got '{text}'")


def share_draw(seed: int, vehicle: str) -> float:
    """A number in [0, 1) fixed by the seed and the vehicle's id: which cars become agents does
    not depend on what happens in the run (nor on the order cars depart in)."""
    digest = hashlib.blake2b(f"{seed}/{vehicle}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big") / 2**64


def run_as_sumocfg(options: SimOptions, scenario: ScenarioConfig) -> SimOptions:
    """behave's SUMO `options` (its vTypes in `additional`, its routes, its `extra` after) run as the
    user's sumocfg: with all of the sumocfg's own options and its files named again first (SUMO reads
    `-c` first; files given again replace its lists, so behave's are added to the sumocfg's)."""
    return replace(
        options,
        additional=(*scenario.additional, *options.additional),
        routes=(*scenario.routes, *options.routes),
        lateral_resolution=scenario.lateral_resolution or LATERAL_RESOLUTION,
        ballistic=scenario.ballistic,
        extra=("--configuration-file", str(scenario.path), *options.extra),
    )
