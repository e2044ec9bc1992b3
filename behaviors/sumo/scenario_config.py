"""A user's SUMO scenario as its .sumocfg sets it: net, routes, additionals, time and options.

behave runs the scenario through SUMO with the sumocfg itself (`-c`), so every option the
user set holds, and overrides on SUMO's command line only what behave must own (see the
README: collision handling, seed, step length, FCD output, its vehicle types added to the
additionals). The few files and times behave needs to know itself are read
here with the standard library's parser; relative paths are resolved against the sumocfg's
folder, as SUMO does.
"""

from __future__ import annotations

import gzip
import hashlib
import math
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path

from behaviors.errors import BehaveError
from behaviors.files import ensure_writable_dir
from behaviors.sumo.sim import COLLISION_OPTIONS, SimOptions

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
    options: tuple[tuple[str, str], ...] = ()  # every option the sumocfg sets, (name, value) as written

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
        options=tuple(values.items()),
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


def run_as_sumocfg(
    options: SimOptions,
    scenario: ScenarioConfig,
    lateral_resolution: float | None = None,
    outputs: Path | None = None,
    staging: Path | None = None,
) -> SimOptions:
    """behave's SUMO `options` (its vTypes in `additional`, its routes, its `extra` after) run as the
    user's sumocfg: with all of the sumocfg's own options and its files named again first (SUMO reads
    `-c` first; files given again replace its lists, so behave's are added to the sumocfg's), at the
    `lateral_resolution` decided for the run (`plan_run`; None: `lateral_for` a run with agents). With
    `outputs`, every output the scenario names is written into that folder instead (`redirect_outputs`,
    additionals rewritten into `staging`)."""
    additional: tuple[Path, ...] = scenario.additional
    redirect: tuple[str, ...] = ()
    if outputs is not None:
        if staging is None:
            raise ValueError("redirecting a scenario's outputs needs a staging folder for its additionals")
        redirect, additional = redirect_outputs(scenario, outputs, staging)
    return replace(
        options,
        additional=(*additional, *options.additional),
        routes=(*scenario.routes, *options.routes),
        lateral_resolution=lateral_for(scenario, True) if lateral_resolution is None else lateral_resolution,
        ballistic=scenario.ballistic,
        extra=("--configuration-file", str(scenario.path), *redirect, *unrandom(scenario), *options.extra),
    )


# --- how behave runs a scenario, said where it is not as `sumo -c` runs it ------------------------

SUMO_STEP_LENGTH = 1.0
"""s: SUMO's step where a sumocfg sets none."""
SUBLANES_OFF = -1.0
"""SUMO's own --lateral-resolution: no sublane model (a vehicle fills its lane)."""
FORCED = {
    name.removeprefix("--"): value
    for name, value in zip(COLLISION_OPTIONS[::2], COLLISION_OPTIONS[1::2], strict=True)
}
"""Options behave always sets (sim.COLLISION_OPTIONS): agents are removed at a contact, not teleported,
and a stuck vehicle stays where it stands."""


@dataclass(frozen=True)
class RunPlan:
    """How behave runs a scenario, and one line for each way that differs from how `sumo -c` runs it."""

    step_length: float
    duration: float
    lateral_resolution: float
    notes: tuple[str, ...] = ()


def lateral_for(scenario: ScenarioConfig, agents: bool) -> float:
    """The lateral resolution of a run: the sumocfg's; where it sets none (or turns sublanes off), SUMO's
    sublane model at LATERAL_RESOLUTION if agents drive (they move sideways within a lane), else none."""
    own = scenario.lateral_resolution
    if own is not None and (own > 0 or not agents):
        return own
    return LATERAL_RESOLUTION if agents else SUBLANES_OFF


