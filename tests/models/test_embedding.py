"""Conditional mean embeddings and kernel trajectory prediction (Secs. 2.4, 5.1, 5.2)."""

import numpy as np
import pytest
import torch
from _tolerances import fp_tol

from skillkit.models.embedding import (
    ConditionalEmbedding,
    initial_weights,
    regularized_cholesky,
    rollout_weights,
)
from skillkit.models.embedding_prediction import predict
from skillkit.models.kernels import Linear, SquaredExponential, gram


def _se(d, ls=1.0):
    return SquaredExponential(d, lengthscale=ls)


def _linear_system(rng, n=400, noise=0.02):
    a = np.array([[0.95, 0.1], [-0.2, 0.9]])
    b = np.array([[0.0], [0.1]])
    x = rng.normal(size=(n, 2))
    u = rng.normal(size=(n, 1))
    xn = x @ a.T + u @ b.T + noise * rng.normal(size=(n, 2))
    return a, b, x, u, xn


def _ridge(inputs, targets, lam):
    """Independent ridge estimate W with targets ≈ W inputs (linear-kernel embedding's map)."""
    z = inputs
    return targets.T @ z @ np.linalg.inv(z.T @ z + lam * np.eye(z.shape[1]))


def _shrink(inputs, lam):
    """Eq. 5.9's first step for a linear kernel, in input space: P = S (S + λI)⁻¹, S = ZᵀZ.

    (G + λI)⁻¹ G (G + λI)⁻¹ Z z₀ = Z (S + λI)⁻¹ S (S + λI)⁻¹ z₀ (push-through identity), so
    the first predicted mean is Ŵ P z₀ and every later one applies Ŵ alone."""
    s = inputs.T @ inputs
    return s @ np.linalg.inv(s + lam * np.eye(s.shape[0]))


def _col_norm(x):
    """Largest column 2-norm of x (N,) or (..., N, B): bounds every entry's error when the
    normwise error of that column is bounded."""
    x = np.asarray(x)
    return float(np.linalg.norm(x, axis=-2).max()) if x.ndim > 1 else float(np.linalg.norm(x))


def _solve_tol(a, x, n_ops=None):
    """Two backward-stable solves of ``a x = b`` (Cholesky vs LU) differ by up to the forward
    error c n ε κ(a) ‖x‖ each (n = ``a``'s order unless ``n_ops`` says otherwise)."""
    return fp_tol(n_ops or a.shape[0], scale=_col_norm(x), cond=np.linalg.cond(a))


def _readout_tol(a, y, betas, n_solves):
    """Round-off of the read-out Yᵀβ where β went through ``n_solves`` backward-stable solves
    with a = G + λI: each has backward error n ε ‖a‖, which reaches Yᵀβ through Yᵀa⁻¹, so
    ‖δ(Yᵀβ)‖ ≲ n ε ‖Yᵀa⁻¹‖ ‖a‖ ‖β‖ per solve (the rollout map (G + λI)⁻¹G is a contraction,
    so errors of earlier steps are not amplified). ‖Yᵀa⁻¹‖ ‖a‖ ≤ κ(a) ‖Y‖ is the read-out's
    condition number; it is far below κ(a) when Y is nearly in the range of G."""
    cond = np.linalg.norm(np.linalg.solve(a, y), 2) * np.linalg.norm(a, 2)
    return fp_tol(n_solves * a.shape[0], scale=_col_norm(betas), cond=cond)


def _step_tol(tol, gain, beta, kappa, n_ops):
    """Round-off of a recursion β_{t+1} = a⁻¹ G̃_t β_t evaluated two ways, after one more
    step: the earlier error ``tol`` amplified by at most ``gain`` = ‖a⁻¹G̃_t‖₂, plus the new
    solve's forward error c n ε κ(a) ‖β_{t+1}‖ (``beta`` = β_{t+1})."""
    return gain * tol + fp_tol(n_ops, scale=_col_norm(beta), cond=kappa)


# --------------------------------------------------------------------------- weights
def test_weights_match_direct_solve():
    rng = np.random.default_rng(0)
    z, y = rng.normal(size=(30, 3)), rng.normal(size=(30, 2))
    k = _se(3, [0.7, 1.2, 0.9])
    m = ConditionalEmbedding(z, y, k, lam=1e-2)
    q = rng.normal(size=(5, 3))
    ref = np.linalg.solve(gram(k, z) + 1e-2 * np.eye(30), gram(k, z, q))  # Eq. 2.39
    a = gram(k, z) + 1e-2 * np.eye(30)  # the cross kernels are the same forward() calls
    np.testing.assert_allclose(m.weights(q), ref, rtol=0, atol=_solve_tol(a, ref))


