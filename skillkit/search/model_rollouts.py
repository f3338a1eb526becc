r"""Predicted rollouts of a task under a learned forward model (GPREPS's *Predict Rewards* step,
Table 4.1, Eqs. 4.1–4.3): start states from the task's ``initial_states`` (Eq. 4.3), controls
from its batched ``controller``, next states from
:func:`~skillkit.models.sampling.sample_trajectories`, rewards from its ``reward_batch``, and
:math:`\mathcal{R}_{s\omega} = \frac{1}{L} \sum_{l=1}^{L} R(\tau^{[l]}, s)` (4.1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from skillkit._validation import as_generator, check_array, check_count, check_type
from skillkit.models.reward import Prediction, worst_if_failed, worst_if_nonfinite
from skillkit.models.sampling import SampledTrajectories, StepModel, sample_trajectories
from skillkit.tasks.base import Task

__all__ = ["ModelRollouts", "predict_trajectories"]


@dataclass(frozen=True)
class ModelRollouts(Prediction):
    """L predicted trajectories for each of B (ω, s) pairs, scored by the task's reward.

    ``states`` (B, L, T + 1, n_x), ``controls`` (B, L, T + 1, n_u) at every predicted state,
    ``rewards`` (B, L; ``task.worst_reward`` where ``failed``), ``contexts`` (B, context_dim)
    and the sampler's output ``sampled``.
    """

    states: np.ndarray
    controls: np.ndarray
    rewards: np.ndarray
    contexts: np.ndarray
    sampled: SampledTrajectories
    failed: np.ndarray

    def __repr__(self) -> str:
        B, L, T1, n_x = self.states.shape
        r = self.expected_rewards
        return (
            f"ModelRollouts(pairs={B}, trajectories={L}, horizon={T1 - 1}, state_dim={n_x}, "
            f"expected_reward={r.min():.4g}…{r.max():.4g}, "
            f"failed={int(self.failed.sum())}, saturated={self.sampled.n_saturated})"
        )


def predict_trajectories(
    task: Task,
    model: StepModel,
    omegas,
    contexts=None,
    *,
    horizon: int,
    n_samples: int = 1,
    rng=None,
    x0=None,
    control_limit=None,
    device=None,
    dtype: torch.dtype = torch.float64,
) -> ModelRollouts:
    """Sample and score L = ``n_samples`` model trajectories of T = ``horizon`` steps per pair.

    Parameters
    ----------
    task : Task
        With ``supports_model_rollout``.
    model : StepModel
        A fitted forward model of the task's ``model_signals()`` state and controls.
    omegas : array_like, shape (B, parameter_dim)
    contexts : array_like, shape (B, context_dim), optional
        Omit for context-free tasks.
    x0 : array_like, shape (B, n_x) or (B, L, n_x), optional
        Start states (default: drawn from ``task.initial_states``).
    control_limit, device, dtype
        Passed to :func:`~skillkit.models.sampling.sample_trajectories`.
    """
    check_type(task, Task, "task", "a Task")
    if not task.supports_model_rollout:
        reason = task.no_model_rollout_reason
        raise NotImplementedError(f"task: {task.name!r} has no model rollouts: {reason}")
    if task.model_signals().signals:
        raise NotImplementedError(
            f"task: {task.name!r}'s reward reads the signals {task.model_signals().signals}, "
            "which a state forward model does not predict; use the task's decomposed models"
        )
    w = check_array(omegas, "omegas", shape=(None, task.parameter_dim))
    B = w.shape[0]
    if contexts is None:
        if task.context_dim:
            raise ValueError(f"contexts: task {task.name!r} needs contexts of shape ({B}, ...)")
        s = np.zeros((B, 0))
    else:
        s = check_array(contexts, "contexts", shape=(B, task.context_dim))
    T, L = check_count(horizon, "horizon"), check_count(n_samples, "n_samples")
    rng = as_generator(rng)
    n_x = task.model_signals().state_dim
    if x0 is None:  # otherwise checked by sample_trajectories
        x0 = np.stack([task.initial_states(s_b, L, rng) for s_b in s])
    policy = task.controller(w, s if task.context_dim else None, device=device, dtype=dtype)
    sampled = sample_trajectories(
        model, x0, policy, T, L, rng, control_limit=control_limit, device=device, dtype=dtype
    )
    x_last = sampled.states[:, :, -1].reshape(B * L, n_x)
    pair = torch.arange(B, device=x_last.device).repeat_interleave(L)
    u_last = policy(T, x_last, pair).reshape(B, L, 1, -1)
    if control_limit is not None:
        limit = torch.as_tensor(control_limit, dtype=u_last.dtype, device=u_last.device)
        u_last = torch.clamp(u_last, -limit, limit)
    states = np.asarray(sampled.states.cpu(), dtype=np.float64)  # no copy for float64 on CPU
    controls = np.asarray(torch.cat([sampled.controls, u_last], dim=2).cpu(), dtype=np.float64)
    flat_x = states.reshape(B * L, T + 1, n_x)
    flat_u = controls.reshape(B * L, T + 1, -1)
    rewards = task.reward_batch(flat_x, flat_u, {}, np.repeat(s, L, axis=0))
    rewards, failed = worst_if_failed(np.asarray(rewards, dtype=np.float64), flat_x, task)
    rewards = worst_if_nonfinite(rewards.reshape(B, L), task, "predict_trajectories")
    return ModelRollouts(states, controls, rewards, s, sampled, failed.reshape(B, L))
