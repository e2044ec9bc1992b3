"""Policy checkpoints: one torch file holding plain-python metadata plus state dicts.

Written atomically so a crash mid-save never leaves a half file under the real name, and read
with torch.load(weights_only=True) so opening a downloaded policy cannot execute code.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from behaviors.errors import BehaveError
from behaviors.files import atomic_path
from behaviors.fleet.drivers import driver_of_obs_size
from behaviors.learn.ddpg.networks import ACTION_HIGH, ACTION_LOW, ACTION_NAMES, Actor

FORMAT_VERSION = 1
ALGORITHMS = ("ps-ddpg", "ddpg", "multi-ddpg")
REQUIRED_META = (
    "algorithm",
    "behaviours",
    "obs_dim",
    "observation_layout",
    "normalisation",
    "hidden",
    "training_steps",
)
_PAYLOAD_KEYS = {"meta", "actor", "critic", "extra"}


@dataclass(frozen=True)
class Checkpoint:
    """meta: plain python dict (see REQUIRED_META plus format_version and action bounds);
    critic_state / extra_state are None in actor-only files."""

    meta: dict[str, Any]
    actor_state: dict[str, torch.Tensor]
    critic_state: dict[str, torch.Tensor] | None
    extra_state: dict[str, Any] | None


def checkpoint_meta(meta: dict[str, Any]) -> dict[str, Any]:
    """Validate caller metadata and add the fields the file format owns."""
    missing = [k for k in REQUIRED_META if k not in meta]
    if missing:
        raise BehaveError(f"checkpoint metadata is missing {', '.join(missing)}")
    if meta["algorithm"] not in ALGORITHMS:
        raise BehaveError(f"unknown algorithm {meta['algorithm']!r}; expected one of {ALGORITHMS}")
    return {
        **meta,
        **recorded_driver(meta),
        "format_version": FORMAT_VERSION,
        "action_names": list(ACTION_NAMES),
        "action_low": list(ACTION_LOW),
        "action_high": list(ACTION_HIGH),
        "hidden": [int(h) for h in meta["hidden"]],
    }


def recorded_driver(meta: dict[str, Any]) -> dict[str, str]:
    """The driver model a new checkpoint names: the caller's, else the one whose observation has its
    size, so that the file still names its driver after that driver's observation grows; nothing for
    sizes no driver takes (the policy loader refuses those)."""
    if meta.get("driver"):
        return {"driver": str(meta["driver"])}
    try:
        return {"driver": driver_of_obs_size(int(meta["obs_dim"]))[0]}
    except BehaveError:
        return {}


def _atomic_torch_save(payload: dict[str, Any], path: Path) -> None:
    """Readers see the old file or the new one, never half of one."""
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def save_checkpoint(
    path: str | os.PathLike[str],
    *,
    actor_state: dict[str, torch.Tensor],
    critic_state: dict[str, torch.Tensor] | None = None,
    extra_state: dict[str, Any] | None = None,
    meta: dict[str, Any],
) -> None:
    payload = {
        "meta": checkpoint_meta(meta),
        "actor": actor_state,
        "critic": critic_state,
        "extra": extra_state,
    }
    _atomic_torch_save(payload, Path(path))


def _read_payload(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise BehaveError(f"checkpoint not found: {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for bad bytes; all mean the same here
        raise BehaveError(f"{path} is not a behave checkpoint (corrupt or truncated)") from err
    if not (isinstance(payload, dict) and set(payload) == _PAYLOAD_KEYS):
        raise BehaveError(f"{path} is not a behave checkpoint (corrupt or truncated)")
    if not isinstance(payload["meta"], dict):
        raise BehaveError(f"{path} is not a behave checkpoint (corrupt or truncated)")
    return payload


def _check_meta(path: Path, meta: dict[str, Any], expect_obs_dim: int | None, task: str) -> None:
    version = meta.get("format_version")
    if version != FORMAT_VERSION:
        raise BehaveError(
            f"{path} has checkpoint format version {version!r}; this behave reads {FORMAT_VERSION}"
        )
    missing = [k for k in REQUIRED_META if k not in meta]
    if missing:
        raise BehaveError(f"{path} is not a behave checkpoint (metadata lacks {', '.join(missing)})")
    if expect_obs_dim is not None and meta["obs_dim"] != expect_obs_dim:
        task_note = f" ({task})" if task else ""
        raise BehaveError(
            f"policy expects {meta['obs_dim']} observations ({meta['observation_layout']}) "
            f"but the task gives {expect_obs_dim}{task_note}: {path}"
        )


def load_checkpoint(
    path: str | os.PathLike[str], *, expect_obs_dim: int | None = None, expect_layout: str = ""
) -> Checkpoint:
    """Read and validate; every problem is a one-line BehaveError. expect_layout only names the
    task's observation layout in the obs_dim mismatch message."""
    path = Path(path)
    payload = _read_payload(path)
    _check_meta(path, payload["meta"], expect_obs_dim, expect_layout)
    return Checkpoint(payload["meta"], payload["actor"], payload["critic"], payload["extra"])


def load_actor(
    path: str | os.PathLike[str], expect_obs_dim: int | None = None, expect_layout: str = ""
) -> Actor:
    """The policy alone, in eval mode; works for full and actor-only files."""
    ckpt = load_checkpoint(path, expect_obs_dim=expect_obs_dim, expect_layout=expect_layout)
    actor = Actor(ckpt.meta["obs_dim"], ckpt.meta["hidden"])
    try:
        actor.load_state_dict(ckpt.actor_state)
    except (RuntimeError, AttributeError, TypeError) as err:
        raise BehaveError(f"{path}: actor weights do not match the obs_dim/hidden it declares") from err
    return actor.eval().requires_grad_(False)


def save_actor_only(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
    """Strip critic and training state (what bundled policies ship); metadata is kept."""
    ckpt = load_checkpoint(src)
    save_checkpoint(dst, actor_state=ckpt.actor_state, meta=ckpt.meta)
