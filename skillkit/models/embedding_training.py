"""Hyper-parameter learning for kernel embeddings (thesis Sec. 5.3, Eqs. 5.15–5.26).

θ = [log w_1, …, log w_d, log λ] (SE input kernel, σ_f² = 1) minimises a k-fold
cross-validated prediction error, differentiated by autograd (Eqs. 5.20–5.21, 5.24–5.26).
Target Gram matrices are fixed: a θ-dependent target kernel would make (5.16) vanish."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import gpytorch
import numpy as np
import torch
from scipy.optimize import minimize

from skillkit._repr import number, vector
from skillkit._validation import as_generator, check_array, check_count, check_positive
from skillkit.models.embedding import (
    conditional_weights,
    initial_weights,
    regularized_cholesky,
    rollout_weights,
)
from skillkit.models.kernels import gram, se_kernel

__all__ = [
    "CrossValidatedLoss",
    "FitResult",
    "fit_hyperparameters",
    "kfold_splits",
    "state_embedding_error",
    "state_embedding_loss",
    "step_reward_error",
    "step_reward_loss",
    "trajectory_reward_error",
    "trajectory_reward_loss",
    "transitions",
]

Folds = Sequence[tuple[np.ndarray, np.ndarray]]


def kfold_splits(n: int, k: int = 10, rng=None, groups=None) -> list[tuple[np.ndarray, np.ndarray]]:
    """k random (train_idx, val_idx) splits whose validation sets partition ``range(n)``; samples
    sharing a ``groups`` label (e.g. a trajectory) stay in one fold."""
    n = int(n)
    if n < 2:
        raise ValueError(f"n: expected at least 2 samples, got {n}")
    labels = np.arange(n) if groups is None else np.asarray(groups)
    if labels.shape != (n,):
        raise ValueError(f"groups: expected shape ({n},), got {labels.shape}")
    unique, inverse = np.unique(labels, return_inverse=True)
    k = int(k)
    if not 2 <= k <= unique.size:
        raise ValueError(f"k: expected 2 <= k <= {unique.size} (the number of groups), got {k}")
    order = as_generator(rng).permutation(unique.size)
    fold_of_group = np.empty(unique.size, dtype=int)
    fold_of_group[order] = np.arange(unique.size) % k
    fold = fold_of_group[inverse]
    idx = np.arange(n)
    return [(idx[fold != f], idx[fold == f]) for f in range(k)]


def transitions(states, controls=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flatten trajectories ``states`` (M, T, n_x) into transition pairs.

    With ``controls`` (M, T, n_u) the inputs are z_t = [x_t, u_t] (Table 5.2), else states
    (Table 5.1). Returns inputs (M(T−1), d_z), successors (M(T−1), n_x) and the trajectory index
    of each transition (for :func:`kfold_splits`)."""
    x = check_array(states, "states", ndim=3)
    m, t, n_x = x.shape
    if t < 2:
        raise ValueError(f"states: expected at least 2 time steps, got shape {x.shape}")
    z = x
    if controls is not None:
        u = check_array(controls, "controls", ndim=3)
        if u.shape[:2] != (m, t):
            raise ValueError(f"controls: expected shape ({m}, {t}, n_u) like states, got {u.shape}")
        z = np.concatenate([x, u], axis=-1)
    inputs = z[:, :-1].reshape(m * (t - 1), -1)
    successors = x[:, 1:].reshape(m * (t - 1), n_x)
    groups = np.repeat(np.arange(m), t - 1)
    return inputs, successors, groups


