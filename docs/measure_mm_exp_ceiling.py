"""The ceiling of moment matching's GFLOP/s set by ``exp`` (issue #18, item 2).

Every entry of every Q^{ab} block of :func:`~skillkit.models.moment_matching.moment_match`
needs one ``exp`` and 2D + 4 flops around it (2D for the cross term, 2 for the offsets, 2 for
the contraction); :func:`~skillkit.models.moment_matching.moment_matching_flops_per_step`
counts 2D + 5 per entry, ``exp`` as one. With the flops at the matmul peak and ``exp`` at its
measured in-cache cost, the counted rate cannot exceed (2D + 5) / (t_flops + t_exp). Run
from the repository root::

    OMP_NUM_THREADS=1 python docs/measure_mm_exp_ceiling.py

Measured on the 2-CPU VM (torch 2.13.0+cpu, AVX-512; nothing else running, load average 0.33)::

    exp 0.55 ns/entry (in place after copy 0.40), copy 0.45; peak 66.6 GFLOP/s
    D=12: 28 flops per entry besides exp take 0.42 ns at peak; with exp (1 counted flop) the
    ceiling is 29.9 GFLOP/s = 45% of peak

(an earlier run, with another job paused: exp 0.55 ns, peak 69.2, ceiling 44%).

The batched moment matching runs at 21–23% of peak (``benchmarks/bench_moment_matching.py``),
its bare product + exp + contraction at ~33%: the product is a K = D + 2 = 14 GEMM, far from
peak, and ``exp`` is a separate pass over each block.
"""

import timeit

import torch


def _best(f, repeats: int) -> float:
    """Least wall time of ``repeats`` single calls."""
    return min(timeit.repeat(f, number=1, repeat=repeats))


def main() -> None:
    torch.set_num_threads(1)
    x = -torch.rand(1 << 17, dtype=torch.float64) * 30  # one in-cache block of exponents
    y = torch.empty_like(x)
    t_exp = _best(lambda: torch.exp(x, out=y), 200) / x.numel()
    t_exp_ = _best(lambda: y.copy_(x).exp_(), 200) / x.numel()
    t_copy = _best(lambda: y.copy_(x), 200) / x.numel()
    a = torch.randn(2000, 2000, dtype=torch.float64)
    b = torch.randn(2000, 2000, dtype=torch.float64)
    peak = 2 * 2000**3 / _best(lambda: a @ b, 5) / 1e9
    print(
        f"exp {t_exp * 1e9:.2f} ns/entry (in place after copy {(t_exp_ - t_copy) * 1e9:.2f}), "
        f"copy {t_copy * 1e9:.2f}; peak {peak:.1f} GFLOP/s"
    )
    D = 12
    flops = 2 * D + 4  # besides exp
    t_flops = flops / (peak * 1e9)
    ceiling = (flops + 1) / (t_flops + t_exp) / 1e9
    print(
        f"D={D}: {flops} flops per entry besides exp take {t_flops * 1e9:.2f} ns at peak; with "
        f"exp (1 counted flop) the ceiling is {ceiling:.1f} GFLOP/s = {ceiling / peak:.0%} of peak"
    )


if __name__ == "__main__":
    main()
