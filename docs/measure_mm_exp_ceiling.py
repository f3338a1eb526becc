"""The ceiling of moment matching's GFLOP/s set by ``exp`` (issue #18, item 2), and whether a
fused compiled loop beats torch's passes.

Every entry of every Q^{ab} block of :func:`~skillkit.models.moment_matching.moment_match`
needs one ``exp`` and 2D + 4 flops around it (2D for the cross term, 2 for the offsets, 2 for
the contraction); :func:`~skillkit.models.moment_matching.moment_matching_flops_per_step`
counts 2D + 5 per entry, ``exp`` as one. With the flops at the matmul peak and ``exp`` at its
measured in-cache cost, the counted rate cannot exceed (2D + 5) / (t_flops + t_exp).

With ``--fused-c`` (needs gcc) the script also compiles that per-entry work,
q_ij = exp(c_i + c'_j + Σ_d t_id z_dj) contracted with β, twice: as one fused C loop (gcc ``-O3
-march=native -ffast-math``: the loop over j vectorised, ``exp`` from glibc's libmvec), and with
AVX-512 intrinsics (four rows × eight columns in registers, a hand-written ``exp``: a 16-entry
table picked by ``vpermi2pd``, a degree-6 polynomial, ``vscalefpd``; needs a CPU with AVX-512).
It times both beside torch's blocked passes as ``_second_moments`` runs them (the bare-kernel
timing of ``benchmarks/bench_moment_matching.py``) and each ``exp`` alone, for P = 36 pairs,
M = 700, D = 12, and checks each against numpy. Run from the repository root::

    OMP_NUM_THREADS=1 python docs/measure_mm_exp_ceiling.py [--fused-c]

Measured on the 2-CPU VM (torch 2.13.0+cpu, AVX-512; nothing else running, load average 0.33)::

    exp 0.55 ns/entry (in place after copy 0.40), copy 0.45; peak 66.6 GFLOP/s
    D=12: 28 flops per entry besides exp take 0.42 ns at peak; with exp (1 counted flop) the
    ceiling is 29.9 GFLOP/s = 45% of peak

(an earlier run, with another job paused: exp 0.55 ns, peak 69.2, ceiling 44%; a later one on a
slow stretch of the VM: exp 0.73 ns, peak 59.7, ceiling 41%). With ``--fused-c`` (gcc 12.2;
2026-12-02, load average 0.08 before; that run: torch's exp 0.52 ns, peak 62.3, ceiling 48%)::

    fused C loop (libmvec exp): vs numpy 1.3e-15 (relative); exp alone (libmvec) 0.694
    ns/entry, largest error 4.4e-16 relative above 1e-300, 0.0e+00 absolute below
    fused AVX-512 (hand exp): vs numpy 1.4e-15 (relative); exp alone (hand AVX-512) 0.562
    ns/entry, largest error 6.4e-16 relative above 1e-300, 0.0e+00 absolute below
    torch blocked passes         1.120 ns/entry, 25.9 GFLOP/s = 42% of peak
    fused C loop (libmvec exp)   2.743 ns/entry, 10.6 GFLOP/s = 17% of peak
    fused AVX-512 (hand exp)     1.021 ns/entry, 28.4 GFLOP/s = 46% of peak

Two more runs that hour: torch 1.119 / 1.225, hand AVX-512 1.046 / 1.694, libmvec loop 2.554 /
4.115 ns per entry (peaks 74.7 / 67.7: torch's passes at 35% / 35%, the AVX-512 loop at 37% /
25%); hand ``exp`` alone 0.51 / 0.71 ns against torch's 0.53 / 0.75. So the system's vectorised
``exp`` (libmvec) loses to torch's, and a hand-written AVX-512 ``exp`` fused with the product in
registers gains at most ~10% over torch's passes, within this VM's run-to-run spread: torch's
bare per-entry work is already at the speed a compiled kernel reaches here, 35–46% of the peak
depending on the peak's reading.

The batched moment matching step runs at 16–26% of peak (``benchmarks/bench_moment_matching.py``):
besides the bare per-entry work (~72% of its time at M = 700) it streams iK_a (M × M per output,
31 MB at M = 700) for the traces tr(iK_a Q^{aa}) and sets up the operands.
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

AVX512_SOURCE = r"""
#include <immintrin.h>
#include <math.h>
#include <stddef.h>
/* The same work with a hand-written AVX-512 exp: n = round(16 x / ln 2), r = x - n ln2/16
   (two-part constant), exp(x) = 2^floor(n/16) 2^((n mod 16)/16) p(r) with p of degree 6
   (|r| <= ln2/32, truncation 4e-16), the 16 table entries picked by vpermi2pd straight from
   the low mantissa bits of n + 1.5 * 2^52 and 2^floor(n/16) applied by vscalefpd. */
