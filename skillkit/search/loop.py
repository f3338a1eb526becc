"""The model-free learning loop of Table 3.1, shared by every model-free experiment.

The loop is built from three named pieces, and :func:`learn` runs them top to bottom:

* :func:`collect` — observe N contexts s_i ~ μ(s), draw ω_i ~ π(ω|s_i), roll out and score
  R(τ_i, s_i): one :class:`~skillkit.search.base.Batch` for ``algorithm.update(batch)``. With
  ``extra_contexts=k`` each trajectory is also re-scored in k freshly drawn contexts through the
  task's reward (the *extra context* variant of Sec. 3.4), which is only valid when the
  trajectory does not depend on the context. The batch marks its first N rows as the
  rollouts (``Batch.n_rollouts``); in the re-scored rows ω does not depend on s, which
  :class:`~skillkit.search.reps.ContextualREPS` corrects with ``extra_context_weighting``.
* :class:`Evaluator` — the average reward of the policy *mean* on fixed contexts.
* :class:`LoopState` — what the loop has done so far (curves, diagnostics, policies, callback
  values, the algorithm); the state a :class:`~skillkit.trial.TrialContext` checkpoints after
  every update, so a later call resumes where an interrupted one stopped.

Learning curves
---------------
* ``mean_reward``: average reward of the policy *mean* ω = E[π(ω|s)] on fixed evaluation
  contexts, before the first update and after each update. Evaluation rollouts are not counted
  as rollouts and use their own random stream, re-seeded identically at every evaluation
  (common random numbers), so they neither perturb learning nor add update-to-update noise.
* ``explore_reward``: average reward of the exploratory rollouts of each batch (in their own
  contexts, extra-context re-scorings excluded).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike
from tqdm.auto import tqdm

from skillkit._validation import as_generator, check_count
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
    """A policy-search algorithm: a current policy and an update from a batch of samples."""

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
    """Roll out ``n`` samples of ``policy`` on ``task`` (one batch of Table 3.1).

    Draws, in this order from ``rng``: contexts s_i ~ μ(s) (n, context_dim); parameters
    ω_i ~ π(ω|s_i); one rollout τ_i per pair; then, with ``extra_contexts=k``, k fresh
    contexts per trajectory (n k, context_dim).

    Parameters
    ----------
    task : Task
    policy : SearchPolicy
        E.g. ``algorithm.policy``; dimensions must match the task.
    n : int
        Rollouts N ≥ 1.
    rng : Generator, int or None
    extra_contexts : int
        k ≥ 0 extra contexts per trajectory (Sec. 3.4); needs a contextual task whose
        trajectories do not depend on the context.

    Returns
    -------
    Batch
        N (1 + k) rows: first the N rollouts in their own contexts, then each trajectory's k
        re-scorings (rows N + i k … N + (i + 1) k − 1 re-score trajectory i, with ω_i and
        τ_i repeated); ``n_rollouts`` = N. The re-scored pairs (s′, ω_i) are not draws of
        μ(s)π(ω|s): how an algorithm uses them is its choice, e.g. ContextualREPS's
        ``extra_context_weighting`` (:func:`~skillkit.search.base.extra_context_importance`).
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
    """Average reward of a policy's mean on fixed contexts, with common random numbers.

    Every call rolls out ω = E[π(ω|s)] once per context with a generator seeded by ``seed``
    afresh, so two policies are compared on the same noise and evaluation never touches the
    learning stream.

    Parameters
    ----------
    task : Task
    contexts : ndarray, shape (m, context_dim)
        Evaluation contexts (already validated; see :meth:`draw`).
    seed : int
        Seed of the evaluation stream.
    """

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
        """An evaluator on ``contexts`` (default: :data:`N_EVAL_CONTEXTS` contexts drawn from
        ``rng``), with its seed drawn from ``rng`` after them; a given ``seed`` replaces the
        drawn one (the draw still happens, so ``rng``'s later stream is the same).

        Raises
        ------
        ValueError
            Naming ``eval_contexts`` when a context has the wrong shape or lies outside μ(s),
            ``eval_seed`` when ``seed`` is not a non-negative integer, or ``rng``.
        """
        rng = as_generator(rng)
        if contexts is None:
            eval_s = task.sample_context(rng, n=N_EVAL_CONTEXTS)
        else:
            eval_s = np.asarray(contexts, dtype=np.float64)
            if eval_s.ndim != 2 or eval_s.shape[0] == 0:
                raise ValueError(
                    f"eval_contexts: expected shape (m, {task.context_dim}) with m ≥ 1, "
                    f"got {eval_s.shape}"
                )
            eval_s = np.stack([task.check_context(s, "eval_contexts") for s in eval_s])
        drawn = int(rng.integers(2**63))
        return cls(task, eval_s, drawn if seed is None else check_count(seed, "eval_seed", 0))

    def __call__(self, policy: SearchPolicy) -> float:
        """Mean of R(τ, s) over the contexts s for ω = the policy mean at s."""
        eval_rng = np.random.default_rng(self.seed)
        means = np.atleast_2d(policy.mean_of(self.contexts))
        return float(
            np.mean(
                [
                    self.task.evaluate(w, s, eval_rng)[0]
                    for w, s in zip(means, self.contexts, strict=True)
                ]
            )
        )

    def __repr__(self) -> str:
        return (
            f"Evaluator(task={self.task.name!r}, {self.contexts.shape[0]} contexts, "
            f"seed={self.seed})"
        )


