"""The arithmetic and threads of populate's batched actor call: bfloat16 for big fleets where the CPU has
it natively, one torch thread."""

from __future__ import annotations

import functools

import torch

PRECISIONS = ("auto", "float32", "bfloat16")


@functools.cache
def native_bfloat16() -> bool:
    """Whether this CPU multiplies bfloat16 in hardware (AVX512-BF16 or AMX); emulated it is slower."""
    cpu = torch.cpu
    checks = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    return any(getattr(cpu, name, lambda: False)() for name in checks)


BFLOAT16_MIN_BATCH = 128
"""With `auto`, fleets from this size on use bfloat16; below it the conversions cost more than they save."""


def use_bfloat16(precision: str, batch: int) -> bool:
    """Whether a batch of `batch` observations goes through the actor in bfloat16.

    `auto` takes bfloat16 for big fleets where the CPU has it natively: it more than halves
    the batched actor call (docs/history.md). On real highway
    observations it moves the steering by 0.003 (median) to 0.06 (max) of full lock, and
    throttle and brake by less (tests/run/test_populate.py): far below the exploration noise
    the policy was trained with. `float32` drives exactly as `behave evaluate` does.
    """
    if precision == "auto":
        return batch >= BFLOAT16_MIN_BATCH and native_bfloat16()
    return precision == "bfloat16"


POLICY_THREADS = 1
"""Threads for the batched actor call: a second thread saves little on an idle machine and costs
tens of milliseconds per call while another process keeps a core busy (docs/benchmarks.md)."""
