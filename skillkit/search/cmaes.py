r"""CMA-ES behind the search interface: the ``cma`` package's own ask/tell, and only the glue.

:class:`CMAES` holds a :class:`cma.CMAEvolutionStrategy` (Hansen's CMA-ES with its default
population size λ = 4 + ⌊3 ln P⌋ and step-size adaptation) and exposes it as
:func:`~skillkit.search.loop.learn` expects (``policy.sample``/``policy.mean_of``,
``update(batch)`` → :class:`CMAESDiagnostics`). CMA-ES minimises, so it is told −R.

CMA-ES searches a linear context mapping of the lower-level parameters,

.. math:: \omega(s) = b + W \varphi(s), \qquad \varphi(s) = (s - c) / h
          \qquad \theta = [b, \operatorname{vec}(W)] \in \mathbb{R}^{d (1 + n_s)},

with c, h the centre and half-width of the context range (:meth:`CMAES.for_task`). For a
context-free task θ = b = ω (plain episodic CMA-ES); for a contextual one the fitness of θ_k is
J(θ) = E_{s∼μ}[R(ω_θ(s), s)], estimated from that candidate's rollouts.

One generation is one batch: each generation ``ask``s λ candidates (from this object's own
``rng``), batch rows m k … m k + m − 1 go to candidate k (m = ``contexts_per_candidate``, each
row a fresh context), and ``update`` ``tell``s each candidate's mean reward over its m rows.
Hence **rollouts_per_update must equal λ m** (:attr:`CMAES.rollouts_per_update`); otherwise
``policy.sample`` raises ``ValueError`` before any rollout, and ``update`` refuses a batch
whose rows are not this generation's candidates, or that holds extra-context rows (Sec. 3.4;
a candidate's ω depends on its context, so re-scored rows are not its rollouts).

Because the loop draws independent contexts per rollout, a candidate's fitness carries the
spread of R over μ(s), which can reorder candidates; m > 1 averages it down at m times the
rollouts. A contextual task defaults to m = :data:`DEFAULT_CONTEXTS_PER_CANDIDATE` (a setting
of this glue, chosen on a 2-D linear-target toy where m = 1 made no progress; not tuned per
task), a context-free one to m = 1.

Randomness: normal deviates come from ``rng`` through cma's ``randn`` option (no global
seeding); ``policy.sample`` ignores the loop's ``rng``. The object pickles, so
:class:`~skillkit.trial.TrialContext` checkpoints it. Imported lazily by
``from skillkit.search import CMAES`` (the ``cma`` package imports pyplot).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cma
import numpy as np
from numpy.typing import ArrayLike

from skillkit._validation import as_generator, check_array, check_count, check_positive
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.base import Batch, as_batch

__all__ = ["CMAES", "DEFAULT_CONTEXTS_PER_CANDIDATE", "CMAESDiagnostics", "CMAESPolicy"]

#: cma options this glue sets (the user's ``options`` may override all but ``randn``/``seed``):
#: quiet, and no log files written to the working directory.
QUIET_OPTIONS: dict[str, Any] = {"verbose": -9, "verb_disp": 0, "verb_log": 0}

#: m, rollouts (contexts) per candidate of the contextual variant unless given (module notes).
DEFAULT_CONTEXTS_PER_CANDIDATE = 4


class _Randn:
    """cma's ``randn`` option drawing from a numpy Generator (picklable; no global seeding)."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng

    def __call__(self, *shape: int) -> np.ndarray:
        return self.rng.standard_normal(shape)