static double TAB[16];
__attribute__((constructor)) static void init(void) {
    for (int k = 0; k < 16; ++k) TAB[k] = exp2(k / 16.0);
}
static inline __m512d vexp8(__m512d x, __m512d tlo, __m512d thi) {
    const __m512d magic = _mm512_set1_pd(6755399441055744.0);
    __m512d t = _mm512_fmadd_pd(x, _mm512_set1_pd(23.083120654223414), magic);
    __m512d n = _mm512_sub_pd(t, magic);
    __m512d r = _mm512_fnmadd_pd(n, _mm512_set1_pd(0.04332169878499658), x);
    r = _mm512_fnmadd_pd(n, _mm512_set1_pd(1.4494042586539372e-18), r);
    __m512d T = _mm512_permutex2var_pd(tlo, _mm512_castpd_si512(t), thi);
    __m512d p = _mm512_set1_pd(1.0 / 720);
    p = _mm512_fmadd_pd(p, r, _mm512_set1_pd(1.0 / 120));
    p = _mm512_fmadd_pd(p, r, _mm512_set1_pd(1.0 / 24));
    p = _mm512_fmadd_pd(p, r, _mm512_set1_pd(1.0 / 6));
    p = _mm512_fmadd_pd(p, r, _mm512_set1_pd(0.5));
    p = _mm512_fmadd_pd(p, r, _mm512_set1_pd(1.0));
    p = _mm512_fmadd_pd(T, _mm512_mul_pd(p, r), T);
    return _mm512_scalef_pd(p, _mm512_mul_pd(n, _mm512_set1_pd(0.0625)));
}
/* rows i0 .. i0 + R - 1 of one pair; columns in 8s, the last ones masked (b = 0 there) */
static inline __attribute__((always_inline)) void rows(
        int R, int i0, int M, int D, const double *T, const double *ca, const double *Z,
        const double *c2, const double *b, double *out, __m512d tlo, __m512d thi) {
    __m512d acc[4], c[4];
    for (int r = 0; r < R; ++r) {
        acc[r] = _mm512_setzero_pd();
        c[r] = _mm512_set1_pd(ca[i0 + r]);
    }
    for (int j = 0; j < M; j += 8) {
        __mmask8 k = M - j >= 8 ? 0xFF : (__mmask8)((1u << (M - j)) - 1);
        __m512d cc = _mm512_maskz_loadu_pd(k, c2 + j), g[4];
        for (int r = 0; r < R; ++r) g[r] = _mm512_add_pd(c[r], cc);
        for (int d = 0; d < D; ++d) {
            __m512d z = _mm512_maskz_loadu_pd(k, Z + (size_t)d * M + j);
            for (int r = 0; r < R; ++r)
                g[r] = _mm512_fmadd_pd(_mm512_set1_pd(T[(size_t)(i0 + r) * D + d]), z, g[r]);
        }
        __m512d bb = _mm512_maskz_loadu_pd(k, b + j);
        for (int r = 0; r < R; ++r) acc[r] = _mm512_fmadd_pd(vexp8(g[r], tlo, thi), bb, acc[r]);
    }
    for (int r = 0; r < R; ++r) out[i0 + r] = _mm512_reduce_add_pd(acc[r]);
}
void fused(int P, int M, int D, const double *ta, const double *ca, const double *zt,
           const double *cb, const double *beta, double *out, double *unused) {
    __m512d tlo = _mm512_loadu_pd(TAB), thi = _mm512_loadu_pd(TAB + 8);
    for (int p = 0; p < P; ++p) {
        const double *T = ta + (size_t)p * M * D, *Z = zt + (size_t)p * D * M;
        const double *a = ca + (size_t)p * M, *c2 = cb + (size_t)p * M, *b = beta + (size_t)p * M;
        double *o = out + (size_t)p * M;
        int i = 0;
        for (; i + 4 <= M; i += 4) rows(4, i, M, D, T, a, Z, c2, b, o, tlo, thi);
        for (; i < M; ++i) rows(1, i, M, D, T, a, Z, c2, b, o, tlo, thi);
    }
}
void vexp(int n, const double *x, double *y) {
    __m512d tlo = _mm512_loadu_pd(TAB), thi = _mm512_loadu_pd(TAB + 8);
    int i = 0;
    for (; i + 8 <= n; i += 8) _mm512_storeu_pd(y + i, vexp8(_mm512_loadu_pd(x + i), tlo, thi));
    for (; i < n; ++i) y[i] = exp(x[i]);
}
"""


def _best(f, repeats: int) -> float:
    """Least wall time of ``repeats`` single calls."""
    return min(timeit.repeat(f, number=1, repeat=repeats))


def _ptr(a: np.ndarray) -> ctypes.c_void_p:
    return a.ctypes.data_as(ctypes.c_void_p)


def _build(source: str, flags: list[str], tmp: Path, name: str) -> ctypes.CDLL | None:
    """Compile ``source`` with gcc into a shared library; None if gcc refuses it (e.g. the
    AVX-512 source on a CPU without AVX-512)."""
    src, so = tmp / f"{name}.c", tmp / f"lib{name}.so"
    src.write_text(source)
    cmd = ["gcc", "-O3", "-march=native", *flags, "-fPIC", "-shared", str(src), "-o", str(so)]
    if subprocess.run([*cmd, "-lm", "-lmvec"], capture_output=True).returncode:
        return None
    return ctypes.CDLL(str(so))


def fused_c(peak: float, x: torch.Tensor, E: int = 8, M: int = 700, D: int = 12) -> None:
    """Time the fused C loops (libmvec's exp; the hand-written AVX-512 exp), torch's blocked
    passes and each exp alone (see the docstring); E outputs, so P = E(E + 1)/2 pairs."""
    P = E * (E + 1) // 2
    spec = importlib.util.spec_from_file_location("bench_moment_matching", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    rng = np.random.default_rng(0)
    ta, zb = 0.1 * rng.normal(size=(2, P, M, D))
    ca, cb = -rng.uniform(0, 3, size=(2, P, M))
    beta = rng.normal(size=(P, M))
    zt = np.ascontiguousarray(zb.transpose(0, 2, 1))
    ref = np.einsum("pij,pj->pi", np.exp(ca[..., None] + cb[:, None, :] + ta @ zt), beta)
    xs, ys = x.numpy(), np.empty(x.numel())
    wide = np.linspace(-745.0, 5.0, 1 << 20)  # exp's accuracy down to the denormals
    normal = np.exp(wide) > 1e-300
    entries, flops = P * M * M, P * M * M * (2 * D + 5)
    rows = [("torch blocked passes", bench._kernel_floor(E, M, D, 7))]
    variants = (
        ("fused C loop (libmvec exp)", "libmvec", C_SOURCE, ["-ffast-math"]),
        ("fused AVX-512 (hand exp)", "hand AVX-512", AVX512_SOURCE, []),
    )
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, exp_name, source, flags) in enumerate(variants):
            lib = _build(source, flags, Path(tmp), f"fused{i}")
            if lib is None:
                print(f"{name}: gcc could not build it here (AVX-512 needed), not measured")
                continue
            out, work = np.empty((P, M)), np.empty(M)

            def fused(lib=lib, out=out, work=work) -> None:
                lib.fused(P, M, D, *map(_ptr, (ta, ca, zt, cb, beta, out, work)))

            fused()
            diff = np.abs(out - ref).max() / np.abs(ref).max()
            rows.append((name, _best(fused, 7)))
            t_exp = _best(lambda lib=lib: lib.vexp(len(xs), _ptr(xs), _ptr(ys)), 200) / len(xs)
            acc = np.empty_like(wide)
            lib.vexp(len(wide), _ptr(wide), _ptr(acc))
            err = np.abs(acc - np.exp(wide))
            rel = np.max(err[normal] / np.exp(wide)[normal])
            print(
                f"{name}: vs numpy {diff:.1e} (relative); exp alone ({exp_name}) "
                f"{1e9 * t_exp:.3f} ns/entry, largest error {rel:.1e} relative "
                f"above 1e-300, {np.max(err[~normal]):.1e} absolute below"
            )
    for name, t in rows:
        rate = flops / t / 1e9
        share = f"{rate:.1f} GFLOP/s = {rate / peak:.0%} of peak"
        print(f"{name:28s} {1e9 * t / entries:.3f} ns/entry, {share}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fused-c", action="store_true", help="also time fused C loops")
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
