"""CrKR (Eqs. 2.19–2.20): predictions vs the textbook formulas, numerics, sampling, bad input."""

import numpy as np
import pytest
from _tolerances import fp_tol

from skillkit.models.kernels import Linear, SquaredExponential, gram
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.base import Batch
from skillkit.search.crkr import CrKR, CrKRPolicy
from skillkit.search.rwr import rwr_beta, rwr_weights


def kernels():
    return [
        SquaredExponential(2, lengthscale=[0.7, 1.3], outputscale=0.8),
        Linear(variance=0.5, bias=1.0),
    ]


def data(seed, n=30, d=3):
    rng = np.random.default_rng(seed)
    s = rng.uniform(-1, 1, size=(n, 2))
    w = rng.normal(size=(n, d))
    return s, w, rng.uniform(0.05, 1.0, size=n)


def _solve_tols(A, kq, rhs, kss):
    """Round-off of the mean kᵀA⁻¹y (Eq. 2.19) and the variance k** + λ − kᵀA⁻¹k (Eq. 2.20),
    one evaluation: a factorisation or inverse of the N×N matrix A (forward error N ε κ(A)) and
    N-term sums, relative to the sums' absolute terms |k|ᵀ|A⁻¹y| and k** + λ + |k|ᵀ|A⁻¹||k|
    (``kss`` includes λ); absolute."""
    iA, n, kappa = np.linalg.inv(A), len(A), np.linalg.cond(A)
    mean_scale = (np.abs(kq).T @ np.abs(iA @ rhs)).max()
    var_scale = (kss + np.einsum("ij,ik,kj->j", np.abs(kq), np.abs(iA), np.abs(kq))).max()
    return fp_tol(n, scale=mean_scale, cond=kappa), fp_tol(n, scale=var_scale, cond=kappa)


@pytest.mark.parametrize("kernel", kernels(), ids=["se", "linear"])
def test_predictions_equal_eqs_2_19_and_2_20(kernel):
    s, w, weights = data(0)
    prior = LinearGaussianPolicy(np.zeros(3), np.eye(3), context_dim=2)  # zero prior mean
    lam = 0.3
    pol = CrKRPolicy(prior, kernel, s, w, weights, lam)
    q = np.random.default_rng(1).uniform(-1.5, 1.5, size=(6, 2))
    K, k = gram(kernel, s), gram(kernel, s, q)
    C = np.diag(1.0 / (weights / weights.max()))  # C = W^-1 (any common scale of w is absorbed)
    inv = np.linalg.inv(K + lam * C)
    # Cholesky of W^½ K W^½ + λI vs the explicit inverse of K + λC (the worse conditioned of
    # the two): each within the bound.
    kss = np.diag(gram(kernel, q)) + lam
    mean_tol, var_tol = (2 * t for t in _solve_tols(K + lam * C, k, w, kss))
    np.testing.assert_allclose(pol.mean_of(q), k.T @ inv @ w, rtol=0, atol=mean_tol)  # Eq. 2.19
    var = np.diag(gram(kernel, q)) + lam - np.einsum("ij,ik,kj->j", k, inv, k)  # Eq. 2.20
    np.testing.assert_allclose(pol.variance_of(q), var, rtol=0, atol=var_tol)
    assert pol.mean_of(q[0]).shape == (3,) and isinstance(pol.variance_of(q[0]), float)


def test_prior_mean_is_added_to_the_residual_regression():
    s, w, weights = data(2)
    kernel = kernels()[0]
    prior = LinearGaussianPolicy(
        np.array([1.0, -1.0, 0.5]), np.eye(3), np.ones((3, 2)), context_dim=2
    )
    zero = LinearGaussianPolicy(np.zeros(3), np.eye(3), context_dim=2)
    q = np.array([[0.2, -0.4], [5.0, 5.0]])
    shifted = CrKRPolicy(prior, kernel, s, w, weights, 0.1)
    plain = CrKRPolicy(zero, kernel, s, w - prior.mean_of(s), weights, 0.1)
    # Same residuals w − μ_prior(s) (a zero prior's mean is exactly 0), so the same α and
    # W^½ k: μ_prior(q) + kᵀα on both sides, equal by construction.
    np.testing.assert_array_equal(shifted.mean_of(q), plain.mean_of(q) + prior.mean_of(q))
    # far from the data (SE kernel): back to the prior mean, variance k(s,s) + λ
    np.testing.assert_allclose(shifted.mean_of(q[1]), prior.mean_of(q[1]), atol=1e-8)
    assert shifted.variance_of(q[1]) == pytest.approx(0.8 + 0.1, rel=1e-8)


def test_zero_weight_samples_drop_out_and_variance_is_at_least_lambda():
    s, w, weights = data(3)
    kernel = kernels()[1]
    prior = LinearGaussianPolicy(np.zeros(3), np.eye(3), context_dim=2)
    rewards = np.zeros(30)
    rewards[:5] = -1e6  # exp(β ΔR) underflows to exactly 0: infinite cost
    p = rwr_weights(rewards, 1.0)
    assert np.all(p[:5] == 0)
    full = CrKRPolicy(prior, kernel, s, w, p, 0.2)
    kept = CrKRPolicy(prior, kernel, s[5:], w[5:], p[5:], 0.2)
    q = np.random.default_rng(4).uniform(-1, 1, size=(5, 2))
    # The zero-weight rows of W^½ K W^½ + λI are λ on the diagonal and exactly 0 elsewhere,
    # but a 30×30 and a 25×25 Cholesky split their blocks differently: each within the bound.
    u = np.sqrt(p[5:] / p.max())
    A = u[:, None] * gram(kernel, s[5:]) * u + 0.2 * np.eye(25)
    kss = np.diag(gram(kernel, q)) + 0.2
    kq = u[:, None] * gram(kernel, s[5:], q)
    mean_tol, var_tol = (2 * t for t in _solve_tols(A, kq, u[:, None] * w[5:], kss))
    np.testing.assert_allclose(full.mean_of(q), kept.mean_of(q), rtol=0, atol=mean_tol)
    np.testing.assert_allclose(full.variance_of(q), kept.variance_of(q), rtol=0, atol=var_tol)
    assert np.all(full.variance_of(q) >= 0.2 - 1e-12)


