"""The model-free learning loop of Table 3.1, shared by every model-free experiment.

Each update: observe N contexts s_i ~ μ(s), draw ω_i ~ π(ω|s_i) from ``algorithm.policy``, roll
out, score R(τ_i, s_i) and call ``algorithm.update``. With ``extra_contexts=k`` each trajectory is
also re-scored in k freshly drawn contexts through the task's reward (the *extra context*
variant of Sec. 3.4), which is only valid when the trajectory does not depend on the context.

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
from typing import Any, Protocol

import numpy as np

from skillkit._validation import as_generator
from skillkit.tasks.base import Task

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

    def update(self, contexts, omegas, rewards) -> Any: ...


def learn(
    task: Task,
    algorithm: SearchAlgorithm,
    n_updates: int,
    rollouts_per_update: int,
    rng,
    progress=None,
    extra_contexts: int = 0,
    eval_contexts=None,
    callback: Callable[[int, SearchAlgorithm], Any] | None = None,
    checkpoint=None,
    checkpoint_key: str = "learn",
) -> dict:
    """Run model-free policy search on a task (Table 3.1).

    Parameters
    ----------
    task : Task
        The task (contexts, rollouts, rewards).
    algorithm : SearchAlgorithm
        E.g. :class:`~skillkit.search.reps.ContextualREPS`, :class:`~skillkit.search.rwr.RWR`,
        :class:`~skillkit.search.crkr.CrKR`; its policy must match the task's dimensions.
    n_updates : int
        Number of policy updates K ≥ 1.
    rollouts_per_update : int
        Rollouts N ≥ 1 per update.
    rng : Generator, int or None
        All randomness (contexts, exploration, rollouts, evaluation seed).
    progress : tqdm-like, optional
        ``reset(total=n_updates)`` is called once and ``update()`` after each policy update.
    extra_contexts : int
        k ≥ 0 extra contexts per trajectory (Sec. 3.4); requires
        ``task.trajectory_depends_on_context`` to be False and a contextual task.
    eval_contexts : array_like, shape (m, context_dim), optional
        Contexts on which the policy mean is evaluated (default: ``N_EVAL_CONTEXTS`` contexts
        drawn from the task at the start).
    callback : callable, optional
        ``callback(k, algorithm)`` after the initial evaluation (k = 0) and after each update
        k = 1..K (e.g. to record parameter errors). Its return values are collected in the
        result's ``callback`` list (K + 1 entries), which survives checkpoint and resume —
        record through return values, not through side effects, in resumable experiments.
    checkpoint : TrialContext-like, optional
        An object with ``save(key, state, rng)`` and ``resume(key, rng)`` (the ``progress``
        argument :func:`skillkit.experiments.runner.reproduce` gives ``run_trial``). The loop's
        state — algorithm, curves, diagnostics, callback values and the generator — is saved
        after every update, and a call with the same key resumes where the last one stopped,
        giving the same numbers as an uninterrupted run.
    checkpoint_key : str
        Key of this loop's state (distinct per ``learn`` call within a trial).

    Returns
    -------
    dict
        ``rollouts`` (K + 1,) rollouts so far at each evaluation (0, N, 2N, …);
        ``mean_reward`` (K + 1,) average reward of the policy mean on ``eval_contexts``;
        ``explore_rollouts`` (K,) and ``explore_reward`` (K,) for the exploratory rollouts;
        ``n_failed`` (K,) failed rollouts per batch; ``diagnostics`` (list of K update
        diagnostics); ``callback`` (list of K + 1 callback return values);
        ``eval_contexts`` (m, context_dim); ``policy`` (the final policy); ``policies``
        (the K + 1 policies, before the first update and after each one: what the viewer's
        learning playback steps through, see :func:`policy_history_arrays`).
    """
    if not isinstance(task, Task):
        raise ValueError(f"task: expected a Task, got {type(task).__name__}")
    n_updates = _check_count(n_updates, "n_updates", 1)
    n_roll = _check_count(rollouts_per_update, "rollouts_per_update", 1)
    n_extra = _check_count(extra_contexts, "extra_contexts", 0)
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
    pol = algorithm.policy
    if pol.dim != task.parameter_dim or pol.context_dim != task.context_dim:
        raise ValueError(
            f"algorithm: policy has dim={pol.dim}, context_dim={pol.context_dim}; "
            f"task {task.name!r} "
            f"needs dim={task.parameter_dim}, context_dim={task.context_dim}"
        )
    rng = as_generator(rng)
    if eval_contexts is None:
        eval_s = task.sample_context(rng, n=N_EVAL_CONTEXTS)
    else:
        eval_s = np.asarray(eval_contexts, dtype=np.float64)
        if eval_s.ndim != 2 or eval_s.shape[0] == 0:
            raise ValueError(
                f"eval_contexts: expected shape (m, {task.context_dim}) with m ≥ 1, "
                f"got {eval_s.shape}"
            )
        eval_s = np.stack([task.check_context(s, "eval_contexts") for s in eval_s])
    eval_seed = int(rng.integers(2**63))

    def evaluate() -> float:
        eval_rng = np.random.default_rng(eval_seed)
        means = np.atleast_2d(algorithm.policy.mean_of(eval_s))
        return float(
            np.mean([task.evaluate(w, s, eval_rng)[0] for w, s in zip(means, eval_s, strict=True)])
        )

    if progress is not None:
        progress.reset(total=n_updates)
    saved = None if checkpoint is None else checkpoint.resume(checkpoint_key, rng)
    if saved is not None:
        # Resume: restore the algorithm's state in place (the caller holds this object) and the
        # records; the generator was restored by ``resume``.
        vars(algorithm).update(vars(saved["algorithm"]))
        start, eval_s, eval_seed = saved["k"] + 1, saved["eval_contexts"], saved["eval_seed"]
        mean_reward, explore_reward = saved["mean_reward"], saved["explore_reward"]
        n_failed, diagnostics, cb_values = (
            saved["n_failed"],
            saved["diagnostics"],
            saved["callback"],
        )
        policies = saved["policies"]
        if progress is not None:
            progress.update(saved["k"])
    else:
        start = 1
        mean_reward = [evaluate()]
        cb_values = [None if callback is None else callback(0, algorithm)]
        explore_reward, n_failed, diagnostics = [], [], []
        policies = [algorithm.policy]
    for k in range(start, n_updates + 1):
        contexts = task.sample_context(rng, n=n_roll)
        omegas = np.atleast_2d(algorithm.policy.sample(contexts, rng))
        trajs = [task.rollout(w, s, rng) for w, s in zip(omegas, contexts, strict=True)]
        rewards = np.array([task.reward(t, s) for t, s in zip(trajs, contexts, strict=True)])
        explore_reward.append(float(rewards.mean()))
        n_failed.append(sum(t.failed for t in trajs))
        if n_extra:
            extra_s = task.sample_context(rng, n=n_roll * n_extra).reshape(n_roll, n_extra, -1)
            extra_r = np.array(
                [[task.reward(t, s) for s in ss] for t, ss in zip(trajs, extra_s, strict=True)]
            )
            contexts = np.concatenate([contexts, extra_s.reshape(n_roll * n_extra, -1)])
            omegas = np.concatenate([omegas, np.repeat(omegas, n_extra, axis=0)])
            rewards = np.concatenate([rewards, extra_r.reshape(-1)])
        diagnostics.append(algorithm.update(contexts, omegas, rewards))
        mean_reward.append(evaluate())
        cb_values.append(None if callback is None else callback(k, algorithm))
        policies.append(algorithm.policy)
        if checkpoint is not None:
            checkpoint.save(
                checkpoint_key,
                {
                    "k": k,
                    "algorithm": algorithm,
                    "eval_contexts": eval_s,
                    "eval_seed": eval_seed,
                    "mean_reward": mean_reward,
                    "explore_reward": explore_reward,
                    "n_failed": n_failed,
                    "diagnostics": diagnostics,
                    "callback": cb_values,
                    "policies": policies,
                },
                rng,
            )
        if progress is not None:
            progress.update()
    return {
        "rollouts": n_roll * np.arange(n_updates + 1),
        "mean_reward": np.array(mean_reward),
        "explore_rollouts": n_roll * np.arange(1, n_updates + 1),
        "explore_reward": np.array(explore_reward),
        "n_failed": np.array(n_failed, dtype=int),
        "diagnostics": diagnostics,
        "callback": cb_values,
        "eval_contexts": eval_s,
        "policy": algorithm.policy,
        "policies": policies,
    }


def policy_history_arrays(policies) -> dict[str, np.ndarray]:
    """The ``policy_*`` arrays of a learning run's policies (linear-Gaussian ones), the format
    :func:`skillkit.viz.viewer.load_policy_history` reads from a run folder's ``trials.npz``.

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


def _check_count(value, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name}: expected an integer ≥ {minimum}, got {value!r}")
    return int(value)
