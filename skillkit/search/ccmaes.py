r"""Contextual CMA-ES (C-CMA-ES; Abdolmaleki, Price, Lau, Reis and Neumann, IJCAI 2017).

A contextual evolution strategy on π(ω|s) = N(ω | a + Aφ(s), σ² C). One generation draws N
samples s_k ∼ μ(s), ω_k ∼ π(ω|s_k) and updates, in the order :meth:`CCMAES.update` runs:

1. **Baseline** V(s) = βᵀ[1, φ_V(s)] by ridge regression on the rewards, advantages
   A_k = R_k − V(s_k) (:func:`fit_baseline`).
2. **Weights**: CMA-ES's rank weights by advantage, d_j ∝ ln(μ + ½) − ln j for the best
   μ = ⌊N/2⌋, 0 for the rest (:func:`advantage_weights`).
3. **Mean** [a, A] by weighted linear regression of ω_k on [1, φ(s_k)]
   (:func:`weighted_linear_regression`).
4. **Paths** from the mean shift at the average context, Δ = (m_new(φ̄) − m_old(φ̄)) / σ:

   .. math:: p_\sigma \leftarrow (1 - c_\sigma) p_\sigma
             + \sqrt{c_\sigma (2 - c_\sigma) \mu_{\mathrm{eff}}}\, C^{-1/2} \Delta, \qquad
             p_c \leftarrow (1 - c_c) p_c
             + h_\sigma \sqrt{c_c (2 - c_c) \mu_{\mathrm{eff}}}\,\Delta.

5. **Covariance** (rank-one and rank-μ, y_k = (ω_k − m_old(s_k)) / σ):

   .. math:: C \leftarrow (1 - c_1 - c_\mu) C + c_1 \big(p_c p_c^\top
             + (1 - h_\sigma) c_c (2 - c_c) C\big) + c_\mu \textstyle\sum_k d_k y_k y_k^\top.

6. **Step size**: σ ← σ exp(min(ℓ_max, (c_σ/d_σ)(‖p_σ‖ / E‖N(0, I_d)‖ − 1))).

Steps 4–6 are :func:`adapt_covariance`; the rates (:func:`ccmaes_rates`) are Hansen's CMA-ES
defaults (Tutorial 2016, Table 1) with n = d + n_s, and the population
N = (4 + ⌊3 ln n⌋)(1 + 2 n_s) is bolero's. Where the paper leaves a detail open we follow
CMA-ES (h_σ, ℓ_max, weights on the best half only). Samples are drawn by the loop's ``rng``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skillkit._validation import check_array, check_count, check_positive
from skillkit.policies.features import check_feature_name, context_features
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.base import (
    Batch,
    as_batch,
    check_policy,
    check_settings,
    fields_repr,
    rollouts_only,
)


# ----------------------------------------------------------------- pure functions
def default_population(dim: int, context_dim: int) -> int:
    """N = (4 + ⌊3 ln n⌋)(1 + 2 n_s), n = d + n_s (d ≥ 1, n_s ≥ 0)."""
    d = check_count(dim, "dim")
    n_s = check_count(context_dim, "context_dim", 0)
    return (4 + math.floor(3 * math.log(d + n_s))) * (1 + 2 * n_s)


def rank_weights(n: int) -> np.ndarray:
    """CMA-ES's rank weights, best first: d_j ∝ ln(μ + ½) − ln j for j ≤ μ = max(⌊n/2⌋, 1), else 0.

    Returns an array of shape (n,) summing to one.
    """
    n = check_count(n, "n")
    mu = max(n // 2, 1)
    w = np.zeros(n)
    w[:mu] = math.log(mu + 0.5) - np.log(np.arange(1, mu + 1))
    return w / w.sum()


def advantage_weights(advantages: ArrayLike) -> np.ndarray:
    """Each sample's rank weight by its advantage A_k, largest first (ties keep the order).

    Returns an array of shape (N,) summing to one.
    """
    adv = check_array(advantages, "advantages", ndim=1)
    if adv.size == 0:
        raise ValueError("advantages: expected at least one sample, got shape (0,)")
    order = np.argsort(-adv, kind="stable")
    w = np.empty_like(adv)
    w[order] = rank_weights(adv.size)
    return w


def _design(features: ArrayLike, ridge: float) -> tuple[np.ndarray, np.ndarray]:
    """[1, φ_k] (N, 1 + F) and the ridge λ I₀ (no penalty on the intercept)."""
    phi = check_array(features, "features", ndim=2)
    lam = check_positive(ridge, "ridge", allow_zero=True)
    return np.hstack([np.ones((phi.shape[0], 1)), phi]), lam * np.diag(
        np.r_[0.0, np.ones(phi.shape[1])]
    )


def fit_baseline(
    features: ArrayLike, rewards: ArrayLike, ridge: float
) -> tuple[np.ndarray, np.ndarray]:
    r"""The baseline V(s) = βᵀ[1, φ_V(s)] by ridge regression on the rewards.

    .. math:: \beta = (\Psi^\top \Psi + \lambda I_0)^{-1} \Psi^\top R, \qquad
              \Psi = [1, \varphi_V(s_k)]_k,

    I₀ the identity without the intercept; ``features`` (N, F) are φ_V(s_k) (F = 0: V is the mean
    reward), ``rewards`` (N,), ``ridge`` λ ≥ 0. Returns β (1 + F,) and V(s_k) (N,).
    """
    psi, reg = _design(features, ridge)
    r = check_array(rewards, "rewards", shape=(psi.shape[0],))
    if r.size == 0:
        raise ValueError("rewards: expected at least one sample, got shape (0,)")
    beta = np.linalg.lstsq(psi.T @ psi + reg, psi.T @ r, rcond=None)[0]
    return beta, psi @ beta


def weighted_linear_regression(
    features: ArrayLike, targets: ArrayLike, weights: ArrayLike, ridge: float = 0.0
) -> np.ndarray:
    """[a, A] (d, 1 + F) minimising Σ_k d_k ‖ω_k − a − A φ_k‖² + λ ‖A‖²_F (the C-CMA-ES mean).

    ``features`` (N, F), ``targets`` (N, d), ``weights`` (N,) non-negative and not all zero,
    ``ridge`` λ ≥ 0 on the gain A only.
    """
    x, reg = _design(features, ridge)
    y = check_array(targets, "targets", shape=(x.shape[0], None))
    w = check_array(weights, "weights", shape=(x.shape[0],))
    if np.any(w < 0) or not np.any(w > 0):
        raise ValueError("weights: expected non-negative weights, not all zero")
    xw = x * w[:, None]
    return np.linalg.lstsq(xw.T @ x + reg, xw.T @ y, rcond=None)[0].T


@dataclass(frozen=True)
class CCMAESRates:
    """Learning rates of one generation (:func:`ccmaes_rates`): μ_eff = 1 / Σ d_j², c_σ and d_σ of
    the step-size path, c_c of the covariance path, c_1 and c_μ of the rank-one and rank-μ
    updates, and χ_d = E‖N(0, I_d)‖."""

    mu_eff: float
    c_sigma: float
    d_sigma: float
    c_c: float
    c_1: float
    c_mu: float
    chi_d: float


def ccmaes_rates(n_samples: int, dim: int, context_dim: int) -> CCMAESRates:
    """Hansen's CMA-ES default rates (Tutorial 2016, Table 1) for N ≥ 2 samples, n = d + n_s."""
    n_samples = check_count(n_samples, "n_samples", 2)
    d = check_count(dim, "dim")
    n = d + check_count(context_dim, "context_dim", 0)
    mu_eff = float(1.0 / np.sum(rank_weights(n_samples) ** 2))
    c_sigma = (mu_eff + 2) / (n + mu_eff + 5)
    d_sigma = 1 + 2 * max(0.0, math.sqrt((mu_eff - 1) / (n + 1)) - 1) + c_sigma
    c_c = (4 + mu_eff / n) / (n + 4 + 2 * mu_eff / n)
    c_1 = 2 / ((n + 1.3) ** 2 + mu_eff)
    c_mu = min(1 - c_1, 2 * (mu_eff - 2 + 1 / mu_eff) / ((n + 2) ** 2 + mu_eff))
    chi_d = math.sqrt(d) * (1 - 1 / (4 * d) + 1 / (21 * d**2))
    return CCMAESRates(mu_eff, c_sigma, d_sigma, c_c, c_1, max(c_mu, 0.0), chi_d)


