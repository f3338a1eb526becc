"""The learning loop of Table 3.1, shared by every experiment.

:func:`learn` runs :func:`collect` (one :class:`~skillkit.search.base.Batch` of rollouts, with
``extra_contexts=k`` each trajectory also re-scored in k fresh contexts, Sec. 3.4),
``algorithm.update(batch)`` and an :class:`Evaluator` (the reward of the policy mean on fixed
contexts, with its own, identically re-seeded stream: the mean over the rollouts that did not
fail, and the fraction that failed), and records a :class:`LoopState`, which
a :class:`~skillkit.trial.TrialContext` checkpoints after every update.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike
from tqdm.auto import tqdm

from skillkit._validation import as_generator, check_count, check_type
from skillkit.search.base import Batch
from skillkit.tasks.base import Task
from skillkit.trial import TrialContext

#: Number of evaluation contexts drawn when ``eval_contexts`` is not given.
N_EVAL_CONTEXTS = 20


class SearchPolicy(Protocol):
    """What the loop needs from ``algorithm.policy``."""

    dim: int
    context_dim: int

    def sample(self, contexts, rng=None) -> np.ndarray: ...

    def mean_of(self, contexts=None) -> np.ndarray: ...


class SearchAlgorithm(Protocol):
    """A policy-search algorithm: a current policy and an update from a batch."""

    @property
    def policy(self) -> SearchPolicy: ...

    def update(self, batch: Batch) -> Any: ...


Callback = Callable[[int, SearchAlgorithm], Any]


# --------------------------------------------------------------------------- collection
def collect(
    task: Task,
    policy: SearchPolicy,
    n: int,
    rng: np.random.Generator | int | None,
    extra_contexts: int = 0,
) -> Batch:
    """Roll out ``n`` ≥ 1 samples of ``policy`` on ``task`` (one batch of Table 3.1).

    Draws from ``rng``, in order: contexts s_i ~ μ(s), parameters ω_i ~ π(ω|s_i), one rollout per
    pair, then n k extra contexts. With ``extra_contexts`` = k > 0 (Sec. 3.4; a contextual task
    whose trajectories do not depend on the context) the batch has N (1 + k) rows: the N rollouts,
    then trajectory i's k re-scorings at rows N + i k … N + (i + 1) k − 1 (``n_rollouts`` = N).
    """
    n = check_count(n, "n", 1)
    n_extra = _check_extra_contexts(task, extra_contexts)
    rng = as_generator(rng)
    contexts = task.sample_context(rng, n=n)
    omegas = np.atleast_2d(policy.sample(contexts, rng))
    trajs = [task.rollout(w, s, rng) for w, s in zip(omegas, contexts, strict=True)]
    rewards = np.array([task.reward(t, s) for t, s in zip(trajs, contexts, strict=True)])
    if n_extra:
        extra_s = task.sample_context(rng, n=n * n_extra).reshape(n, n_extra, -1)
        extra_r = np.array(
            [[task.reward(t, s) for s in ss] for t, ss in zip(trajs, extra_s, strict=True)]
        )
        contexts = np.concatenate([contexts, extra_s.reshape(n * n_extra, -1)])
        omegas = np.concatenate([omegas, np.repeat(omegas, n_extra, axis=0)])
        rewards = np.concatenate([rewards, extra_r.reshape(-1)])
        trajs = trajs + [t for t in trajs for _ in range(n_extra)]
    return Batch(contexts, omegas, rewards, trajs, n_rollouts=n)


# --------------------------------------------------------------------------- evaluation
@dataclass(frozen=True, repr=False)
class Evaluator:
    """Average reward of a policy's mean on fixed ``contexts`` (m, context_dim), each call with a
    generator seeded afresh by ``seed`` (common random numbers), and the fraction of failed
    rollouts (:attr:`~skillkit.trajectory.Trajectory.failed`), which it leaves out of the mean."""

    task: Task
    contexts: np.ndarray
    seed: int

    @classmethod
    def draw(
        cls,
        task: Task,
        rng: np.random.Generator | int | None,
        contexts: ArrayLike | None = None,
        seed: int | None = None,
    ) -> Evaluator:
        """An evaluator on ``contexts`` (default :data:`N_EVAL_CONTEXTS` drawn from ``rng``),
        its seed drawn from ``rng`` after them (and replaced by ``seed`` if given);
        ``ValueError`` naming ``eval_contexts`` or ``eval_seed`` when they do not fit."""
        rng = as_generator(rng)
        if contexts is None:
            eval_s = task.sample_context(rng, n=N_EVAL_CONTEXTS)
        else:
            eval_s = np.asarray(contexts, dtype=np.float64)
            if eval_s.ndim != 2 or eval_s.shape[0] == 0:
                raise ValueError(f"eval_contexts: expected shape (m ≥ 1, n_s), got {eval_s.shape}")
            eval_s = np.stack([task.check_context(s, "eval_contexts") for s in eval_s])
        drawn = int(rng.integers(2**63))
        return cls(task, eval_s, drawn if seed is None else check_count(seed, "eval_seed", 0))

    def __call__(self, policy: SearchPolicy) -> tuple[float, float]:
        """``(mean_reward, failure_rate)`` for ω = the policy mean at each context s: the mean
        of R(τ, s) over the rollouts that did not fail (NaN if all m failed) and the fraction
        of the m rollouts that failed."""
        eval_rng = np.random.default_rng(self.seed)
        pairs = zip(np.atleast_2d(policy.mean_of(self.contexts)), self.contexts, strict=True)
        runs = [self.task.evaluate(w, s, eval_rng) for w, s in pairs]
        ok = [r for r, traj in runs if not traj.failed]
        return float(np.mean(ok)) if ok else np.nan, (len(runs) - len(ok)) / len(runs)

    def __repr__(self) -> str:
        return (
            f"Evaluator(task={self.task.name!r}, {self.contexts.shape[0]} contexts, "
            f"seed={self.seed})"
        )


# --------------------------------------------------------------------------- loop state
@dataclass(repr=False)
class LoopState:
    """Everything :func:`learn` has done after ``k`` updates: what it checkpoints.

    ``mean_reward`` and ``eval_failure_rate`` (the :class:`Evaluator`'s pair), ``callback`` and
    ``policies`` hold k + 1 entries (before the first update and after each);
    ``explore_reward`` (the rollouts' mean reward), ``n_failed`` (failed rollouts) and
    ``diagnostics`` hold k. ``initial_rollouts`` is N₀ where the first batch differs from N =
    ``rollouts_per_update`` (``None`` in states saved without it).
    """

    algorithm: SearchAlgorithm
    eval_contexts: np.ndarray
    eval_seed: int
    k: int = 0
    mean_reward: list[float] = field(default_factory=list)
    eval_failure_rate: list[float] = field(default_factory=list)
    explore_reward: list[float] = field(default_factory=list)
    n_failed: list[int] = field(default_factory=list)
    diagnostics: list[Any] = field(default_factory=list)
    callback: list[Any] = field(default_factory=list)
    policies: list[SearchPolicy] = field(default_factory=list)
    initial_rollouts: int | None = None
    rollouts_per_update: int | None = None

    def record_evaluation(self, evaluation: tuple[float, float], callback: Any) -> None:
        """Append the :class:`Evaluator`'s ``evaluation`` of the current policy."""
        self.mean_reward.append(evaluation[0])
        self.eval_failure_rate.append(evaluation[1])
        self.callback.append(callback)
        self.policies.append(self.algorithm.policy)

    def record_update(
        self, batch: Batch, n_rollouts: int, diagnostics: Any, evaluation: tuple, callback: Any
    ) -> None:
        """Append update k + 1 (its first ``n_rollouts`` rows are the rollouts)."""
        self.k += 1
        self.explore_reward.append(float(batch.rewards[:n_rollouts].mean()))
        self.n_failed.append(sum(t.failed for t in batch.trajectories[:n_rollouts]))
        self.diagnostics.append(diagnostics)
        self.record_evaluation(evaluation, callback)

    def result(self, n_rollouts: int) -> dict:
        """The curves as :func:`learn` returns them; after update j ≥ 1, N₀ + (j − 1) N rollouts."""
        counts = n_rollouts * np.arange(self.k + 1)
        if self.initial_rollouts is not None and self.k:
            counts[1:] += self.initial_rollouts - n_rollouts
        return {
            "rollouts": counts,
            "mean_reward": np.array(self.mean_reward),
            "eval_failure_rate": np.array(self.eval_failure_rate),
            "explore_rollouts": counts[1:],
            "explore_reward": np.array(self.explore_reward),
            "n_failed": np.array(self.n_failed, dtype=int),
            "diagnostics": self.diagnostics,
            "callback": self.callback,
            "eval_contexts": self.eval_contexts,
            "policy": self.algorithm.policy,
            "policies": self.policies,
        }

    def __repr__(self) -> str:
        curve = (
            f"mean_reward {self.mean_reward[0]:.4g} -> {self.mean_reward[-1]:.4g}"
            if self.mean_reward
            else "not evaluated"
        )
        return (
            f"LoopState(k={self.k} updates, {curve}, {sum(self.n_failed)} failed rollouts, "
            f"algorithm={type(self.algorithm).__name__})"
        )


# --------------------------------------------------------------------------- the loop
def learn(
    task: Task,
    algorithm: SearchAlgorithm,
    n_updates: int,
    rollouts_per_update: int,
    rng: np.random.Generator | int | None,
    *,
    trial: TrialContext | None = None,
    progress: bool = True,
    extra_contexts: int = 0,
    eval_contexts: ArrayLike | None = None,
    callback: Callback | None = None,
    checkpoint_key: str = "learn",
    initial_rollouts: int | None = None,
    eval_seed: int | None = None,
) -> dict:
    """Run policy search on a task (Table 3.1): K = ``n_updates`` updates of N =
    ``rollouts_per_update`` rollouts each (N₀ = ``initial_rollouts`` in the first batch).

    Parameters
    ----------
    task : Task
    algorithm : SearchAlgorithm
        Its policy must match the task's dimensions; updated in place.
    rng : Generator, int or None
        All randomness (contexts, exploration, rollouts, evaluation seed).
    trial : TrialContext, optional
        Advanced per update; checkpoints the :class:`LoopState` and the generator under
        ``checkpoint_key``, so a call with the same key (same N and N₀) resumes with the same
        numbers. Without one: a progress bar (``progress``), no checkpoints.
    extra_contexts : int
        k ≥ 0 extra contexts per trajectory (:func:`collect`).
    eval_contexts, eval_seed : optional
        Contexts (m, context_dim) and seed of the :class:`Evaluator` (default: drawn from ``rng``).
    callback : callable, optional
        ``callback(k, algorithm)`` for k = 0..K; its return values are kept (and checkpointed).

    Returns
    -------
    dict
        :meth:`LoopState.result`: ``rollouts``, ``mean_reward`` (over the evaluation rollouts
        that did not fail), ``eval_failure_rate`` and ``callback`` (K + 1),
        ``explore_rollouts``, ``explore_reward``, ``n_failed`` and ``diagnostics`` (K),
        ``eval_contexts``, ``policy`` (the final one) and ``policies`` (K + 1).
    """
    check_type(task, Task, "task", "a Task")
    pol = algorithm.policy
    want, got = (task.parameter_dim, task.context_dim), (pol.dim, pol.context_dim)
    if got != want:
        raise ValueError(f"algorithm: expected a policy of (dim, context_dim) {want}, got {got}")
    n_updates = check_count(n_updates, "n_updates", 1)
    n = check_count(rollouts_per_update, "rollouts_per_update", 1)
    n0 = n if initial_rollouts is None else check_count(initial_rollouts, "initial_rollouts", 1)
    n_extra = _check_extra_contexts(task, extra_contexts)
    if trial is not None and not isinstance(trial, TrialContext):
        raise ValueError(f"trial: expected a TrialContext or None, got {type(trial).__name__}")
    rng = as_generator(rng)

    # The evaluator's draws come first on every run, resumed or not.
    evaluator = Evaluator.draw(task, rng, eval_contexts, eval_seed)
    state = None if trial is None else trial.resume(checkpoint_key, rng)
    if state is None:
        state = LoopState(algorithm, evaluator.contexts, evaluator.seed)
        state.initial_rollouts = None if n0 == n else n0
        state.rollouts_per_update = n
        state.record_evaluation(
            evaluator(algorithm.policy), None if callback is None else callback(0, algorithm)
        )
    else:  # the generator is restored; the caller's algorithm object takes the saved state
        if state.k > n_updates:
            raise ValueError(f"n_updates: the saved state has {state.k} > {n_updates} updates")
        saved_n = state.rollouts_per_update
        saved_n0 = state.initial_rollouts if state.initial_rollouts is not None else saved_n
        for name, saved, got, unit in (
            ("rollouts_per_update", saved_n, n, " per update"),
            ("initial_rollouts", saved_n0, n0, ""),
        ):
            if saved is not None and saved != got:
                raise ValueError(f"{name}: the saved state has {saved} rollouts{unit}, got {got}")
        vars(algorithm).update(vars(state.algorithm))
        state.algorithm = algorithm
        evaluator = Evaluator(task, state.eval_contexts, state.eval_seed)
    bar = (
        trial
        if trial is not None
        else tqdm(total=n_updates, desc=type(algorithm).__name__, disable=not progress)
    )
    bar.update(state.k)

    try:
        for k in range(state.k + 1, n_updates + 1):
            n_k = n0 if k == 1 else n
            batch = collect(task, algorithm.policy, n_k, rng, n_extra)
            diagnostics = algorithm.update(batch)
            evaluation = evaluator(algorithm.policy)
            value = None if callback is None else callback(k, algorithm)
            state.record_update(batch, n_k, diagnostics, evaluation, value)
            if trial is not None:
                trial.save(checkpoint_key, state, rng)
            bar.update(1)
            mean, failed = evaluation
            bar.set_postfix(mean_reward=f"{mean:.4g}", eval_failed=f"{failed:.0%}", refresh=False)
    finally:
        if trial is None:
            bar.close()
    return state.result(n)


def policy_history_arrays(policies) -> dict[str, np.ndarray]:
    """The ``policy_*`` arrays of a run's linear-Gaussian policies, as ``trials.npz`` stores them
    (:func:`skillkit.viz.history.load_policy_history`): ``policy_mean`` (K+1, d), ``policy_cov``
    (K+1, d, d), ``policy_gain`` (K+1, d, F), ``policy_context_dim``, ``policy_features``."""
    from skillkit.policies.gaussian import LinearGaussianPolicy

    if not policies or not all(isinstance(p, LinearGaussianPolicy) for p in policies):
        raise ValueError("policies: expected a non-empty sequence of LinearGaussianPolicy objects")
    return {
        "policy_mean": np.stack([p.mean for p in policies]),
        "policy_cov": np.stack([p.cov for p in policies]),
        "policy_gain": np.stack([p.gain for p in policies]),
        "policy_context_dim": np.asarray(policies[0].context_dim),
        "policy_features": np.asarray(policies[0].features),
    }


def _check_extra_contexts(task: Task, extra_contexts: int) -> int:
    n_extra = check_count(extra_contexts, "extra_contexts", 0)
    if n_extra and (task.trajectory_depends_on_context or task.context_dim == 0):
        why = "no context" if task.context_dim == 0 else "trajectories that depend on the context"
        raise ValueError(f"extra_contexts: task {task.name!r} has {why} (Sec. 3.4)")
    return n_extra
