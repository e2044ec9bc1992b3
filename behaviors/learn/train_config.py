"""TrainConfig: a training run's settings (its episodes, its learner, the run's own), `behave train`'s
options mapped onto them (OPTIONS), and config.json written and read back."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

from behaviors.errors import BehaveError
from behaviors.fleet.drivers import make_driver
from behaviors.learn.ddpg.learner import DDPGConfig
from behaviors.learn.env import EnvConfig

ALGORITHMS = ("ps-ddpg", "ddpg", "multi-ddpg")
T = TypeVar("T")


@dataclass(frozen=True)
class TrainConfig:
    """A training run: its episodes (`env`, whose seed is the run's), its learner (`ddpg`) and the run's
    own settings; saved as config.json and read back on --resume."""

    env: EnvConfig = field(default_factory=lambda: EnvConfig(seed=0))
    ddpg: DDPGConfig = field(default_factory=DDPGConfig)  # the driver's `exploration` replaces its OU noise
    algo: str = "ps-ddpg"
    episodes: int = 100
    updates_per_step: int | None = None  # None: one per live agent (the paper)
    reward_scale: float | None = None  # for the critic (logged raw); None: the driver's reward_scale
    checkpoint_every: int = 10
    init: str | None = None  # a policy to start from, as policy.resolve takes it (curriculum)
    max_minutes: float | None = None  # wall-clock budget: stop after the episode that exceeds it
    workers: int = 1  # more: rollout workers on Ray (distributed.py), one learner (DistributedTrainer)

    @property
    def seed(self) -> int:
        """Seeds the networks, the replay buffer, the noise and every episode."""
        assert self.env.seed is not None, "validate() refuses a run without a seed"
        return self.env.seed

    def validate(self) -> None:
        if self.algo not in ALGORITHMS:
            raise BehaveError(f"unknown algorithm '{self.algo}' (choose from {', '.join(ALGORITHMS)})")
        if not isinstance(self.env.scenario, str):
            raise BehaveError("a training run names its scenario (config.json holds the name)")
        if self.env.seed is None:
            raise BehaveError("a training run needs a seed")
        if self.episodes < 1:
            raise BehaveError(f"episodes must be positive, got {self.episodes}")
        if self.updates_per_step is not None and self.updates_per_step < 0:
            raise BehaveError(f"updates per step must be >= 0, got {self.updates_per_step}")
        if self.workers < 1:
            raise BehaveError(f"workers must be positive, got {self.workers}")
        if self.workers > 1 and self.algo == "multi-ddpg":
            raise BehaveError("--workers trains ps-ddpg or ddpg (multi-ddpg has a learner per agent)")
        if not self.ddpg.hidden or min(self.ddpg.hidden) < 1:
            raise BehaveError(f"network sizes must be positive, got {self.ddpg.hidden}")
        self.env_config().validate()

    def env_config(self) -> EnvConfig:
        """The episodes as driven: the single-agent baseline (ddpg) drives one agent."""
        single = self.algo == "ddpg" and self.env.behaviour != "multi"
        return replace(self.env, agents=1) if single else self.env

    @property
    def critic_reward_scale(self) -> float:
        return make_driver(self.env.driver).reward_scale if self.reward_scale is None else self.reward_scale

    def ddpg_config(self) -> DDPGConfig:
        """The learner as run: the driver's exploration noise over `ddpg`'s."""
        exploration: dict[str, Any] = make_driver(self.env.driver).exploration
        return replace(self.ddpg, **exploration)

    def options(self) -> dict[str, Any]:
        """The settings `behave train` takes, by option name (OPTIONS)."""
        return {name: getattr(self._part(part), attr) for name, (part, attr) in OPTIONS.items()}

    @classmethod
    def from_options(cls, **options: Any) -> TrainConfig:
        """A run from `behave train`'s options (OPTIONS; the others keep their defaults)."""
        unknown = set(options) - set(OPTIONS)
        if unknown:
            raise BehaveError(f"unknown training settings: {', '.join(sorted(unknown))}")
        parts: dict[str, dict[str, Any]] = {"env": {}, "ddpg": {}, "": {}}
        for name, value in options.items():
            part, attr = OPTIONS[name]
            parts[part][attr] = tuple(value) if isinstance(value, list) else value
        base = cls()
        return replace(
            base, env=replace(base.env, **parts["env"]), ddpg=replace(base.ddpg, **parts["ddpg"]), **parts[""]
        )

    def _part(self, part: str) -> Any:
        return getattr(self, part) if part else self

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True, default=str)  # paths as text

    @classmethod
    def from_json(cls, text: str) -> TrainConfig:
        """config.json as written now (nested), or as older runs wrote it (flat: `behave train`'s options)."""
        data = json.loads(text)
        if "env" not in data:
            return cls.from_options(**data)
        return dataclass_from_dict(cls, data, "config.json")


ENV_OPTIONS = ("behaviour", "scenario", "agents", "overtakers", "keepers", "placement", "opponents",
               "max_steps", "step_length", "seed", "lane_weight", "driver", "net", "sumocfg",
               "reward_weights")  # fmt: skip
DDPG_OPTIONS = ("hidden", "batch_size", "gamma", "tau", "actor_lr", "critic_lr", "buffer_size", "warmup",
                "explore_decay_steps")  # fmt: skip
RUN_OPTIONS = ("algo", "episodes", "updates_per_step", "reward_scale", "checkpoint_every", "init",
               "max_minutes", "workers")  # fmt: skip
OPTIONS: dict[str, tuple[str, str]] = {
    **{name: ("env", name) for name in ENV_OPTIONS},
    **{name: ("ddpg", name) for name in DDPG_OPTIONS},
    "batched_updates": ("ddpg", "batched"),
    **{name: ("", name) for name in RUN_OPTIONS},
}
"""`behave train`'s options (the keys of a flat config.json): the (part of TrainConfig, field) each sets."""


def dataclass_from_dict(cls: type[T], data: dict[str, Any], where: str) -> T:
    """A (frozen, nested) config from its `asdict` form: JSON's lists back to tuples, nested configs
    rebuilt by their field's default; unknown keys named."""
    known = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = set(data) - set(known)
    if unknown:
        raise BehaveError(f"{where} has unknown keys: {', '.join(sorted(unknown))}")
    values: dict[str, Any] = {}
    for name, value in data.items():
        f = known[name]
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if isinstance(value, dict) and dataclasses.is_dataclass(default):
            value = dataclass_from_dict(type(default), value, f"{where} {name}")
        values[name] = tuple(value) if isinstance(value, list) else value
    return cls(**values)
