"""Hyper-parameter learning for kernel embeddings (thesis Sec. 5.3, Eqs. 5.15–5.26).

Kernel embeddings have no likelihood, so the SE input-kernel hyper-parameters are found by
minimising a prediction error on held-out data (k-fold cross-validation, 10 folds in the
thesis). Three errors are implemented, each a pure torch function of the hyper-parameters
whose gradient (Eqs. 5.20–5.21 and 5.24–5.26) is obtained by reverse-mode differentiation
through the same linear algebra the predictions use:

* :func:`state_embedding_error`, Eqs. (5.15)–(5.16): squared RKHS distance between the
  observed successor feature and the predicted embedding;
* :func:`step_reward_error`, Eqs. (5.17)–(5.19): one-step reward prediction error with a
  linear reward kernel;
* :func:`trajectory_reward_error`, Eqs. (5.22)–(5.23): the reward prediction error of whole
  predicted trajectories (long-term prediction, Table 5.2 propagation).

Parametrisation. The hyper-parameters are ``theta = [log w_1, …, log w_d, log λ]``: ARD
length-scales of the SE input kernel g (Eq. 2.25) and the regulariser. The SE signal
variance is fixed to 1 because only the ratio λ/σ_f² enters
:math:`\\beta = (G + \\lambda I)^{-1} g(z)`.

Target features. In Eq. (5.16) the target kernel must not depend on θ: if it did, the error
would vanish trivially as its length-scales grow (all features coincide). The target Gram
matrices are therefore fixed data here (a kernel chosen once, e.g. an SE kernel with the
targets' standard deviations as length-scales).
"""

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


