r"""CMA-ES (the ``cma`` package's ask/tell) behind the search interface.

CMA-ES searches a linear context mapping of the lower-level parameters,

.. math:: \omega(s) = b + W \varphi(s), \qquad \varphi(s) = (s - c) / h,
          \qquad \theta = [b, \operatorname{vec}(W)] \in \mathbb{R}^{d (1 + n_s)},

with c, h the centre and half-width of the context range (θ = ω without contexts). One
generation is one batch of λ m rows: rows m k … m k + m − 1 evaluate candidate k in fresh
contexts, and its fitness is −(mean reward over them) (m = ``contexts_per_candidate``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cma
import numpy as np
from numpy.typing import ArrayLike

from skillkit._validation import as_generator, check_array, check_count, check_positive
from skillkit.policies.gaussian import LinearGaussianPolicy, query_contexts
from skillkit.search.base import Batch, as_batch, check_policy, fields_repr, rollouts_only

#: cma options set here: quiet, and no log files.
QUIET_OPTIONS: dict[str, Any] = {"verbose": -9, "verb_disp": 0, "verb_log": 0}

#: m, contexts per candidate of a contextual task unless given.
DEFAULT_CONTEXTS_PER_CANDIDATE = 4


class _Randn:
    """cma's ``randn`` option drawing from a numpy Generator (picklable)."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng

    def __call__(self, *shape: int) -> np.ndarray:
        return self.rng.standard_normal(shape)


@dataclass(repr=False, eq=False)
class CMAESPolicy:
    """One CMA-ES generation as a policy: its λ candidates and its mean, mapped to ω(s).

    Made by :class:`CMAES` after every ``tell``: ``theta_mean`` (P,) is the mean of
    θ = [b, vec(W)], P = d (1 + context_dim), ``population`` (λ, P) the candidates, c and h of
    φ(s) = (s − c) / h are ``context_center`` and ``context_scale``, and m =
    ``contexts_per_candidate``.
    """

    theta_mean: np.ndarray
    population: np.ndarray
    dim: int
    context_dim: int
    context_center: np.ndarray
    context_scale: np.ndarray
    contexts_per_candidate: int
    generation: int
    sigma: float

    def __post_init__(self):
        for name in ("theta_mean", "population", "context_center", "context_scale"):
            arr = np.array(getattr(self, name), dtype=np.float64)
            arr.setflags(write=False)
            setattr(self, name, arr)

    @property
    def popsize(self) -> int:
        """λ, candidates in this generation."""
        return int(self.population.shape[0])

    @property
    def n_rows(self) -> int:
        """λ m, the rollouts one generation needs."""
        return self.popsize * self.contexts_per_candidate

    def _omega(self, thetas: np.ndarray, s: np.ndarray) -> np.ndarray:
        """ω_i = b_i + W_i φ(s_i) for row-wise θ_i (n, P) and s_i (n, context_dim)."""
        d = self.dim
        phi = (s - self.context_center) / self.context_scale
        gain = thetas[:, d:].reshape(thetas.shape[0], d, self.context_dim)
        return thetas[:, :d] + np.einsum("nij,nj->ni", gain, phi)

    def mean_of(self, contexts: ArrayLike | None = None) -> np.ndarray:
        """ω(s) of the distribution mean: shape (n, d), or (d,) for one context (or None)."""
        s, single = query_contexts(contexts, self.context_dim)
        omega = self._omega(np.broadcast_to(self.theta_mean, (s.shape[0], self.theta_mean.size)), s)
        return omega[0] if single else omega

    def sample(self, contexts: ArrayLike | None = None, rng=None) -> np.ndarray:
        """The candidates in the given contexts, shape (λ m, d): row i is candidate i // m in s_i.

        ``rng`` is unused. ``ValueError`` unless there are exactly λ m contexts.
        """
        s, single = query_contexts(contexts, self.context_dim)
        if s.shape[0] != self.n_rows:
            raise ValueError(f"contexts: got {len(s)}, set rollouts_per_update to {self.n_rows}")
        thetas = np.repeat(self.population, self.contexts_per_candidate, axis=0)
        omega = self._omega(thetas, s)
        return omega[0] if single else omega

    def __repr__(self) -> str:
        return (
            f"CMAESPolicy(dim={self.dim}, context_dim={self.context_dim}, "
            f"generation={self.generation}, popsize={self.popsize}, "
            f"contexts_per_candidate={self.contexts_per_candidate}, sigma={self.sigma:.4g})"
        )


