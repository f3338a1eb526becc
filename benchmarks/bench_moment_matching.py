"""Moment matching's speed (PILCO-style exact moments at a Gaussian input) against the
machine's float64 matmul peak and the ceiling ``exp`` sets, and 100-step predictions, batched
and unbatched.

Models: FITC forward models with an 8-D state and a 4-D control (D = 12 GP inputs, E = 8
outputs), M = 300 (the fig4.4 size) and M = 700 (the fig4.3 size) pseudo-inputs, fitted to
N = 1500 random smooth transitions without hyper-parameter optimisation (timings depend on the
sizes only). Run::

    OMP_NUM_THREADS=1 python benchmarks/bench_moment_matching.py [--inducing 300 700]
        [--steps 100] [--repeats 5] [--skip-reference]

Printed, on one thread, with the load average before and after (all times are this process's
CPU time, the least of several calls):

* the float64 peak: GFLOP/s of a (2000 × 2000)(2000 × 2000) product;
* the ``exp`` ceiling: every entry of every Q^{ab} block needs one ``exp`` and 2D + 4 flops
  around it; with those flops at the peak and ``exp`` at its measured in-cache cost (ns per
  entry), the counted rate (2D + 5 flops per entry, ``exp`` as one) cannot exceed
  (2D + 5) / (t_flops + t_exp): printed in GFLOP/s and as a fraction of the peak;
* per M, one moment-matching step (``moment_match_step`` at a Gaussian z = [x, Kx + k]): its time,
  counted MFLOP, GFLOP/s and fraction of the peak (to be read against the ceiling), and the
  bare per-entry work alone (product, ``exp``, vector product per pair on random operands, no
  set-up: the floor of any implementation of these formulas in this form) in ms and ns per
  entry;
* per M, one ``--steps`` :func:`~skillkit.models.moment_matching.propagate` with the batched
  code and with the unbatched reference implementation in
  ``tests/models/test_moment_matching_batched.py`` (CPU and wall time, the speed-up), and the
  largest difference between the two relative to the largest entry.

Flops are counted by :func:`~skillkit.models.moment_matching.moment_matching_flops_per_step`
(its docstring lists what is counted); the exponent floor's clamp pass, index copies and
concatenations are not counted.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
import torch
from _machine import matmul_peak

from skillkit.models.gp import DTYPE, ForwardModel
from skillkit.models.moment_matching import moment_match_step, propagate
from skillkit.models.moment_matching import moment_matching_flops_per_step as flops_per_step
from skillkit.models.sparse import FITC

N_X, N_U, N_DATA = 8, 4, 1500
REFERENCE = Path(__file__).resolve().parents[1] / "tests/models/test_moment_matching_batched.py"


def _best(f, repeats: int) -> float:
    """The least CPU time (``time.process_time``: this process only, so other processes on a
    shared machine cost cache but not time slices) of ``repeats`` calls."""
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        f()
        times.append(time.process_time() - t0)
    return min(times)


def _kernel_floor(E: int, M: int, D: int, repeats: int) -> float:
    """CPU seconds of the bare per-entry work of one step on random operands, without set-up:
    for each of the P pairs one (M × (D + 2))((D + 2) × M) product, ``exp`` in place and the
    product with a vector, all in one reused buffer (what any implementation must do per
    entry, in the same cache-sized row blocks as :func:`_second_moments`)."""
    from skillkit.models.moment_matching import BLOCK_ENTRIES

    P = E * (E + 1) // 2
    left = 0.1 * torch.randn(P, M, D + 2, dtype=DTYPE)
    right = 0.1 * torch.randn(P, D + 2, M, dtype=DTYPE)
    vec = torch.randn(P, M, 1, dtype=DTYPE)
    rows = max(1, min(M, BLOCK_ENTRIES // M))
    buffer = torch.empty(rows * M, dtype=DTYPE)

    def run() -> None:
        for p in range(P):
            for r0 in range(0, M, rows):
                r1 = min(M, r0 + rows)
                out = buffer[: (r1 - r0) * M].view(1, r1 - r0, M)
                Q = torch.bmm(left[p : p + 1, r0:r1], right[p : p + 1], out=out).exp_()
                torch.bmm(Q, vec[p : p + 1])

    return _best(run, repeats)


def _load_reference():
    """The unbatched reference implementation from the tests (which import their helpers from
    ``tests/``)."""
    sys.path.insert(0, str(REFERENCE.parents[1]))
    try:
        spec = importlib.util.spec_from_file_location("mm_reference", REFERENCE)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(REFERENCE.parents[1]))
    return module._reference_propagate


def _model(M: int, seed: int = 0) -> ForwardModel:
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, size=(N_DATA, N_X))
    u = rng.uniform(-1.0, 1.0, size=(N_DATA, N_U))
    W = 0.3 * rng.normal(size=(N_X + N_U, N_X))
    xn = x + 0.1 * np.tanh(np.concatenate([x, u], 1) @ W) + 0.01 * rng.normal(size=(N_DATA, N_X))
    gp = FITC(n_inducing=M, n_steps=0, additive_noise=0.0, noise=1e-3, lengthscale=1.5)
    return ForwardModel(gp).fit(x, u, xn, rng=seed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--inducing", type=int, nargs="+", default=[300, 700])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--skip-reference", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"load before: {os.getloadavg()}")
    peak = matmul_peak(1, DTYPE, n=2000, repeats=args.repeats, clock=time.process_time)
    print(f"float64 matmul peak, 1 thread: {peak:.1f} GFLOP/s")
    x = -30 * torch.rand(1 << 17, dtype=DTYPE)  # one in-cache block of exponents
    y = torch.empty_like(x)
    t_exp = _best(lambda: torch.exp(x, out=y), 200) / x.numel()
    D = N_X + N_U
    t_flops = (2 * D + 4) / (peak * 1e9)
    ceiling = (2 * D + 5) / (t_flops + t_exp) / 1e9
    print(
        f"exp {1e9 * t_exp:.2f} ns per entry; D={D}: {2 * D + 4} flops per entry besides exp "
        f"take {1e9 * t_flops:.2f} ns at peak, so the exp ceiling is {ceiling:.1f} GFLOP/s = "
        f"{ceiling / peak:.0%} of peak"
    )
    reference_propagate = None if args.skip_reference else _load_reference()
    rng = np.random.default_rng(1)
    K = -0.2 * rng.uniform(0.5, 1.5, size=(N_U, N_X))
    k = 0.1 * rng.normal(size=N_U)
    m0 = 0.2 * rng.normal(size=N_X)
    S0 = np.diag(rng.uniform(0.005, 0.02, size=N_X))
    for M in args.inducing:
        fm = _model(M)
        pred = fm.predictor
        E, _, D = pred.support.shape
        A_z = torch.as_tensor(np.concatenate([np.eye(N_X), K]), dtype=DTYPE)
        mz = A_z @ torch.as_tensor(m0) + torch.cat([torch.zeros(N_X), torch.as_tensor(k)])
        Sz = A_z @ torch.as_tensor(S0) @ A_z.T
        with torch.no_grad():
            t_step = _best(partial(moment_match_step, pred, mz, Sz), 3 * args.repeats)
        gflops = flops_per_step(E, M, D) / t_step / 1e9
        floor = _kernel_floor(E, M, D, args.repeats)
        print(
            f"M={M} (E={E}, D={D}): one step {1e3 * t_step:.2f} ms, "
            f"{flops_per_step(E, M, D) / 1e6:.0f} MFLOP counted, {gflops:.1f} GFLOP/s = "
            f"{100 * gflops / peak:.0f}% of peak; bare product + exp + vector product per "
            f"pair alone: {1e3 * floor:.2f} ms ({1e9 * floor / (E * (E + 1) // 2 * M * M):.2f} "
            "ns per entry of Q)"
        )
        t0, w0 = time.process_time(), time.perf_counter()
        means, covs = propagate(fm, m0, S0, args.steps, K, k)
        t_new, w_new = time.process_time() - t0, time.perf_counter() - w0
        line = f"  {args.steps}-step propagate: batched {t_new:.2f} s CPU ({w_new:.2f} s wall)"
        if reference_propagate is not None:
            t0, w0 = time.process_time(), time.perf_counter()
            with torch.no_grad():
                ref_means, ref_covs = reference_propagate(fm, m0, S0, args.steps, K, k)
            t_old, w_old = time.process_time() - t0, time.perf_counter() - w0
            diff = float((covs - ref_covs).abs().max() / ref_covs.abs().max())
            diff_m = float((means - ref_means).abs().max() / ref_means.abs().max())
            line += (
                f", unbatched {t_old:.2f} s CPU ({w_old:.2f} s wall), {t_old / t_new:.1f}x; "
                "largest difference "
                f"{diff_m:.1e} (means), {diff:.1e} (covariances), relative"
            )
        print(line)
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
