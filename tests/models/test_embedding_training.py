"""Hyper-parameter learning for kernel embeddings (Sec. 5.3, Eqs. 5.15–5.26)."""

import numpy as np
import pytest
import torch
from _tolerances import fp_tol

from skillkit.models.embedding import ConditionalEmbedding
from skillkit.models.embedding_prediction import predict
from skillkit.models.embedding_training import (
    fit_hyperparameters,
    kfold_splits,
    state_embedding_error,
    state_embedding_loss,
    step_reward_error,
    step_reward_loss,
    trajectory_reward_error,
    trajectory_reward_loss,
    transitions,
)
from skillkit.models.kernels import Linear, SquaredExponential, gram


def _se_np(a, b, ls):
    d = (a[:, None, :] - b[None, :, :]) / ls
    return np.exp(-0.5 * (d**2).sum(-1))


def _se_ops(ls, *points):
    """Length of the round-off chain of an SE kernel entry (σ_f² = 1) inside an N-point
    solve: the library's exponent is a (d + 2)-term product of terms up to 2 max‖x/w‖², so
    entries are relatively off by (d + 2) S ε; the factorisation adds N ε (backward error
    |ΔA| ≤ N ε |L||Lᵀ|). Returns N + (d + 2) S with N the first point set's size."""
    S = 2 * max(((p / ls) ** 2).sum(-1).max() for p in points)
    return len(points[0]) + (len(ls) + 2) * S


def _factor(z, ls, lam):
    """G, A⁻¹ and |L||Lᵀ| (the bound on the Cholesky backward error per N ε) of A = G + λI."""
    G = _se_np(z, z, ls)
    A = G + lam * np.eye(len(z))
    L = np.abs(np.linalg.cholesky(A))
    return G, np.linalg.inv(A), L @ L.T


def _solve_bound(z, q, ls, lam, w):
    """First-order |ΔJ| of a J(β), β_v = A⁻¹g(z, q_v), per unit relative perturbation of
    A = G + λI (|ΔA| ≤ |L||Lᵀ|) and of g: with the adjoint u_v = A⁻¹w_v of w_v = ∂J/∂β_v,
    Σ_v |u_v|ᵀ(|L||Lᵀ||β_v| + |g_v|) (no |A⁻¹|, which would count κ(A) in full)."""
    _, iA, LL = _factor(z, ls, lam)
    g = _se_np(z, q, ls)
    return (np.abs(iA @ w) * (LL @ np.abs(iA @ g) + g)).sum()


def _rollout_bound(z, z0, bases, basis_rewards, rewards, ls, lam):
    """|ΔJ| of Eq. 5.23 per unit relative perturbation (as in _solve_bound), to first order,
    by the adjoint of β₁ = A⁻¹GA⁻¹g(z₀), β_{t+1} = A⁻¹G̃β_t: with w_t = ∂J/∂β_t = −2 res_t r'
    and λ_t = w_t + G̃A⁻¹λ_{t+1}, step t+1 adds |A⁻¹λ_{t+1}|ᵀ(|L||Lᵀ||β_{t+1}| + |G̃||β_t|) and
    β₁ its two solves; the N-term r'ᵀβ_t adds 2 |res_t| |r'|ᵀ|β_t|, the sum its terms."""
    G, iA, LL = _factor(z, ls, lam)
    g = _se_np(z, z0, ls)
    alpha = iA @ g
    total = 0.0
    for i, beta1 in enumerate((iA @ G @ alpha).T):
        Gt = _se_np(z, bases[i], ls)
        betas = [beta1]
        for _ in range(2, rewards.shape[1]):
            betas.append(iA @ Gt @ betas[-1])
        res = rewards[i, 1:] - np.array(betas) @ basis_rewards[i]
        total += (res**2).sum() + 2 * np.abs(res) @ (np.abs(betas) @ np.abs(basis_rewards[i]))
        lam_t = np.zeros(len(z))
        for t in range(len(betas) - 1, -1, -1):  # adjoint, backwards
            lam_t = -2 * res[t] * basis_rewards[i] + Gt @ iA @ lam_t
            if t:
                u = np.abs(iA @ lam_t)
                total += u @ (LL @ np.abs(betas[t]) + Gt @ np.abs(betas[t - 1]))
        mu = iA @ lam_t
        nu = iA @ G @ mu
        total += np.abs(mu) @ (LL @ np.abs(beta1) + G @ np.abs(alpha[:, i]))
        total += np.abs(nu) @ (LL @ np.abs(alpha[:, i]) + g[:, i])
    return total


