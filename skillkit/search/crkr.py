r"""Cost-regularized Kernel Regression (CrKR, Kober et al.), Eqs. (2.19)–(2.20).

CrKR represents the upper-level policy by its samples: π(ω|s*) = N(μ(s*), σ²(s*) D) with

.. math::
    \mu(s_*) = m_0(s_*) + k(s_*)^\top (K + \lambda C)^{-1} (\Omega - m_0(S)),  \quad (2.19)

    \sigma^2(s_*) = k(s_*, s_*) + \lambda - k(s_*)^\top (K + \lambda C)^{-1} k(s_*),  \quad (2.20)

K the Gram matrix of the sample contexts, k(s*) the kernel between them and s*, and the cost
matrix C = W⁻¹, W = diag(w), w_i = exp(β (R_i − max R)) (the RWR weights,
:func:`~skillkit.search.rwr.rwr_beta`). Beyond Eqs. (2.19)–(2.20): the prior mean m₀ is the
initial policy's mean (2.19 has m₀ = 0); (K + λC)⁻¹ = W^{1/2} (W^{1/2} K W^{1/2} + λ I)⁻¹ W^{1/2}
by Cholesky, so samples whose weight underflows drop out; D = diag(``variance_scale``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import linalg

from skillkit._validation import as_generator, check_array, check_positive
from skillkit.policies.gaussian import RNG, LinearGaussianPolicy, query_contexts
from skillkit.search.base import (
    Batch,
    SampleBuffer,
    WeightedMLSearch,
    as_batch,
    check_batch,
    check_policy,
    fields_repr,
)
from skillkit.search.rwr import rwr_weighting


def gram(kernel, X, Z=None) -> np.ndarray:
    """:func:`skillkit.models.kernels.gram`, imported on first use (no torch at import)."""
    from skillkit.models.kernels import gram as kernel_gram

    return kernel_gram(kernel, X, Z)


class CrKRPolicy:
    """The CrKR policy N(μ(s), σ²(s) D) of Eqs. (2.19)–(2.20) for fixed samples and weights.

    Parameters
    ----------
    prior : LinearGaussianPolicy
        Supplies m₀(s) and the dimensions.
    kernel : gpytorch kernel
        Kernel on contexts (:mod:`skillkit.models.kernels`).
    contexts, omegas : array_like, shapes (N, context_dim) and (N, d)
    weights : array_like, shape (N,)
        Non-negative, positive sum, any scale (divided by their maximum).
    lam : float
        λ > 0.
    variance_scale : array_like, shape (d,), optional
        D's diagonal (default ones).
    """

    def __init__(
        self,
        prior: LinearGaussianPolicy,
        kernel,
        contexts,
        omegas,
        weights,
        lam: float,
        variance_scale=None,
    ):
        self.prior = prior
        d, s_dim = self.dim, self.context_dim = prior.dim, prior.context_dim
        self.kernel = kernel
        self.lam = check_positive(lam, "lam")
        w_omega = check_array(omegas, "omegas", ndim=2)
        s, w_omega, _ = check_batch(contexts, w_omega, np.zeros(w_omega.shape[0]), d, s_dim)
        w = check_array(weights, "weights", shape=(s.shape[0],))
        if np.any(w < 0) or not np.any(w > 0):
            raise ValueError("weights: expected non-negative weights with a positive sum")
        scale = np.ones(d) if variance_scale is None else variance_scale
        self.variance_scale = check_array(scale, "variance_scale", shape=(d,))
        if np.any(self.variance_scale <= 0):
            raise ValueError("variance_scale: expected positive values")
        self._s = s
        self._u = np.sqrt(w / w.max())
        m = self._u[:, None] * gram(kernel, s) * self._u[None, :]
        m[np.diag_indices_from(m)] += self.lam
        self._chol = linalg.cho_factor(m, lower=True)
        resid = w_omega - prior.mean_of(s)
        self._alpha = linalg.cho_solve(self._chol, self._u[:, None] * resid)  # (N, d)

    def mean_of(self, contexts: ArrayLike) -> np.ndarray:
        """μ(s*) of Eq. (2.19): shape (n, d), or (d,) for one context."""
        s, single = query_contexts(contexts, self.context_dim)
        b = self._u[:, None] * gram(self.kernel, self._s, s)  # (N, n): W^{1/2} k(s*)
        mu = self.prior.mean_of(s) + b.T @ self._alpha
        return mu[0] if single else mu

    def variance_of(self, contexts: ArrayLike) -> np.ndarray | float:
        """σ²(s*) of Eq. (2.20): shape (n,), or a float for one context."""
        s, single = query_contexts(contexts, self.context_dim)
        b = self._u[:, None] * gram(self.kernel, self._s, s)
        k_ss = np.concatenate(
            [np.diag(gram(self.kernel, s[i : i + 256])) for i in range(0, len(s), 256)]
        )
        var = k_ss + self.lam - np.sum(b * linalg.cho_solve(self._chol, b), axis=0)
        return float(var[0]) if single else var

    def sample(self, contexts: ArrayLike, rng: RNG = None) -> np.ndarray:
        """ω ~ N(μ(s), σ²(s) D) per context: shape (n, d), or (d,) for one context."""
        rng = as_generator(rng)
        s, single = query_contexts(contexts, self.context_dim)
        mu = np.atleast_2d(self.mean_of(s))
        var = np.atleast_1d(self.variance_of(s))
        if np.any(var <= 0):
            raise FloatingPointError(f"CrKR variance σ²(s) ≤ 0 (min {var.min():.3g}); increase lam")
        scale = np.sqrt(var)[:, None] * np.sqrt(self.variance_scale)
        omega = mu + scale * rng.standard_normal(mu.shape)
        return omega[0] if single else omega


@dataclass(frozen=True)
class CrKRDiagnostics:
    """What one :meth:`CrKR.update` did: samples used, β, KL(w ‖ uniform) and Kish effective sample
    size of the weights, and the newest batch's mean reward."""

    n_samples: int
    beta: float
    kl: float
    ess: float
    mean_reward: float

    def __repr__(self) -> str:
        return fields_repr(self, "n_samples", "beta", "kl", "ess", "mean_reward")


