"""What the benchmarks share about the machine: the matmul peak they compare rates with, and
best-of-n timing. Imported by the benchmark scripts (``from _machine import matmul_peak``), which
Python finds beside the script it runs."""

from __future__ import annotations

import time
from collections.abc import Callable

import torch


def best_time(fn: Callable[[], object], repeats: int, clock=time.perf_counter) -> float:
    """Least time of ``repeats`` calls of ``fn`` after one warm-up call; ``clock`` is
    ``time.perf_counter`` (wall time) or ``time.process_time`` (this process's CPU time, which
    other processes on a shared machine do not inflate)."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        t0 = clock()
        fn()
        best = min(best, clock() - t0)
    return best


def matmul_peak(
    n_threads: int = 1,
    dtype: torch.dtype = torch.float64,
    n: int = 1536,
    repeats: int = 3,
    clock=time.perf_counter,
) -> float:
    """GFLOP/s of the fastest of ``repeats`` n × n matrix products on ``n_threads`` torch
    threads (restored afterwards): the rate the benchmarks quote their kernels against."""
    a, b = torch.randn(n, n, dtype=dtype), torch.randn(n, n, dtype=dtype)
    out = torch.empty(n, n, dtype=dtype)
    before = torch.get_num_threads()
    torch.set_num_threads(n_threads)
    try:
        t = best_time(lambda: torch.matmul(a, b, out=out), repeats, clock)
    finally:
        torch.set_num_threads(before)
    return 2.0 * n**3 / t / 1e9
