"""What the search algorithms share: the batch, sample reuse and the weighted ML step.

Every ``update`` takes one :class:`Batch` (s_i, ω_i, R_i and the trajectories τ_i).
Contextual REPS and RWR run the same loop (Table 3.1), :class:`WeightedMLSearch`: keep the last
L batches (:class:`SampleBuffer`), weight the kept samples (:meth:`~WeightedMLSearch._weigh`:
Eq. 3.10 for REPS, Eq. 2.18 for RWR) and refit the linear-Gaussian policy by weighted maximum
likelihood (Eqs. 3.11–3.13).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import ArrayLike
from scipy import special

from skillkit._validation import check_array, check_count, check_type
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.trajectory import Trajectory

S = TypeVar("S")


# --------------------------------------------------------------------------- samples
def check_batch(
    contexts: ArrayLike | None, omegas: ArrayLike, rewards: ArrayLike, dim: int, context_dim: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated (contexts, omegas, rewards) of shapes (N, context_dim), (N, dim), (N,).

    ``contexts`` may be ``None`` when ``context_dim`` is 0; rewards must be finite.
    """
    w = check_array(omegas, "omegas", shape=(None, dim))
    n = w.shape[0]
    if n == 0:
        raise ValueError("omegas: expected at least one sample, got 0 rows")
    if contexts is None and context_dim == 0:
        contexts = np.zeros((n, 0))
    s = check_array(contexts, "contexts", shape=(n, context_dim))
    r = check_array(rewards, "rewards", shape=(n,))
    return s, w, r


@dataclass(frozen=True, repr=False)
class Batch:
    """One batch of samples (s_i, ω_i ~ π(ω|s_i), R(τ_i, s_i), optionally τ_i) for
    ``algorithm.update(batch)``, validated when built.

    Parameters
    ----------
    contexts : array_like, shape (N, context_dim), or None
        ``None`` for a context-free task (stored as shape (N, 0)).
    omegas : array_like, shape (N, d)
    rewards : array_like, shape (N,)
    trajectories : sequence of Trajectory, optional
    n_rollouts : int, optional
        The first ``n_rollouts`` rows (default N) are rollouts in their own contexts; the rest
        re-score them in extra contexts (Sec. 3.4).
    """

    contexts: np.ndarray
    omegas: np.ndarray
    rewards: np.ndarray
    trajectories: Sequence[Trajectory] | None = None
    n_rollouts: int | None = None

    def __post_init__(self):
        w = check_array(self.omegas, "omegas", ndim=2)
        c = None if self.contexts is None else check_array(self.contexts, "contexts", ndim=2)
        s, w, r = check_batch(c, w, self.rewards, w.shape[1], 0 if c is None else c.shape[1])
        object.__setattr__(self, "contexts", s)
        object.__setattr__(self, "omegas", w)
        object.__setattr__(self, "rewards", r)
        if self.trajectories is not None:
            trajs = tuple(self.trajectories)
            if len(trajs) != r.shape[0] or not all(isinstance(t, Trajectory) for t in trajs):
                raise ValueError(f"trajectories: expected {len(r)} Trajectories, got {len(trajs)}")
            object.__setattr__(self, "trajectories", trajs)
        k = len(r) if self.n_rollouts is None else _check_n_rollouts(self.n_rollouts, len(r))
        object.__setattr__(self, "n_rollouts", k)

    def __len__(self) -> int:
        return int(self.rewards.shape[0])

    @property
    def dim(self) -> int:
        """Dimension d of ω."""
        return int(self.omegas.shape[1])

    @property
    def context_dim(self) -> int:
        """Dimension of the context s (0 for a context-free task)."""
        return int(self.contexts.shape[1])

    def __repr__(self) -> str:
        r = self.rewards
        n_traj = "none" if self.trajectories is None else str(len(self.trajectories))
        return (
            f"Batch(N={len(self)}, dim={self.dim}, context_dim={self.context_dim}, "
            f"reward mean {r.mean():.4g} in [{r.min():.4g}, {r.max():.4g}], "
            f"trajectories: {n_traj}"
            + (f", {self.n_rollouts} rollouts" if self.n_rollouts < len(self) else "")
            + ")"
        )


def as_batch(batch: Batch, dim: int, context_dim: int) -> Batch:
    """``batch`` after checking it is a :class:`Batch` for ``dim`` and ``context_dim``."""
    check_type(batch, Batch, "batch", "a skillkit.search.Batch")
    if batch.dim != dim:
        raise ValueError(f"omegas: expected shape (N, {dim}), got {batch.omegas.shape}")
    if batch.context_dim != context_dim:
        raise ValueError(f"contexts: expected shape (N, {context_dim}), got {batch.contexts.shape}")
    return batch