class CrKR:
    """Cost-regularized Kernel Regression (Eqs. 2.19–2.20) as a policy-search algorithm.

    Parameters
    ----------
    prior : LinearGaussianPolicy
        Sampled from until the first update, then the prior mean m₀(s).
    kernel : gpytorch kernel
        Kernel on contexts.
    lam : float
        λ > 0: the regulariser, and the smallest exploration variance.
    beta_scale : float
        β = ``beta_scale`` / std(R).
    n_reuse_batches : int or None
        Batches kept (``None``: all, as in Kober et al.).
    variance_scale : array_like, shape (d,), optional
        Per-dimension scale of σ².
    """

    def __init__(
        self,
        prior: LinearGaussianPolicy,
        kernel,
        lam: float = 1.0,
        beta_scale: float = 1.0,
        n_reuse_batches: int | None = None,
        variance_scale=None,
    ):
        check_policy(prior, "prior")
        self.kernel = kernel
        self.lam = check_positive(lam, "lam")
        self.beta_scale = check_positive(beta_scale, "beta_scale")
        self.variance_scale = variance_scale
        self._prior = prior
        self._policy: LinearGaussianPolicy | CrKRPolicy = prior
        self._buffer = SampleBuffer(n_reuse_batches)
        self.n_updates = 0

    @property
    def policy(self) -> LinearGaussianPolicy | CrKRPolicy:
        """The current policy (the prior before the first update)."""
        return self._policy

    def update(self, batch: Batch) -> CrKRDiagnostics:
        """Add a batch and rebuild the kernel policy (2.19–2.20) on the kept samples."""
        prior = self._prior
        batch = as_batch(batch, prior.dim, prior.context_dim)
        self._buffer.add(batch.contexts, batch.omegas, batch.rewards)
        s_all, w_all, r_all = self._buffer.arrays()
        p, weighting = rwr_weighting(r_all, self.beta_scale)
        self._policy = CrKRPolicy(
            prior, self.kernel, s_all, w_all, p, self.lam, self.variance_scale
        )
        self.n_updates += 1
        return CrKRDiagnostics(
            n_samples=int(r_all.size), mean_reward=float(batch.rewards.mean()), **weighting
        )

    def _settings_repr(self) -> str:
        return (
            f"lam={self.lam:.4g}, beta_scale={self.beta_scale:.4g}, "
            f"kernel={type(self.kernel).__name__}"
        )

    __repr__ = WeightedMLSearch.__repr__