def _unpack(theta: torch.Tensor, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    if theta.shape != (dim + 1,):
        raise ValueError(f"theta: expected shape ({dim + 1},), got {tuple(theta.shape)}")
    return torch.exp(theta[:dim]), torch.exp(theta[dim])


def _weights(theta: torch.Tensor, inputs: torch.Tensor, queries: torch.Tensor) -> torch.Tensor:
    ls, lam = _unpack(theta, inputs.shape[-1])
    chol = regularized_cholesky(se_kernel(inputs, inputs, ls, 1.0), lam)
    return conditional_weights(chol, se_kernel(inputs, queries, ls, 1.0))


def state_embedding_error(
    theta: torch.Tensor,
    inputs: torch.Tensor,
    val_inputs: torch.Tensor,
    target_gram: torch.Tensor,
    target_cross: torch.Tensor,
    target_diag: torch.Tensor,
) -> torch.Tensor:
    """Squared RKHS error of predicted successor embeddings, Eqs. (5.15)–(5.16):
    J = Σ_v g_y(y_v, y_v) − 2 g_y(y_v)ᵀβ_v + β_vᵀ G_y β_v, β_v = (G + λI)⁻¹ g(z_v), from
    ``target_gram`` G_y (N, N), ``target_cross`` g_y(y_v, y_j) (V, N), ``target_diag`` (V,)."""
    beta = _weights(theta, inputs, val_inputs)  # (N, V)
    return (
        target_diag.sum()
        - 2.0 * (target_cross * beta.T).sum()
        + (beta * (target_gram @ beta)).sum()
    )


def step_reward_error(
    theta: torch.Tensor,
    inputs: torch.Tensor,
    rewards: torch.Tensor,
    val_inputs: torch.Tensor,
    val_rewards: torch.Tensor,
) -> torch.Tensor:
    """One-step reward error with a linear reward kernel, Eqs. (5.17)–(5.19):
    J = Σ_v (r'_v − r'ᵀβ_v)², β_v = (G + λI)⁻¹ g(z_v)."""
    beta = _weights(theta, inputs, val_inputs)
    return ((val_rewards - rewards @ beta) ** 2).sum()


def trajectory_reward_error(
    theta: torch.Tensor,
    inputs: torch.Tensor,
    initial_inputs: torch.Tensor,
    bases: torch.Tensor,
    basis_rewards: torch.Tensor,
    rewards: torch.Tensor,
    project_initial: bool = True,
) -> torch.Tensor:
    """Long-term reward prediction error, Eqs. (5.22)–(5.23):
    J = Σ_i Σ_{t≥1} (r^i_t − r'^{π_i}_tᵀ β^i_t)², β^i_{t+1} = (G + λI)⁻¹ G̃^{π_i}_t β^i_t, over
    ``bases`` [x'_j, π_i(x'_j, t)] (M, N, d) or (T − 2, M, N, d) with ``basis_rewards``; β₁ is
    Eq. (5.9)'s first step (``project_initial=False``: Eq. 5.23 as printed)."""
    n_rows = rewards.shape[1]
    ls, lam = _unpack(theta, inputs.shape[-1])
    g_train = se_kernel(inputs, inputs, ls, 1.0)
    chol = regularized_cholesky(g_train, lam)
    beta1 = initial_weights(
        chol, g_train, se_kernel(inputs, initial_inputs, ls, 1.0), project_initial
    )  # (N, M)

    def transition(t):
        return se_kernel(inputs, bases[t - 1], ls, 1.0)

    shared = bases.ndim == 3  # one G̃^π (M, N, N) for every step
    g = se_kernel(inputs, bases, ls, 1.0) if shared else transition
    betas = rollout_weights(chol, beta1, g, n_rows - 1)  # (T-1, N, M)
    r_basis = basis_rewards if basis_rewards.ndim == 3 else basis_rewards[None]
    predicted = torch.einsum("tmn,tnm->tm", r_basis.expand(n_rows - 1, -1, -1), betas)
    return ((rewards[:, 1:].T - predicted) ** 2).sum()


@dataclass
class CrossValidatedLoss:
    """A cross-validation error of θ: one ``theta -> Tensor`` closure per fold, the input
    dimension and the number of validation terms (the loss is reported per term)."""

    folds: list[Callable[[torch.Tensor], torch.Tensor]]
    dim: int
    n_val: int = 1

    def __repr__(self) -> str:
        return f"CrossValidatedLoss(folds={len(self.folds)}, dim={self.dim}, n_val={self.n_val})"

    def value_and_grad(self, theta) -> tuple[float, np.ndarray]:
        """Mean error per term and its gradient w.r.t. θ."""
        th = check_array(theta, "theta", shape=(self.dim + 1,))
        total, grad = 0.0, np.zeros_like(th)
        for fold in self.folds:
            t = torch.tensor(th, dtype=torch.float64, requires_grad=True)
            value = fold(t) / self.n_val
            value.backward()
            total += float(value.detach())
            grad += t.grad.numpy()
        return total, grad

    def __call__(self, theta) -> float:
        th = check_array(theta, "theta", shape=(self.dim + 1,))
        with torch.no_grad():
            t = torch.from_numpy(th)
            return float(sum(float(fold(t)) for fold in self.folds)) / self.n_val


def _t(a) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))


