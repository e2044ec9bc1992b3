"""One loader for every policy a command drives: a bundled name (`traffic`, `lanekeeping`, ...), an
actor-only file, a training checkpoint or a training run's directory.

Whatever the file, the caller gets one batched act function and what the policy needs around it: its
driver model, its behaviour and its input size, so no command has to know which driver a file was
trained for.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from behaviors.errors import BehaveError
from behaviors.fleet.drivers import driver_of_obs_size, make_driver
from behaviors.learn.ddpg.checkpoint import Checkpoint, load_actor, load_checkpoint
from behaviors.learn.ddpg.networks import Actor, driving_function

PRETRAINED = Path(__file__).parents[1] / "pretrained"
"""The bundled policies: `--policy NAME` means PRETRAINED/NAME.pt."""
RUN_CHECKPOINTS = ("final", "interrupted", "last")
"""Which checkpoint of a training run's directory drives, first found first: the end of a finished run,
else where a stopped one stopped, else its latest save."""

Act = Callable[[np.ndarray, np.ndarray | None], np.ndarray]
"""(observations [n, D], agent slots [n] or None) -> actions [n, 3] (steer, accel, brake)."""


@dataclass(frozen=True)
class Policy:
    """A loaded policy and what it needs: its driver model, behaviour and number of inputs."""

    label: str  # how tables name it: the bundled name, the run's directory or the file's stem
    path: Path
    driver: str  # "paper" or "traffic" (drivers.DRIVERS)
    behaviour: str  # "lanekeeping", "overtaking" or "multi"
    obs_dim: int
    act: Act
    sees_behaviour: bool  # its agents are told their behaviour: it drives keepers and overtakers alike

    @property
    def with_id(self) -> bool:
        """Whether its environment appends the behaviour id to the observation (EnvConfig.with_id, for
        multi-behaviour policies); the traffic driver's observation holds it anyway."""
        return self.behaviour == "multi"


def bundled_names() -> list[str]:
    return sorted(path.stem for path in PRETRAINED.glob("*.pt"))


def resolve(spec: str | Path) -> tuple[Path, str]:
    """The checkpoint file a user means, and its label: a file, a run directory (its RUN_CHECKPOINTS)
    or a bare bundled name."""
    path = Path(spec)
    if path.is_file():
        return path, path.stem
    if path.is_dir():
        for name in RUN_CHECKPOINTS:
            if (path / "checkpoints" / f"{name}.pt").is_file():
                return path / "checkpoints" / f"{name}.pt", path.name
        names = ", ".join(f"{name}.pt" for name in RUN_CHECKPOINTS)
        raise BehaveError(f"{path} is not a training run: its checkpoints/ holds none of {names}")
    if not path.suffix and path.parent == Path("."):  # a bare name: a bundled policy
        bundled = PRETRAINED / f"{path.name}.pt"
        if bundled.is_file():
            return bundled, path.name
    if path.parent == PRETRAINED:
        raise BehaveError(f"the bundled policy {path.name} is missing; run `make pretrained`")
    raise BehaveError(
        f"checkpoint not found: {spec} (give a .pt file, a training run's directory or a bundled "
        f"policy: {', '.join(bundled_names())})"
    )


def policy_driver(meta: dict[str, Any]) -> str:
    """The driver model a checkpoint names, or for files saved before checkpoints named it, the one
    whose observation has its input size."""
    return str(meta.get("driver") or driver_of_obs_size(int(meta["obs_dim"]))[0])


def policy_behaviour(meta: dict[str, Any]) -> str:
    """The behaviour it was trained for: recorded, else one learnt behaviour or several (multi)."""
    behaviours = meta["behaviours"]
    return str(meta.get("behaviour") or ("multi" if len(behaviours) > 1 else behaviours[0]))


def load_policy(spec: str | Path, *, half: Callable[[int], bool] | None = None) -> Policy:
    """Load any policy as one batched act function; BehaveError names what does not fit.

    `half(batch)`: whether a batch of that many observations runs in bfloat16 (populate's big
    fleets); None: always float32, exactly as trained.
    """
    path, label = resolve(spec)
    ckpt = load_checkpoint(path)
    obs_dim = int(ckpt.meta["obs_dim"])
    driver, behaviour = policy_driver(ckpt.meta), policy_behaviour(ckpt.meta)
    model = make_driver(driver)
    size = model.obs_size(behaviour == "multi")
    if obs_dim != size:
        raise BehaveError(
            f"{path} takes {obs_dim} observations, but the {driver} driver's {behaviour} agents see {size} "
            "now: it was trained for an earlier observation; retrain it"
        )
    actors = independent_actors(ckpt)
    act = slot_act(actors) if actors else actor_act(load_actor(path), half)
    sees_behaviour = behaviour == "multi" or model.obs_size(False) == model.obs_size(True)
    return Policy(label, path, driver, behaviour, obs_dim, act, sees_behaviour)