def test_weights_from_samples_average_the_kernel_vectors():
    rng = np.random.default_rng(1)
    z, y = rng.normal(size=(25, 2)), rng.normal(size=(25, 2))
    m = ConditionalEmbedding(z, y, _se(2), lam=1e-3)
    samples = rng.normal(size=(3, 7, 2))
    beta = m.weights_from_samples(samples)  # Eq. 5.6
    ref = np.stack([m.weights(s).mean(axis=1) for s in samples], axis=1)  # linearity
    # Mean of L = 7 kernel vectors then one solve, vs a solve per sample then the mean: the
    # solves' forward errors (‖x‖ the largest single-sample weights) and the L-term means.
    single = np.concatenate([m.weights(s) for s in samples], axis=1)
    tol = _solve_tol(m.gram + 1e-3 * np.eye(25), single, n_ops=25 + 7)
    np.testing.assert_allclose(beta, ref, rtol=0, atol=tol)
    np.testing.assert_allclose(m.weights_from_samples(samples[0]), ref[:, 0], rtol=0, atol=tol)


def test_apply_is_the_operator_times_alpha_and_composes():
    rng = np.random.default_rng(2)
    x, xn = rng.normal(size=(20, 2)), rng.normal(size=(20, 2))
    m = ConditionalEmbedding(x, xn, _se(2), lam=1e-2)
    alpha = rng.normal(size=(20, 3))
    # solve(a, G̃ α) vs solve(a, G̃) α: the solves' forward errors, c n ε κ(a) ‖C‖ ‖α‖
    # (C = a⁻¹G̃, n = 20), plus the 20-term products; twice that through two steps, the first
    # step's error amplified by ‖C‖.
    c = m.operator(xn)
    kappa, c_norm = np.linalg.cond(m.gram + 1e-2 * np.eye(20)), np.linalg.norm(c, 2)
    tol = fp_tol(2 * 20, scale=c_norm * _col_norm(alpha), cond=kappa)
    np.testing.assert_allclose(m.apply(alpha, xn), c @ alpha, rtol=0, atol=tol)
    # Two steps of Table 5.1 are the product of the operator with itself.
    tol2 = (1 + c_norm) * fp_tol(2 * 20, scale=c_norm**2 * _col_norm(alpha), cond=kappa)
    np.testing.assert_allclose(
        m.apply(m.apply(alpha[:, 0], xn), xn), c @ c @ alpha[:, 0], rtol=0, atol=tol2
    )


def test_expected_value_with_linear_reward_kernel():
    rng = np.random.default_rng(4)
    m = ConditionalEmbedding(rng.normal(size=(10, 2)), rng.normal(size=(10, 2)), _se(2), lam=1e-3)
    r, beta = rng.normal(size=10), rng.normal(size=(10, 4))
    # The same 10-term sums computed another way: ≤ 10 ε Σ|terms| apart (a relative
    # tolerance alone would fail on a sum near 0 by cancellation).
    tol = fp_tol(10, float((np.abs(r) @ np.abs(beta)).max()))
    np.testing.assert_allclose(m.expected(r, beta), r @ beta, rtol=0, atol=tol)
    tol = fp_tol(10, float((np.abs(beta).T @ np.abs(m.targets)).max()))
    np.testing.assert_allclose(m.mean(beta), beta.T @ m.targets, rtol=0, atol=tol)


# --------------------------------------------------------------------------- pre-images
def test_preimage_of_one_hot_beta_is_the_training_point_exactly():
    rng = np.random.default_rng(5)
    y = rng.normal(size=(15, 3))
    m = ConditionalEmbedding(
        rng.normal(size=(15, 2)), y, _se(2), lam=1e-3, target_kernel=_se(3, [0.5, 1.0, 2.0])
    )
    eye = np.eye(15)
    out = m.preimage(eye[:, [0, 7, 14]])
    np.testing.assert_array_equal(out, y[[0, 7, 14]])
    np.testing.assert_array_equal(m.preimage(eye[:, 3] * 0.2), y[3])  # scale invariant