def test_linear_kernel_recovers_a_linear_map():
    rng = np.random.default_rng(5)
    s = rng.uniform(-1, 1, size=(200, 2))
    a, A = np.array([1.0, -0.5]), np.array([[0.5, -0.3], [0.2, 0.8]])
    w = a + s @ A.T
    prior = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2)
    pol = CrKRPolicy(prior, Linear(variance=1.0, bias=1.0), s, w, np.ones(200), 1e-6)
    q = rng.uniform(-1, 1, size=(10, 2))
    np.testing.assert_allclose(pol.mean_of(q), a + q @ A.T, atol=1e-5)


def test_algorithm_update_sampling_and_determinism():
    prior = LinearGaussianPolicy(np.zeros(2), 0.25 * np.eye(2), context_dim=2)

    def run(seed):
        rng = np.random.default_rng(seed)
        crkr = CrKR(prior, Linear(0.25, 0.25), lam=0.01, beta_scale=1.0, n_reuse_batches=2)
        assert crkr.policy is prior  # before the first update
        diags = []
        for _ in range(3):
            s = rng.uniform(-1, 1, size=(15, 2))
            w = crkr.policy.sample(s, rng)
            r = -np.sum((w - 1.0) ** 2, axis=1)
            diags.append(crkr.update(Batch(s, w, r)))
        return crkr, diags, r

    crkr, diags, r = run(0)
    assert isinstance(crkr.policy, CrKRPolicy)
    assert [d.n_samples for d in diags] == [15, 30, 30]
    assert diags[-1].mean_reward == pytest.approx(r.mean())
    assert diags[0].beta > 0 and 1 <= diags[0].ess <= 15
    q = np.array([[0.1, 0.2], [0.3, -0.3]])
    assert crkr.policy.sample(q, 0).shape == (2, 2) and crkr.policy.sample(q[0], 0).shape == (2,)
    np.testing.assert_array_equal(crkr.policy.sample(q, 3), run(0)[0].policy.sample(q, 3))
    # samples have mean μ(s) and variance σ²(s) · variance_scale
    scaled = CrKRPolicy(
        prior,
        Linear(0.25, 0.25),
        np.zeros((3, 2)),
        np.zeros((3, 2)),
        np.ones(3),
        0.5,
        variance_scale=[1.0, 4.0],
    )
    draws = scaled.sample(np.tile(q[0], (40_000, 1)), 1)
    var = scaled.variance_of(q[0])
    # 5 Monte Carlo standard errors of 40,000 normal draws: sample variance rel. SE √(2/n),
    # sample mean SE √(var · scale / n) (compared in units of the draws' standard deviation)
    n = draws.shape[0]
    np.testing.assert_allclose(draws.var(axis=0), [var, 4 * var], rtol=5 * np.sqrt(2 / n))
    z = (draws.mean(axis=0) - scaled.mean_of(q[0])) / np.sqrt(var * np.array([1.0, 4.0]))
    np.testing.assert_allclose(z, 0.0, atol=5 / np.sqrt(n))
    assert rwr_beta(r, 1.0) > 0


def test_bad_input_names_the_argument():
    prior = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2)
    k = Linear(1.0)
    with pytest.raises(ValueError, match="lam"):
        CrKR(prior, k, lam=0.0)
    with pytest.raises(ValueError, match="beta_scale"):
        CrKR(prior, k, beta_scale=-1.0)
    with pytest.raises(ValueError, match="prior"):
        CrKR("prior", k)
    crkr = CrKR(prior, k)
    with pytest.raises(ValueError, match="rewards"):
        crkr.update(Batch(np.zeros((3, 2)), np.zeros((3, 2)), [0.0, np.inf, 1.0]))
    with pytest.raises(ValueError, match="contexts"):
        crkr.update(Batch(np.zeros((3, 1)), np.zeros((3, 2)), np.zeros(3)))
    with pytest.raises(ValueError, match="omegas"):
        crkr.update(Batch(np.zeros((3, 2)), np.zeros((3, 4)), np.zeros(3)))
    with pytest.raises(ValueError, match="weights"):
        CrKRPolicy(prior, k, np.zeros((3, 2)), np.zeros((3, 2)), [1.0, -1.0, 1.0], 1.0)
    with pytest.raises(ValueError, match="variance_scale"):
        CrKRPolicy(
            prior, k, np.zeros((3, 2)), np.zeros((3, 2)), np.ones(3), 1.0, variance_scale=[1.0, 0.0]
        )
    pol = CrKRPolicy(prior, k, np.zeros((3, 2)), np.zeros((3, 2)), np.ones(3), 1.0)
    with pytest.raises(ValueError, match="contexts"):
        pol.mean_of(np.zeros((2, 3)))