def _central_difference(f, theta, h=1e-6):
    return np.array([(f(theta + h * e) - f(theta - h * e)) / (2 * h) for e in np.eye(theta.size)])


def _rollouts(rng, m=6, t_len=7):
    """Small nonlinear system, one linear feedback policy per trajectory."""
    gains = np.array([[-1.0, -0.5]]) + 0.3 * rng.normal(size=(m, 1, 2))
    x = np.zeros((m, t_len, 2))
    u = np.zeros((m, t_len, 1))
    x[:, 0] = rng.normal(size=(m, 2))
    for t in range(t_len):
        u[:, t] = np.einsum("mij,mj->mi", gains, x[:, t])
        if t < t_len - 1:
            acc = -np.sin(x[:, t, 0]) + u[:, t, 0]
            x[:, t + 1] = x[:, t] + 0.1 * np.stack([x[:, t, 1], acc], -1)
            x[:, t + 1] += 0.01 * rng.normal(size=(m, 2))

    def reward(s, c):
        return -(s**2).sum(-1) - 0.01 * (c**2).sum(-1)

    def policy(s, t):
        return np.einsum("mij,bkj->mki", gains, s)

    return x, u, reward(x, u), policy, reward, gains


# --------------------------------------------------------------------------- folds
@pytest.mark.parametrize("n,k", [(10, 10), (23, 10), (7, 3), (100, 2)])
def test_kfold_splits_partition_the_data(n, k):
    folds = kfold_splits(n, k, rng=3)
    assert len(folds) == k
    vals = np.concatenate([va for _, va in folds])
    np.testing.assert_array_equal(np.sort(vals), np.arange(n))  # disjoint and covering
    for tr, va in folds:
        np.testing.assert_array_equal(np.sort(np.r_[tr, va]), np.arange(n))
        assert np.intersect1d(tr, va).size == 0
        assert abs(len(va) - n / k) < 1
    assert all(
        np.array_equal(a[1], b[1]) for a, b in zip(folds, kfold_splits(n, k, rng=3), strict=True)
    )


def test_kfold_splits_keep_groups_together():
    groups = np.repeat(np.arange(15), 20)
    for tr, va in kfold_splits(groups.size, 10, rng=0, groups=groups):
        assert np.intersect1d(groups[tr], groups[va]).size == 0
        assert len(va) % 20 == 0
    with pytest.raises(ValueError, match="k"):
        kfold_splits(groups.size, 16, groups=groups)
    with pytest.raises(ValueError, match="k"):
        kfold_splits(10, 1)
    with pytest.raises(ValueError, match="groups"):
        kfold_splits(10, 2, groups=np.zeros(9))


def test_transitions_flatten_trajectories():
    x = np.arange(2 * 4 * 2, dtype=float).reshape(2, 4, 2)
    u = -np.arange(2 * 4, dtype=float).reshape(2, 4, 1)
    z, xn, g = transitions(x, u)
    np.testing.assert_array_equal(z[4], np.r_[x[1, 1], u[1, 1]])
    np.testing.assert_array_equal(xn[4], x[1, 2])
    np.testing.assert_array_equal(g, [0, 0, 0, 1, 1, 1])
    with pytest.raises(ValueError, match="controls"):
        transitions(x, u[:, :3])