# --------------------------------------------------------------------------- loop state
@dataclass(repr=False)
class LoopState:
    """Everything :func:`learn` has done so far: what it checkpoints after every update.

    Attributes
    ----------
    algorithm : SearchAlgorithm
        The algorithm (its policy and sample buffer).
    eval_contexts : ndarray, shape (m, context_dim)
        The :class:`Evaluator`'s contexts.
    eval_seed : int
        The :class:`Evaluator`'s seed.
    k : int
        Updates done.
    mean_reward : list of float
        k + 1 evaluations of the policy mean (before the first update, after each one).
    explore_reward : list of float
        k mean rewards of the exploratory rollouts (extra-context re-scorings excluded).
    n_failed : list of int
        k numbers of failed rollouts.
    diagnostics : list
        k values returned by ``algorithm.update``.
    callback : list
        k + 1 values returned by the callback (``None`` without one).
    policies : list of SearchPolicy
        k + 1 policies (before the first update, after each one).
    initial_rollouts : int or None
        Rollouts of the first batch when it differs from the others (``None``: all batches
        have the same size, e.g. GPREPS's N₀ initial rollouts, Table 4.1).
    rollouts_per_update : int or None
        N, the rollouts of every later batch (``None`` in states saved without
        it); a resumed :func:`learn` must use the same N and N₀.
    """

    algorithm: SearchAlgorithm
    eval_contexts: np.ndarray
    eval_seed: int
    k: int = 0
    mean_reward: list[float] = field(default_factory=list)
    explore_reward: list[float] = field(default_factory=list)
    n_failed: list[int] = field(default_factory=list)
    diagnostics: list[Any] = field(default_factory=list)
    callback: list[Any] = field(default_factory=list)
    policies: list[SearchPolicy] = field(default_factory=list)
    initial_rollouts: int | None = None
    rollouts_per_update: int | None = None

    def record_update(
        self, batch: Batch, n_rollouts: int, diagnostics: Any, mean_reward: float, callback: Any
    ) -> None:
        """Append update k + 1: its batch (the first ``n_rollouts`` rows are the rollouts),
        the update's diagnostics, the evaluation and the callback value after it."""
        self.k += 1
        self.explore_reward.append(float(batch.rewards[:n_rollouts].mean()))
        self.n_failed.append(sum(t.failed for t in batch.trajectories[:n_rollouts]))
        self.diagnostics.append(diagnostics)
        self.mean_reward.append(mean_reward)
        self.callback.append(callback)
        self.policies.append(self.algorithm.policy)

    def rollouts(self, n_rollouts: int) -> np.ndarray:
        """Rollouts done after 0, 1, …, k updates, shape (k + 1,): N₀ + (j − 1) N after update
        j ≥ 1 (N₀ = ``initial_rollouts``, default N = ``n_rollouts``)."""
        counts = n_rollouts * np.arange(self.k + 1)
        if self.initial_rollouts is not None and self.k:
            counts[1:] += self.initial_rollouts - n_rollouts
        return counts

    def result(self, n_rollouts: int) -> dict:
        """The curves as :func:`learn` returns them (``n_rollouts`` rollouts per update after
        the first batch of ``initial_rollouts``)."""
        counts = self.rollouts(n_rollouts)
        return {
            "rollouts": counts,
            "mean_reward": np.array(self.mean_reward),
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
    """Run model-free policy search on a task (Table 3.1).

    Parameters
    ----------
    task : Task
        The task (contexts, rollouts, rewards).
    algorithm : SearchAlgorithm
        E.g. :class:`~skillkit.search.reps.ContextualREPS`, :class:`~skillkit.search.rwr.RWR`,
        :class:`~skillkit.search.crkr.CrKR`; its policy must match the task's dimensions.
        Updated in place.
    n_updates : int
        Number of policy updates K ≥ 1.
    rollouts_per_update : int
        Rollouts N ≥ 1 per update.
    rng : Generator, int or None
        All randomness (contexts, exploration, rollouts, evaluation seed).
    trial : TrialContext, optional
        The trial this run belongs to (what an experiment's ``run_trial`` receives). The loop
        advances its progress bar by one per update (the trial's owner sets the total with
        ``trial.reset``) and checkpoints the :class:`LoopState` and the generator under
        ``checkpoint_key`` after every update; a call with the same key resumes where the last
        one stopped, giving the same numbers as an uninterrupted run (it must use the same
        ``rollouts_per_update`` and ``initial_rollouts``, else ``ValueError``). Without a trial the
        loop shows its own progress bar and keeps no checkpoints.
    progress : bool
        Show that progress bar (only used without ``trial``).
    extra_contexts : int
        k ≥ 0 extra contexts per trajectory (Sec. 3.4, :func:`collect`).
    eval_contexts : array_like, shape (m, context_dim), optional
        Contexts on which the policy mean is evaluated (default: :data:`N_EVAL_CONTEXTS`
        contexts drawn from the task at the start), see :class:`Evaluator`.
    callback : callable, optional
        ``callback(k, algorithm)`` after the initial evaluation (k = 0) and after each update
        k = 1..K (e.g. to record parameter errors). Its return values are collected in the
        result's ``callback`` list (K + 1 entries), which survives checkpoint and resume —
        record through return values, not through side effects, in resumable experiments.
    checkpoint_key : str
        Key of this loop's state in ``trial`` (distinct per ``learn`` call within a trial).
    initial_rollouts : int, optional
        N₀ ≥ 1, the rollouts of the first batch (GPREPS starts its model from N₀ rollouts, then
        collects N per update, Table 4.1); default N, every batch the same size.
    eval_seed : int, optional
        Seed of the :class:`Evaluator`'s stream (default: drawn from ``rng``). Give several
        runs the same seed (and contexts) to evaluate them on the same noise, e.g. the same
        start states of a context-free task.

    Returns
    -------
    dict
        ``rollouts`` (K + 1,) rollouts so far at each evaluation (0, N₀, N₀ + N, …);
        ``mean_reward`` (K + 1,) average reward of the policy mean on ``eval_contexts``;
        ``explore_rollouts`` (K,) and ``explore_reward`` (K,) for the exploratory rollouts;
        ``n_failed`` (K,) failed rollouts per batch; ``diagnostics`` (list of K update
        diagnostics); ``callback`` (list of K + 1 callback return values);
        ``eval_contexts`` (m, context_dim); ``policy`` (the final policy); ``policies``
        (the K + 1 policies, before the first update and after each one: what the viewer's
        learning playback steps through, see :func:`policy_history_arrays`).
    """
    _check_task_and_algorithm(task, algorithm)
    n_updates = check_count(n_updates, "n_updates", 1)
    n = check_count(rollouts_per_update, "rollouts_per_update", 1)
    n0 = n if initial_rollouts is None else check_count(initial_rollouts, "initial_rollouts", 1)
    n_extra = _check_extra_contexts(task, extra_contexts)
    if trial is not None and not isinstance(trial, TrialContext):
        raise ValueError(
            f"trial: expected a skillkit.trial.TrialContext or None, got {type(trial).__name__}"
        )
    rng = as_generator(rng)

    # Set up: the evaluator's draws come first on every run, resumed or not.
    evaluator = Evaluator.draw(task, rng, eval_contexts, eval_seed)
    state = None if trial is None else trial.resume(checkpoint_key, rng)
    if state is None:
        state = LoopState(algorithm, evaluator.contexts, evaluator.seed)
        state.initial_rollouts = None if n0 == n else n0
        state.rollouts_per_update = n
        state.mean_reward.append(evaluator(algorithm.policy))
        state.callback.append(None if callback is None else callback(0, algorithm))
        state.policies.append(algorithm.policy)
    else:  # the generator is restored; the caller's algorithm object takes the saved state
        if state.k > n_updates:
            raise ValueError(
                f"n_updates: the state saved under checkpoint_key={checkpoint_key!r} has "
                f"{state.k} updates, more than n_updates={n_updates}"
            )
        _check_resumed_rollouts(state, n, n0, checkpoint_key)
        vars(algorithm).update(vars(state.algorithm))
        state.algorithm = algorithm
        evaluator = Evaluator(task, state.eval_contexts, state.eval_seed)
    bar = (
        trial
        if trial is not None
        else tqdm(total=n_updates, desc=type(algorithm).__name__, disable=not progress)
    )
    bar.update(state.k)

    # Learn: collect, update, evaluate, record, checkpoint.
    try:
        for k in range(state.k + 1, n_updates + 1):
            n_k = n0 if k == 1 else n
            batch = collect(task, algorithm.policy, n_k, rng, n_extra)
            diagnostics = algorithm.update(batch)
            mean_reward = evaluator(algorithm.policy)
            value = None if callback is None else callback(k, algorithm)
            state.record_update(batch, n_k, diagnostics, mean_reward, value)
            if trial is not None:
                trial.save(checkpoint_key, state, rng)
            bar.update(1)
            bar.set_postfix(mean_reward=f"{mean_reward:.4g}", refresh=False)
    finally:
        if trial is None:
            bar.close()
    return state.result(n)


def policy_history_arrays(policies) -> dict[str, np.ndarray]:
    """The ``policy_*`` arrays of a learning run's policies (linear-Gaussian ones), the format
    :func:`skillkit.viz.history.load_policy_history` reads from a run folder's ``trials.npz``.

    Parameters
    ----------
    policies : sequence of LinearGaussianPolicy
        E.g. ``learn(...)["policies"]`` (K + 1 policies).

    Returns
    -------
    dict
        ``policy_mean`` (K+1, d), ``policy_cov`` (K+1, d, d), ``policy_gain`` (K+1, d, F),
        ``policy_context_dim`` and ``policy_features``.
    """
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


def _check_task_and_algorithm(task: Task, algorithm: SearchAlgorithm) -> None:
    if not isinstance(task, Task):
        raise ValueError(f"task: expected a Task, got {type(task).__name__}")
    pol = algorithm.policy
    if pol.dim != task.parameter_dim or pol.context_dim != task.context_dim:
        raise ValueError(
            f"algorithm: policy has dim={pol.dim}, context_dim={pol.context_dim}; "
            f"task {task.name!r} "
            f"needs dim={task.parameter_dim}, context_dim={task.context_dim}"
        )


def _check_resumed_rollouts(state: LoopState, n: int, n0: int, key: str) -> None:
    """A resumed state must have been collected with the same N and N₀: its rollout counts
    (:meth:`LoopState.rollouts`) are computed from them."""
    saved_n = state.rollouts_per_update
    if saved_n is not None and saved_n != n:
        raise ValueError(
            f"rollouts_per_update: the state saved under checkpoint_key={key!r} was collected "
            f"with {saved_n} rollouts per update, got {n}"
        )
    saved_n0 = state.initial_rollouts if state.initial_rollouts is not None else saved_n
    if saved_n0 is not None and saved_n0 != n0:
        raise ValueError(
            f"initial_rollouts: the state saved under checkpoint_key={key!r} has a first "
            f"batch of {saved_n0} rollouts, got {n0}"
        )


def _check_extra_contexts(task: Task, extra_contexts: int) -> int:
    n_extra = check_count(extra_contexts, "extra_contexts", 0)
    if n_extra and (task.trajectory_depends_on_context or task.context_dim == 0):
        raise ValueError(
            f"extra_contexts: task {task.name!r} "
            + (
                "has no context"
                if task.context_dim == 0
                else "has trajectories that depend on the context"
            )
            + "; re-scoring a trajectory in other contexts is not valid (Sec. 3.4)"
        )
    return n_extra