def test_preimage_se_is_a_stationary_maximiser():
    rng = np.random.default_rng(6)
    y = np.vstack([rng.normal(0.0, 0.3, size=(10, 2)), rng.normal(3.0, 0.3, size=(10, 2))])
    kern = _se(2, 1.0)
    m = ConditionalEmbedding(y, y, kern, lam=1e-3)
    beta = np.r_[np.full(10, 0.08), np.full(10, 0.02)]
    x = m.preimage(beta)
    # Independent check of Eq. 2.45: gradient of beta^T k(x) vanishes, and x beats every y_j.
    xt = torch.tensor(x, requires_grad=True)
    score = (
        torch.exp(-0.5 * ((xt - torch.from_numpy(y)) ** 2).sum(1)) * torch.from_numpy(beta)
    ).sum()
    score.backward()
    assert float(xt.grad.norm()) < 1e-8
    assert float(score.detach()) >= float((gram(kern, y) @ beta).max()) - 1e-12
    assert np.linalg.norm(x) < 1.0  # the heavier cluster around the origin wins


def test_preimage_linear_kernel_is_closed_form():
    rng = np.random.default_rng(7)
    y = rng.normal(size=(9, 2))
    m = ConditionalEmbedding(rng.normal(size=(9, 2)), y, Linear(variance=2.0, bias=0.5), lam=1e-3)
    beta = rng.normal(size=(9, 3))
    tol = fp_tol(9, float((np.abs(beta).T @ np.abs(y)).max()))  # 9-term sums, see above
    np.testing.assert_allclose(m.preimage(beta), beta.T @ y, rtol=0, atol=tol)


def test_preimage_reports_negative_weight_mass():
    rng = np.random.default_rng(8)
    y = rng.normal(size=(6, 2))
    m = ConditionalEmbedding(y, y, _se(2), lam=1e-3)
    with pytest.warns(RuntimeWarning, match="stopped early for 1 of 2"):
        out = m.preimage(np.stack([-np.eye(6)[2], np.eye(6)[1]], axis=1))
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[1], y[1])


# --------------------------------------------------------------------------- prediction
def test_linear_kernel_fixed_policy_mean_equals_closed_form():
    """Table 5.1 with a linear kernel on x' = A x + noise: E[x_t] = Â^t x_0 (ridge Â), and Â → A."""
    rng = np.random.default_rng(9)
    a, _, x, _, _ = _linear_system(rng)
    xn = x @ a.T + 0.02 * rng.normal(size=x.shape)
    lam = 1e-3
    m = ConditionalEmbedding(x, xn, Linear(), lam=lam)
    x0 = np.array([[1.0, -0.5], [0.2, 0.8]])
    pred = predict(m, x0, n_steps=12)
    a_hat = _ridge(x, xn, lam)
    ref = [x0, x0 @ (a_hat @ _shrink(x, lam)).T]
    for _ in range(10):
        ref.append(ref[-1] @ a_hat.T)
    # 11 solves with G + λI (κ ≈ 4e5: rank-2 linear Gram, λ = 1e-3) read out through Yᵀ;
    # the ridge reference (2×2 inverses) is exact by comparison.
    tol = _readout_tol(m.gram + lam * np.eye(400), xn, pred.betas, n_solves=11)  # ~1e-7
    np.testing.assert_allclose(pred.means(m), np.array(ref), rtol=0, atol=tol)
    np.testing.assert_allclose(pred.preimages(m), np.array(ref), rtol=0, atol=tol)
    # The closed-form mean of the true linear-Gaussian system, within the estimation error.
    true = [x0]
    for _ in range(11):
        true.append(true[-1] @ a.T)
    assert np.abs(pred.means(m) - np.array(true)).max() < 0.02


def test_linear_kernel_initial_samples_propagate_their_mean():
    rng = np.random.default_rng(10)
    a, _, x, _, _ = _linear_system(rng)
    xn = x @ a.T
    m = ConditionalEmbedding(x, xn, Linear(), lam=1e-9)
    samples = rng.normal(size=(1, 50, 2)) + np.array([0.5, -1.0])
    pred = predict(m, samples, n_steps=5)
    mean0 = samples[0].mean(axis=0)
    expected = np.stack([mean0 @ np.linalg.matrix_power(a, t).T for t in range(5)])
    np.testing.assert_allclose(pred.means(m)[:, 0], expected, atol=1e-7)