def adapt_covariance(
    shape: np.ndarray,
    sigma: float,
    path_sigma: np.ndarray,
    path_c: np.ndarray,
    mean_shift: np.ndarray,
    deviations: np.ndarray,
    weights: np.ndarray,
    rates: CCMAESRates,
    generation: int,
    max_log_step: float,
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, bool]:
    """Steps 4–6 of the module notes: paths, shape C and step size σ (inputs are not changed).

    Takes C (d, d), the σ that drew the samples, p_σ and p_c (d,), the mean shift Δ (d,), the
    deviations y_k (N, d), their weights d_k (N,), the rates, the generation g ≥ 1 (for h_σ's
    bias correction 1 − (1 − c_σ)^{2g}) and ℓ_max; returns the new C, σ, p_σ, p_c and h_σ.
    """
    d = shape.shape[0]
    lam, vec = np.linalg.eigh(shape)
    inv_sqrt = (vec / np.sqrt(np.maximum(lam, np.finfo(float).tiny))) @ vec.T
    r = rates
    p_s = (1 - r.c_sigma) * path_sigma + math.sqrt(
        r.c_sigma * (2 - r.c_sigma) * r.mu_eff
    ) * inv_sqrt @ mean_shift
    norm = float(np.linalg.norm(p_s))
    bias = math.sqrt(1 - (1 - r.c_sigma) ** (2 * generation))
    h_sigma = norm / bias < (1.4 + 2 / (d + 1)) * r.chi_d
    p_c = (1 - r.c_c) * path_c + h_sigma * math.sqrt(r.c_c * (2 - r.c_c) * r.mu_eff) * mean_shift
    rank_mu = (deviations * weights[:, None]).T @ deviations
    new = (
        (1 - r.c_1 - r.c_mu) * shape
        + r.c_1 * (np.outer(p_c, p_c) + (1 - h_sigma) * r.c_c * (2 - r.c_c) * shape)
        + r.c_mu * rank_mu
    )
    new = 0.5 * (new + new.T)
    log_step = min(max_log_step, (r.c_sigma / r.d_sigma) * (norm / r.chi_d - 1))
    return new, sigma * math.exp(log_step), p_s, p_c, bool(h_sigma)


