r"""What contextual REPS and RWR share: sample reuse and the weighted maximum-likelihood step.

Both algorithms run the same loop (Table 3.1): validate a batch of (s_i, ω_i, R_i), keep the
last L batches (:class:`SampleBuffer`), weight the kept samples, and refit the linear-Gaussian
policy by weighted maximum likelihood (Eqs. 3.11–3.13,
:meth:`~skillkit.policies.gaussian.LinearGaussianPolicy.fit_with_info`). They differ only in
the weights: REPS solves its dual for p_i ∝ exp((R_i − V(s_i))/η) (Eq. 3.10), RWR takes
w_i ∝ exp(β R_i) (Eq. 2.18). :class:`WeightedMLSearch` runs the loop; a subclass supplies
:meth:`~WeightedMLSearch._weigh` and its diagnostics dataclass.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from skillkit._validation import check_array
from skillkit.policies.gaussian import LinearGaussianPolicy


# --------------------------------------------------------------------------- samples
def check_batch(
    contexts: ArrayLike | None, omegas: ArrayLike, rewards: ArrayLike, dim: int, context_dim: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate one batch of samples for a policy of dimension ``dim`` and ``context_dim``.

    Parameters
    ----------
    contexts : array_like, shape (N, context_dim)
        ``None`` is accepted for context-free policies.
    omegas : array_like, shape (N, dim)
    rewards : array_like, shape (N,)
        Must be finite (NaN/inf raise ``ValueError`` naming ``rewards``).

    Returns
    -------
    (contexts, omegas, rewards) as float64 arrays of shapes (N, context_dim), (N, dim), (N,).
    """
    w = check_array(omegas, "omegas", ndim=2)
    if w.shape[1] != dim:
        raise ValueError(f"omegas: expected shape (N, {dim}), got {w.shape}")
    n = w.shape[0]
    if n == 0:
        raise ValueError("omegas: expected at least one sample, got 0 rows")
    if contexts is None and context_dim == 0:
        contexts = np.zeros((n, 0))
    s = check_array(contexts, "contexts", shape=(n, context_dim))
    r = check_array(rewards, "rewards", shape=(n,))
    return s, w, r


class SampleBuffer:
    """The last ``n_batches`` batches of (context, ω, reward) samples (data reuse, Table 3.1).

    Parameters
    ----------
    n_batches : int or None
        Number of batches kept, the newest included (``None`` keeps all).
    """

    def __init__(self, n_batches: int | None):
        if n_batches is not None and (
            isinstance(n_batches, bool) or int(n_batches) != n_batches or n_batches < 1
        ):
            raise ValueError(
                f"n_reuse_batches: expected a positive integer or None, got {n_batches!r}"
            )
        self._batches: deque = deque(maxlen=None if n_batches is None else int(n_batches))

    def add(self, contexts: np.ndarray, omegas: np.ndarray, rewards: np.ndarray) -> None:
        """Append a validated batch (oldest batch dropped when full)."""
        self._batches.append((contexts, omegas, rewards))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All kept samples: contexts (N, s), omegas (N, d), rewards (N,), oldest first."""
        s, w, r = (np.concatenate(parts) for parts in zip(*self._batches, strict=True))
        return s, w, r

    def __len__(self) -> int:
        return sum(b[2].shape[0] for b in self._batches)


# --------------------------------------------------------------------------- algorithm
D = TypeVar("D")
Fields = dict[str, Any]  # diagnostics fields by name


class WeightedMLSearch(Generic[D]):
    """Policy search by reweighted samples and a weighted ML refit (Table 3.1).

    Subclasses set ``_diagnostics`` (a dataclass with fields ``n_samples``, ``policy_kl``,
    ``mean_reward``, ``fit`` and those returned by :meth:`_weigh`) and implement
    :meth:`_weigh`. All state is in instance attributes, so an algorithm pickles.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial upper-level policy π(ω|s).
    n_reuse_batches : int or None
        L: the weights and the fit use the last L batches, the newest included (``None``: all).
    ridge, cov_shrinkage, cov_floor, min_effective_samples
        Regularisation of the weighted ML fit, see
        :meth:`~skillkit.policies.gaussian.LinearGaussianPolicy.fit_with_info`.
    """

    _diagnostics: Callable[..., D]

    def __init__(
        self,
        policy: LinearGaussianPolicy,
        n_reuse_batches: int | None,
        ridge: float,
        cov_shrinkage: float,
        cov_floor: float,
        min_effective_samples: float | None,
    ):
        if not isinstance(policy, LinearGaussianPolicy):
            raise ValueError(
                f"policy: expected a LinearGaussianPolicy, got {type(policy).__name__}"
            )
        self._fit_kwargs = {
            "ridge": ridge,
            "cov_shrinkage": cov_shrinkage,
            "cov_floor": cov_floor,
            "min_effective_samples": min_effective_samples,
        }
        self._policy = policy
        self._buffer = SampleBuffer(n_reuse_batches)

    @property
    def policy(self) -> LinearGaussianPolicy:
        """The current upper-level policy."""
        return self._policy

    def _weigh(self, contexts: np.ndarray, rewards: np.ndarray) -> tuple[np.ndarray, Fields]:
        """Weights (summing to one) of the kept samples, and the diagnostics fields they add."""
        raise NotImplementedError

    def update(self, contexts: ArrayLike | None, omegas: ArrayLike, rewards: ArrayLike) -> D:
        """Add a batch, weight the last L batches (:meth:`_weigh`) and refit the policy.

        Parameters
        ----------
        contexts : array_like, shape (N, context_dim)
            Contexts s_i (``None`` for a context-free policy).
        omegas : array_like, shape (N, d)
            Parameters ω_i ~ π(ω|s_i).
        rewards : array_like, shape (N,)
            Rewards R(τ_i, s_i); must be finite.

        Returns
        -------
        The subclass's diagnostics (:class:`~skillkit.search.reps.REPSDiagnostics`,
        :class:`~skillkit.search.rwr.RWRDiagnostics`).
        """
        pol = self._policy
        s, w, r = check_batch(contexts, omegas, rewards, pol.dim, pol.context_dim)
        self._buffer.add(s, w, r)
        s_all, w_all, r_all = self._buffer.arrays()
        weights, weighting = self._weigh(s_all, r_all)
        new, info = pol.fit_with_info(s_all, w_all, weights, **self._fit_kwargs)
        policy_kl = new.kl(pol, s_all)
        self._policy = new
        return self._diagnostics(
            n_samples=int(r_all.shape[0]),
            policy_kl=policy_kl,
            mean_reward=float(r.mean()),
            fit=info,
            **weighting,
        )