def test_linear_kernel_with_policy_equals_closed_form_per_query():
    """Table 5.2 / Eq. 5.14: z = [x, u], one linear policy u = K_b x per query b."""
    rng = np.random.default_rng(11)
    _, _, x, u, xn = _linear_system(rng)
    lam = 1e-3
    m = ConditionalEmbedding(np.hstack([x, u]), xn, Linear(), lam=lam)
    gains = np.array([[[-1.0, -0.5]], [[-3.0, -1.0]], [[0.0, 0.0]]])  # (B, n_u, n_x)

    def policy(states, t):
        return (
            np.einsum("bij,kmj->bmi", gains, states)
            if states.shape[0] == 1
            else np.einsum("bij,bmj->bmi", gains, states)
        )

    def reward(states, controls):
        return -(states**2).sum(-1) - 0.1 * (controls**2).sum(-1)

    x0 = np.array([[1.0, 0.0], [0.5, -0.5], [-1.0, 1.0]])
    pred = predict(m, x0, n_steps=8, policy=policy, reward=reward, time_invariant=True)
    w = _ridge(np.hstack([x, u]), xn, lam)
    z_shrink = _shrink(np.hstack([x, u]), lam)
    for b in range(3):
        closed = w[:, :2] + w[:, 2:] @ gains[b]
        ref = [x0[b], w @ z_shrink @ np.r_[x0[b], gains[b] @ x0[b]]]
        for _ in range(6):
            ref.append(closed @ ref[-1])
        a = m.gram + lam * np.eye(400)  # κ ≈ 4e5 as above; 7 solves
        tol = _readout_tol(a, xn, pred.betas[:, :, b], n_solves=7)
        np.testing.assert_allclose(pred.means(m)[:, b], np.array(ref), rtol=0, atol=tol)
    # Rewards: row 0 exact, rows t >= 1 equal r'^T beta_t with r' evaluated under the policy.
    np.testing.assert_allclose(pred.rewards[0], reward(x0[:, None], policy(x0[:, None], 0))[:, 0])
    r_basis = reward(np.broadcast_to(xn, (3,) + xn.shape), policy(xn[None], 1))  # (B, N)
    for t in range(1, 8):
        beta_t = pred.betas[t - 1]  # N = 400-term sums: ≤ 400 ε Σ|terms|
        tol = fp_tol(400, scale=float(np.einsum("bn,nb->b", np.abs(r_basis), np.abs(beta_t)).max()))
        np.testing.assert_allclose(
            pred.rewards[t], np.einsum("bn,nb->b", r_basis, beta_t), rtol=0, atol=tol
        )


def test_time_dependent_policy_matches_manual_recursion():
    rng = np.random.default_rng(12)
    _, _, x, u, xn = _linear_system(rng, n=60)
    k = _se(3, [1.0, 1.5, 2.0])
    m = ConditionalEmbedding(np.hstack([x, u]), xn, k, lam=1e-3)

    def policy(states, t):
        return np.sin(0.3 * t) * states[..., :1] - 0.5 * states[..., 1:]

    x0 = rng.normal(size=(2, 2))
    pred = predict(m, x0, n_steps=5, policy=policy)
    z0 = np.hstack([x0, policy(x0[None], 0)[0]])
    g = gram(k, m.inputs)
    a = g + 1e-3 * np.eye(60)
    alpha = np.linalg.solve(a, gram(k, m.inputs, z0))  # Eq. 5.6
    beta = np.linalg.solve(a, g @ alpha)  # Eq. 5.9
    # Cholesky (predict) vs LU (here) solves, κ(a) ≈ 3e4, each step's error amplified by
    # ‖a⁻¹G̃_t‖ in the next; β₁ from two solves, the first through a⁻¹G (‖·‖ ≤ 1).
    kappa, gain = np.linalg.cond(a), 1.0
    tol = fp_tol(60, scale=_col_norm(alpha), cond=kappa)
    for t in range(1, 5):
        tol = _step_tol(tol, gain, beta, kappa, 60)
        np.testing.assert_allclose(pred.betas[t - 1], beta, rtol=0, atol=tol)
        basis = np.hstack([xn, policy(xn[None], t)[0]])
        op = np.linalg.solve(a, gram(k, m.inputs, basis))
        gain = np.linalg.norm(op, 2)
        beta = np.linalg.solve(a, gram(k, m.inputs, basis) @ beta)