# ----------------------------------------------------------------- settings and state
@dataclass(frozen=True)
class CCMAESSettings:
    """Settings of :class:`CCMAES`: φ_V of the baseline (``"linear"`` or ``"quadratic"``), the
    ridges λ_V ≥ 0 of the baseline and λ ≥ 0 on the mean's gain A, and ℓ_max > 0, the largest
    increase of ln σ in one update."""

    baseline_features: str = "quadratic"
    baseline_ridge: float = 1e-6
    mean_ridge: float = 1e-9
    max_log_step: float = 0.6

    def __post_init__(self):
        check_feature_name(self.baseline_features, "baseline_features")
        check_positive(self.baseline_ridge, "baseline_ridge", allow_zero=True)
        check_positive(self.mean_ridge, "mean_ridge", allow_zero=True)
        check_positive(self.max_log_step, "max_log_step")


@dataclass(frozen=True)
class CCMAESDiagnostics:
    """What one :meth:`CCMAES.update` did: the generation, its N samples and mean reward, the
    standard deviation of the advantages R − V(s), and after the update σ, the axis ratio
    √(λ_max/λ_min) of C, σ √λ_max(C), ‖p_σ‖ and whether p_c was fed (h_σ)."""

    generation: int
    n_samples: int
    mean_reward: float
    advantage_std: float
    sigma: float
    axis_ratio: float
    std_max: float
    path_norm: float
    h_sigma: bool

    def __repr__(self) -> str:
        return fields_repr(self)