# --------------------------------------------------------------------------- objectives
def test_objectives_equal_independent_numpy_computations():
    rng = np.random.default_rng(0)
    z, y = rng.normal(size=(20, 3)), rng.normal(size=(20, 2))
    zv, yv = rng.normal(size=(5, 3)), rng.normal(size=(5, 2))
    ls, lam = np.array([0.8, 1.1, 1.5]), 3e-2
    theta = torch.tensor(np.r_[np.log(ls), np.log(lam)])
    beta = np.linalg.solve(_se_np(z, z, ls) + lam * np.eye(20), _se_np(z, zv, ls))
    # Eq. 5.16 with a linear target kernel is the squared error of the mean, with explicit features.
    lin = Linear()
    gy, gyc = gram(lin, y), gram(lin, yv, y)
    value = state_embedding_error(
        theta,
        *(torch.from_numpy(a) for a in (z, zv, gy, gyc, np.diag(gram(lin, yv)))),
    )
    # Cholesky and augmented-product kernel vs LU and direct kernel: two evaluations. Each
    # rounds the expanded Σ g_y(y_v, y_v) − 2 g_yᵀβ + βᵀG_yβ (which cancels) relative to its
    # terms' absolute values, and its β = A⁻¹g, which moves J by at most _solve_bound.
    n_ops = _se_ops(ls, z, zv)
    res = yv - beta.T @ y
    terms = (yv**2).sum() + 2 * np.abs(gyc * beta.T).sum()
    terms += (np.abs(beta) * (np.abs(gy) @ np.abs(beta))).sum()
    scale = terms + _solve_bound(z, zv, ls, lam, -2 * y @ res.T)  # ∂J/∂β_v = −2 y res_v
    np.testing.assert_allclose(float(value), (res**2).sum(), rtol=0, atol=2 * fp_tol(n_ops, scale))
    # Eq. 5.19: the N-term rᵀβ_v moves each squared residual by 2 |res_v| |r|ᵀ|β_v|.
    r, rv = rng.normal(size=20), rng.normal(size=5)
    value = step_reward_error(theta, *(torch.from_numpy(a) for a in (z, r, zv, rv)))
    res = rv - r @ beta
    scale = (res**2).sum() + 2 * np.abs(res) @ (np.abs(r) @ np.abs(beta))
    scale += _solve_bound(z, zv, ls, lam, -2 * r[:, None] * res)  # ∂J/∂β_v = −2 res_v r
    np.testing.assert_allclose(float(value), (res**2).sum(), rtol=0, atol=2 * fp_tol(n_ops, scale))


def test_trajectory_error_equals_prediction_module():
    """Eq. 5.23 uses the same propagation as Table 5.2 (``predict``)."""
    rng = np.random.default_rng(1)
    x, u, r, _, reward, gains = _rollouts(rng)
    ls, lam = np.array([0.9, 1.3, 2.0]), 1e-2
    z, xn, _ = transitions(x[:4], u[:4])
    model = ConditionalEmbedding(z, xn, SquaredExponential(3, lengthscale=ls), lam=lam)
    val_gains = gains[4:]  # (2, n_u, n_x)

    def policy(s, t):
        return np.einsum("bij,bmj->bmi", val_gains, np.broadcast_to(s, (2,) + s.shape[1:]))

    pred = predict(model, x[4:, 0], x.shape[1], policy=policy, reward=reward, time_invariant=True)
    expected = ((r[4:, 1:] - pred.rewards[1:].T) ** 2).sum()
    c = policy(xn[None], 1)
    bases = np.concatenate([np.broadcast_to(xn, (2,) + xn.shape), c], -1)
    data = (z, np.hstack([x[4:, 0], u[4:, 0]]), bases, reward(xn[None], c), r[4:])
    value = trajectory_reward_error(
        torch.tensor(np.r_[np.log(ls), np.log(lam)]),
        *(torch.from_numpy(np.ascontiguousarray(a)) for a in data),
    )
    # gpytorch-module kernels and λ = 1e-2 vs exp(log λ) (one ulp apart) against se_kernel:
    # two evaluations of the 6-step propagation, each within _rollout_bound
    n_ops = _se_ops(ls, z, data[1], *bases)
    tol = 2 * fp_tol(n_ops, scale=_rollout_bound(*data[:3], data[3], r[4:], ls, lam))
    np.testing.assert_allclose(float(value), expected, rtol=0, atol=tol)