def rollouts_only(batch: Batch, algorithm: str) -> Batch:
    """``batch`` after checking it has no rows re-scored in extra contexts."""
    if batch.n_rollouts != len(batch):
        raise ValueError(f"batch: {algorithm} takes no rows re-scored in extra contexts")
    return batch


def check_policy(policy: LinearGaussianPolicy, name: str = "policy") -> LinearGaussianPolicy:
    """``policy`` after checking it is a :class:`LinearGaussianPolicy`."""
    return check_type(policy, LinearGaussianPolicy, name, "a LinearGaussianPolicy")


def check_settings(settings: S | None, cls: type[S]) -> S:
    """``settings`` (``None``: ``cls()``) after checking it is a ``cls``."""
    return check_type(cls() if settings is None else settings, cls, "settings")


def fields_repr(obj: Any, *names: str) -> str:
    """``Type(name=value, …)`` of some attributes of ``obj`` (default: its dataclass fields),
    floats as ``.4g``."""
    values = ((n, getattr(obj, n)) for n in names or [f.name for f in fields(obj)])
    text = ", ".join(f"{n}={v:.4g}" if isinstance(v, float) else f"{n}={v}" for n, v in values)
    return f"{type(obj).__name__}({text})"


def _check_n_rollouts(k, n: int) -> int:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= n:
        raise ValueError(f"n_rollouts: expected an integer in 1..{n}, got {k!r}")
    return int(k)


def extra_context_importance(
    policy: LinearGaussianPolicy,
    contexts: ArrayLike,
    omegas: ArrayLike,
    n_rollouts: int,
) -> np.ndarray:
    r"""Importance weights that make a batch with extra contexts stand for μ(s)π(ω|s).

    In the k re-scored rows (s′, ω_i) of each of the N rollouts (Sec. 3.4) ω is drawn from its
    marginal m, not from π(ω|s′). As samples of q(s, ω) = μ(s)[f π(ω|s) + (1 − f) m(ω)],
    f = 1/(1 + k), every row gets the balance-heuristic weight

    .. math::
        w(s, \omega) = \frac{\pi(\omega|s)}{f\,\pi(\omega|s) + (1 - f)\,\hat m(\omega)},
        \qquad \hat m(\omega) = \frac1N \sum_{j=1}^N \pi(\omega|s_j),

    with 0 < w ≤ 1 + k.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        π, the policy that drew the batch.
    contexts : array_like, shape (M, context_dim)
        All rows' contexts, the N rollouts first.
    omegas : array_like, shape (M, d)
    n_rollouts : int
        N, 1 ≤ N ≤ M.

    Returns
    -------
    ndarray, shape (M,)
    """
    s = check_array(contexts, "contexts", ndim=2)
    w = check_array(omegas, "omegas", shape=(s.shape[0], policy.dim))
    m_rows = s.shape[0]
    n = _check_n_rollouts(n_rollouts, m_rows)
    if n == m_rows:
        return np.ones(m_rows)
    f = n / m_rows
    log_own = policy.log_prob(w, s)
    cross = policy.log_prob(np.repeat(w, n, axis=0), np.tile(s[:n], (m_rows, 1)))
    log_m = special.logsumexp(cross.reshape(m_rows, n), axis=1) - np.log(n)
    log_q = np.logaddexp(np.log(f) + log_own, np.log1p(-f) + log_m)
    return np.exp(log_own - log_q)


class SampleBuffer:
    """The last ``n_batches`` batches of samples (data reuse, Table 3.1; ``None`` keeps all)."""

    def __init__(self, n_batches: int | None):
        if n_batches is not None:
            n_batches = check_count(n_batches, "n_reuse_batches")
        self._batches: deque = deque(maxlen=n_batches)

    def add(
        self,
        contexts: np.ndarray,
        omegas: np.ndarray,
        rewards: np.ndarray,
        n_rollouts: int | None = None,
        importance: np.ndarray | None = None,
    ) -> None:
        """Append a batch (the oldest dropped when full); ``importance`` is stored at mean one."""
        if importance is not None:
            importance = importance / importance.mean()
        n = rewards.shape[0] if n_rollouts is None else n_rollouts
        self._batches.append((contexts, omegas, rewards, n, importance))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All kept contexts (N, s), omegas (N, d) and rewards (N,), oldest first."""
        return tuple(np.concatenate([b[i] for b in self._batches]) for i in range(3))

    def rollout_mask(self) -> np.ndarray:
        """Whether each kept row is a rollout in its own context, shape (N,)."""
        return np.concatenate([np.arange(r.shape[0]) < n for _, _, r, n, _ in self._batches])

    def importance(self) -> np.ndarray | None:
        """The kept rows' importance weights, shape (N,) (``None`` when no batch has any)."""
        if all(b[4] is None for b in self._batches):
            return None
        return np.concatenate(
            [np.ones(r.shape[0]) if q is None else q for _, _, r, _, q in self._batches]
        )

    def __len__(self) -> int:
        return sum(b[2].shape[0] for b in self._batches)

    @property
    def max_batches(self) -> int | None:
        """L, the number of batches kept (``None``: all)."""
        return self._batches.maxlen

    def __repr__(self) -> str:
        keep = "all" if self.max_batches is None else f"last {self.max_batches}"
        return f"SampleBuffer({keep} batches; {len(self._batches)} kept, {len(self)} samples)"