class CCMAES:
    """Contextual CMA-ES (module notes) as a policy-search algorithm for :func:`learn`.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial search distribution N(a + Aφ(s), Σ₀): σ₀ = √(max_i Σ₀,ii), C₀ = Σ₀ / σ₀².
    settings : CCMAESSettings, optional
    """

    def __init__(self, policy: LinearGaussianPolicy, settings: CCMAESSettings | None = None):
        check_policy(policy)
        self.settings = check_settings(settings, CCMAESSettings)
        d = policy.dim
        self._dims = (d, policy.context_dim)
        self._features = policy.features
        self.coefficients = policy.coefficients.copy()  # [a, A], (d, 1 + F)
        self.sigma = float(np.sqrt(np.diag(policy.cov).max()))
        self.shape = policy.cov / self.sigma**2
        self.path_sigma = np.zeros(d)
        self.path_c = np.zeros(d)
        self.generation = 0
        self._policy = self._make_policy()

    # ----------------------------------------------------------------- state
    @property
    def policy(self) -> LinearGaussianPolicy:
        """The search distribution N(a + Aφ(s), σ² C)."""
        return self._policy

    @property
    def rollouts_per_update(self) -> int:
        """The default population :func:`default_population`."""
        return default_population(*self._dims)

    def _make_policy(self) -> LinearGaussianPolicy:
        d, n_s = self._dims
        return LinearGaussianPolicy(
            self.coefficients[:, 0],
            self.sigma**2 * self.shape,
            self.coefficients[:, 1:],
            context_dim=n_s,
            features=self._features,
        )

    # ----------------------------------------------------------------- update
    def update(self, batch: Batch) -> CCMAESDiagnostics:
        """One C-CMA-ES generation (steps 1–6) from N ≥ 2 rollouts (no extra-context rows)."""
        old = self._policy
        d, n_s = self._dims
        batch = rollouts_only(as_batch(batch, d, n_s), "CCMAES")
        n = len(batch)
        if n < 2:
            raise ValueError(f"batch: expected at least 2 rollouts to rank, got {n}")
        s, omegas, rewards = batch.contexts, batch.omegas, batch.rewards
        cfg = self.settings
        _, values = fit_baseline(
            context_features(s, cfg.baseline_features), rewards, cfg.baseline_ridge
        )
        advantages = rewards - values
        weights = advantage_weights(advantages)
        phi = old.phi(s)[0]
        self.coefficients = weighted_linear_regression(phi, omegas, weights, cfg.mean_ridge)
        phi_bar = np.r_[1.0, phi.mean(axis=0)]
        mean_shift = (self.coefficients - old.coefficients) @ phi_bar / self.sigma
        deviations = (omegas - old.mean_of(s)) / self.sigma
        self.generation += 1
        rates = ccmaes_rates(n, d, n_s)
        state = (self.shape, self.sigma, self.path_sigma, self.path_c)
        self.shape, self.sigma, self.path_sigma, self.path_c, h_sigma = adapt_covariance(
            *state, mean_shift, deviations, weights, rates, self.generation, cfg.max_log_step
        )
        self._policy = self._make_policy()
        eig = np.linalg.eigvalsh(self.shape)
        return CCMAESDiagnostics(
            generation=self.generation,
            n_samples=n,
            mean_reward=float(rewards.mean()),
            advantage_std=float(advantages.std()),
            sigma=self.sigma,
            axis_ratio=float(np.sqrt(eig.max() / eig.min())),
            std_max=float(self.sigma * np.sqrt(eig.max())),
            path_norm=float(np.linalg.norm(self.path_sigma)),
            h_sigma=h_sigma,
        )

    def __repr__(self) -> str:
        d, n_s = self._dims
        return (
            f"CCMAES(dim={d}, context_dim={n_s}, rollouts_per_update="
            f"{self.rollouts_per_update}, generation={self.generation}, sigma={self.sigma:.4g})"
        )