class CMAESPolicy:
    """One CMA-ES generation as a policy: its λ candidates and its mean, mapped to ω(s).

    Immutable; :class:`CMAES` makes a new one after every ``tell``.

    Parameters
    ----------
    theta_mean : ndarray, shape (P,)
        The distribution mean of θ = [b, vec(W)] (P = d (1 + context_dim)).
    population : ndarray, shape (λ, P)
        The candidates ``ask`` returned for this generation.
    dim, context_dim : int
        d and the context dimension.
    context_center, context_scale : ndarray, shape (context_dim,)
        c and h of φ(s) = (s − c) / h.
    contexts_per_candidate : int
        m: consecutive rows of a batch per candidate.
    generation : int
        Generations told so far.
    sigma : float
        CMA-ES's step size σ.
    """

    def __init__(
        self,
        theta_mean: np.ndarray,
        population: np.ndarray,
        dim: int,
        context_dim: int,
        context_center: np.ndarray,
        context_scale: np.ndarray,
        contexts_per_candidate: int,
        generation: int,
        sigma: float,
    ):
        self._dim, self._context_dim = int(dim), int(context_dim)
        self.theta_mean = np.array(theta_mean, dtype=np.float64)
        self.population = np.array(population, dtype=np.float64)
        self.context_center = np.array(context_center, dtype=np.float64)
        self.context_scale = np.array(context_scale, dtype=np.float64)
        for arr in (self.theta_mean, self.population, self.context_center, self.context_scale):
            arr.setflags(write=False)
        self.contexts_per_candidate = int(contexts_per_candidate)
        self.generation = int(generation)
        self.sigma = float(sigma)

    @property
    def dim(self) -> int:
        """Dimension d of ω."""
        return self._dim

    @property
    def context_dim(self) -> int:
        """Dimension of the context s."""
        return self._context_dim

    @property
    def popsize(self) -> int:
        """λ, candidates in this generation."""
        return int(self.population.shape[0])

    @property
    def n_rows(self) -> int:
        """λ m, the rows (rollouts) one generation needs."""
        return self.popsize * self.contexts_per_candidate

    def offset_and_gain(self, theta: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(b, W) of a θ, shapes (d,) and (d, context_dim): ω(s) = b + W (s − c) / h."""
        theta = np.asarray(theta, dtype=np.float64)
        d = self._dim
        return theta[:d], theta[d:].reshape(d, self._context_dim)

    def _contexts(self, contexts, name: str = "contexts") -> tuple[np.ndarray, bool]:
        if contexts is None:
            if self._context_dim:
                raise ValueError(
                    f"{name}: this policy needs contexts of shape (n, {self._context_dim})"
                )
            return np.zeros((1, 0)), True
        s = check_array(contexts, name, ndim=(1, 2))
        if s.shape[-1] != self._context_dim:
            raise ValueError(
                f"{name}: expected shape (n, {self._context_dim}) or ({self._context_dim},), "
                f"got {s.shape}"
            )
        return (s[None, :], True) if s.ndim == 1 else (s, False)

    def _omega(self, thetas: np.ndarray, s: np.ndarray) -> np.ndarray:
        """ω_i = b_i + W_i φ(s_i) for row-wise θ_i (n, P) and s_i (n, context_dim)."""
        d = self._dim
        phi = (s - self.context_center) / self.context_scale
        gain = thetas[:, d:].reshape(thetas.shape[0], d, self._context_dim)
        return thetas[:, :d] + np.einsum("nij,nj->ni", gain, phi)

    def mean_of(self, contexts: ArrayLike | None = None) -> np.ndarray:
        """ω(s) of the distribution mean: shape (n, d), or (d,) for one context (or None)."""
        s, single = self._contexts(contexts)
        omega = self._omega(np.broadcast_to(self.theta_mean, (s.shape[0], self.theta_mean.size)), s)
        return omega[0] if single else omega

    def sample(self, contexts: ArrayLike | None = None, rng=None) -> np.ndarray:
        """The generation's candidates in the given contexts, shape (λ m, d): row i is
        candidate i // m in context s_i. ``rng`` is unused (the candidates were asked).

        Raises
        ------
        ValueError
            Naming ``contexts`` unless there are exactly λ m of them (λ m =
            ``rollouts_per_update`` of :func:`~skillkit.search.loop.learn`).
        """
        s, single = self._contexts(contexts)
        if s.shape[0] != self.n_rows:
            raise ValueError(
                f"contexts: a CMA-ES generation evaluates popsize λ={self.popsize} candidates × "
                f"{self.contexts_per_candidate} context(s) each = {self.n_rows} rollouts, got "
                f"{s.shape[0]} context(s): set learn's rollouts_per_update to {self.n_rows}"
            )
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
    """What one :meth:`CMAES.update` (one ``tell``) did.

    Attributes
    ----------
    generation : int
        Generations told so far (cma's ``countiter``).
    n_evaluations : int
        Candidates evaluated so far (cma's ``countevals``).
    mean_reward : float
        Mean reward of the batch.
    best_reward : float
        Best candidate's reward (its mean over its m rows).
    sigma : float
        Step size σ after the update.
    axis_ratio : float
        Ratio of the longest to the shortest axis of CMA-ES's covariance (its conditioning).
    stop : dict
        cma's termination criteria met (``es.stop()``; empty while none is). The loop keeps
        asking and telling regardless; a met criterion says the search has converged or stalled.
    """

    generation: int
    n_evaluations: int
    mean_reward: float
    best_reward: float
    sigma: float
    axis_ratio: float
    stop: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        stop = f", stop={sorted(self.stop)}" if self.stop else ""
        return (
            f"CMAESDiagnostics(generation={self.generation}, evaluations={self.n_evaluations}, "
            f"mean_reward={self.mean_reward:.4g}, best_reward={self.best_reward:.4g}, "
            f"sigma={self.sigma:.4g}, axis_ratio={self.axis_ratio:.4g}{stop})"
        )


class CMAES:
    """CMA-ES (the ``cma`` package) as a policy-search algorithm for :func:`learn`.

    Starts at the mean of an upper-level policy with its exploration: x₀ = θ of the policy
    mean, per-coordinate standard deviations √diag Σ (for b and for each column of W), so
    CMA-ES starts from what REPS starts from. Everything else is cma's default unless
    ``options`` says otherwise.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial policy with linear context features (e.g. ``task.initial_policy()``): b₀ =
        a + A c, W₀ = A diag(h); its covariance Σ sets the initial standard deviations.
    contexts_per_candidate : int, optional
        m ≥ 1 rollouts (contexts) per candidate in a contextual task (module notes; default
        :data:`DEFAULT_CONTEXTS_PER_CANDIDATE`); must be 1 (the default) for a context-free
        task.
    context_center, context_scale : array_like, shape (context_dim,), optional
        c and h > 0 of φ(s) = (s − c) / h (default 0 and 1; :meth:`for_task` takes the task's
        range).
    sigma0 : float, optional
        CMA-ES's initial step size (default: the largest of the standard deviations, the
        others set through cma's ``CMA_stds``).
    options : dict, optional
        cma options (``cma.CMAOptions()`` lists them), e.g. ``{"popsize": 20}``; they override
        :data:`QUIET_OPTIONS` and ``CMA_stds``. ``seed`` and ``randn`` are refused: the
        randomness is ``rng``.
    rng : Generator, int or None
        CMA-ES's own stream (its normal deviates). Same seed ⇒ same candidates.
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
        if not isinstance(policy, LinearGaussianPolicy):
            raise ValueError(
                f"policy: expected a LinearGaussianPolicy, got {type(policy).__name__}"
            )
        if policy.context_dim and policy.features != "linear":
            raise ValueError(
                f"policy: CMAES maps contexts linearly; got features={policy.features!r}"
            )
        d, n_s = policy.dim, policy.context_dim
        if contexts_per_candidate is None:
            contexts_per_candidate = DEFAULT_CONTEXTS_PER_CANDIDATE if n_s else 1
        self.contexts_per_candidate = check_count(contexts_per_candidate, "contexts_per_candidate")
        if n_s == 0 and self.contexts_per_candidate != 1:
            raise ValueError(
                "contexts_per_candidate: a context-free task evaluates each candidate once (1), "
                f"got {contexts_per_candidate}"
            )
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
        self._dims = (d, n_s)
        self._es = cma.CMAEvolutionStrategy(x0.tolist(), sigma, opts)
        self._policy = self._ask()

    @classmethod
    def for_task(cls, task, policy: LinearGaussianPolicy | None = None, **kwargs) -> CMAES:
        """CMA-ES on a task: ``policy`` (default ``task.initial_policy()``), and φ(s) scaled to
        the task's context range (c its centre, h its half-width, 1 where the range is a
        point). Other keyword arguments go to :class:`CMAES`."""
        low = np.asarray(task.context_low, dtype=np.float64)
        high = np.asarray(task.context_high, dtype=np.float64)
        half = (high - low) / 2
        kwargs.setdefault("context_center", (low + high) / 2)
        kwargs.setdefault("context_scale", np.where(half > 0, half, 1.0))
        return cls(task.initial_policy() if policy is None else policy, **kwargs)

    # ----------------------------------------------------------------- state
    @property
    def policy(self) -> CMAESPolicy:
        """This generation's candidates and mean (:class:`CMAESPolicy`)."""
        return self._policy

    @property
    def popsize(self) -> int:
        """λ, candidates per generation (cma's default unless ``options`` set ``popsize``)."""
        return int(self._es.popsize)

    @property
    def rollouts_per_update(self) -> int:
        """λ m: what :func:`learn`'s ``rollouts_per_update`` must be."""
        return self.popsize * self.contexts_per_candidate

    @property
    def es(self) -> cma.CMAEvolutionStrategy:
        """The underlying ``cma.CMAEvolutionStrategy`` (read it; changing it voids the glue)."""
        return self._es

    def _ask(self) -> CMAESPolicy:
        es = self._es
        d, n_s = self._dims
        return CMAESPolicy(
            theta_mean=es.result.xfavorite,
            population=np.asarray(es.ask(), dtype=np.float64),
            dim=d,
            context_dim=n_s,
            context_center=self.context_center,
            context_scale=self.context_scale,
            contexts_per_candidate=self.contexts_per_candidate,
            generation=es.countiter,
            sigma=es.sigma,
        )

    # ----------------------------------------------------------------- update
    def update(self, batch: Batch) -> CMAESDiagnostics:
        """Tell CMA-ES this generation's rewards, and ask the next generation.

        Parameters
        ----------
        batch : Batch
            λ m rows drawn with ``self.policy.sample`` (row i: candidate i // m in context
            s_i) and their rewards; the trajectories are not used.

        Raises
        ------
        ValueError
            Naming ``batch`` when it has rows re-scored in extra contexts, not λ m rows, or
            parameters other than this generation's candidates in its contexts.
        """
        pol = self._policy
        batch = as_batch(batch, pol.dim, pol.context_dim)
        if batch.n_rollouts != len(batch):
            raise ValueError(
                "batch: CMAES takes rollouts only; rows re-scored in extra contexts "
                "(learn's extra_contexts > 0) are no rollouts of a candidate"
            )
        if len(batch) != pol.n_rows:
            raise ValueError(
                f"batch: expected {pol.n_rows} rows (popsize λ={pol.popsize} × "
                f"contexts_per_candidate={pol.contexts_per_candidate}; learn's "
                f"rollouts_per_update), got {len(batch)}"
            )
        expected = pol.sample(batch.contexts)
        scale = 1.0 + np.abs(expected).max()
        if not np.allclose(batch.omegas, expected, rtol=0, atol=1e-9 * scale):
            raise ValueError(
                "batch: its omegas are not this generation's candidates in its contexts "
                "(draw the batch with algorithm.policy.sample and update once per generation)"
            )
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
        d, n_s = self._dims
        return (
            f"CMAES(dim={d}, context_dim={n_s}, popsize={self.popsize}, "
            f"contexts_per_candidate={self.contexts_per_candidate}, "
            f"rollouts_per_update={self.rollouts_per_update}, "
            f"generation={self._es.countiter}, sigma={self._es.sigma:.4g})"
        )