def test_initial_weights_are_eq_5_9_by_explicit_inverses():
    """β₁ = (G + λI)⁻¹ G (G + λI)⁻¹ ḡ with ḡ the kernel vector averaged over the samples."""
    rng = np.random.default_rng(15)
    z, samples = rng.normal(size=(25, 3)), rng.normal(size=(2, 7, 3))
    k, lam = _se(3, [0.8, 1.3, 1.1]), 5e-2
    g = gram(k, z)
    inv = np.linalg.inv(g + lam * np.eye(25))
    mean_k = np.stack([gram(k, z, s).mean(axis=1) for s in samples], axis=1)  # (N, B)
    chol = regularized_cholesky(torch.from_numpy(g), lam)
    got = initial_weights(chol, torch.from_numpy(g), torch.from_numpy(mean_k)).numpy()
    # Explicit inverses (forward error c n ε κ ‖a⁻¹‖ each) vs Cholesky solves, κ(a) ≈ 94:
    # scales ‖a⁻¹‖ ‖ḡ‖ (one inverse) and ‖a⁻¹‖² ‖G‖ ‖ḡ‖ (two, with the product by G).
    kappa, inv_norm = np.linalg.cond(g + lam * np.eye(25)), np.linalg.norm(inv, 2)
    scale1 = inv_norm * _col_norm(mean_k)
    scale2 = inv_norm * np.linalg.norm(g, 2) * scale1
    tol1, tol2 = fp_tol(25, scale1, kappa), fp_tol(3 * 25, scale2, kappa)
    np.testing.assert_allclose(got, inv @ g @ inv @ mean_k, rtol=0, atol=tol2)
    direct = initial_weights(chol, torch.from_numpy(g), torch.from_numpy(mean_k), project=False)
    np.testing.assert_allclose(direct.numpy(), inv @ mean_k, rtol=0, atol=tol1)
    # predict's first row is this β₁; with project_initial=False it is Eq. 5.7's weights.
    # Same factor and solves; the kernel vectors' L = 7-term means (torch vs numpy) may be
    # summed in another order: 7 ε ‖ḡ‖ through the same maps.
    m = ConditionalEmbedding(z, np.tanh(z), k, lam=lam)
    tol1, tol2 = fp_tol(7 + 25, scale1, kappa), fp_tol(7 + 2 * 25, scale2, kappa)
    np.testing.assert_allclose(predict(m, samples, 3).betas[0], got, rtol=0, atol=tol2)
    np.testing.assert_allclose(
        predict(m, samples, 3, project_initial=False).betas[0],
        m.weights_from_samples(samples),
        rtol=0,
        atol=tol1,
    )


def test_initial_projection_differs_from_eq_5_7_by_lam_times_a_solve():
    """(G + λI)⁻¹ G α = α − λ (G + λI)⁻¹ α exactly: "β₂ = β₁ for sufficiently small λ"."""
    rng = np.random.default_rng(16)
    z = rng.normal(size=(20, 2))
    g = torch.from_numpy(gram(_se(2, 2.0), z))
    cross = torch.from_numpy(gram(_se(2, 2.0), z, rng.normal(size=(3, 2))))
    for lam in (1e-1, 1e-3):
        chol = regularized_cholesky(g, lam)
        a = initial_weights(chol, g, cross, project=False)
        b = initial_weights(chol, g, cross)
        torch.testing.assert_close(b, a - lam * torch.cholesky_solve(a, chol))


def test_rollout_weights_per_query_transitions_match_columnwise():
    rng = np.random.default_rng(13)
    g = torch.from_numpy(gram(_se(2), rng.normal(size=(8, 2))))
    chol = regularized_cholesky(g, 1e-2)
    trans = torch.from_numpy(rng.uniform(size=(3, 8, 8)))
    beta1 = torch.from_numpy(rng.normal(size=(8, 3)))
    both = rollout_weights(chol, beta1, trans, 4)
    a = g.numpy() + 1e-2 * np.eye(8)
    kappa = np.linalg.cond(a)
    for b in range(3):
        single = rollout_weights(chol, beta1[:, b : b + 1], trans[b], 4)
        # Batched einsum vs matrix product, and solves on a block vs one column, per step: an
        # 8-term product, 8 ε ‖a⁻¹‖ ‖G̃‖ ‖β_t‖ after the solve, and the solve's forward error
        # 8 ε κ ‖β_{t+1}‖; both ≤ 8 ε κ ‖a⁻¹G̃‖ ‖β_t‖ (‖G̃‖ ≤ ‖a‖ ‖a⁻¹G̃‖). Earlier errors
        # are amplified by ‖a⁻¹G̃‖ each step.
        gain = np.linalg.norm(np.linalg.solve(a, trans[b].numpy()), 2)
        tol = np.zeros(4)
        for t in range(1, 4):
            prev = single[t - 1].numpy()
            step = fp_tol(2 * 8, scale=gain * _col_norm(prev), cond=kappa)
            tol[t] = gain * tol[t - 1] + step
        err = (both[:, :, b] - single[:, :, 0]).abs().amax(dim=1).numpy()
        assert np.all(err <= tol), (err, tol)


