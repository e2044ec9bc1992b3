"""What a `behave populate` run is asked to do (PopulateConfig), from the user's options (config_from), and
the checks of the policy against it: a policy drives at the step it was trained at, and only the agents it
can drive."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from behaviors.errors import BehaveError
from behaviors.fleet.drivers import DRIVERS, StyledDriver, make_driver
from behaviors.learn.ddpg.checkpoint import load_checkpoint
from behaviors.learn.env_core import EnvConfig
from behaviors.learn.policy import PRETRAINED, RULES, Policy, load_policy, rules_policy
from behaviors.learn.policy import resolve as resolve_policy
from behaviors.report.fcd_read import FCD_SUFFIXES
from behaviors.run.precision import PRECISIONS, use_bfloat16
from behaviors.sumo.display import check_display
from behaviors.sumo.fcd_parquet import PRECISION as PARQUET_PRECISION
from behaviors.sumo.joined import SUMO_NET
from behaviors.sumo.scenario_config import SUMO_STEP_LENGTH, lateral_for, plan_run, read_sumocfg
from behaviors.sumo.traci_connection import parse_address
from sumo_scenarios import get_scenario

DEFAULT_POLICY = PRETRAINED / "traffic.pt"


@dataclass(frozen=True)
class PopulateConfig:
    net: Path = field(default_factory=lambda: get_scenario("highway").net)
    overtakers: int = 4
    keepers: int = 4
    lorries: int = 0  # learned lorries (a styled policy drives them through their style)
    policy: Path = DEFAULT_POLICY
    background: int = 20
    routes: Path | None = None
    duration: float = 180.0
    step_length: float = 0.2
    seed: int = 0
    fcd: Path = Path("fcd.xml")
    geo: bool = False
    keep_count: bool = False
    shield: bool = True
    precision: str = "auto"  # the actor's arithmetic: float32, bfloat16, or auto (see use_bfloat16)
    sumocfg: Path | None = None  # the user's scenario; `net` is then its net
    share: float = 0.0  # of the scenario's passenger cars, the fraction that become agents
    overtaker_fraction: float = 0.5  # of those agents, the fraction that are overtakers
    share_lorries: bool = False  # the share draws the scenario's lorries too, as learned lorries
    gui: bool = False  # run in sumo-gui (needs a display)
    driver: str | None = None  # None: the policy's own; "rules": the traffic driver's rules, no policy
    lateral_resolution: float | None = None  # with a sumocfg: SUMO's sublane width (m); None: lateral_for
    outputs: Path | None = None  # with a sumocfg: the folder its own outputs (detectors, summary, ...) go to
    population: str | None = None  # the styled driver's: a preset name or a JSON file of style distributions
    connect: str | None = None  # HOST:PORT: join that running SUMO as a TraCI client (populate_joined)
    order: int = 2  # with connect: this client's place in each step (traci.setOrder)
    agents_csv: Path | None = None  # the agents table; None: beside the FCD (fcd.agents.csv)
    leave_alone: tuple[str, ...] = ()  # with connect: vehicle id prefixes never drawn (another client's)

    @property
    def has_agents(self) -> bool:
        """Whether a policy drives in this run (agents of the share or of behave's own)."""
        return self.share > 0 or self.keepers + self.overtakers + self.lorries > 0

    @property
    def share_kinds(self) -> tuple[bool, bool]:
        """Whether the share brings (keepers, overtakers)."""
        return self.share * (1 - self.overtaker_fraction) > 0, self.share * self.overtaker_fraction > 0

    def validate(self) -> None:
        if min(self.overtakers, self.keepers, self.lorries, self.background) < 0:
            raise BehaveError("agent and background counts must be >= 0")
        empty = self.overtakers + self.keepers + self.lorries == 0 and self.background == 0
        if empty and self.routes is None and self.sumocfg is None and self.connect is None:
            raise BehaveError("nothing to simulate: zero agents and no background traffic")
        if self.duration <= 0:
            raise BehaveError(f"duration must be positive, got {self.duration}")
        top = 1.0 if self.has_agents or self.background else 60.0  # a scenario alone: any step SUMO takes
        if not 0.01 <= self.step_length <= top:
            raise BehaveError(f"step length must be in [0.01, {top:g}] s, got {self.step_length}")
        if self.fcd.suffix not in FCD_SUFFIXES:
            raise BehaveError(f"FCD output must end in {', '.join(FCD_SUFFIXES)}: {self.fcd}")
        if self.precision not in PRECISIONS:
            raise BehaveError(f"unknown precision '{self.precision}' (choose from {', '.join(PRECISIONS)})")
        if self.routes is not None and not self.routes.is_file():
            raise BehaveError(f"routes file not found: {self.routes}")
        for name in ("share", "overtaker_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise BehaveError(f"{name.replace('_', ' ')} must be in [0, 1], got {getattr(self, name)}")
        if self.share_lorries and self.sumocfg is None and self.connect is None:
            raise BehaveError(
                "--share-lorries draws a scenario's lorries: it goes with --sumocfg or --connect"
            )
        if self.leave_alone and self.connect is None:
            raise BehaveError("--leave-alone names another client's vehicles: it goes with --connect")
        if self.connect is not None:
            self._validate_joined()
        elif self.share > 0 and self.sumocfg is None:
            raise BehaveError("--share converts a scenario's own cars: it needs --sumocfg (or --connect)")
        if self.outputs is not None and self.sumocfg is None:
            raise BehaveError("--outputs takes a scenario's own outputs: it needs --sumocfg")
        if self.lateral_resolution is not None and self.sumocfg is None:
            raise BehaveError("--lateral-resolution sets a scenario's sublanes: it needs --sumocfg")
        if self.driver is not None and self.driver not in (*DRIVERS, RULES):
            raise BehaveError(f"unknown driver '{self.driver}' (choose from {', '.join((*DRIVERS, RULES))})")
        if self.gui:
            check_display()

    def _validate_joined(self) -> None:
        """A joined run drives a share of the running simulation's cars; what would change that
        simulation otherwise is set on its own side."""
        parse_address(self.connect or "")
        if self.order < 1:
            raise BehaveError(f"--order must be 1 or more, got {self.order}")
        if self.share <= 0:
            raise BehaveError(
                "--connect drives a share of the running simulation's passenger cars: give --share F > 0"
            )
        not_here = {
            "--sumocfg": self.sumocfg is not None, "--routes": self.routes is not None, "--gui": self.gui,
            "--geo": self.geo, "--keep-count": self.keep_count, "--outputs": self.outputs is not None,
            "--lateral-resolution": self.lateral_resolution is not None,
            "--keepers, --overtakers, --lorries or --background": (
                self.keepers + self.overtakers + self.lorries + self.background > 0
            ),
        }  # fmt: skip
        for option, given in not_here.items():
            if given:
                raise BehaveError(
                    f"--connect drives a share of the running simulation's cars: {option} does not apply "
                    "(set it where that simulation is started; docs/manual/connect.md)"
                )


def config_from(
    sumocfg: Path | None, notes: list[str] | None = None, agent_settings: bool = False, **given: Any
) -> PopulateConfig:
    """The config for the options a user gave (None = not given). Agents drive at the step their policy
    was trained at (`trained_step`). With a sumocfg, its net, and behave adds no cars of its own unless
    asked (--keepers, --overtakers, --background); its step, duration and lateral resolution as
    scenario_config.plan_run decides (as SUMO runs it, except what agents need), each difference from
    `sumo -c` a line appended to `notes`. `agent_settings`: a run without agents runs as one with
    agents would (a sweep's share 0 beside its other shares)."""
    values = {name: value for name, value in given.items() if value is not None}
    if values.get("driver") == RULES and "policy" in values:
        raise BehaveError("--driver rules drives with no network: drop --policy")
    if values.get("connect") is not None and sumocfg is None:
        return joined_config(values)
    if sumocfg is not None:
        if "net" in values:
            raise BehaveError(
                "--net and --sumocfg both name a network: the sumocfg's net is used, drop --net"
            )
        scenario = read_sumocfg(sumocfg)
        values["net"] = scenario.net
        values.update({k: 0 for k in ("overtakers", "keepers", "background") if k not in values})
    counts = [
        values.get(kind, getattr(PopulateConfig, kind)) for kind in ("keepers", "overtakers", "lorries")
    ]
    agents = values.get("share", 0.0) > 0 or sum(counts) > 0
    step = trained_step(values) if agents or agent_settings else TRAINED_STEP
    if agents and "step_length" in values:
        check_step(policy_name(values), values["step_length"], step)
    if sumocfg is not None:
        plan = plan_run(
            scenario, agents=agents or agent_settings, policy_step=step,
            default_duration=PopulateConfig.duration, seed=values.get("seed", PopulateConfig.seed),
            step_length=values.get("step_length"), duration=values.get("duration"),
            lateral_resolution=values.get("lateral_resolution"),
        )  # fmt: skip
        values.update(step_length=plan.step_length, duration=plan.duration)
        values.update(lateral_resolution=plan.lateral_resolution)
        if notes is not None:
            notes.extend(plan.notes)
        if notes is not None and Path(values.get("fcd", "")).suffix == ".parquet":
            notes.append(
                f"the parquet FCD is written from SUMO's csv at {PARQUET_PRECISION} decimals, and SUMO's "
                f"--precision is for all its outputs: {sumocfg.name}'s own outputs get {PARQUET_PRECISION} "
                "decimals too (--fcd .xml or .csv keeps theirs)"
            )
        own = lateral_for(scenario, False), scenario.step_length or SUMO_STEP_LENGTH
        ran = plan.lateral_resolution, plan.step_length
        if notes is not None and agent_settings and not agents and own != ran:
            notes.append(
                f"{sumocfg.name}'s runs without agents run as those with agents do (at {ran[1]:g} s "
                f"steps, --lateral-resolution {ran[0]:g}), so that they compare"
            )
    elif agents:
        values.setdefault("step_length", step)
    return PopulateConfig(sumocfg=sumocfg, **values)


def joined_config(values: dict[str, Any]) -> PopulateConfig:
    """The config of a joined run (--connect): no cars of behave's own unless asked (validate refuses
    them), until the simulation ends unless --duration; the net and step are the running simulation's,
    filled in when joining (`populate_joined`), so a step given here is refused."""
    if "step_length" in values:
        raise BehaveError(
            "--connect runs at the step of the simulation it joins: drop --step-length (start SUMO with "
            "the policy's step, --step-length 0.2 for the bundled ones)"
        )
    values.update({k: 0 for k in ("overtakers", "keepers", "background") if k not in values})
    values.setdefault("duration", math.inf)
    values.setdefault("net", SUMO_NET)
    values["step_length"] = trained_step(values)  # checked against SUMO's when joining
    return PopulateConfig(**values)


TRAINED_STEP = EnvConfig.step_length
"""s: the step of a policy whose checkpoint records none (training's default), and the rules driver's."""


def trained_step(given: dict[str, Any]) -> float:
    """The step (s) the policy the options name (`policy`, `driver`) was trained at."""
    if given.get("driver") == RULES:
        return TRAINED_STEP
    return checkpoint_step(resolve_policy(given.get("policy") or DEFAULT_POLICY)[0])


def policy_name(given: dict[str, Any]) -> str:
    """The policy the options name, as messages name it."""
    return RULES if given.get("driver") == RULES else str(given.get("policy") or "traffic")


def check_step(policy: str | Path, step: float, trained: float) -> None:
    """BehaveError if the policy, trained at `trained` s steps, would drive at `step`: a policy drives
    at the step it was trained at or not at all."""
    if not math.isclose(step, trained):
        raise BehaveError(
            f"{policy} was trained at {trained:g} s steps and drives at no other: --step-length {step:g} "
            f"would run it at {step:g} s (leave --step-length out)"
        )


def checkpoint_step(path: Path) -> float:
    """The step (s) a checkpoint's policy was trained at, as its metadata records it."""
    if not Path(path).is_file():  # a policy made in Python, not loaded from a file
        return TRAINED_STEP
    return _recorded_step(Path(path).resolve(), Path(path).stat().st_mtime_ns)


@functools.cache
def _recorded_step(path: Path, mtime_ns: int) -> float:
    return float(load_checkpoint(path).meta.get("step_length") or TRAINED_STEP)


def populate_policy(config: PopulateConfig, given: Policy | None = None) -> Policy:
    """The configured policy (policy.load_policy, in config.precision; with `driver` "rules" the
    rules' constant action, policy.rules_policy), or the policy `given` already loaded, checked
    against the agents it must drive before anything is set up."""
    if given is not None:
        policy = given
    elif config.driver == RULES:
        policy = rules_policy()
    else:
        half = None if config.precision == "float32" else functools.partial(use_bfloat16, config.precision)
        policy = load_policy(config.policy, half=half)
    if config.driver not in (None, RULES, policy.driver):
        raise BehaveError(
            f"{policy.path} drives the {policy.driver} driver, not the {config.driver} one "
            f"(drop --driver, or give a {config.driver}-driver policy)"
        )
    check_fits(config, policy)
    return policy


def check_fits(config: PopulateConfig, policy: Policy) -> None:
    """BehaveError if the policy cannot drive the agents asked for: one not told the behaviour drives
    only its own, and one that never trained among traffic only on the multi-lane roads behave routes
    its own cars on."""
    keepers, overtakers = config.share_kinds
    keepers, overtakers = keepers or config.keepers > 0, overtakers or config.overtakers > 0
    if keepers or overtakers:
        trained = TRAINED_STEP if policy.label == RULES else checkpoint_step(policy.path)
        check_step(policy.label, config.step_length, trained)
    if not make_driver(policy.driver).among_traffic and config.share > 0:
        raise BehaveError(
            f"{policy.path} drives the {policy.driver} driver, which cannot leave multi-lane roads: "
            "--share needs a traffic-driver policy"
        )
    if (config.lorries or config.share_lorries) and policy.driver != StyledDriver.name:
        raise BehaveError(
            f"learned lorries drive through their style, which the {policy.driver} driver has none of "
            "(use a styled policy: --policy styled)"
        )
    if policy.sees_behaviour:
        return
    if overtakers and keepers:
        raise BehaveError(
            f"{policy.path} is a {policy.behaviour} policy: it cannot drive both keepers and overtakers "
            "(use a multi-behaviour policy)"
        )
    if policy.behaviour == "lanekeeping" and overtakers:
        raise BehaveError(f"{policy.path} is a lanekeeping policy: use --keepers, not --overtakers")
    if policy.behaviour == "overtaking" and keepers:
        raise BehaveError(f"{policy.path} is an overtaking policy: use --overtakers, not --keepers")
