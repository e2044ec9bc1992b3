"""Shared replay buffer: one ring of preallocated arrays that every agent's transitions go into."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch

from behaviors.learn.ddpg.networks import ACT_DIM

_FIELDS = ("obs", "act", "rew", "next_obs", "terminated")


class Batch(NamedTuple):
    """float32 tensors: obs [B,D], act [B,3], rew [B], next_obs [B,D], terminated [B] (0/1)."""

    obs: torch.Tensor
    act: torch.Tensor
    rew: torch.Tensor
    next_obs: torch.Tensor
    terminated: torch.Tensor


def ring_indices(ptr: int, n: int, capacity: int) -> np.ndarray:
    """Slots for n consecutive writes starting at ptr, wrapping at capacity."""
    return (ptr + np.arange(n)) % capacity


class ReplayBuffer:
    """Fixed-capacity FIFO of transitions. `terminated` is true termination only: a time-limit
    truncation must be stored as 0 so that its target still bootstraps."""

    def __init__(self, capacity: int, obs_dim: int, act_dim: int = ACT_DIM, seed: int = 0) -> None:
        if capacity < 1:
            raise ValueError(f"replay capacity must be positive, got {capacity}")
        self.capacity = capacity
        self.obs_dim = obs_dim
        self.act_dim = act_dim
        self.rng = np.random.default_rng(seed)
        self._data = {
            "obs": np.zeros((capacity, obs_dim), np.float32),
            "act": np.zeros((capacity, act_dim), np.float32),
            "rew": np.zeros(capacity, np.float32),
            "next_obs": np.zeros((capacity, obs_dim), np.float32),
            "terminated": np.zeros(capacity, np.float32),
        }
        self._ptr = 0
        self._size = 0
        self.added = 0  # rows ever added: row g sits in ring slot g % capacity while it is kept

    def __len__(self) -> int:
        return self._size

    def add(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        rew: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """Store the N transitions of one step (one row per agent) in a single vectorised write."""
        rows = dict(zip(_FIELDS, (obs, act, rew, next_obs, terminated), strict=True))
        n = len(obs)
        for name, value in rows.items():
            expected = (n, *self._data[name].shape[1:])
            if np.shape(value) != expected:
                raise ValueError(f"replay add: {name} has shape {np.shape(value)}, want {expected}")
        keep = min(n, self.capacity)  # a step larger than the ring keeps only its newest rows
        start = (self._ptr + n - keep) % self.capacity
        idx = ring_indices(start, keep, self.capacity)
        for name, value in rows.items():
            self._data[name][idx] = value[n - keep :]
        self._ptr = (start + keep) % self.capacity
        self._size = min(self._size + n, self.capacity)
        self.added += n

    def sample(self, batch_size: int) -> Batch:
        """Uniform sample with replacement (cheap, and unbiased for the DDPG loss)."""
        if self._size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        idx = self.rng.integers(0, self._size, size=batch_size)
        return Batch(*(torch.from_numpy(self._data[name][idx]) for name in _FIELDS))

    def state_dict(self, rows: bool = True) -> dict[str, Any]:
        """Counters, sampling RNG and (unless `rows` is False: a trainer saves them as they come,
        with `rows_since`) the filled rows, as tensors so torch.load(weights_only=True) accepts them."""
        arrays = {name: torch.tensor(self._data[name][: self._size]) for name in _FIELDS} if rows else None
        return {
            "capacity": self.capacity,
            "ptr": self._ptr,
            "size": self._size,
            "added": self.added,
            "arrays": arrays,
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Without rows in `state` the ring starts zeroed: `put_rows` then fills it."""
        if state["capacity"] != self.capacity:
            raise ValueError(f"replay capacity {state['capacity']} != {self.capacity}")
        size = state["size"]
        for name in _FIELDS:
            self._data[name][:] = 0
            if state["arrays"] is not None:
                self._data[name][:size] = state["arrays"][name].numpy()
        self._ptr = state["ptr"]
        self._size = size
        self.added = state["added"]
        self.rng.bit_generator.state = state["rng"]

    def rows_since(self, start: int) -> tuple[int, dict[str, torch.Tensor]]:
        """The rows added since `start` rows had been added (those still kept), and the first one's
        number: saving only these after each episode keeps a trainer's saves small."""
        first = max(start, self.added - self._size)
        slots = np.arange(first, self.added) % self.capacity
        return first, {name: torch.from_numpy(self._data[name][slots]) for name in _FIELDS}

    def put_rows(self, first: int, arrays: dict[str, torch.Tensor]) -> None:
        """Put rows from `rows_since` back in their ring slots (after `load_state_dict`)."""
        n = len(arrays["rew"])
        if first < 0 or first + n > self.added:
            raise ValueError(f"replay rows {first}..{first + n} lie beyond the {self.added} added")
        lo = max(first, self.added - self._size)  # older rows were overwritten since
        slots = np.arange(lo, first + n) % self.capacity
        for name in _FIELDS:
            self._data[name][slots] = arrays[name][lo - first :].numpy()
