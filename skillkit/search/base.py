r"""What the search algorithms share: the batch, sample reuse and the weighted ML step.

Every algorithm's ``update`` takes one :class:`Batch` of samples (s_i, ω_i, R_i, and the
trajectories τ_i they came from), validated once when it is built. Model-free algorithms use
the (s, ω, R) arrays; a model-based one (GPREPS) also learns from the trajectories.

Contextual REPS and RWR run the same loop (Table 3.1): take a batch of (s_i, ω_i, R_i), keep the
last L batches (:class:`SampleBuffer`), weight the kept samples, and refit the linear-Gaussian
policy by weighted maximum likelihood (Eqs. 3.11–3.13,
:meth:`~skillkit.policies.gaussian.LinearGaussianPolicy.fit_with_info`). They differ only in
the weights: REPS solves its dual for p_i ∝ exp((R_i − V(s_i))/η) (Eq. 3.10), RWR takes
w_i ∝ exp(β R_i) (Eq. 2.18). :class:`WeightedMLSearch` runs the loop; a subclass supplies
:meth:`~WeightedMLSearch._weigh` and its diagnostics dataclass, and may override two hooks
(REPS does): :meth:`~WeightedMLSearch._importance` (importance weights of a new
batch's rows, e.g. :func:`extra_context_importance` for re-scored extra-context rows) and
:meth:`~WeightedMLSearch._m_step` (what becomes of the weighted ML fit).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import ArrayLike
from scipy import special

from skillkit._validation import check_array, check_count
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.trajectory import Trajectory


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


@dataclass(frozen=True, repr=False)
class Batch:
    """One batch of samples for ``algorithm.update(batch)``, validated once when built.

    Row i is one sample: the context s_i, the parameters ω_i ~ π(ω|s_i), the reward
    R(τ_i, s_i) and (optionally) the trajectory τ_i it was scored on. With extra contexts
    (Sec. 3.4, :func:`skillkit.search.loop.collect`) a trajectory appears in several rows,
    each re-scored in another context.

    Parameters
    ----------
    contexts : array_like, shape (N, context_dim), or None
        Contexts s_i; ``None`` for a context-free task (stored as shape (N, 0)).
    omegas : array_like, shape (N, d)
        Parameters ω_i (N ≥ 1).
    rewards : array_like, shape (N,)
        Finite rewards R_i.
    trajectories : sequence of Trajectory, optional
        τ_i, one per row (model-based algorithms learn from them; model-free ones ignore them).
    n_rollouts : int, optional
        The first ``n_rollouts`` rows are rollouts in their own contexts, s_i ~ μ(s) and
        ω_i ~ π(ω|s_i); the remaining rows re-score them in extra contexts (Sec. 3.4), so their
        (s, ω) pairs are not drawn from μ(s)π(ω|s) (:func:`extra_context_importance`).
        Default (``None``): every row is a rollout (stored as N).

    Raises
    ------
    ValueError
        Naming ``contexts``, ``omegas``, ``rewards``, ``trajectories`` or ``n_rollouts`` when
        a shape disagrees, a value is not finite, or ``n_rollouts`` is not in 1..N.
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
                raise ValueError(
                    f"trajectories: expected {r.shape[0]} Trajectory objects (one per row), "
                    f"got {len(trajs)} items"
                )
            object.__setattr__(self, "trajectories", trajs)
        n = r.shape[0]
        k = n if self.n_rollouts is None else _check_n_rollouts(self.n_rollouts, n)
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

    def check_dims(self, dim: int, context_dim: int) -> Batch:
        """This batch, after checking it fits a policy with ``dim`` and ``context_dim``.

        Raises
        ------
        ValueError
            Naming ``omegas`` or ``contexts`` when a dimension differs.
        """
        if self.dim != dim:
            raise ValueError(f"omegas: expected shape (N, {dim}), got {self.omegas.shape}")
        if self.context_dim != context_dim:
            raise ValueError(
                f"contexts: expected shape (N, {context_dim}), got {self.contexts.shape}"
                + (" (a contextual policy needs contexts)" if self.context_dim == 0 else "")
            )
        return self

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
    """``batch`` after checking it is a :class:`Batch` for ``dim`` and ``context_dim``
    (what every ``update`` starts with)."""
    if not isinstance(batch, Batch):
        raise ValueError(f"batch: expected a skillkit.search.Batch, got {type(batch).__name__}")
    return batch.check_dims(dim, context_dim)


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

    A batch of N rollouts, s_i ~ μ(s), ω_i ~ π(ω|s_i), each re-scored in k extra contexts
    s′ ~ μ(s) (Sec. 3.4, :func:`skillkit.search.loop.collect`), has N (1 + k) rows. An extra
    pair (s′, ω_i) is drawn from μ(s′) m(ω), with m the marginal of ω, not from μ(s′)π(ω|s′):
    in the k extra rows of each rollout ω is independent of s. Seen as one sample of the mixture
    q(s, ω) = μ(s) [f π(ω|s) + (1 − f) m(ω)], f = 1/(1 + k), every row gets the
    (deterministic-mixture, balance-heuristic) importance weight

    .. math::
        w(s, \omega) = \frac{\pi(\omega|s)}{f\,\pi(\omega|s) + (1 - f)\,\hat m(\omega)},
        \qquad \hat m(\omega) = \frac1N \sum_{j=1}^N \pi(\omega|s_j),

    with m estimated by the mixture of π(ω|s_j) over the batch's own contexts. With the exact
    m, E[w | s] = 1 under q; always 0 < w ≤ 1/f = 1 + k. Cost: M N log-densities (M = N (1 + k)
    rows), held in one (M N, d) array.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        π, the policy that drew the batch.
    contexts : array_like, shape (M, context_dim)
        All rows' contexts, the N rollouts first.
    omegas : array_like, shape (M, d)
        All rows' parameters.
    n_rollouts : int
        N, 1 ≤ N ≤ M (M = N: every w is 1).

    Returns
    -------
    ndarray, shape (M,)
        w, computed in log space.
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
    """The last ``n_batches`` batches of (context, ω, reward) samples (data reuse, Table 3.1).

    Parameters
    ----------
    n_batches : int or None
        Number of batches kept, the newest included (``None`` keeps all).
    """

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
        """Append a validated batch (oldest batch dropped when full).

        ``n_rollouts``: its first rows that are rollouts in their own contexts (``None``: all);
        ``importance``: its rows' importance weights, shape (M,), stored normalised to mean
        one so that every batch keeps a mass proportional to its rows (``None``: all one).
        """
        if importance is not None:
            importance = importance / importance.mean()
        self._batches.append((contexts, omegas, rewards, n_rollouts, importance))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All kept samples: contexts (N, s), omegas (N, d), rewards (N,), oldest first."""
        s, w, r = (np.concatenate([b[i] for b in self._batches]) for i in range(3))
        return s, w, r

    def rollout_mask(self) -> np.ndarray:
        """Whether each kept row is a rollout in its own context, shape (N,), oldest first."""
        return np.concatenate([_rows(b) < _n_rollouts(b) for b in self._batches])

    def importance(self) -> np.ndarray | None:
        """The kept rows' importance weights, shape (N,) (``None`` when every batch has none)."""
        if all(_importance(b) is None for b in self._batches):
            return None
        return np.concatenate(
            [
                np.ones(b[2].shape[0]) if _importance(b) is None else _importance(b)
                for b in self._batches
            ]
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


def _rows(b: tuple) -> np.ndarray:
    return np.arange(b[2].shape[0])


def _n_rollouts(b: tuple) -> int:
    """A kept batch's rollouts (a batch stored as a 3-tuple, from a buffer pickled without
    rollout counts, counts every row as one rollout)."""
    return b[2].shape[0] if len(b) < 4 or b[3] is None else b[3]


def _importance(b: tuple) -> np.ndarray | None:
    return None if len(b) < 5 else b[4]


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
        self.n_updates = 0

    @property
    def policy(self) -> LinearGaussianPolicy:
        """The current upper-level policy."""
        return self._policy

    def _weigh(self, contexts: np.ndarray, rewards: np.ndarray) -> tuple[np.ndarray, Fields]:
        """Weights (summing to one) of the kept samples, and the diagnostics fields they add."""
        raise NotImplementedError

    def update(self, batch: Batch) -> D:
        """Add a batch, weight the last L batches (:meth:`_weigh`) and refit the policy.

        In order: the batch's importance weights under the current policy
        (:meth:`_importance`) are kept with it in the buffer; the kept rows are weighted
        (:meth:`_weigh`); the policy is refitted by weighted ML (Eqs. 3.11–3.13) and passed
        through :meth:`_m_step`; KL(π_new ‖ π_old) is averaged over the kept contexts.

        Parameters
        ----------
        batch : Batch
            Contexts s_i (N, context_dim), parameters ω_i ~ π(ω|s_i) (N, d) and rewards
            R(τ_i, s_i) (N,); the trajectories, if any, are not used.

        Returns
        -------
        The subclass's diagnostics (:class:`~skillkit.search.reps.REPSDiagnostics`,
        :class:`~skillkit.search.rwr.RWRDiagnostics`).
        """
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
        """Importance weights of a new batch's rows under the current (sampling) policy, kept
        with the batch (default ``None``: every row counts as drawn from μ(s)π(ω|s))."""
        return None

    def _m_step(
        self, old: LinearGaussianPolicy, fitted: LinearGaussianPolicy, contexts: np.ndarray
    ) -> tuple[LinearGaussianPolicy, Fields]:
        """The new policy from the weighted ML fit, and the diagnostics fields this adds
        (default: the fit itself, no fields)."""
        return fitted, {}

    def _settings_repr(self) -> str:
        """The subclass's own settings, for :meth:`__repr__` (e.g. ``"epsilon=0.5"``)."""
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