def test_prediction_is_deterministic():
    rng = np.random.default_rng(14)
    x = rng.normal(size=(40, 2))
    m = ConditionalEmbedding(x, np.tanh(x), _se(2), lam=1e-3)
    x0 = rng.normal(size=(3, 2))
    a, b = predict(m, x0, 6).preimages(m), predict(m, x0, 6).preimages(m)
    np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------- bad input
def test_bad_input_raises_naming_the_argument():
    rng = np.random.default_rng(15)
    z, y = rng.normal(size=(10, 2)), rng.normal(size=(10, 2))
    for lam in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="lam"):
            ConditionalEmbedding(z, y, _se(2), lam=lam)
    with pytest.raises(ValueError, match="targets"):
        ConditionalEmbedding(z, y[:9], _se(2))
    bad = z.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="inputs"):
        ConditionalEmbedding(bad, y, _se(2))
    m = ConditionalEmbedding(z, y, _se(2), lam=1e-3)
    with pytest.raises(ValueError, match="queries"):
        m.weights(rng.normal(size=(4, 3)))
    with pytest.raises(ValueError, match="queries"):
        m.weights(np.array([[np.inf, 0.0]]))
    with pytest.raises(ValueError, match="samples"):
        m.weights_from_samples(rng.normal(size=(5, 1)))
    with pytest.raises(ValueError, match="basis"):
        m.apply(np.ones(4), rng.normal(size=(4, 5)))
    with pytest.raises(ValueError, match="alpha"):
        m.apply(np.ones(3), rng.normal(size=(4, 2)))
    with pytest.raises(ValueError, match="beta"):
        m.preimage(np.ones(9))
    with pytest.raises(ValueError, match="values"):
        m.expected(np.ones(11), np.ones(10))
    with pytest.raises(ValueError, match="initial"):
        predict(m, rng.normal(size=(2, 3)), 4)
    with pytest.raises(ValueError, match="n_steps"):
        predict(m, rng.normal(size=(2, 2)), 1)
    sa = ConditionalEmbedding(rng.normal(size=(10, 3)), y, _se(3), lam=1e-3)
    with pytest.raises(ValueError, match="policy"):
        predict(sa, rng.normal(size=(2, 2)), 4)
    with pytest.raises(ValueError, match="policy"):
        predict(sa, rng.normal(size=(2, 2)), 4, policy=lambda s, t: np.zeros(s.shape[:-1] + (2,)))
    with pytest.raises(ValueError, match="target_kernel"):
        sa.preimage(np.ones(10))
    with pytest.raises(np.linalg.LinAlgError, match="lam"):
        regularized_cholesky(-torch.eye(3, dtype=torch.float64), 1e-3)


@pytest.mark.parametrize("n_steps", [2.7, "5", None])
def test_n_steps_must_be_an_integer(n_steps):
    """Without the check 2.7 rows would become 2 silently (int()) and a string or None would
    fail elsewhere."""
    rng = np.random.default_rng(16)
    x = rng.normal(size=(10, 2))
    m = ConditionalEmbedding(x, np.tanh(x), _se(2), lam=1e-3)
    with pytest.raises(ValueError, match="n_steps: expected an integer"):
        predict(m, x[:2], n_steps)
    assert len(predict(m, x[:2], np.int64(3)).betas) == 2  # rows 1 and 2


@pytest.mark.parametrize("n_steps", [0, -2, 1.5])
def test_rollout_weights_n_steps_must_be_a_positive_integer(n_steps):
    """Without the check n_steps = 0 would return one weight vector (shape (1, N, B), not
    (0, N, B))."""
    chol = torch.eye(3, dtype=torch.float64)
    beta = torch.ones((3, 2), dtype=torch.float64)
    with pytest.raises(ValueError, match="n_steps: expected an integer"):
        rollout_weights(chol, beta, torch.eye(3, dtype=torch.float64), n_steps)
    assert rollout_weights(chol, beta, torch.eye(3, dtype=torch.float64), 1).shape == (1, 3, 2)