def plan_run(
    scenario: ScenarioConfig,
    *,
    agents: bool,
    policy_step: float,
    default_duration: float,
    seed: int,
    step_length: float | None = None,
    duration: float | None = None,
    lateral_resolution: float | None = None,
) -> RunPlan:
    """The step, duration and lateral resolution of a run of `scenario` (None: not given by the user).

    Without agents the scenario runs as SUMO runs it: its step (SUMO's 1 s where it sets none) and its
    lateral resolution. Agents drive at the step their policy was trained at (`policy_step`) and need
    SUMO's sublane model: where the sumocfg asks otherwise, behave runs it so and says so in a note. A
    step given by the user is taken as given (populate refuses one the policy was not trained at,
    `check_fits`). A duration past the sumocfg's end is refused: SUMO would stop there, and the
    scenario's demand and detector periods were laid out for its time window."""
    name, notes = scenario.path.name, []
    own_step = scenario.step_length if scenario.step_length is not None else SUMO_STEP_LENGTH
    step = own_step if step_length is None else step_length
    if step_length is None and agents and not math.isclose(own_step, policy_step):
        asked = (
            "it sets" if scenario.step_length is not None else "of SUMO's default (it sets no step-length)"
        )
        notes.append(
            f"{name} runs at {policy_step:g} s steps, not the {own_step:g} s {asked}: the policy was "
            f"trained at {policy_step:g} s steps and drives at no other"
        )
        step = policy_step
    if lateral_resolution is None:
        lateral_resolution = lateral_for(scenario, agents)
        if agents and lateral_resolution != scenario.lateral_resolution:
            notes.append(
                f"{name} runs with SUMO's sublane model (--lateral-resolution {lateral_resolution:g}), "
                "which it does not use: the agents move sideways within their lanes"
            )
    begin, end = scenario.begin, scenario.end
    if duration is None and end is None:
        duration = default_duration
        notes.append(
            f"{name} sets no end: behave runs {duration:g} s of it (--duration S for another length; "
            "SUMO would run until its last vehicle left)"
        )
    elif duration is None:
        duration = end - begin  # type: ignore[operator]  # end is set here
    elif end is not None and begin + duration > end + 1e-9:
        raise BehaveError(
            f"--duration {duration:g} runs past the end of {name} at {end:g} s"
            f"{f' ({end - begin:g} s after its begin)' if begin else ''}: SUMO stops there; give "
            f"--duration {end - begin:g} or less, or move the sumocfg's end"
        )
    notes += option_notes(scenario, seed)
    return RunPlan(step, duration, lateral_resolution, tuple(notes))


def option_notes(scenario: ScenarioConfig, seed: int) -> list[str]:
    """A line for options of the sumocfg that behave sets otherwise on SUMO's command line: the seed,
    SUMO's own random seeding, and collision handling (FORCED)."""
    values, name, notes = dict(scenario.options), scenario.path.name, []
    own_seed = values.get("seed", "").strip()
    if own_seed and own_seed != str(seed):
        notes.append(f"{name} runs with behave's --seed {seed}, not its seed {own_seed}")
    if flag(scenario.path, values, "random"):
        notes.append(f"{name} runs with behave's --seed {seed}, not seeded by the clock as its random asks")
    changed = [f"{option} {values[option]}" for option, value in FORCED.items()
               if option in values and not same_value(values[option], value)]  # fmt: skip
    if changed:
        notes.append(
            f"{name} runs with {' '.join(f'--{o} {v}' for o, v in FORCED.items())}, not its "
            f"{', '.join(changed)}: agents are taken out at a contact and a stuck vehicle stays"
        )
    return notes


def same_value(text: str, value: str) -> bool:
    """Whether an option's value as written in a sumocfg is `value` (numbers and yes/no words compared
    as SUMO reads them)."""
    text, value = text.strip().lower(), value.strip().lower()
    if NUMBER.fullmatch(text) and NUMBER.fullmatch(value):
        return float(text) == float(value)
    if text in TRUE_WORDS + FALSE_WORDS and value in TRUE_WORDS + FALSE_WORDS:
        return (text in TRUE_WORDS) == (value in TRUE_WORDS)
    return text == value


def unrandom(scenario: ScenarioConfig) -> tuple[str, ...]:
    """`--random false` where the sumocfg asks SUMO to seed from the clock: behave's seed must hold."""
    return ("--random", "false") if flag(scenario.path, dict(scenario.options), "random") else ()


# --- the scenario's own outputs into a folder of the run's -----------------------------------------