@dataclass(frozen=True)
class CMAESDiagnostics:
    """What one :meth:`CMAES.update` did: cma's ``countiter``, ``countevals``, σ, axis ratio and
    ``es.stop()`` after the ``tell``, the batch's mean reward and the best candidate's."""

    generation: int
    n_evaluations: int
    mean_reward: float
    best_reward: float
    sigma: float
    axis_ratio: float
    stop: dict = field(default_factory=dict)

    __repr__ = fields_repr


class CMAES:
    """CMA-ES (the ``cma`` package) as a policy-search algorithm for :func:`learn`.

    It starts at the policy mean with per-coordinate standard deviations √diag Σ; the rest is
    cma's default unless ``options`` says otherwise.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial policy with linear context features: b₀ = a + A c, W₀ = A diag(h).
    contexts_per_candidate : int, optional
        m ≥ 1 (default :data:`DEFAULT_CONTEXTS_PER_CANDIDATE`; 1 for a context-free task).
    context_center, context_scale : array_like, shape (context_dim,), optional
        c and h > 0 of φ(s) (default 0 and 1; :meth:`for_task` takes the task's range).
    sigma0 : float, optional
        Initial step size (default: the largest standard deviation).
    options : dict, optional
        cma options, overriding :data:`QUIET_OPTIONS` and ``CMA_stds``; ``seed`` and ``randn``
        are refused.
    rng : Generator, int or None
        CMA-ES's own stream.
    """

    def __init__(
        self,
        policy: LinearGaussianPolicy,
        *,
        contexts_per_candidate: int | None = None,
        context_center: ArrayLike | None = None,
        context_scale: ArrayLike | None = None,
        sigma0: float | None = None,
        options: dict[str, Any] | None = None,
        rng: np.random.Generator | int | None = None,
    ):
        if check_policy(policy).context_dim and policy.features != "linear":
            raise ValueError(f"policy: CMAES maps contexts linearly, got {policy.features!r}")
        d, n_s = policy.dim, policy.context_dim
        if contexts_per_candidate is None:
            contexts_per_candidate = DEFAULT_CONTEXTS_PER_CANDIDATE if n_s else 1
        m = check_count(contexts_per_candidate, "contexts_per_candidate")
        if n_s == 0 and m != 1:
            raise ValueError(f"contexts_per_candidate: expected 1 without contexts, got {m}")
        self.contexts_per_candidate = m
        c = np.zeros(n_s) if context_center is None else context_center
        h = np.ones(n_s) if context_scale is None else context_scale
        self.context_center = check_array(c, "context_center", shape=(n_s,))
        self.context_scale = check_array(h, "context_scale", shape=(n_s,))
        if np.any(self.context_scale <= 0):
            raise ValueError(f"context_scale: expected positive values, got {self.context_scale}")
        options = {} if options is None else dict(options)
        for key in ("seed", "randn"):
            if key in options:
                raise ValueError(f"options: {key!r} is set by CMAES (its randomness is rng)")

        gain = policy.gain  # (d, n_s) for linear features
        b0 = policy.mean + gain @ self.context_center
        w0 = gain * self.context_scale
        x0 = np.concatenate([b0, w0.ravel()])
        std = np.sqrt(np.diag(policy.cov))
        stds = np.concatenate([std, np.repeat(std, n_s)])
        sigma = float(stds.max()) if sigma0 is None else check_positive(sigma0, "sigma0")
        opts: dict[str, Any] = dict(QUIET_OPTIONS)
        if not np.allclose(stds, sigma, rtol=1e-12, atol=0):
            opts["CMA_stds"] = (stds / sigma).tolist()
        opts.update(options)
        opts.update({"randn": _Randn(as_generator(rng)), "seed": np.nan})
        self.dims = (d, n_s)
        self._es = cma.CMAEvolutionStrategy(x0.tolist(), sigma, opts)
        self._policy = self._ask()

    @classmethod
    def for_task(cls, task, policy: LinearGaussianPolicy | None = None, **kwargs) -> CMAES:
        """CMA-ES on a task, φ(s) scaled to its context range (h = 1 where the range is a point)."""
        low = np.asarray(task.context_low, dtype=np.float64)
        high = np.asarray(task.context_high, dtype=np.float64)
        half = (high - low) / 2
        kwargs.setdefault("context_center", (low + high) / 2)
        kwargs.setdefault("context_scale", np.where(half > 0, half, 1.0))
        return cls(task.initial_policy() if policy is None else policy, **kwargs)

    # ----------------------------------------------------------------- state
    @property
    def policy(self) -> CMAESPolicy:
        """This generation's :class:`CMAESPolicy`."""
        return self._policy

    @property
    def popsize(self) -> int:
        """λ, candidates per generation."""
        return int(self._es.popsize)

    @property
    def rollouts_per_update(self) -> int:
        """λ m: what :func:`learn`'s ``rollouts_per_update`` must be."""
        return self.popsize * self.contexts_per_candidate

    @property
    def es(self) -> cma.CMAEvolutionStrategy:
        """The underlying ``cma.CMAEvolutionStrategy`` (read only)."""
        return self._es

    def _ask(self) -> CMAESPolicy:
        es = self._es
        d, n_s = self.dims
        return CMAESPolicy(
            theta_mean=es.result.xfavorite,
            population=np.asarray(es.ask(), dtype=np.float64),
            dim=d,
            context_dim=n_s,
            context_center=self.context_center,
            context_scale=self.context_scale,
            contexts_per_candidate=self.contexts_per_candidate,
            generation=int(es.countiter),
            sigma=float(es.sigma),
        )

    # ----------------------------------------------------------------- update
    def update(self, batch: Batch) -> CMAESDiagnostics:
        """Tell CMA-ES the rewards of this generation's λ m rows (drawn with ``policy.sample``),
        and ask the next generation."""
        pol = self._policy
        batch = rollouts_only(as_batch(batch, pol.dim, pol.context_dim), "CMAES")
        if len(batch) != pol.n_rows:
            raise ValueError(f"batch: expected {pol.n_rows} rows (λ m), got {len(batch)}")
        expected = pol.sample(batch.contexts)
        scale = 1.0 + np.abs(expected).max()
        if not np.allclose(batch.omegas, expected, rtol=0, atol=1e-9 * scale):
            raise ValueError("batch: its omegas are not this generation's candidates")
        reward = batch.rewards.reshape(pol.popsize, pol.contexts_per_candidate).mean(axis=1)
        es = self._es
        es.tell(list(pol.population), (-reward).tolist())
        stop = {str(k): v for k, v in es.stop().items()}
        diagnostics = CMAESDiagnostics(
            generation=int(es.countiter),
            n_evaluations=int(es.countevals),
            mean_reward=float(batch.rewards.mean()),
            best_reward=float(reward.max()),
            sigma=float(es.sigma),
            axis_ratio=float(es.D.max() / es.D.min()),
            stop=stop,
        )
        self._policy = self._ask()
        return diagnostics

    def __repr__(self) -> str:
        d, n_s = self.dims
        return (
            f"CMAES(dim={d}, context_dim={n_s}, popsize={self.popsize}, "
            f"contexts_per_candidate={self.contexts_per_candidate}, "
            f"rollouts_per_update={self.rollouts_per_update}, "
            f"generation={self._es.countiter}, sigma={self._es.sigma:.4g})"
        )
