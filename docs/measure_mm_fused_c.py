"""Would a fused compiled kernel lift moment matching above torch's? (issue #18, item 2).

Moment matching's inner work is, per output pair and entry (i, j) of Q^{ab},
q_ij = exp(c_i + c'_j + Σ_d t_id z_dj) and the contraction Σ_j q_ij β_j
(:func:`~skillkit.models.moment_matching._second_moments`; ``docs/measure_mm_exp_ceiling.py``
bounds its counted rate by the cost of ``exp``). Torch does it in separate passes over
cache-sized row blocks (a K = D + 2 product, ``exp`` in place, a matrix-vector product). This
script compiles the same per-entry work as one fused C loop (gcc ``-O3 -march=native
-ffast-math``, so the loop over j is vectorised and ``exp`` comes from glibc's libmvec) and
times, on one thread and in one run: the fused C loop, torch's blocked passes as
``_second_moments`` runs them, and ``exp`` alone from libmvec and from torch. Needs gcc
(skipped with a message otherwise). Run from the repository root::

    OMP_NUM_THREADS=1 python docs/measure_mm_fused_c.py

Measured on the 2-CPU VM (torch 2.13.0+cpu, gcc 12.2, AVX-512), P = 36 pairs, M = 700, D = 12;
see the closing note of the session that added it for the figures of its run.
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess
import tempfile
import timeit
from pathlib import Path

import numpy as np
import torch

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


def _compile(folder: Path) -> ctypes.CDLL:
    src, lib = folder / "fused.c", folder / "libfused.so"
    src.write_text(C_SOURCE)
    cmd = ["gcc", "-O3", "-march=native", "-ffast-math", "-fPIC", "-shared", str(src)]
    subprocess.run([*cmd, "-o", str(lib), "-lm", "-lmvec"], check=True)
    return ctypes.CDLL(str(lib))


def main(P: int = 36, M: int = 700, D: int = 12) -> None:
    if shutil.which("gcc") is None:
        print("gcc not found: nothing measured")
        return
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    ta, zb = 0.1 * rng.normal(size=(2, P, M, D))
    ca, cb = -rng.uniform(0, 3, size=(2, P, M))
    beta = rng.normal(size=(P, M))
    zt = np.ascontiguousarray(zb.transpose(0, 2, 1))
    out, work = np.empty((P, M)), np.empty(M)

    def ptr(a: np.ndarray) -> ctypes.c_void_p:
        return a.ctypes.data_as(ctypes.c_void_p)

    with tempfile.TemporaryDirectory() as tmp:
        lib = _compile(Path(tmp))

        def fused() -> None:
            lib.fused(P, M, D, ptr(ta), ptr(ca), ptr(zt), ptr(cb), ptr(beta), ptr(out), ptr(work))

        # torch, as _second_moments runs it: [t, c, 1] · [z, 1, c']ᵀ by row blocks of 2^17
        # entries, exp in place, then the product with β.
        one = torch.ones(P, M, 1, dtype=torch.float64)
        left = torch.cat([torch.as_tensor(ta), torch.as_tensor(ca)[..., None], one], -1)
        right = torch.cat([torch.as_tensor(zb), one, torch.as_tensor(cb)[..., None]], -1)
        right = right.transpose(-1, -2).contiguous()
        vec = torch.as_tensor(beta)[..., None]
        rows = (1 << 17) // M
        buffer = torch.empty(rows * M, dtype=torch.float64)

        def blocked() -> torch.Tensor:
            parts = []
            for p in range(P):
                for r0 in range(0, M, rows):
                    r1 = min(M, r0 + rows)
                    q = torch.mm(left[p, r0:r1], right[p], out=buffer[: (r1 - r0) * M].view(-1, M))
                    parts.append(q.exp_() @ vec[p])
            return torch.cat(parts).reshape(P, M)

        fused()
        ref = blocked().numpy()
        x = -rng.uniform(0, 30, size=1 << 17)
        y, xt = np.empty_like(x), torch.as_tensor(x)
        yt = torch.empty_like(xt)
        a = torch.randn(2000, 2000, dtype=torch.float64)
        peak = 2 * 2000**3 / _best(lambda: a @ a, 5) / 1e9
        entries, flops = P * M * M, P * M * M * (2 * D + 5)
        print(f"float64 matmul peak {peak:.1f} GFLOP/s (1 thread)")
        diff = np.abs(out - ref).max() / np.abs(ref).max()
        print(f"fused C vs torch: largest difference {diff:.1e} (relative)")
        for name, f, n in (
            ("fused C loop (libmvec exp)", fused, entries),
            ("torch blocked passes", blocked, entries),
            ("exp alone, libmvec", lambda: lib.vexp(len(x), ptr(x), ptr(y)), len(x)),
            ("exp alone, torch", lambda: torch.exp(xt, out=yt), len(x)),
        ):
            t = _best(f, 7 if n == entries else 200)
            rate = f", {flops / t / 1e9:.1f} GFLOP/s = {flops / t / 1e9 / peak:.0%} of peak"
            print(f"{name:28s} {1e9 * t / n:.3f} ns/entry" + (rate if n == entries else ""))


if __name__ == "__main__":
    main()
