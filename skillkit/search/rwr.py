r"""Contextual Reward-Weighted Regression (RWR), Eq. (2.18).

RWR fits the linear-Gaussian policy of contextual REPS by weighted maximum likelihood, with the
weights w_i ∝ exp(β R_i) instead of (3.10): no KL bound, no baseline. The thesis leaves β open;
we take β = ``beta_scale`` / std(R) over the samples used, invariant to the reward scale (for
roughly Gaussian rewards KL(w ‖ uniform) ≈ ``beta_scale``² / 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skillkit._validation import check_positive
from skillkit.policies.gaussian import FitInfo, LinearGaussianPolicy, effective_sample_size
from skillkit.search.base import Fields, WeightedMLSearch, fields_repr
from skillkit.search.reps import check_samples, kl_from_uniform


def rwr_beta(rewards: ArrayLike, beta_scale: float = 1.0) -> float:
    """β = ``beta_scale`` / std(R) over rewards of shape (N,), N ≥ 1 (0 when all are equal)."""
    r = check_samples(rewards, None)[0]
    kappa = check_positive(beta_scale, "beta_scale")
    sd = float(r.std())
    return kappa / sd if sd > 0 else 0.0


def rwr_weights(rewards: ArrayLike, beta: float) -> np.ndarray:
    """Normalised weights w_i ∝ exp(β R_i) (Eq. 2.18) of rewards (N,), for β ≥ 0."""
    r = check_samples(rewards, None)[0]
    b = check_positive(beta, "beta", allow_zero=True)
    w = np.exp(b * (r - r.max()))
    return w / w.sum()


def rwr_weighting(rewards: ArrayLike, beta_scale: float = 1.0) -> tuple[np.ndarray, Fields]:
    """Weights w_i ∝ exp(β R_i) (Eq. 2.18) with β from :func:`rwr_beta`, and their diagnostics
    ``beta``, ``kl`` (KL(w ‖ uniform)) and ``ess`` (Kish effective sample size)."""
    beta = rwr_beta(rewards, beta_scale)
    p = rwr_weights(rewards, beta)
    return p, {"beta": beta, "kl": kl_from_uniform(p), "ess": effective_sample_size(p)}


@dataclass(frozen=True)
class RWRDiagnostics:
    """What one :meth:`RWR.update` did: :func:`rwr_weighting`'s fields and those of
    :meth:`~skillkit.search.base.WeightedMLSearch.update`."""

    n_samples: int
    beta: float
    kl: float
    ess: float
    policy_kl: float
    mean_reward: float
    fit: FitInfo

    def __repr__(self) -> str:
        names = ("n_samples", "beta", "kl", "ess", "policy_kl", "mean_reward")
        return fields_repr(self, *names)


class RWR(WeightedMLSearch[RWRDiagnostics]):
    """Contextual RWR (Eq. 2.18): :class:`~skillkit.search.base.WeightedMLSearch` with the
    weights of :func:`rwr_weighting`.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial upper-level policy.
    beta_scale : float
        β = ``beta_scale`` / std(R) (module notes).
    n_reuse_batches : int or None
        Use the last L batches, the newest included (``None``: all).
    ridge, cov_shrinkage, cov_floor, min_effective_samples
        Regularisation of the weighted ML fit (:class:`~skillkit.search.base.WeightedMLSearch`).
    """

    def __init__(
        self,
        policy: LinearGaussianPolicy,
        beta_scale: float = 1.0,
        n_reuse_batches: int | None = 1,
        ridge: float = 1e-6,
        cov_shrinkage: float = 0.0,
        cov_floor: float = 1e-4,
        min_effective_samples: float | None = None,
    ):
        super().__init__(
            policy, n_reuse_batches, ridge, cov_shrinkage, cov_floor, min_effective_samples
        )
        self.beta_scale = check_positive(beta_scale, "beta_scale")

    _diagnostics = RWRDiagnostics

    def _settings_repr(self) -> str:
        return f"beta_scale={self.beta_scale:.4g}"

    def _weigh(self, contexts: np.ndarray, rewards: np.ndarray) -> tuple[np.ndarray, Fields]:
        """Weights exp(βR) (Eq. 2.18) of the kept samples."""
        return rwr_weighting(rewards, self.beta_scale)
