r"""Contextual CMA-ES (C-CMA-ES; Abdolmaleki, Price, Lau, Reis and Neumann, IJCAI 2017).

A contextual evolution strategy on the linear-Gaussian search distribution

.. math:: \pi(\omega|s) = \mathcal N\big(\omega \mid a + A\varphi(s),\ \sigma^2 C\big),

with step size σ and shape C as in CMA-ES. One generation draws N samples, each in its own
context, s_k ∼ μ(s), ω_k ∼ π(ω|s_k), and updates, in the order :meth:`CCMAES.update` runs:

1. **Baseline** (the paper's context-dependent baseline): V(s) = βᵀψ(s), ψ(s) = [1, φ_V(s)],
   fitted by ridge regression on the rewards, β = (ΨᵀΨ + λ_V I₀)⁻¹ΨᵀR (I₀: the identity
   without the intercept), and the advantages A_k = R_k − V(s_k) (:func:`fit_baseline`).
2. **Weights**: the samples ranked by advantage get CMA-ES's rank weights, best first: d_j ∝
   ln(μ + ½) − ln j for the best μ = ⌊N/2⌋, 0 for the rest (:func:`rank_weights`,
   :func:`advantage_weights`). Ranking advantages, not rewards, compares each sample with what
   its own context allows.
3. **Mean**: [a, A] by weighted linear regression of ω_k on [1, φ(s_k)] with weights d_k (the
   paper's weighted maximum-likelihood mean; :func:`weighted_linear_regression`).
4. **Evolution paths** of the mean shift at the average context φ̄ = (1/N) Σ_k φ(s_k),
   Δ = (m_new(φ̄) − m_old(φ̄)) / σ (the paper's contextual paths, CMA-ES's Eqs. for p_σ and
   p_c with the mean shift replaced by Δ):

   .. math:: p_\sigma \leftarrow (1 - c_\sigma) p_\sigma
             + \sqrt{c_\sigma (2 - c_\sigma) \mu_{\mathrm{eff}}}\, C^{-1/2} \Delta, \qquad
             p_c \leftarrow (1 - c_c) p_c
             + h_\sigma \sqrt{c_c (2 - c_c) \mu_{\mathrm{eff}}}\,\Delta.

5. **Covariance**: rank-one and rank-μ update, the rank-μ term from each sample's deviation
   from the *old mean in its own context*, y_k = (ω_k − m_old(s_k)) / σ:

   .. math:: C \leftarrow (1 - c_1 - c_\mu) C + c_1 \big(p_c p_c^\top
             + (1 - h_\sigma) c_c (2 - c_c) C\big) + c_\mu \textstyle\sum_k d_k y_k y_k^\top.

6. **Step size**: σ ← σ exp(min(ℓ_max, (c_σ/d_σ)(‖p_σ‖ / E‖N(0, I_d)‖ − 1))).

Steps 4–6 are :func:`adapt_covariance`. The rates (:func:`ccmaes_rates`) are Hansen's CMA-ES
defaults (*The CMA Evolution Strategy: A Tutorial*, 2016, Table 1) with the dimension n = d + n_s
(search and context dimensions, as bolero's ``CCMAESOptimizer`` takes them), and the default
population N = (4 + ⌊3 ln n⌋)(1 + 2 n_s) is bolero's: more samples per generation with more
context dimensions to regress on. Where the paper leaves a detail open we follow CMA-ES: h_σ,
the (1 − h_σ) variance correction, the bound ℓ_max on one step's log step-size change, and the
weights on the best half only (bolero weights all N samples, d_j ∝ ln(N + ½) − ln j; on a
context-free 3-D sphere that left the mean ~20× farther from the optimum after 420 rollouts
than the half-weights, which match the ``cma`` package's CMA-ES there).

Against :class:`~skillkit.search.cmaes.CMAES` (the ``cma`` package on θ = [b, vec W], one
fitness per candidate averaged over m contexts), C-CMA-ES searches ω directly with one context
per sample and removes the spread of R over μ(s) with the baseline instead of averaging.

The algorithm draws nothing itself: ``policy.sample(contexts, rng)`` draws with the loop's
``rng``, so same seed ⇒ same run. The object pickles (checkpoints).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skillkit._validation import check_array, check_count, check_positive
from skillkit.policies.features import check_feature_name, context_features
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.base import Batch, as_batch

__all__ = [
    "CCMAES",
    "CCMAESDiagnostics",
    "CCMAESRates",
    "CCMAESSettings",
    "adapt_covariance",
    "advantage_weights",
    "ccmaes_rates",
    "default_population",
    "fit_baseline",
    "rank_weights",
    "weighted_linear_regression",
]


# ----------------------------------------------------------------- pure functions
def default_population(dim: int, context_dim: int) -> int:
    """N = (4 + ⌊3 ln n⌋)(1 + 2 n_s), n = d + n_s: CMA-ES's population times 1 + 2 n_s.

    Parameters
    ----------
    dim : int
        d ≥ 1, the dimension of ω.
    context_dim : int
        n_s ≥ 0.
    """
    d = check_count(dim, "dim")
    n_s = check_count(context_dim, "context_dim", 0)
    return (4 + math.floor(3 * math.log(d + n_s))) * (1 + 2 * n_s)


def rank_weights(n: int) -> np.ndarray:
    """CMA-ES's rank weights, best first: d_j ∝ ln(μ + ½) − ln j for j ≤ μ = max(⌊n/2⌋, 1),
    d_j = 0 for j > μ (Hansen's default positive weights).

    Parameters
    ----------
    n : int
        Number of samples n ≥ 1.

    Returns
    -------
    ndarray, shape (n,)
        Summing to one; positive and strictly decreasing over the ranks 1 … μ, zero after.
    """
    n = check_count(n, "n")
    mu = max(n // 2, 1)
    w = np.zeros(n)
    w[:mu] = math.log(mu + 0.5) - np.log(np.arange(1, mu + 1))
    return w / w.sum()


def advantage_weights(advantages: ArrayLike) -> np.ndarray:
    """Each sample's rank weight (:func:`rank_weights`) by its advantage, largest first.

    Parameters
    ----------
    advantages : array_like, shape (N,)
        A_k = R_k − V(s_k); ties keep the samples' order.

    Returns
    -------
    ndarray, shape (N,)
        d_k = d_{rank(k)}, summing to one.
    """
    adv = check_array(advantages, "advantages", ndim=1)
    if adv.size == 0:
        raise ValueError("advantages: expected at least one sample, got shape (0,)")
    order = np.argsort(-adv, kind="stable")
    w = np.empty_like(adv)
    w[order] = rank_weights(adv.size)
    return w


def _design(features: ArrayLike, name: str) -> np.ndarray:
    phi = check_array(features, name, ndim=2)
    return np.hstack([np.ones((phi.shape[0], 1)), phi])


def fit_baseline(
    features: ArrayLike, rewards: ArrayLike, ridge: float
) -> tuple[np.ndarray, np.ndarray]:
    r"""The context-dependent baseline V(s) = βᵀ[1, φ_V(s)] by ridge regression on the rewards.

    .. math:: \beta = (\Psi^\top \Psi + \lambda I_0)^{-1} \Psi^\top R, \qquad
              \Psi = [1, \varphi_V(s_k)]_k,

    I₀ the identity with a zero for the intercept (which is not shrunk).

    Parameters
    ----------
    features : array_like, shape (N, F)
        φ_V(s_k) (F may be 0: V is then the mean reward).
    rewards : array_like, shape (N,)
    ridge : float
        λ ≥ 0.

    Returns
    -------
    beta : ndarray, shape (1 + F,)
        Intercept first.
    values : ndarray, shape (N,)
        V(s_k).
    """
    psi = _design(features, "features")
    r = check_array(rewards, "rewards", shape=(psi.shape[0],))
    if r.size == 0:
        raise ValueError("rewards: expected at least one sample, got shape (0,)")
    lam = check_positive(ridge, "ridge", allow_zero=True)
    reg = lam * np.diag(np.r_[0.0, np.ones(psi.shape[1] - 1)])
    beta = np.linalg.lstsq(psi.T @ psi + reg, psi.T @ r, rcond=None)[0]
    return beta, psi @ beta


def weighted_linear_regression(
    features: ArrayLike, targets: ArrayLike, weights: ArrayLike, ridge: float = 0.0
) -> np.ndarray:
    r"""[a, A] minimising Σ_k d_k ‖ω_k − a − A φ_k‖² + λ ‖A‖²_F (the C-CMA-ES mean).

    .. math:: [a, A]^\top = (\tilde\Phi^\top D \tilde\Phi + \lambda I_0)^{-1}
              \tilde\Phi^\top D\, \Omega, \qquad \tilde\Phi = [1, \varphi_k]_k,
              \ D = \operatorname{diag}(d).

    Parameters
    ----------
    features : array_like, shape (N, F)
        φ(s_k).
    targets : array_like, shape (N, d)
        ω_k.
    weights : array_like, shape (N,)
        d_k ≥ 0, not all zero.
    ridge : float
        λ ≥ 0 on the gain A (the offset a is not shrunk).

    Returns
    -------
    ndarray, shape (d, 1 + F)
        [a, A]: the mean is [a, A] [1, φ(s)].
    """
    x = _design(features, "features")
    y = check_array(targets, "targets", shape=(x.shape[0], None))
    w = check_array(weights, "weights", shape=(x.shape[0],))
    if np.any(w < 0) or not np.any(w > 0):
        raise ValueError("weights: expected non-negative weights, not all zero")
    lam = check_positive(ridge, "ridge", allow_zero=True)
    reg = lam * np.diag(np.r_[0.0, np.ones(x.shape[1] - 1)])
    xw = x * w[:, None]
    return np.linalg.lstsq(xw.T @ x + reg, xw.T @ y, rcond=None)[0].T


@dataclass(frozen=True)
class CCMAESRates:
    """Learning rates of one generation (:func:`ccmaes_rates`).

    Attributes
    ----------
    mu_eff : float
        μ_eff = 1 / Σ d_j², the variance-effective number of samples.
    c_sigma, d_sigma : float
        Rate and damping of the step-size path.
    c_c : float
        Rate of the covariance path.
    c_1, c_mu : float
        Rates of the rank-one and rank-μ covariance updates.
    chi_d : float
        E‖N(0, I_d)‖ ≈ √d (1 − 1/(4d) + 1/(21 d²)).
    """

    mu_eff: float
    c_sigma: float
    d_sigma: float
    c_c: float
    c_1: float
    c_mu: float
    chi_d: float


def ccmaes_rates(n_samples: int, dim: int, context_dim: int) -> CCMAESRates:
    """Hansen's CMA-ES default rates (Tutorial 2016, Table 1) for N samples, n = d + n_s.

    Parameters
    ----------
    n_samples : int
        N ≥ 2.
    dim : int
        d ≥ 1 (the paths live in R^d, so E‖N(0, I_d)‖ uses d).
    context_dim : int
        n_s ≥ 0.
    """
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
    """Steps 4–6 of the module notes: paths, shape C and step size σ (no input is changed).

    Parameters
    ----------
    shape : ndarray, shape (d, d)
        C, symmetric positive definite.
    sigma : float
        σ > 0 of the generation that drew the samples.
    path_sigma, path_c : ndarray, shape (d,)
        p_σ and p_c.
    mean_shift : ndarray, shape (d,)
        Δ = (m_new(φ̄) − m_old(φ̄)) / σ.
    deviations : ndarray, shape (N, d)
        y_k = (ω_k − m_old(s_k)) / σ.
    weights : ndarray, shape (N,)
        d_k (summing to one).
    rates : CCMAESRates
    generation : int
        g ≥ 1, this update's number (for h_σ's bias correction 1 − (1 − c_σ)^{2g}).
    max_log_step : float
        ℓ_max: the largest increase of ln σ in one update.

    Returns
    -------
    shape : ndarray, shape (d, d)
    sigma : float
    path_sigma, path_c : ndarray, shape (d,)
    h_sigma : bool
        Whether p_σ was short enough to feed p_c (CMA-ES's stall guard).
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
    """Settings of :class:`CCMAES`.

    Attributes
    ----------
    baseline_features : {"linear", "quadratic"}
        φ_V of the baseline V(s) = βᵀ[1, φ_V(s)] (:mod:`skillkit.policies.features`). The
        default is quadratic: for a reward quadratic in ω and a mean linear in s, E[R | s] is
        quadratic in s.
    baseline_ridge : float
        λ_V ≥ 0 of the baseline's ridge regression (reward² units; the intercept is free).
    mean_ridge : float
        λ ≥ 0 on the gain A in the weighted regression of the mean (keeps it solvable when
        the samples' contexts are degenerate).
    max_log_step : float
        ℓ_max > 0, the largest increase of ln σ in one update (CMA-ES's guard against a step
        size blown up by one long path).
    """

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
    """What one :meth:`CCMAES.update` did.

    Attributes
    ----------
    generation : int
        Updates so far.
    n_samples : int
        N, samples of this generation.
    mean_reward : float
        Mean reward of the batch.
    advantage_std : float
        Standard deviation of the advantages R − V(s) (what the baseline left).
    sigma : float
        Step size σ after the update.
    axis_ratio : float
        √(largest / smallest eigenvalue) of C after the update.
    std_max : float
        σ √λ_max(C), the largest standard deviation of the new search distribution.
    path_norm : float
        ‖p_σ‖ after the update (E‖N(0, I_d)‖ when σ is right).
    h_sigma : bool
        Whether p_c was fed this generation.
    """

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
        return (
            f"CCMAESDiagnostics(generation={self.generation}, n_samples={self.n_samples}, "
            f"mean_reward={self.mean_reward:.4g}, advantage_std={self.advantage_std:.4g}, "
            f"sigma={self.sigma:.4g}, axis_ratio={self.axis_ratio:.4g}, "
            f"std_max={self.std_max:.4g}, path_norm={self.path_norm:.4g}, h_sigma={self.h_sigma})"
        )


class CCMAES:
    """Contextual CMA-ES (module notes) as a policy-search algorithm for :func:`learn`.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial search distribution N(a + Aφ(s), Σ₀) (e.g. ``task.initial_policy()``); its
        features are the mean's. σ₀ = √(max_i Σ₀,ii) and C₀ = Σ₀ / σ₀².
    settings : CCMAESSettings, optional

    Notes
    -----
    ``learn(task, alg, K, alg.rollouts_per_update, rng)`` runs it; any batch of N ≥ 2
    rollouts is accepted (the rates follow N), rows re-scored in extra contexts are refused.
    """

    def __init__(self, policy: LinearGaussianPolicy, settings: CCMAESSettings | None = None):
        if not isinstance(policy, LinearGaussianPolicy):
            raise ValueError(
                f"policy: expected a LinearGaussianPolicy, got {type(policy).__name__}"
            )
        if settings is None:
            settings = CCMAESSettings()
        if not isinstance(settings, CCMAESSettings):
            raise ValueError(f"settings: expected CCMAESSettings, got {type(settings).__name__}")
        self.settings = settings
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
        """The default population N = :func:`default_population` (d, n_s)."""
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
        """One C-CMA-ES generation (module notes, steps 1–6) from the batch's rollouts.

        Parameters
        ----------
        batch : Batch
            N ≥ 2 rollouts drawn from ``self.policy`` (row k: s_k, ω_k, R_k).

        Raises
        ------
        ValueError
            Naming ``batch`` when it has rows re-scored in extra contexts or fewer than 2 rows.
        """
        old = self._policy
        d, n_s = self._dims
        batch = as_batch(batch, d, n_s)
        if batch.n_rollouts != len(batch):
            raise ValueError(
                "batch: CCMAES takes rollouts only; rows re-scored in extra contexts "
                "(learn's extra_contexts > 0) were not drawn from π(ω|s) in their context"
            )
        n = len(batch)
        if n < 2:
            raise ValueError(f"batch: expected at least 2 rollouts to rank, got {n}")
        s, omegas, rewards = batch.contexts, batch.omegas, batch.rewards
        cfg = self.settings
        # 1. baseline and advantages
        _, values = fit_baseline(
            context_features(s, cfg.baseline_features), rewards, cfg.baseline_ridge
        )
        advantages = rewards - values
        # 2. rank weights
        weights = advantage_weights(advantages)
        # 3. mean by weighted linear regression
        phi = old.phi(s)[0]
        self.coefficients = weighted_linear_regression(phi, omegas, weights, cfg.mean_ridge)
        # 4–6. paths, covariance, step size
        phi_bar = np.r_[1.0, phi.mean(axis=0)]
        old_coef = old.coefficients
        mean_shift = (self.coefficients - old_coef) @ phi_bar / self.sigma
        deviations = (omegas - old.mean_of(s)) / self.sigma
        self.generation += 1
        rates = ccmaes_rates(n, d, n_s)
        self.shape, self.sigma, self.path_sigma, self.path_c, h_sigma = adapt_covariance(
            self.shape,
            self.sigma,
            self.path_sigma,
            self.path_c,
            mean_shift,
            deviations,
            weights,
            rates,
            self.generation,
            cfg.max_log_step,
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