def _check_folds(folds: Folds, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for i, (tr, va) in enumerate(folds):
        tr, va = np.asarray(tr, dtype=int), np.asarray(va, dtype=int)
        both = np.concatenate([tr.ravel(), va.ravel()])
        if tr.size == 0 or va.size == 0 or both.min() < 0 or both.max() >= n:
            raise ValueError(f"folds: fold {i} has empty or out-of-range indices for {n} samples")
        out.append((tr, va))
    if not out:
        raise ValueError("folds: expected at least one (train, val) pair")
    return out


def _fold_loss(error, folds: Folds, z: np.ndarray, parts) -> CrossValidatedLoss:
    """``error(theta, *parts(train, val))`` summed over the checked folds of the rows of ``z``."""
    folds = _check_folds(folds, z.shape[0])
    args = [tuple(_t(v) for v in parts(tr, va)) for tr, va in folds]
    fns = [lambda th, a=a: error(th, *a) for a in args]
    return CrossValidatedLoss(fns, z.shape[1], sum(len(va) for _, va in folds))


def state_embedding_loss(
    inputs, targets, folds: Folds, target_kernel: gpytorch.kernels.Kernel
) -> CrossValidatedLoss:
    """Cross-validated state-embedding error (5.16) for ``inputs`` (N, d), ``targets`` (N, d_y),
    ``folds`` and a fixed ``target_kernel``."""
    z = check_array(inputs, "inputs", ndim=2)
    y = check_array(targets, "targets", ndim=2)
    if y.shape[0] != z.shape[0]:
        raise ValueError(f"targets: expected {z.shape[0]} rows like inputs, got shape {y.shape}")
    g_y = gram(target_kernel, y)

    def parts(tr, va):
        return z[tr], z[va], g_y[np.ix_(tr, tr)], g_y[np.ix_(va, tr)], np.diag(g_y)[va]

    return _fold_loss(state_embedding_error, folds, z, parts)


def step_reward_loss(inputs, rewards, folds: Folds) -> CrossValidatedLoss:
    """Cross-validated one-step reward error (5.19) for ``inputs`` (N, d) and ``rewards`` (N,)."""
    z = check_array(inputs, "inputs", ndim=2)
    r = check_array(rewards, "rewards", shape=(z.shape[0],))
    return _fold_loss(step_reward_error, folds, z, lambda tr, va: (z[tr], r[tr], z[va], r[va]))


def trajectory_reward_loss(
    states,
    controls,
    rewards,
    policy,
    reward,
    folds: Folds,
    chunk: int = 8,
) -> CrossValidatedLoss:
    """Cross-validated trajectory reward error (5.23), folds over whole trajectories.

    ``policy(states, t)`` is time-invariant: states (1, K, n_x) give controls (M, K, n_u) or
    (1, K, n_u); ``reward(states, controls)`` maps (b, K, ·) to (b, K); ``chunk`` validation
    trajectories share a backward pass."""
    x = check_array(states, "states", ndim=3)
    m, t_len, _ = x.shape
    u = check_array(controls, "controls", ndim=3)
    if u.shape[:2] != (m, t_len):
        raise ValueError(f"controls: expected shape ({m}, {t_len}, n_u) like states, got {u.shape}")
    r = check_array(rewards, "rewards", shape=(m, t_len))
    chunk = check_count(chunk, "chunk")
    z_all = np.concatenate([x, u], axis=-1)
    fns, n_val = [], 0
    for tr, va in _check_folds(folds, m):
        z_tr, xp_tr, _ = transitions(x[tr], u[tr])
        c = check_array(policy(xp_tr[None], 1), "policy(states, t)", ndim=3)
        if c.shape[0] not in (1, m) or c.shape[1] != xp_tr.shape[0]:
            raise ValueError(
                f"policy(states, t): expected ({m} or 1, {xp_tr.shape[0]}, n_u), got {c.shape}"
            )
        c = np.broadcast_to(c, (m,) + c.shape[1:])[va]
        s = np.broadcast_to(xp_tr[None], (len(va),) + xp_tr.shape)
        bases = np.concatenate([s, c], axis=-1)  # (V, N, d)
        basis_r = check_array(reward(s, c), "reward(states, controls)", shape=(len(va), len(s[0])))
        for lo in range(0, len(va), chunk):
            sl = slice(lo, lo + chunk)
            args = (_t(z_tr), _t(z_all[va][sl, 0]), _t(bases[sl]), _t(basis_r[sl]), _t(r[va][sl]))
            fns.append(lambda th, a=args: trajectory_reward_error(th, *a))
        n_val += len(va) * (t_len - 1)
    return CrossValidatedLoss(fns, z_all.shape[-1], n_val)


@dataclass
class FitResult:
    """Outcome of :func:`fit_hyperparameters`: length-scales, λ, the loss per term at the optimum
    and start, evaluations, the optimiser's verdict and the hyper-parameters left on a bound."""

    lengthscale: np.ndarray
    lam: float
    loss: float
    initial_loss: float
    n_evaluations: int
    success: bool
    message: str
    at_bound: list[str] = field(default_factory=list)

    def __repr__(self) -> str:
        bound = f", at_bound={self.at_bound}" if self.at_bound else ""
        return (
            f"FitResult(lengthscale={vector(self.lengthscale)}, lam={number(self.lam)}, "
            f"loss={number(self.loss, '.4g')} (initial {number(self.initial_loss, '.4g')}), "
            f"n_evaluations={self.n_evaluations}, success={self.success}{bound})"
        )


def fit_hyperparameters(
    loss: CrossValidatedLoss,
    lengthscale,
    lam: float = 1e-3,
    lengthscale_factor: float = 100.0,
    lam_bounds: tuple[float, float] = (1e-6, 1.0),
    max_iter: int = 100,
    lengthscale_reference=None,
) -> FitResult:
    """Minimise a cross-validated embedding error over log length-scales and log λ, L-BFGS-B.

    Parameters
    ----------
    loss : CrossValidatedLoss
        The error to minimise, over d input dimensions.
    lengthscale : float or array_like, shape (d,)
        Initial length-scales (> 0).
    lam : float, default 1e-3
        Initial λ, inside ``lam_bounds``.
    lengthscale_factor : float, default 100
        Length-scales are searched in [w_ref / factor, w_ref · factor].
    lam_bounds : (float, float), default (1e-6, 1.0)
    max_iter : int, default 100
    lengthscale_reference : float or array_like, shape (d,), optional
        w_ref (default: the initial ``lengthscale``, clipped into the box).

    Returns
    -------
    FitResult

    Raises
    ------
    ValueError
        On non-positive length-scales or λ outside ``lam_bounds``.
    """
    d = loss.dim

    def positive(value, name: str) -> np.ndarray:
        w = np.broadcast_to(check_array(value, name, ndim=(0, 1)), (d,)).copy()
        if np.any(w <= 0):
            raise ValueError(f"{name}: expected positive values, got {w}")
        return w

    w0 = positive(lengthscale, "lengthscale")
    lam = check_positive(lam, "lam")
    lo_l, hi_l = (check_positive(v, "lam_bounds") for v in lam_bounds)
    if not lo_l <= lam <= hi_l:
        raise ValueError(f"lam: expected a value inside lam_bounds {lam_bounds}, got {lam}")
    f = check_positive(lengthscale_factor, "lengthscale_factor")
    ref = w0
    if lengthscale_reference is not None:
        ref = positive(lengthscale_reference, "lengthscale_reference")
        w0 = np.clip(w0, ref / f, ref * f)
    bounds = [(np.log(w / f), np.log(w * f)) for w in ref] + [(np.log(lo_l), np.log(hi_l))]
    theta0 = np.append(np.log(w0), np.log(lam))
    initial = loss(theta0)
    res = minimize(
        loss.value_and_grad,
        theta0,
        jac=True,
        method="L-BFGS-B",
        bounds=bounds,
        options={"maxiter": int(max_iter)},
    )
    names = [f"lengthscale[{i}]" for i in range(d)] + ["lam"]
    at_bound = [
        n
        for n, v, (lo, hi) in zip(names, res.x, bounds, strict=True)
        if np.isclose(v, lo, atol=1e-6) or np.isclose(v, hi, atol=1e-6)
    ]
    return FitResult(
        lengthscale=np.exp(res.x[:d]),
        lam=float(np.exp(res.x[d])),
        loss=float(res.fun),
        initial_loss=float(initial),
        n_evaluations=int(res.nfev),
        success=bool(res.success),
        message=str(res.message),
        at_bound=at_bound,
    )