OUTPUT_OPTIONS = {
    "netstate-dump": ("ndump", "netstate", "netstate-output"), "emission-output": (), "battery-output": (),
    "elechybrid-output": (), "chargingstations-output": (), "overheadwiresegments-output": (),
    "substations-output": (), "person-fcd-output": ("person-fcd",), "full-output": (), "queue-output": (),
    "vtk-output": (), "amitran-output": (), "summary-output": ("summary",), "person-summary-output": (),
    "tripinfo-output": ("tripinfo",), "personinfo-output": ("personinfo",),
    "vehroute-output": ("vehroutes",), "personroute-output": ("personroutes",), "link-output": (),
    "railsignal-block-output": (), "railsignal-vehicle-output": (), "bt-output": (),
    "lanechange-output": (), "stop-output": (), "collision-output": (), "edgedata-output": (),
    "lanedata-output": (), "statistic-output": ("statistics-output",), "deadlock-output": (),
    "save-state.files": (), "save-state.prefix": (), "device.rerouting.output": (),
    "device.taxi.dispatch-algorithm.output": (), "device.taxi.idle-algorithm.output": (),
    "device.ssm.file": (), "device.toc.file": (), "log": ("l", "log-file"), "message-log": (),
    "error-log": (),
}  # fmt: skip
"""SUMO's options that name a file it writes (SUMO 1.28's `sumo --save-template`), with their synonyms.
`fcd-output` is behave's own (`--fcd`)."""
OUTPUT_NAMES = {alias: option for option, aliases in OUTPUT_OPTIONS.items() for alias in (option, *aliases)}
ADDITIONAL_OUTPUTS = {
    **dict.fromkeys(("inductionLoop", "e1Detector", "instantInductionLoop", "laneAreaDetector", "e2Detector",
                     "entryExitDetector", "e3Detector", "edgeData", "laneData", "edgeRelations",
                     "tazRelations", "routeProbe", "vTypeProbe"), "file"),
    "calibrator": "output", "routeCalibrator": "output", "timedEvent": "dest",
}  # fmt: skip
"""The elements of additional files that name a file SUMO writes, and the attribute that names it."""


def redirect_outputs(
    scenario: ScenarioConfig, folder: Path, staging: Path
) -> tuple[tuple[str, ...], tuple[Path, ...]]:
    """SUMO's command-line options and additional files that make it write every output the scenario
    names into `folder` instead of where the sumocfg and its additionals name them, each at its place
    relative to the sumocfg's folder (a file outside it: by its name). The options override the
    sumocfg's; an additional that names an output (a detector's `file`, ...) is replaced by a copy in
    `staging` that names `folder`'s file, its other relative paths made absolute."""
    base = scenario.path.parent
    options: list[str] = []
    for name, value in scenario.options:
        option = OUTPUT_NAMES.get(name)
        if option is None or not value.strip():
            continue
        places = [str(into(folder, base, base / part.strip())) for part in value.split(",") if part.strip()]
        options += [f"--{option}", ",".join(places)]
    values = dict(scenario.options)
    if values.get("save-state.times", "").strip() and not any(
        OUTPUT_NAMES.get(n) == "save-state.prefix" for n in values
    ):
        options += ["--save-state.prefix", str(into(folder, base, base / "state"))]
    additional = tuple(
        rewrite_additional(path, folder, base, staging / f"{k}-{path.name.removesuffix('.gz')}")
        for k, path in enumerate(scenario.additional)
    )
    return tuple(options), additional


def into(folder: Path, base: Path, path: Path) -> Path:
    """Where in `folder` an output named `path` goes: at its place relative to `base` if within it,
    else by its name; its folder created."""
    path = Path(os.path.normpath(path))
    try:
        place = path.relative_to(Path(os.path.normpath(base)))
    except ValueError:
        place = Path(path.name)
    target = Path(folder).resolve() / place
    ensure_writable_dir(target.parent)
    return target


def rewrite_additional(path: Path, folder: Path, base: Path, copy: Path) -> Path:
    """`path` itself if it names no output, else `copy`: the same elements, outputs into `folder`
    (`into`), and every other attribute that names an existing file by a relative path made absolute
    (the copy lives elsewhere)."""
    opener = gzip.open if path.suffix == ".gz" else open
    try:
        with opener(path, "rb") as stream:
            tree = ET.parse(stream)
    except (ET.ParseError, OSError) as exc:
        raise BehaveError(f"cannot read additional file {path}: {exc}") from None
    outputs = [
        (elem, ADDITIONAL_OUTPUTS[elem.tag])
        for elem in tree.iter()
        if elem.get(ADDITIONAL_OUTPUTS.get(elem.tag, ""))
    ]
    if not outputs:
        return path
    for elem, attribute in outputs:
        named = Path(elem.get(attribute, ""))
        elem.set(attribute, str(into(folder, base, named if named.is_absolute() else path.parent / named)))
    rewritten = {(id(elem), attribute) for elem, attribute in outputs}
    for elem in tree.iter():
        for attribute, value in elem.attrib.items():
            named = Path(value)
            if (
                (id(elem), attribute) not in rewritten
                and value
                and not named.is_absolute()
                and (path.parent / named).is_file()
            ):
                elem.set(attribute, str((path.parent / named).resolve()))
    ensure_writable_dir(copy.parent)
    tree.write(copy, encoding="utf-8", xml_declaration=True)
    return copy
