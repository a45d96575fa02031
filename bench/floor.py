"""The FLOP floor the benchmarks compare a timing with: a computation's FLOPs at this machine's
measured matrix-multiply rate, in the same precision and thread count.

A shared machine's rate moves between readings (here 143–190 GFLOP/s fp32 for one 2048³ product
within minutes), so a ratio whose rate was read once, before or after the timed runs, moves with
it. ``timed_against_floor`` reads the rate right before each timed run and takes the median of
those readings and of the runs: both sides of the ratio see the machine in the same states.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode, sdpa_flop_count


def _cpu_attention_flops(query: Any, key: Any, value: Any, *args: Any, **kwargs: Any) -> int:
    """The CPU attention kernel's FLOPs (QKᵀ and the weighted sum), which the counter's own
    table (its GPU kernels) lacks."""
    shapes = [getattr(x, "shape", x) for x in (query, key, value)]  # the counter passes shapes
    return int(sdpa_flop_count(*shapes))


CUSTOM = {torch.ops.aten._scaled_dot_product_flash_attention_for_cpu: _cpu_attention_flops}
"""FLOP rules ``FlopCounterMode`` needs on the CPU beyond its own table."""


def flop_counter() -> FlopCounterMode:
    """A ``FlopCounterMode`` that also counts the CPU attention kernel (matmuls, convolutions
    and attention; elementwise work counts nothing)."""
    return FlopCounterMode(display=False, custom_mapping=CUSTOM)


def matmul_rate(
    dtype: torch.dtype = torch.float32, size: int = 2048, repeats: int = 3, warmup: int = 1
) -> float:
    """This machine's matrix-multiply rate in FLOP/s: a ``size``³ product in ``dtype`` with the
    current thread count (median of ``repeats`` after ``warmup``)."""
    a, b = torch.randn(size, size, dtype=dtype), torch.randn(size, size, dtype=dtype)
    for _ in range(warmup):
        a @ b
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        a @ b
        times.append(time.perf_counter() - start)
    return 2 * size**3 / statistics.median(times)


def timed_against_floor(
    fn: Callable[[], Any], runs: int, dtype: torch.dtype = torch.float32, warmup: int = 1
) -> tuple[list[float], float]:
    """Seconds of each of ``runs`` calls of ``fn`` (after ``warmup`` untimed ones), and the
    median matmul rate (FLOP/s) read right before each timed call. A call shorter than
    ``REWARM_BELOW`` is run once more, untimed, between the reading and the timed call: the
    reading's 2048³ product leaves the caches cold for it."""
    started = time.perf_counter()
    for _ in range(warmup):
        fn()
    rewarm = warmup > 0 and (time.perf_counter() - started) / warmup < REWARM_BELOW
    times, rates = [], []
    for _ in range(runs):
        rates.append(matmul_rate(dtype))
        if rewarm:
            fn()
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return times, statistics.median(rates)


REWARM_BELOW = 0.5
"""Seconds: a call this short gets a warm-up call after each rate reading."""