def independent_actors(ckpt: Checkpoint) -> list[Actor]:
    """A multi-DDPG checkpoint's one actor per agent slot (empty for a shared policy)."""
    states = (ckpt.extra_state or {}).get("actors") if ckpt.meta["algorithm"] == "multi-ddpg" else None
    actors = []
    for state in states or []:
        actor = Actor(ckpt.meta["obs_dim"], ckpt.meta["hidden"])
        actor.load_state_dict(state)
        actors.append(actor.eval().requires_grad_(False))
    return actors


def actor_act(actor: Actor, half: Callable[[int], bool] | None = None) -> Act:
    """The whole fleet through one batched forward pass; in bfloat16 where `half` says so."""
    drive = driving_function(actor)
    drive_low = None if half is None else driving_function(copy.deepcopy(actor).to(torch.bfloat16))

    def act(obs: np.ndarray, slots: np.ndarray | None = None) -> np.ndarray:
        obs = np.asarray(obs, np.float32)
        if drive_low is not None and half is not None and half(len(obs)):
            return drive_low(obs)
        return drive(obs)

    return act


def slot_act(actors: list[Actor]) -> Act:
    """Each agent slot its own actor (slot mod count); without slots (populate) the first one."""

    def act(obs: np.ndarray, slots: np.ndarray | None = None) -> np.ndarray:
        owner = np.zeros(len(obs), np.int64) if slots is None else slots % len(actors)
        out = np.empty((len(obs), 3), np.float32)
        with torch.inference_mode():
            for k in np.unique(owner):
                rows = owner == k
                out[rows] = actors[k](torch.as_tensor(obs[rows], dtype=torch.float32)).numpy()
        return out

    return act


RULES = "rules"
"""`--driver rules`: the traffic driver's law and lane-change motives with no network (`rules_policy`)."""
RULES_ACTION = (1.0, 0.5, 0.0)
"""(steer, accel, brake) that leaves every choice of the traffic driver to its hand-written rules
(actuation.actuate_lanes with the driver's `habits`), i.e. the network's "no wish of its own":

* accel 0.5, brake 0: the adjustment `2 accel_span (accel - 0.5) - max_brake brake` is 0, so the
  car-following law (the improved IDM) alone sets the acceleration, bounded by the rules (no
  tailgating, not undertaking, letting in, falling in).
* steer +1, not 0: the slow side is the rules' alone (steer is clipped to >= 0; keeping right and
  leaving an ending lane are rules), and a wish for the fast side counts only where the behaviour's
  motive holds (a leader slower than the car wants by its pass margin, for its patience: `held_up`).
  Overtakers get steer 1 there whatever the action says. Steer +1 lets keepers pass where their
  habits say so too (a leader 8 m/s slower for 10 s); steer 0 would forbid every such pass, a
  choice of the action's, not the rules'. Anywhere no motive holds, +1 is no wish at all.
"""


def constant_act(action: tuple[float, float, float] | np.ndarray) -> Act:
    """A "policy" with the actors' call signature that returns `action` [3] for every observation:
    the rules driver (RULES_ACTION), or a policy's actions held at a fixed vector (the ablation)."""
    row = np.asarray(action, np.float32).reshape(1, 3)

    def act(obs: np.ndarray, slots: np.ndarray | None = None) -> np.ndarray:
        return np.repeat(row, len(obs), axis=0)

    return act


def rules_policy() -> Policy:
    """The traffic driver's rules with no network (RULES_ACTION through one batched call a step, as a
    loaded actor is called): a baseline that needs no checkpoint, for keepers and overtakers alike."""
    size = make_driver("traffic").obs_size(True)
    return Policy(RULES, Path(RULES), "traffic", "multi", size, constant_act(RULES_ACTION), True)


def held_constant(policy: Policy, action: tuple[float, float, float] | np.ndarray) -> Policy:
    """`policy` with its actions replaced by the fixed `action` [3] (steer, accel, brake), its driver
    model and everything around it untouched: what the network adds over its own typical action."""
    text = ",".join(f"{float(v):.3g}" for v in np.asarray(action, float).ravel())
    return replace(policy, label=f"{policy.label}@{text}", act=constant_act(action))