def test_one_step_trajectory_error_equals_step_error():
    rng = np.random.default_rng(2)
    z, r = rng.normal(size=(15, 3)), rng.normal(size=15)
    z0, r1 = rng.normal(size=(4, 3)), rng.normal(size=(4, 2))
    theta = torch.tensor([0.1, -0.3, 0.2, np.log(1e-2)])
    bases = torch.from_numpy(rng.normal(size=(4, 15, 3)))
    traj = trajectory_reward_error(
        theta,
        torch.from_numpy(z),
        torch.from_numpy(z0),
        bases,
        torch.from_numpy(np.broadcast_to(r, (4, 15)).copy()),
        torch.from_numpy(r1),
        project_initial=False,  # Eq. 5.23 as printed: β₁ = (G + λI)⁻¹ g(z₀), one step = 5.19
    )
    step = step_reward_error(
        theta,
        torch.from_numpy(z),
        torch.from_numpy(r),
        torch.from_numpy(z0),
        torch.from_numpy(r1[:, 1]),
    )
    # β₁ = (G + λI)⁻¹ g(z₀) is the same computation on both sides; r'ᵀβ (an einsum vs a
    # matrix product, N terms) and the sums of squares may round differently
    ls, lam = np.exp(theta[:3].numpy()), np.exp(theta[3].item())
    beta = np.linalg.solve(_se_np(z, z, ls) + lam * np.eye(15), _se_np(z, z0, ls))
    res = r1[:, 1] - r @ beta
    scale = (res**2).sum() + 2 * np.abs(res) @ (np.abs(r) @ np.abs(beta))
    np.testing.assert_allclose(float(traj), float(step), rtol=0, atol=2 * fp_tol(15, scale))


def _losses(rng):
    x, u, r, policy, reward, _ = _rollouts(rng)
    z, xn, groups = transitions(x, u)
    r_next = r[:, 1:].ravel()
    folds = kfold_splits(z.shape[0], 3, rng=1, groups=groups)
    return {
        "state (5.16)": state_embedding_loss(
            z, xn, folds, SquaredExponential(2, lengthscale=xn.std(0))
        ),
        "step reward (5.19)": step_reward_loss(z, r_next, folds),
        "trajectory reward (5.23)": trajectory_reward_loss(
            x, u, r, policy, reward, kfold_splits(x.shape[0], 3, rng=2), chunk=1
        ),
    }


@pytest.mark.parametrize("name", ["state (5.16)", "step reward (5.19)", "trajectory reward (5.23)"])
def test_gradients_match_finite_differences(name):
    loss = _losses(np.random.default_rng(3))[name]
    for theta in (
        np.array([0.1, -0.2, 0.3, np.log(1e-2)]),
        np.array([-0.5, 0.4, 1.0, np.log(0.2)]),
    ):
        value, grad = loss.value_and_grad(theta)
        # the same fold computations (autograd leaves the forward pass alone), divided by
        # the number of terms per fold or once after the sum of k non-negative fold errors
        tol = 2 * fp_tol(len(loss.folds) + 1)
        np.testing.assert_allclose(value, loss(theta), rtol=tol)
        fd = _central_difference(loss, theta)
        np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-8 * max(1.0, abs(value)))


def test_time_dependent_trajectory_error_gradient():
    rng = np.random.default_rng(4)
    z, z0 = rng.normal(size=(12, 2)), rng.normal(size=(3, 2))
    bases = torch.from_numpy(rng.normal(size=(4, 3, 12, 2)))  # T - 2 = 4 rows
    br = torch.from_numpy(rng.normal(size=(5, 3, 12)))
    rew = torch.from_numpy(rng.normal(size=(3, 6)))

    def f(th):
        return float(
            trajectory_reward_error(
                torch.from_numpy(th), torch.from_numpy(z), torch.from_numpy(z0), bases, br, rew
            )
        )

    theta = np.array([0.2, -0.1, np.log(3e-2)])
    t = torch.tensor(theta, requires_grad=True)
    trajectory_reward_error(t, torch.from_numpy(z), torch.from_numpy(z0), bases, br, rew).backward()
    np.testing.assert_allclose(t.grad.numpy(), _central_difference(f, theta), rtol=1e-5)


# --------------------------------------------------------------------------- fitting
def test_fit_reduces_the_loss_and_finds_the_irrelevant_input():
    """r' depends only on z_0: ARD must give z_1 (pure noise) a much longer length-scale."""
    rng = np.random.default_rng(5)
    z = rng.uniform(-2, 2, size=(60, 2))
    r = np.sin(2.0 * z[:, 0]) + 0.01 * rng.normal(size=60)
    loss = step_reward_loss(z, r, kfold_splits(60, 3, rng=0))
    fit = fit_hyperparameters(loss, lengthscale=[1.0, 1.0], lam=1e-2, max_iter=30)
    assert fit.loss < 0.2 * fit.initial_loss
    assert fit.lengthscale[1] > 5 * fit.lengthscale[0]
    again = fit_hyperparameters(loss, lengthscale=[1.0, 1.0], lam=1e-2, max_iter=30)
    np.testing.assert_array_equal(fit.lengthscale, again.lengthscale)  # deterministic


