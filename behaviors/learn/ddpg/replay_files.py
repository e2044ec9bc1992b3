"""Replay rows on disk as append-only chunks, so that saving after every episode stays cheap.

The whole state with a full 1e5-row buffer is 55 MB, too much to write after every episode; a trainer
instead writes, after each episode, only the rows added since its last save (one chunk file
per buffer), lists the chunks the buffers still hold in its small state file, and removes the
chunks whose rows the ring has overwritten. A resumed run puts the listed rows back in place.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import torch

from behaviors.files import atomic_path
from behaviors.learn.ddpg.buffer import ReplayBuffer


@dataclass(frozen=True)
class Chunk:
    """Rows first .. first + count - 1 of buffer number `buffer`."""

    buffer: int
    first: int
    count: int

    @property
    def name(self) -> str:
        return f"{self.buffer}-{self.first:012d}-{self.count}.pt"


class ReplayFiles:
    """The chunk files in `directory` of `buffers` (one per learner)."""

    def __init__(self, directory: Path, buffers: list[ReplayBuffer]) -> None:
        self.directory = directory
        self.buffers = buffers
        self.chunks: list[Chunk] = []
        self.saved = [buffer.added for buffer in buffers]  # rows already on disk, per buffer

    def write_new_rows(self) -> list[list[int]]:
        """Write the rows added since the last call; returns the chunks the buffers now hold
        (to list in the state file, as plain ints), oldest first."""
        for k, buffer in enumerate(self.buffers):
            first, rows = buffer.rows_since(self.saved[k])
            if len(rows["rew"]):
                chunk = Chunk(k, first, len(rows["rew"]))
                with atomic_path(self.directory / chunk.name) as tmp:
                    torch.save(rows, tmp)
                self.chunks.append(chunk)
            self.saved[k] = buffer.added
        self.chunks = [c for c in self.chunks if c.first + c.count > self._oldest_kept(c.buffer)]
        return [[c.buffer, c.first, c.count] for c in self.chunks]

    def _oldest_kept(self, k: int) -> int:
        buffer = self.buffers[k]
        return buffer.added - len(buffer)

    def prune(self) -> None:
        """Remove chunk files the last listing does not name (overwritten rows, or rows of an
        episode whose state was never saved)."""
        keep = {c.name for c in self.chunks}
        for path in self.directory.glob("*.pt"):
            if path.name not in keep:
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()

    def restore(self, listing: list[list[int]]) -> None:
        """Put the listed chunks' rows back into the buffers (after their load_state_dict)."""
        self.chunks = [Chunk(*(int(v) for v in entry)) for entry in listing]
        for chunk in self.chunks:
            rows = torch.load(self.directory / chunk.name, map_location="cpu", weights_only=True)
            if len(rows["rew"]) != chunk.count:
                raise ValueError(f"{chunk.name} holds {len(rows['rew'])} rows, not {chunk.count}")
            self.buffers[chunk.buffer].put_rows(chunk.first, rows)
        self.saved = [buffer.added for buffer in self.buffers]
