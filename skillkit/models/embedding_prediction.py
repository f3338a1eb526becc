"""Trajectory and reward prediction with kernel embeddings (thesis Sec. 5.2, Tables 5.1–5.2).

With a fixed policy z = x and β_{t+1} = (K + λI)⁻¹ K̃ β_t (Eqs. 5.9–5.12); with any policy
(Eq. 5.14) z = [x, u] over z^π_{j,t} = [x'_j, π(x'_j, t)]. With a linear reward kernel
E[r_t] = r'_tᵀ β_t (Sec. 5.4). ``betas[t - 1]`` holds the weights of row t."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from skillkit._repr import span
from skillkit._validation import check_array, check_count
from skillkit.models.embedding import ConditionalEmbedding, initial_weights, rollout_weights

__all__ = ["TrajectoryEmbedding", "predict"]

Policy = Callable[[np.ndarray, int], np.ndarray]
Reward = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass
class TrajectoryEmbedding:
    """Predicted embedding of B trajectory distributions over T rows: the ``initial`` means
    (B, n_x), the weights ``betas`` (T − 1, N, B) of rows 1 … T − 1 over the observed successors,
    and the expected ``rewards`` (T, B) or None."""

    initial: np.ndarray
    betas: np.ndarray
    rewards: np.ndarray | None = None

    def __repr__(self) -> str:
        T1, N, B = self.betas.shape
        reward = "None" if self.rewards is None else span(self.rewards.sum(axis=0))
        return (
            f"TrajectoryEmbedding(B={B}, T={T1 + 1}, N={N}, state_dim={self.initial.shape[-1]}, "
            f"total_reward={reward})"
        )

    def means(self, model: ConditionalEmbedding) -> np.ndarray:
        """Expected states :math:`X'^\\top \\beta_t`, shape (T, B, n_x)."""
        return np.concatenate([self.initial[None], *(model.mean(b)[None] for b in self.betas)])

    def preimages(self, model: ConditionalEmbedding, **kwargs) -> np.ndarray:
        """Most likely states per row (Eq. 2.45), shape (T, B, n_x)."""
        b = self.betas
        flat = b.transpose(1, 0, 2).reshape(b.shape[1], -1)  # (N, (T-1) B)
        decoded = model.preimage(flat, **kwargs).reshape(b.shape[0], b.shape[2], -1)
        return np.concatenate([self.initial[None], decoded])


def predict(
    model: ConditionalEmbedding,
    initial,
    n_steps: int,
    policy: Policy | None = None,
    reward: Reward | None = None,
    time_invariant: bool = False,
    project_initial: bool = True,
) -> TrajectoryEmbedding:
    """Kernel trajectory prediction, Table 5.1 (fixed policy) and Table 5.2 (any policy).

    Parameters
    ----------
    model : ConditionalEmbedding
        Fitted on x_i (fixed policy) or [x_i, u_i] → x'_i, N pairs.
    initial : array_like, shape (B, n_x) or (B, L, n_x)
        Start states, or L samples of each (Eq. 5.6).
    n_steps : int
        T ≥ 2 rows.
    policy : callable, optional
        ``policy(states, t)``: (b, M, n_x) → controls (b', M, n_u), b, b' ∈ {1, B}
        (None: the data-collecting policy).
    reward : callable, optional
        ``reward(states, controls)`` → (b, M).
    time_invariant : bool, default False
        The policy ignores ``t``: G̃^π is computed once instead of per step.
    project_initial : bool, default True
        First step as Eq. (5.9); else β₁ = α (Eq. 5.7).

    Returns
    -------
    TrajectoryEmbedding

    Raises
    ------
    ValueError
        On bad shapes or ``n_steps`` < 2, or policy/reward output of the wrong shape.
    """
    n_x = model.target_dim
    x0 = check_array(initial, "initial", ndim=(2, 3))
    if x0.shape[-1] != n_x:
        raise ValueError(f"initial: expected {n_x} columns like the targets, got shape {x0.shape}")
    samples = x0 if x0.ndim == 3 else x0[:, None, :]  # (B, L, n_x)
    n_rows = check_count(n_steps, "n_steps", minimum=2)  # initial state + one prediction
    if policy is None and model.input_dim != n_x:
        raise ValueError(f"policy: needed for {model.input_dim} inputs and {n_x} targets")
    fixed = policy is None or time_invariant

    def inputs_at(states: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        if policy is None:
            controls = np.zeros(states.shape[:-1] + (0,))
        else:
            controls = check_array(policy(states, t), "policy(states, t)", ndim=3)
        rows = (1, states.shape[0], samples.shape[0])
        if controls.shape[1] != states.shape[1] or controls.shape[0] not in rows:
            got = controls.shape
            raise ValueError(f"policy(states, t): expected (b, {states.shape[1]}, n_u), got {got}")
        b = max(states.shape[0], controls.shape[0])
        s = np.broadcast_to(states, (b,) + states.shape[1:])
        c = np.broadcast_to(controls, (b,) + controls.shape[1:])
        z = np.concatenate([s, c], axis=-1)
        if z.shape[-1] != model.input_dim:
            raise ValueError(f"policy(states, t): expected {model.input_dim} inputs, got {z.shape}")
        return z, c

    def rewards_at(s: np.ndarray, c: np.ndarray) -> np.ndarray:
        out = reward(np.broadcast_to(s, c.shape[:-1] + s.shape[-1:]), c)
        r = check_array(out, "reward(states, controls)", ndim=2)
        if r.shape != c.shape[:-1]:
            raise ValueError(f"reward(states, controls): expected {c.shape[:-1]}, got {r.shape}")
        return r

    successors = model.targets[None]  # (1, N, n_x)
    grams: dict[int, torch.Tensor] = {}
    reward_vectors: dict[int, np.ndarray] = {}

    def transition(t: int) -> torch.Tensor:
        key = 1 if fixed else t
        if key not in grams:
            z, c = inputs_at(successors, key)
            g = model.cross_kernel(torch.from_numpy(np.ascontiguousarray(z)))  # (b, N, N)
            grams.clear()  # time-dependent: keep only the current step
            grams[key] = g[0] if g.shape[0] == 1 else g
            if reward is not None:
                reward_vectors[key] = rewards_at(successors, c)
        return grams[key]

    n_batch = samples.shape[0]
    with torch.no_grad():
        z1, c1 = inputs_at(samples, 0)  # (B, L, d_z)
        cross = model.cross_kernel(torch.from_numpy(np.ascontiguousarray(z1)))  # (B, N, L)
        beta1 = initial_weights(
            model.chol, torch.from_numpy(model.gram), cross.mean(-1).T.contiguous(), project_initial
        )  # (N, B), Eqs. 5.6 and 5.9
        betas = rollout_weights(model.chol, beta1, transition, n_rows - 1).numpy()

    rewards = None
    if reward is not None:
        rewards = np.empty((n_rows, n_batch))
        rewards[0] = rewards_at(samples, c1).mean(axis=1)
        for t in range(1, n_rows):
            key = 1 if fixed else t
            if key not in reward_vectors:  # the last step: computed with its (unused) G̃
                transition(t)
            r_t = np.broadcast_to(reward_vectors[key], (n_batch, model.n))
            rewards[t] = np.einsum("bn,nb->b", r_t, betas[t - 1])
    return TrajectoryEmbedding(initial=samples.mean(axis=1), betas=betas, rewards=rewards)