def test_fit_started_elsewhere_searches_the_reference_box():
    """A warm start keeps the search box of the reference length-scales: [w_ref/f, w_ref·f]."""
    rng = np.random.default_rng(7)
    z = rng.uniform(-2, 2, size=(40, 2))
    loss = step_reward_loss(z, np.sin(2.0 * z[:, 0]), kfold_splits(40, 3, rng=0))
    ref = np.array([1.0, 1.0])
    fit = fit_hyperparameters(
        loss, [500.0, 0.3], lam=1e-2, lengthscale_factor=10.0, max_iter=5, lengthscale_reference=ref
    )
    assert np.all(fit.lengthscale <= 10.0 * (1 + 1e-9)) and np.all(fit.lengthscale >= 0.1)
    assert fit.initial_loss == pytest.approx(loss(np.log([10.0, 0.3, 1e-2])))  # clipped start
    with pytest.raises(ValueError, match="lengthscale_reference"):
        fit_hyperparameters(loss, ref, lengthscale_reference=[1.0, -1.0])


def test_bad_input_raises_naming_the_argument():
    rng = np.random.default_rng(6)
    z, r = rng.normal(size=(20, 2)), rng.normal(size=20)
    folds = kfold_splits(20, 4, rng=0)
    loss = step_reward_loss(z, r, folds)
    with pytest.raises(ValueError, match="theta"):
        loss.value_and_grad(np.zeros(2))
    with pytest.raises(ValueError, match="theta"):
        loss(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="rewards"):
        step_reward_loss(z, r[:19], folds)
    with pytest.raises(ValueError, match="folds"):
        step_reward_loss(z, r, [(np.arange(10), np.arange(15, 25))])
    with pytest.raises(ValueError, match="targets"):
        state_embedding_loss(z, z[:5], folds, SquaredExponential(2))
    with pytest.raises(ValueError, match="lengthscale"):
        fit_hyperparameters(loss, lengthscale=[1.0, -1.0])
    with pytest.raises(ValueError, match="lam"):
        fit_hyperparameters(loss, lengthscale=1.0, lam=0.0)
    with pytest.raises(ValueError, match="lam"):
        fit_hyperparameters(loss, lengthscale=1.0, lam=10.0, lam_bounds=(1e-6, 1.0))


def test_folds_given_once_as_an_iterator_give_the_same_loss():
    """The folds are a sequence read once: an iterator (e.g. a generator over splits) gives the
    loss a list gives, not a loss divided by zero validation terms."""
    rng = np.random.default_rng(8)
    x, u, r, policy, reward, _ = _rollouts(rng)
    z, xn, groups = transitions(x, u)
    folds = kfold_splits(z.shape[0], 3, rng=1, groups=groups)
    theta = np.array([0.1, -0.2, 0.3, np.log(1e-2)])
    kern = SquaredExponential(2, lengthscale=xn.std(0))
    for make in (
        lambda f: state_embedding_loss(z, xn, f, kern),
        lambda f: step_reward_loss(z, r[:, 1:].ravel(), f),
    ):
        listed, once = make(folds), make(iter(folds))
        assert once.n_val == listed.n_val == z.shape[0]
        assert once(theta) == listed(theta) and np.isfinite(listed(theta))


@pytest.mark.parametrize("chunk", [0, -1, 2.5])
def test_trajectory_loss_chunk_must_be_a_positive_integer(chunk):
    """Without the check chunk = -1 would drop every fold (a loss identically 0) and 0 would
    fail inside range()."""
    x, u, r, policy, reward, _ = _rollouts(np.random.default_rng(9))
    with pytest.raises(ValueError, match="chunk: expected an integer"):
        trajectory_reward_loss(x, u, r, policy, reward, kfold_splits(x.shape[0], 3, rng=2), chunk)
