"""The ceiling of moment matching's GFLOP/s set by ``exp`` (issue #18, item 2), and whether a
fused compiled loop beats torch's passes.

Every entry of every Q^{ab} block of :func:`~skillkit.models.moment_matching.moment_match`
needs one ``exp`` and 2D + 4 flops around it (2D for the cross term, 2 for the offsets, 2 for
the contraction); :func:`~skillkit.models.moment_matching.moment_matching_flops_per_step`
counts 2D + 5 per entry, ``exp`` as one. With the flops at the matmul peak and ``exp`` at its
measured in-cache cost, the counted rate cannot exceed (2D + 5) / (t_flops + t_exp).

With ``--fused-c`` (needs gcc) the script also compiles that per-entry work,
q_ij = exp(c_i + c'_j + Σ_d t_id z_dj) contracted with β, as one fused C loop (gcc ``-O3
-march=native -ffast-math``: the loop over j vectorised, ``exp`` from glibc's libmvec) and times
it beside torch's blocked passes as ``_second_moments`` runs them (the bare-kernel timing of
``benchmarks/bench_moment_matching.py``) and libmvec's ``exp`` beside torch's, for P = 36 pairs,
M = 700, D = 12. Run from the repository root::

    OMP_NUM_THREADS=1 python docs/measure_mm_exp_ceiling.py [--fused-c]

Measured on the 2-CPU VM (torch 2.13.0+cpu, AVX-512; nothing else running, load average 0.33)::

    exp 0.55 ns/entry (in place after copy 0.40), copy 0.45; peak 66.6 GFLOP/s
    D=12: 28 flops per entry besides exp take 0.42 ns at peak; with exp (1 counted flop) the
    ceiling is 29.9 GFLOP/s = 45% of peak

(an earlier run, with another job paused: exp 0.55 ns, peak 69.2, ceiling 44%; a later one on a
slow stretch of the VM: exp 0.73 ns, peak 59.7, ceiling 41%). With ``--fused-c`` (gcc 12.2,
nothing else running; that run: torch's exp 0.53 ns, peak 68.1, ceiling 45%)::

    fused C vs numpy: largest difference 1.3e-15 (relative)
    fused C loop (libmvec exp)   3.328 ns/entry, 8.7 GFLOP/s = 13% of peak
    torch blocked passes         1.679 ns/entry, 17.3 GFLOP/s = 25% of peak
    exp alone, libmvec           1.100 ns/entry

so a compiled fused loop with the system's vectorised ``exp`` (2x slower than torch's) loses
to torch's passes.

The batched moment matching runs at 16–26% of peak (``benchmarks/bench_moment_matching.py``),
its bare product + exp + contraction at ~33%: the product is a K = D + 2 = 14 GEMM, far from
peak, and ``exp`` is a separate pass over each block.
"""

from __future__ import annotations

import argparse
import ctypes
import importlib.util
import shutil
import subprocess
import tempfile
import timeit
from pathlib import Path

import numpy as np
import torch

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_moment_matching.py"

C_SOURCE = r"""
#include <math.h>
#include <stddef.h>
/* out[p,i] = sum_j exp(ca[p,i] + cb[p,j] + sum_d ta[p,i,d] zt[p,d,j]) beta[p,j] */
void fused(int P, int M, int D, const double *ta, const double *ca, const double *zt,
           const double *cb, const double *beta, double *out, double *g) {
    for (int p = 0; p < P; ++p) {
        const double *T = ta + (size_t)p * M * D, *Z = zt + (size_t)p * D * M;
        const double *c2 = cb + (size_t)p * M, *b = beta + (size_t)p * M;
        for (int i = 0; i < M; ++i) {
            const double c = ca[(size_t)p * M + i], *t = T + (size_t)i * D;
            for (int j = 0; j < M; ++j) g[j] = c + c2[j];
            for (int d = 0; d < D; ++d) {
                const double td = t[d], *z = Z + (size_t)d * M;
                for (int j = 0; j < M; ++j) g[j] += td * z[j];
            }
            double acc = 0.0;
            for (int j = 0; j < M; ++j) acc += exp(g[j]) * b[j];
            out[(size_t)p * M + i] = acc;
        }
    }
}
void vexp(int n, const double *x, double *y) { for (int i = 0; i < n; ++i) y[i] = exp(x[i]); }
"""


def _best(f, repeats: int) -> float:
    """Least wall time of ``repeats`` single calls."""
    return min(timeit.repeat(f, number=1, repeat=repeats))


def _ptr(a: np.ndarray) -> ctypes.c_void_p:
    return a.ctypes.data_as(ctypes.c_void_p)


def fused_c(peak: float, x: torch.Tensor, E: int = 8, M: int = 700, D: int = 12) -> None:
    """Time the fused C loop, torch's blocked passes and libmvec's exp (see the docstring);
    E outputs, so P = E(E + 1)/2 pairs."""
    P = E * (E + 1) // 2
    spec = importlib.util.spec_from_file_location("bench_moment_matching", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    rng = np.random.default_rng(0)
    ta, zb = 0.1 * rng.normal(size=(2, P, M, D))
    ca, cb = -rng.uniform(0, 3, size=(2, P, M))
    beta = rng.normal(size=(P, M))
    zt = np.ascontiguousarray(zb.transpose(0, 2, 1))
    out, work = np.empty((P, M)), np.empty(M)
    xs, ys = x.numpy(), np.empty(x.numel())
    with tempfile.TemporaryDirectory() as tmp:
        src, so = Path(tmp) / "fused.c", Path(tmp) / "libfused.so"
        src.write_text(C_SOURCE)
        cmd = ["gcc", "-O3", "-march=native", "-ffast-math", "-fPIC", "-shared", str(src)]
        subprocess.run([*cmd, "-o", str(so), "-lm", "-lmvec"], check=True)
        lib = ctypes.CDLL(str(so))

        def fused() -> None:
            args = (ta, ca, zt, cb, beta, out, work)
            lib.fused(P, M, D, *map(_ptr, args))

        fused()
        ref = np.einsum("pij,pj->pi", np.exp(ca[..., None] + cb[:, None, :] + ta @ zt), beta)
        t_fused = _best(fused, 7)
        t_exp = _best(lambda: lib.vexp(len(xs), _ptr(xs), _ptr(ys)), 200) / len(xs)
    t_torch = bench._kernel_floor(E, M, D, 7)
    entries, flops = P * M * M, P * M * M * (2 * D + 5)
    diff = np.abs(out - ref).max() / np.abs(ref).max()
    print(f"fused C vs numpy: largest difference {diff:.1e} (relative)")
    for name, t in (("fused C loop (libmvec exp)", t_fused), ("torch blocked passes", t_torch)):
        rate = flops / t / 1e9
        share = f"{rate:.1f} GFLOP/s = {rate / peak:.0%} of peak"
        print(f"{name:28s} {1e9 * t / entries:.3f} ns/entry, {share}")
    print(f"exp alone, libmvec           {1e9 * t_exp:.3f} ns/entry")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fused-c", action="store_true", help="also time a fused C loop")
    args = parser.parse_args()
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
    if args.fused_c:
        if shutil.which("gcc") is None:
            print("--fused-c: gcc not found, not measured")
        else:
            fused_c(peak, x)


if __name__ == "__main__":
    main()