# --------------------------------------------------------------------------- data helpers
def kfold_splits(n: int, k: int = 10, rng=None, groups=None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Random k-fold cross-validation splits that partition ``range(n)``.

    Parameters
    ----------
    n : int
        Number of samples.
    k : int
        Number of folds, 2 ≤ k ≤ number of groups (10 in the thesis).
    rng : Generator, int or None
        Randomness of the assignment.
    groups : array_like of int, shape (n,), optional
        Group label per sample (e.g. the trajectory a transition belongs to). Groups are
        never split across folds, so a validation fold holds whole trajectories.

    Returns
    -------
    list of (train_idx, val_idx)
        k pairs of sorted index arrays; the validation sets are disjoint and cover
        ``range(n)``, and each training set is the complement of its validation set.
    """
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
    """Flatten M observed trajectories into transition pairs.

    Parameters
    ----------
    states : array_like, shape (M, T, n_x)
    controls : array_like, shape (M, T, n_u), optional
        If given, the inputs are state-actions ``z_t = [x_t, u_t]`` (Table 5.2); otherwise
        states (fixed policy, Table 5.1).

    Returns
    -------
    inputs : ndarray, shape (M (T-1), d_z)
        z_t for t = 0, …, T−2 of every trajectory (trajectory-major).
    successors : ndarray, shape (M (T-1), n_x)
        x_{t+1}.
    groups : ndarray of int, shape (M (T-1),)
        The trajectory index of each transition (for :func:`kfold_splits`).
    """
    x = check_array(states, "states", ndim=3)
    m, t, n_x = x.shape
    if t < 2:
        raise ValueError(
            f"states: expected at least 2 time steps per trajectory, got shape {x.shape}"
        )
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


# --------------------------------------------------------------------------- objectives
def _unpack(theta: torch.Tensor, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    if theta.shape != (dim + 1,):
        raise ValueError(
            f"theta: expected [log lengthscales ({dim}), log lam], i.e. shape "
            f"({dim + 1},), got {tuple(theta.shape)}"
        )
    return torch.exp(theta[:dim]), torch.exp(theta[dim])


def _weights(theta: torch.Tensor, inputs: torch.Tensor, queries: torch.Tensor):
    """Cholesky of G + λI and β = (G + λI)^{-1} g(Z, queries) for the SE kernel at θ."""
    ls, lam = _unpack(theta, inputs.shape[-1])
    chol = regularized_cholesky(se_kernel(inputs, inputs, ls, 1.0), lam)
    return chol, ls, conditional_weights(chol, se_kernel(inputs, queries, ls, 1.0))


def state_embedding_error(
    theta: torch.Tensor,
    inputs: torch.Tensor,
    val_inputs: torch.Tensor,
    target_gram: torch.Tensor,
    target_cross: torch.Tensor,
    target_diag: torch.Tensor,
) -> torch.Tensor:
    """Squared RKHS error of predicted successor embeddings, Eqs. (5.15)–(5.16).

    .. math:: J(\\theta) = \\sum_v g_y(y_v, y_v) - 2\\, g_y(y_v)^\\top \\beta_v
              + \\beta_v^\\top G_y \\beta_v, \\qquad
              \\beta_v = (G + \\lambda I)^{-1} g(z_v)

    over validation pairs (z_v, y_v), with the operator fitted on the training pairs.

    Parameters
    ----------
    theta : Tensor, shape (d + 1,)
        ``[log w, log λ]`` of the SE input kernel.
    inputs : Tensor, shape (N, d)
        Training inputs.
    val_inputs : Tensor, shape (V, d)
        Validation inputs.
    target_gram : Tensor, shape (N, N)
        :math:`G_y` over the training targets (fixed target kernel).
    target_cross : Tensor, shape (V, N)
        :math:`g_y(y_v, y_j)` between validation and training targets.
    target_diag : Tensor, shape (V,)
        :math:`g_y(y_v, y_v)`.

    Returns
    -------
    Tensor, scalar
    """
    _, _, beta = _weights(theta, inputs, val_inputs)  # (N, V)
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
    """One-step reward error with a linear reward kernel, Eqs. (5.17)–(5.19).

    .. math:: J(\\theta) = \\sum_v (r'_v - r'^\\top \\beta_v)^2,
              \\qquad \\beta_v = (G + \\lambda I)^{-1} g(z_v)

    Parameters
    ----------
    theta : Tensor, shape (d + 1,)
    inputs : Tensor, shape (N, d)
        Training state-actions z_i.
    rewards : Tensor, shape (N,)
        Observed successor rewards r'_i = r(z'_i) of the training pairs.
    val_inputs : Tensor, shape (V, d)
    val_rewards : Tensor, shape (V,)

    Returns
    -------
    Tensor, scalar
    """
    _, _, beta = _weights(theta, inputs, val_inputs)
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
    """Long-term reward prediction error of whole trajectories, Eqs. (5.22)–(5.23).

    .. math:: J(\\theta) = \\sum_i \\sum_{t \\ge 1} (r^i_t - r'^{\\pi_i \\top}_t \\beta^i_t)^2,
              \\quad \\beta^i_1 = (G + \\lambda I)^{-1} G (G + \\lambda I)^{-1} g(z^i_0),
              \\quad \\beta^i_{t+1} = (G + \\lambda I)^{-1} \\tilde G^{\\pi_i}_t \\beta^i_t

    (0-based rows: row 0 is the observed initial state-action, whose reward is known
    exactly and so does not enter J). β₁ is the first step of Eq. (5.9), as
    :func:`~skillkit.models.embedding_prediction.predict` computes it, so the
    hyper-parameters are trained for the predictor that uses them; ``project_initial=False``
    gives β₁ = (G + λI)⁻¹ g(z⁰) (Eq. 5.23 as printed).

    Parameters
    ----------
    theta : Tensor, shape (d + 1,)
    inputs : Tensor, shape (N, d)
        Training state-actions z_j.
    initial_inputs : Tensor, shape (M, d)
        Initial state-action z^i_0 of each of M validation trajectories.
    bases : Tensor, shape (M, N, d) or (T - 2, M, N, d)
        :math:`z^{\\pi_i}_{j,t} = [x'_j, \\pi_i(x'_j, t)]`: the training successors with the
        controls of trajectory i's policy, shared by all rows (time-invariant policies) or
        one set per row t = 1, …, T−2.
    basis_rewards : Tensor, shape (M, N) or (T - 1, M, N)
        :math:`r(z^{\\pi_i}_{j,t})`, shared by all rows or one per row t = 1, …, T−1.
    rewards : Tensor, shape (M, T)
        Observed immediate rewards of the validation trajectories.
    project_initial : bool
        Eq. (5.9)'s first step (:func:`~skillkit.models.embedding.initial_weights`).

    Returns
    -------
    Tensor, scalar
    """
    n_rows = rewards.shape[1]
    ls, lam = _unpack(theta, inputs.shape[-1])
    g_train = se_kernel(inputs, inputs, ls, 1.0)
    chol = regularized_cholesky(g_train, lam)
    beta1 = initial_weights(
        chol, g_train, se_kernel(inputs, initial_inputs, ls, 1.0), project_initial
    )  # (N, M)
    if bases.ndim == 3:
        g = se_kernel(inputs, bases, ls, 1.0)  # (M, N, N)

        def transition(t):
            return g
    else:

        def transition(t):
            return se_kernel(inputs, bases[t - 1], ls, 1.0)

    betas = rollout_weights(chol, beta1, transition, n_rows - 1)  # (T-1, N, M)
    r_basis = basis_rewards if basis_rewards.ndim == 3 else basis_rewards[None]
    predicted = torch.einsum("tmn,tnm->tm", r_basis.expand(n_rows - 1, -1, -1), betas)
    return ((rewards[:, 1:].T - predicted) ** 2).sum()


# --------------------------------------------------------------------------- cross-validation
@dataclass
class CrossValidatedLoss:
    """A cross-validation error as a function of θ = ``[log w, log λ]``.

    Attributes
    ----------
    folds : list of callable
        One closure per fold, ``theta (Tensor) -> scalar Tensor`` (the fold's validation
        error with the operator fitted on its training part).
    dim : int
        Input dimension d (θ has d + 1 entries).
    n_val : int
        Total number of validation terms (the loss is reported per term).
    """

    folds: list[Callable[[torch.Tensor], torch.Tensor]]
    dim: int
    n_val: int = 1

    def __repr__(self) -> str:
        return f"CrossValidatedLoss(folds={len(self.folds)}, dim={self.dim}, n_val={self.n_val})"

    def value_and_grad(self, theta) -> tuple[float, np.ndarray]:
        """Mean validation error per term and its gradient w.r.t. θ (one backward per fold)."""
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
        if (
            tr.size == 0
            or va.size == 0
            or tr.min(initial=0) < 0
            or va.min(initial=0) < 0
            or max(tr.max(initial=0), va.max(initial=0)) >= n
        ):
            raise ValueError(f"folds: fold {i} has empty or out-of-range indices for {n} samples")
        out.append((tr, va))
    if not out:
        raise ValueError("folds: expected at least one (train, val) pair")
    return out


def state_embedding_loss(
    inputs, targets, folds: Folds, target_kernel: gpytorch.kernels.Kernel
) -> CrossValidatedLoss:
    """Cross-validated state-embedding error, Eq. (5.16) summed over folds.

    Parameters
    ----------
    inputs : array_like, shape (N, d)
        z_i (states for a fixed policy, state-actions otherwise).
    targets : array_like, shape (N, d_y)
        Successor states (or state-actions) y_i.
    folds : sequence of (train_idx, val_idx)
        E.g. :func:`kfold_splits` by trajectory.
    target_kernel : gpytorch Kernel
        Fixed kernel of the target features.
    """
    z = check_array(inputs, "inputs", ndim=2)
    y = check_array(targets, "targets", ndim=2)
    if y.shape[0] != z.shape[0]:
        raise ValueError(f"targets: expected {z.shape[0]} rows like inputs, got shape {y.shape}")
    g_y = gram(target_kernel, y)
    fns = []
    folds = _check_folds(folds, z.shape[0])
    for tr, va in folds:
        args = (
            _t(z[tr]),
            _t(z[va]),
            _t(g_y[np.ix_(tr, tr)]),
            _t(g_y[np.ix_(va, tr)]),
            _t(np.diag(g_y)[va]),
        )
        fns.append(lambda th, a=args: state_embedding_error(th, *a))
    return CrossValidatedLoss(fns, z.shape[1], sum(len(va) for _, va in folds))


def step_reward_loss(inputs, rewards, folds: Folds) -> CrossValidatedLoss:
    """Cross-validated one-step reward error, Eq. (5.19) summed over folds.

    Parameters
    ----------
    inputs : array_like, shape (N, d)
        State-actions z_i.
    rewards : array_like, shape (N,)
        Successor rewards r'_i.
    folds : sequence of (train_idx, val_idx)
    """
    z = check_array(inputs, "inputs", ndim=2)
    r = check_array(rewards, "rewards", shape=(z.shape[0],))
    fns = []
    folds = _check_folds(folds, z.shape[0])
    for tr, va in folds:
        args = (_t(z[tr]), _t(r[tr]), _t(z[va]), _t(r[va]))
        fns.append(lambda th, a=args: step_reward_error(th, *a))
    return CrossValidatedLoss(fns, z.shape[1], sum(len(va) for _, va in folds))


def trajectory_reward_loss(
    states,
    controls,
    rewards,
    policy,
    reward,
    folds: Folds,
    chunk: int = 8,
    project_initial: bool = True,
) -> CrossValidatedLoss:
    """Cross-validated trajectory reward error, Eq. (5.23), folds over whole trajectories.

    Parameters
    ----------
    states : array_like, shape (M, T, n_x)
        Observed trajectories.
    controls : array_like, shape (M, T, n_u)
        Their (commanded) controls.
    rewards : array_like, shape (M, T)
        Their immediate rewards r(x_t, u_t).
    policy : callable
        ``policy(states, t) -> controls`` as in
        :func:`~skillkit.models.embedding_prediction.predict`, batched over the M
        trajectories: states of shape (1, K, n_x) give controls of shape (M, K, n_u) (row i:
        trajectory i's policy) or (1, K, n_u) if all share one policy.
        Time-invariant (called with t = 1).
    reward : callable
        ``reward(states, controls) -> r`` with shapes (b, K, n_x), (b, K, n_u) → (b, K).
    folds : sequence of (train_idx, val_idx)
        Splits of the M trajectories (e.g. ``kfold_splits(M, 10, rng)``).
    chunk : int
        Validation trajectories (≥ 1) per backward pass (bounds the memory of the
        (chunk, N, N) transition matrices).
    project_initial : bool
        Eq. (5.9)'s first step, as in :func:`trajectory_reward_error`.
    """
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
                f"policy(states, t): expected controls of shape ({m} or 1, "
                f"{xp_tr.shape[0]}, n_u), got {c.shape}"
            )
        c = np.broadcast_to(c, (m,) + c.shape[1:])[va]
        s = np.broadcast_to(xp_tr[None], (len(va),) + xp_tr.shape)
        bases = np.concatenate([s, c], axis=-1)  # (V, N, d)
        basis_r = check_array(reward(s, c), "reward(states, controls)", shape=(len(va), len(s[0])))
        for lo in range(0, len(va), chunk):
            sl = slice(lo, lo + chunk)
            args = (_t(z_tr), _t(z_all[va][sl, 0]), _t(bases[sl]), _t(basis_r[sl]), _t(r[va][sl]))
            fns.append(lambda th, a=args: trajectory_reward_error(th, *a, project_initial))
        n_val += len(va) * (t_len - 1)
    return CrossValidatedLoss(fns, z_all.shape[-1], n_val)


# --------------------------------------------------------------------------- optimisation
@dataclass
class FitResult:
    """Outcome of :func:`fit_hyperparameters`.

    Attributes
    ----------
    lengthscale : ndarray, shape (d,)
        Learned SE length-scales w.
    lam : float
        Learned (or fixed) regulariser λ.
    loss, initial_loss : float
        Cross-validation error per term at the optimum and at the start.
    n_evaluations : int
        Loss/gradient evaluations.
    success : bool
        Whether L-BFGS-B reported convergence.
    message : str
        The optimiser's message.
    at_bound : list of str
        Hyper-parameters that ended on a bound (the optimum may lie beyond it).
    """

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
    learn_lam: bool = True,
    lengthscale_factor: float = 100.0,
    lam_bounds: tuple[float, float] = (1e-6, 1.0),
    max_iter: int = 100,
    lengthscale_reference=None,
) -> FitResult:
    """Minimise a cross-validated embedding error over log length-scales (and log λ).

    Uses L-BFGS-B with the analytic (reverse-mode) gradient; the thesis suggests conjugate
    gradients, any gradient method fits.

    Parameters
    ----------
    loss : CrossValidatedLoss
        From :func:`state_embedding_loss`, :func:`step_reward_loss` or
        :func:`trajectory_reward_loss`.
    lengthscale : float or array_like, shape (d,)
        Initial length-scales (e.g. the inputs' standard deviations).
    lam : float
        Initial (or, with ``learn_lam=False``, fixed) regulariser λ > 0.
    learn_lam : bool
        Optimise λ as well.
    lengthscale_factor : float
        Length-scales are searched in [w_ref / factor, w_ref · factor].
    lam_bounds : (float, float)
        Search interval of λ.
    max_iter : int
        L-BFGS-B iterations.
    lengthscale_reference : float or array_like, shape (d,), optional
        w_ref of the search box (default: the initial ``lengthscale``), so a fit started
        elsewhere (e.g. at another fit's optimum) searches the same box; the initial values
        are clipped into it.

    Returns
    -------
    FitResult
    """
    d = loss.dim
    w0 = np.broadcast_to(check_array(lengthscale, "lengthscale", ndim=(0, 1)), (d,)).copy()
    if np.any(w0 <= 0):
        raise ValueError(f"lengthscale: expected positive values, got {w0}")
    lam = check_positive(lam, "lam")
    lo_l, hi_l = (check_positive(v, "lam_bounds") for v in lam_bounds)
    if not lo_l <= lam <= hi_l:
        raise ValueError(f"lam: expected a value inside lam_bounds {lam_bounds}, got {lam}")
    f = check_positive(lengthscale_factor, "lengthscale_factor")
    ref = w0
    if lengthscale_reference is not None:
        ref = np.broadcast_to(
            check_array(lengthscale_reference, "lengthscale_reference", ndim=(0, 1)), (d,)
        ).copy()
        if np.any(ref <= 0):
            raise ValueError(f"lengthscale_reference: expected positive values, got {ref}")
        w0 = np.clip(w0, ref / f, ref * f)
    bounds = [(np.log(w / f), np.log(w * f)) for w in ref]
    theta0 = np.append(np.log(w0), np.log(lam))

    if learn_lam:

        def fun(th):
            return loss.value_and_grad(th)

        x0, bnds = theta0, bounds + [(np.log(lo_l), np.log(hi_l))]
    else:

        def fun(th):
            v, g = loss.value_and_grad(np.append(th, np.log(lam)))
            return v, g[:d]

        x0, bnds = theta0[:d], bounds

    initial = loss(theta0)
    res = minimize(
        fun, x0, jac=True, method="L-BFGS-B", bounds=bnds, options={"maxiter": int(max_iter)}
    )
    theta = res.x if learn_lam else np.append(res.x, np.log(lam))
    names = [f"lengthscale[{i}]" for i in range(d)] + (["lam"] if learn_lam else [])
    at_bound = [
        n
        for n, v, (lo, hi) in zip(names, res.x, bnds, strict=True)
        if np.isclose(v, lo, atol=1e-6) or np.isclose(v, hi, atol=1e-6)
    ]
    lam_fit = float(np.exp(theta[d])) if learn_lam else lam
    return FitResult(
        lengthscale=np.exp(theta[:d]),
        lam=lam_fit,
        loss=float(res.fun),
        initial_loss=float(initial),
        n_evaluations=int(res.nfev),
        success=bool(res.success),
        message=str(res.message),
        at_bound=at_bound,
    )