# --------------------------------------------------------------------------- algorithm
D = TypeVar("D")
Fields = dict[str, Any]  # diagnostics fields by name


class WeightedMLSearch(Generic[D]):
    """Policy search by reweighted samples and a weighted ML refit (Table 3.1).

    Subclasses set ``_diagnostics`` (a dataclass taking ``n_samples``, ``policy_kl``,
    ``mean_reward``, ``fit`` and the fields :meth:`_weigh` returns) and implement :meth:`_weigh`.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial upper-level policy π(ω|s).
    n_reuse_batches : int or None
        L: the last L batches are used, the newest included (``None``: all).
    ridge, cov_shrinkage, cov_floor, min_effective_samples
        Regularisation of :meth:`~skillkit.policies.gaussian.LinearGaussianPolicy.fit_with_info`.
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
        check_policy(policy)
        self._fit_kwargs = {
            "ridge": ridge,
            "cov_shrinkage": cov_shrinkage,
            "cov_floor": cov_floor,
            "min_effective_samples": min_effective_samples,
        }
        self._policy = policy
        self._buffer = SampleBuffer(n_reuse_batches)
        self.n_updates = 0

    @property
    def policy(self) -> LinearGaussianPolicy:
        """The current upper-level policy."""
        return self._policy

    def _weigh(self, contexts: np.ndarray, rewards: np.ndarray) -> tuple[np.ndarray, Fields]:
        """Weights (summing to one) of the kept samples, and the diagnostics fields they add."""
        raise NotImplementedError

    def update(self, batch: Batch) -> D:
        """Add a batch, weight the last L batches and refit the policy (Eqs. 3.11–3.13); returns the
        subclass's diagnostics, ``policy_kl`` being KL(π_new ‖ π_old) over the kept contexts."""
        pol = self._policy
        batch = as_batch(batch, pol.dim, pol.context_dim)
        importance = self._importance(batch)
        self._buffer.add(batch.contexts, batch.omegas, batch.rewards, batch.n_rollouts, importance)
        s_all, w_all, r_all = self._buffer.arrays()
        weights, weighting = self._weigh(s_all, r_all)
        new, info = pol.fit_with_info(s_all, w_all, weights, **self._fit_kwargs)
        new, stepping = self._m_step(pol, new, s_all)
        policy_kl = new.kl(pol, s_all)
        self._policy = new
        self.n_updates += 1
        return self._diagnostics(
            n_samples=int(r_all.shape[0]),
            policy_kl=policy_kl,
            mean_reward=float(batch.rewards.mean()),
            fit=info,
            **weighting,
            **stepping,
        )

    def _importance(self, batch: Batch) -> np.ndarray | None:
        """Importance weights of a new batch's rows, kept with it (default ``None``)."""
        return None

    def _m_step(
        self, old: LinearGaussianPolicy, fitted: LinearGaussianPolicy, contexts: np.ndarray
    ) -> tuple[LinearGaussianPolicy, Fields]:
        """The new policy from the fit and the diagnostics fields it adds (default: the fit)."""
        return fitted, {}

    def _settings_repr(self) -> str:
        """The subclass's settings for :meth:`__repr__`."""
        return ""

    def __repr__(self) -> str:
        pol, own = self._policy, self._settings_repr()
        reuse = self._buffer.max_batches
        return (
            f"{type(self).__name__}({own + ', ' if own else ''}"
            f"dim={pol.dim}, context_dim={pol.context_dim}, "
            f"reuse={'all' if reuse is None else reuse} batches, "
            f"{self.n_updates} updates, {len(self._buffer)} samples kept)"
        )
