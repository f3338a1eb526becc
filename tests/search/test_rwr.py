"""Contextual RWR (Eq. 2.18): weights, the β rule, the weighted regression, bad input."""

import numpy as np
import pytest
from _tolerances import fp_tol

from skillkit.policies.features import context_features
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.base import Batch
from skillkit.search.rwr import RWR, rwr_beta, rwr_weights


def test_weights_are_normalised_exponentials():
    r = np.array([-3.0, -1.0, 0.5, 2.0])
    w = rwr_weights(r, 0.7)
    # exp(x) carries a relative error of eps·|x| from the rounding of its argument: |0.7 r| ≤ 2.1
    # here, |0.7 (r − max r)| ≤ 3.5 in the library's shifted form, then a sum of 4 terms.
    tol = fp_tol(4, cond=1 + 2.1 + 3.5)
    np.testing.assert_allclose(w, np.exp(0.7 * r) / np.exp(0.7 * r).sum(), rtol=tol)
    # shift invariant: r + 1e8 is exact (ulp(1e8) = 1.5e-8 divides the half-integers), so the
    # shifted arguments r − max r are the same numbers (a shift that rounds would cost 0.7 ulp)
    # and the weights are bitwise equal
    np.testing.assert_array_equal(rwr_weights(r + 1e8, 0.7), w)
    np.testing.assert_allclose(rwr_weights(r, 0.0), np.full(4, 0.25))
    huge = rwr_weights(np.array([0.0, -1e6, -2e6]), 1.0)  # exp(-1e6) underflows to 0 cleanly
    np.testing.assert_array_equal(huge, [1.0, 0.0, 0.0])


def test_beta_rule_is_scale_invariant():
    r = np.random.default_rng(0).normal(size=20)
    assert rwr_beta(r, 2.0) == pytest.approx(2.0 / r.std())
    for scale in (1e-6, 1e6):
        np.testing.assert_allclose(
            rwr_weights(scale * r, rwr_beta(scale * r, 2.0)),
            rwr_weights(r, rwr_beta(r, 2.0)),
            rtol=1e-9,
        )
    assert rwr_beta(np.ones(5)) == 0.0


def test_update_is_weighted_regression_of_eq_2_18():
    rng = np.random.default_rng(1)
    pol = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2, features="quadratic")
    rwr = RWR(pol, beta_scale=1.5, ridge=0.0, cov_floor=1e-12)
    s = rng.uniform(-1, 1, size=(40, 2))
    w = pol.sample(s, rng)
    r = -np.sum((w - s) ** 2, axis=1)
    d = rwr.update(Batch(s, w, r))
    beta = 1.5 / r.std()
    p = np.exp(beta * (r - r.max()))
    Phi = np.column_stack([np.ones(40), context_features(s, "quadratic")])
    W = np.diag(p)
    M = Phi.T @ W @ Phi
    A = np.linalg.solve(M, Phi.T @ W @ w)  # Eq. 2.18 with a bias feature
    # uncentred normal equations vs the library's centred solve, two evaluations: each forms
    # 40-row weighted sums and solves, forward error 40 ε κ(ΦᵀWΦ) ‖A‖ (κ ≈ 45, ‖A‖ ≈ 1.2)
    tol = 2 * fp_tol(40, scale=np.linalg.norm(A, 2), cond=np.linalg.cond(M))
    np.testing.assert_allclose(rwr.policy.coefficients, A.T, rtol=0, atol=tol)
    assert d.beta == pytest.approx(beta)
    q = p / p.sum()
    assert d.kl == pytest.approx(np.sum(q * np.log(40 * q)))
    assert d.ess == pytest.approx(1 / np.sum(q**2))
    assert d.n_samples == 40 and d.policy_kl > 0


def test_improves_on_a_contextual_bowl_and_is_deterministic():
    def run(seed):
        rng = np.random.default_rng(seed)
        rwr = RWR(
            LinearGaussianPolicy(np.zeros(1), np.eye(1), context_dim=1), 1.0, n_reuse_batches=3
        )
        for _ in range(30):
            s = rng.uniform(-1, 1, size=(25, 1))
            w = rwr.policy.sample(s, rng)
            rwr.update(Batch(s, w, -((w - (1 + 2 * s)) ** 2).ravel()))
        return rwr.policy.coefficients

    c = run(0)
    np.testing.assert_array_equal(c, run(0))
    assert np.linalg.norm(c - [[1.0, 2.0]]) < 0.1  # from an initial error of √5


def test_bad_input_names_the_argument():
    pol = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=1)
    with pytest.raises(ValueError, match="beta_scale"):
        RWR(pol, beta_scale=0.0)
    with pytest.raises(ValueError, match="policy"):
        RWR(None)
    with pytest.raises(ValueError, match="beta"):
        rwr_weights([1.0, 2.0], -1.0)
    rwr = RWR(pol)
    with pytest.raises(ValueError, match="rewards"):
        rwr.update(Batch(np.zeros((5, 1)), np.zeros((5, 2)), [0, 1, np.nan, 2, 3]))
    with pytest.raises(ValueError, match="contexts"):
        rwr.update(Batch(np.zeros((5, 2)), np.zeros((5, 2)), np.zeros(5)))
    with pytest.raises(ValueError, match="omegas"):
        rwr.update(Batch(np.zeros((5, 1)), np.zeros((5, 1)), np.zeros(5)))


def test_beta_of_no_rewards_is_refused():
    # not β = 0 (uniform weights) for an empty reward array
    with pytest.raises(ValueError, match=r"rewards: expected at least one sample"):
        rwr_beta(np.zeros(0))
    assert rwr_beta(np.full(3, 2.0)) == 0.0  # equal rewards: uniform weights, as documented
