"""Tolerances derived from an error estimate, not from what one CPU printed.

Two kinds:

* round-off: ``fp_tol(n_ops, scale, cond)`` = ``safety · eps · n_ops · cond · scale``, the
  usual first-order bound for a computation of ``n_ops`` dependent floating-point steps on
  values of size ``scale`` whose result has condition number ``cond``. Two evaluations that
  take different floating-point paths (thread count, SIMD width, fused multiply–add or not)
  differ by up to about twice that.
* Monte Carlo: ``mc_tol(std, n, k)`` = ``k · std / sqrt(n)``, ``k`` standard errors of a mean
  of ``n`` independent draws whose standard deviation is ``std``.

This module is shared by several test directories: add to it, do not rename.
"""

import math

import numpy as np

EPS = float(np.finfo(np.float64).eps)  # 2.22e-16
EPS32 = float(np.finfo(np.float32).eps)  # 1.19e-07

#: Margin on a first-order round-off estimate: the constants hidden in "eps · n" (a few units
#: per operation, reassociation in blocked or vectorised kernels) are covered by this factor.
SAFETY = 10.0


def fp_tol(n_ops, scale=1.0, cond=1.0, safety=SAFETY, eps=EPS) -> float:
    """Round-off bound ``safety · eps · n_ops · cond · scale``.

    ``n_ops``: number of floating-point operations the result depends on in sequence (a sum of
    n terms: n; a product of k matrices of size n: k·n; a recursion of T steps of cost c: T·c).
    ``scale``: magnitude of the values (for an absolute tolerance) or 1 (for a relative one).
    ``cond``: condition number of the computation (1 for sums of same-sign terms and products).
    ``eps``: ``EPS`` for float64, ``EPS32`` for float32.
    """
    return float(safety * eps * n_ops * cond * scale)


def mc_tol(std, n, k=5.0) -> float:
    """``k`` Monte Carlo standard errors of a mean of ``n`` independent draws of spread ``std``
    (k = 5: a correct estimator fails with probability below 1e-6 under a normal approximation)."""
    return float(k * std / math.sqrt(n))


def mean_se(samples):
    """Standard error of the column means of ``samples`` (n, ...): std / sqrt(n)."""
    samples = np.asarray(samples, dtype=float)
    return samples.std(0, ddof=1) / math.sqrt(len(samples))


def cov_se(y, z=None):
    """Standard error of the sample (cross-)covariance entries cov(z_i, y_j), shape (d_z, d_y),
    from the samples' own fourth moments (no Gaussian assumption):
    sqrt((mean(z̃_i² ỹ_j²) − cov_ij²) / n), z̃ and ỹ centred; ``z`` defaults to ``y``."""
    y = np.asarray(y, dtype=float)
    z = y if z is None else np.asarray(z, dtype=float)
    yc, zc = y - y.mean(0), z - z.mean(0)
    n = len(y)
    cov = zc.T @ yc / n
    return np.sqrt(np.maximum((zc**2).T @ yc**2 / n - cov**2, 0.0) / n)
