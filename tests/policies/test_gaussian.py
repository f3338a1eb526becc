"""Upper-level Gaussian policies: density, sampling, KL, weighted ML (Eqs. 3.11–3.13)."""

import numpy as np
import pytest
from _tolerances import fp_tol
from scipy import stats

from skillkit.policies.features import context_features
from skillkit.policies.gaussian import GaussianPolicy, LinearGaussianPolicy, effective_sample_size


def random_spd(rng, d, scale=1.0):
    m = rng.normal(size=(d, d))
    return scale * (m @ m.T / d + 0.5 * np.eye(d))


def random_policy(rng, d=3, s_dim=2, features="linear"):
    n_feat = context_features(np.zeros(s_dim), features).shape[0]
    return LinearGaussianPolicy(
        rng.normal(size=d),
        random_spd(rng, d),
        rng.normal(size=(d, n_feat)),
        context_dim=s_dim,
        features=features,
    )


def _logpdf_tol(cov, w, mu, mean_scale):
    """Round-off of log N(w | μ, Σ) = −½(d log 2π + log|Σ| + δᵀΣ⁻¹δ), δ = w − μ, two paths
    (Cholesky solve here, scipy's eigendecomposition there): each term of size
    T = d log 2π + |log|Σ|| + max δᵀΣ⁻¹δ from a d×d factorisation (forward error d ε κ(Σ)),
    and δ off by a few ε ``mean_scale`` (|w| + |a| + |A||φ|), moved by 2 √maha ‖Σ^-½‖; absolute."""
    cov, delta = np.asarray(cov), np.atleast_2d(np.asarray(w) - np.asarray(mu))
    d, icov = len(cov), np.linalg.inv(cov)
    maha = float(np.einsum("ni,ij,nj->n", delta, icov, delta).max())
    terms = d * np.log(2 * np.pi) + abs(np.linalg.slogdet(cov)[1]) + maha
    shift = 2 * np.sqrt(maha * np.linalg.norm(icov, 2)) * mean_scale
    return 2 * fp_tol(d + 2, scale=terms + shift, cond=np.linalg.cond(cov))


def _coef_tol(S, w, p, coef):
    """Round-off of the weighted least-squares coefficients c of G c = b, G = SᵀPS, b = SᵀPω
    (Eq. 3.11; P = diag(p), Σ p = 1): the N-term sums put N ε max|S| max|ω| into b and
    N ε max|S|² into G, and δc = G⁻¹(δb − δG c) divides by λ_min(G); absolute, one path."""
    s_max, w_max, c_max = np.abs(S).max(), np.abs(w).max(), np.abs(coef).max()
    lam_min = np.linalg.eigvalsh(S.T @ (S * p[:, None])).min()
    return fp_tol(len(S), scale=(s_max * w_max + s_max**2 * c_max) / lam_min)


def _eig_tol(cov):
    """Round-off of rebuilding a d×d covariance V max(Λ, floor) Vᵀ from ``eigh`` (backward
    error ~ d² ε ‖Σ‖, tridiagonalisation and QR), twice in a fit (floor, then the condition
    guard); absolute, one path."""
    d = len(cov)
    return fp_tol(2 * d * d, scale=np.linalg.norm(cov, 2))


@pytest.mark.parametrize("features", ["linear", "quadratic"])
def test_log_prob_matches_scipy(features):
    rng = np.random.default_rng(1)
    pol = random_policy(rng, 4, 2, features)
    s = rng.uniform(-1, 1, size=(7, 2))
    w = rng.normal(size=(7, 4))
    mu = pol.mean_of(s)
    ref = [stats.multivariate_normal(mu[i], pol.cov).logpdf(w[i]) for i in range(7)]
    phi = context_features(s, features)
    mean_scale = np.abs(w).max() + np.abs(pol.mean).max() + (np.abs(phi) @ np.abs(pol.gain.T)).max()
    tol = _logpdf_tol(pol.cov, w, mu, mean_scale)
    np.testing.assert_allclose(pol.log_prob(w, s), ref, rtol=0, atol=tol)
    assert pol.log_prob(w[0], s[0]) == pytest.approx(ref[0], rel=0, abs=tol)


def test_mean_of_is_affine_in_features():
    rng = np.random.default_rng(2)
    pol = random_policy(rng, 3, 2, "quadratic")
    s = rng.normal(size=(5, 2))
    expected = pol.mean + context_features(s, "quadratic") @ pol.gain.T
    np.testing.assert_allclose(pol.mean_of(s), expected)
    np.testing.assert_allclose(pol.mean_of(s[1]), expected[1])
    np.testing.assert_allclose(pol.coefficients, np.column_stack([pol.mean, pol.gain]))


def test_sample_moments_and_seed():
    rng = np.random.default_rng(3)
    pol = random_policy(rng, 3, 2)
    s = np.tile([0.3, -0.7], (100_000, 1))
    w = pol.sample(s, 42)
    n = w.shape[0]
    se = np.sqrt(np.diag(pol.cov) / n)
    assert np.all(np.abs(w.mean(axis=0) - pol.mean_of(s[0])) < 5 * se)
    np.testing.assert_allclose(np.cov(w.T), pol.cov, atol=0.03 * np.max(np.abs(pol.cov)))
    np.testing.assert_array_equal(pol.sample(s[:10], 7), pol.sample(s[:10], 7))
    assert pol.sample(s[0], 7).shape == (3,)


def test_context_free_policy_sampling():
    pol = GaussianPolicy([1.0, 2.0], np.diag([0.1, 0.2]))
    assert pol.sample(None, 0).shape == (2,)
    assert pol.sample(np.zeros((5, 0)), 0).shape == (5, 2)
    np.testing.assert_array_equal(pol.mean_of(), [1.0, 2.0])
    ref = stats.multivariate_normal([1.0, 2.0], np.diag([0.1, 0.2])).logpdf([0.5, 2.5])
    tol = _logpdf_tol(pol.cov, [0.5, 2.5], [1.0, 2.0], mean_scale=2.5 + 2.0)
    assert pol.log_prob([0.5, 2.5]) == pytest.approx(ref, rel=0, abs=tol)


def test_kl_closed_form_vs_monte_carlo():
    rng = np.random.default_rng(4)
    p, q = random_policy(rng, 3, 2), random_policy(rng, 3, 2)
    s = rng.uniform(-1, 1, size=(4, 2))
    n = 50_000
    mc = []
    for i in range(4):
        ctx = np.tile(s[i], (n, 1))
        w = p.sample(ctx, i)
        mc.append(np.mean(p.log_prob(w, ctx) - q.log_prob(w, ctx)))
    # MC standard error of the average of 4 independent means of log-ratios
    assert p.kl(q, s) == pytest.approx(np.mean(mc), abs=0.03 * max(1.0, p.kl(q, s)))
    # KL(p ‖ p): the means and log-determinants cancel exactly (same code path); the trace
    # tr(L⁻¹L) = d up to the triangular solve's round-off (d² entries of size ≤ 1, d steps).
    assert p.kl(p, s) == pytest.approx(0.0, abs=fp_tol(p.dim, scale=p.dim))
    assert p.kl(q, s) > 0


def test_kl_single_context_closed_form():
    # 1-D: KL(N(m1, v1) || N(m2, v2)) = 0.5 (v1/v2 + (m2-m1)^2/v2 - 1 + log(v2/v1))
    p = LinearGaussianPolicy([0.0], [[2.0]], [[1.0]], context_dim=1)
    q = LinearGaussianPolicy([1.0], [[0.5]], [[0.0]], context_dim=1)
    s = np.array([[2.0]])
    m1, m2, v1, v2 = 2.0, 1.0, 2.0, 0.5
    expected = 0.5 * (v1 / v2 + (m2 - m1) ** 2 / v2 - 1 + np.log(v2 / v1))
    # A sum of 4 terms, each a few operations: absolute, scaled by the terms' magnitudes.
    terms = v1 / v2 + (m2 - m1) ** 2 / v2 + 1 + abs(np.log(v2 / v1))
    assert p.kl(q, s) == pytest.approx(expected, rel=0, abs=fp_tol(4 + 4, scale=terms))


def test_fit_recovers_known_parameters():
    rng = np.random.default_rng(5)
    true = random_policy(rng, 3, 2)
    s = rng.uniform(-1, 1, size=(40_000, 2))
    w = true.sample(s, rng)
    start = LinearGaussianPolicy(np.zeros(3), np.eye(3), context_dim=2)
    fitted = start.fit(s, w, np.ones(len(s)))
    np.testing.assert_allclose(fitted.coefficients, true.coefficients, atol=0.03)
    np.testing.assert_allclose(fitted.cov, true.cov, atol=0.03)
    # weighted: duplicating a sample equals doubling its weight
    idx = np.arange(200)
    dup = start.fit(
        np.vstack([s[idx], s[idx[:50]]]), np.vstack([w[idx], w[idx[:50]]]), np.ones(250)
    )
    weights = np.ones(200)
    weights[:50] = 2.0
    # The same weighted least squares summed over 250 or 200 rows: two paths, each within
    # the round-off bound of the exact coefficients.
    S = np.column_stack([np.ones(250), np.vstack([s[idx], s[idx[:50]]])])
    W = np.vstack([w[idx], w[idx[:50]]])
    tol = 2 * _coef_tol(S, W, np.full(250, 1 / 250), dup.coefficients)
    np.testing.assert_allclose(
        start.fit(s[idx], w[idx], weights).coefficients, dup.coefficients, rtol=0, atol=tol
    )


def test_fit_equals_thesis_equations_without_regularisation():
    rng = np.random.default_rng(6)
    start = LinearGaussianPolicy(np.zeros(3), 4 * np.eye(3), context_dim=2, features="quadratic")
    s = rng.uniform(-1, 1, size=(60, 2))
    w = rng.normal(size=(60, 3))
    p = rng.uniform(0.1, 1.0, size=60)
    new, info = start.fit_with_info(s, w, p, ridge=0.0, cov_floor=1e-12)
    S = np.column_stack([np.ones(60), context_features(s, "quadratic")])
    P = np.diag(p)
    coef = np.linalg.solve(S.T @ P @ S, S.T @ P @ w)  # Eq. 3.11
    # Centred ridge-free regression vs the normal equations: each within the bound (p / Σp).
    coef_tol = 2 * _coef_tol(S, w, p / p.sum(), coef)
    np.testing.assert_allclose(new.coefficients, coef.T, rtol=0, atol=coef_tol)
    mu = S @ coef  # Eq. 3.13
    cov = (w - mu).T @ P @ (w - mu) / p.sum()  # Eq. 3.12
    # Σ(c) is stationary at the weighted least-squares optimum (SᵀP r = 0), so the coefficient
    # error enters only squared (λ_max(G) δc²); first order: the residuals r = ω − S c carry
    # (F + 1) ε (|ω| + |S||c|), and the N-term sum N ε r², plus the eigen-floor step.
    r_max, k = np.abs(w - mu).max(), S.shape[1]
    G = S.T @ (S * (p / p.sum())[:, None])
    lin = r_max * (np.abs(w).max() + k * np.abs(S).max() * np.abs(coef).max())
    cov_tol = 2 * fp_tol(len(S) + k, scale=r_max**2 + lin) + 2 * _eig_tol(cov)
    cov_tol += np.linalg.eigvalsh(G).max() * coef_tol**2
    np.testing.assert_allclose(new.cov, cov, rtol=0, atol=cov_tol)
    assert info.n_floored == 0 and info.n_samples == 60
    assert info.effective_samples == pytest.approx(p.sum() ** 2 / np.sum(p**2))


def test_ridge_shrinks_gain_by_documented_amount():
    # one feature: A = X / (C (1 + ridge))
    rng = np.random.default_rng(7)
    s = rng.uniform(-1, 1, size=(30, 1))
    w = 2.0 * s + 0.1 * rng.normal(size=(30, 1))
    start = LinearGaussianPolicy([0.0], [[1.0]], context_dim=1)
    a0 = start.fit(s, w, np.ones(30), ridge=0.0).gain[0, 0]
    a1 = start.fit(s, w, np.ones(30), ridge=0.5).gain[0, 0]
    # X / (1.5 C) vs (X / C) / 1.5 through a 1×1 Cholesky solve: a handful of roundings each.
    assert a1 == pytest.approx(a0 / 1.5, rel=2 * fp_tol(4))


def test_covariance_shrinkage_and_floor():
    rng = np.random.default_rng(8)
    start = GaussianPolicy(np.zeros(3), np.eye(3))
    w = rng.normal(size=(50, 3)) * [1.0, 0.5, 0.0]  # third direction has zero spread
    ml, info = start.fit_with_info(None, w, np.ones(50), cov_floor=1e-12)
    assert info.min_cov_ratio < 1e-12 and info.n_floored == 1
    floored, info = start.fit_with_info(None, w, np.ones(50), cov_floor=1e-3)
    assert info.n_floored == 1
    assert np.linalg.eigvalsh(floored.cov).min() == pytest.approx(1e-3, rel=1e-9)
    # Both rebuilt from an eigendecomposition (Σ_old = I: the whitening is exact); the floored
    # third eigenvector is e₃ up to ε, so the floor adds 1e-3 · ε² to the 2×2 block.
    tol = 2 * _eig_tol(ml.cov)
    np.testing.assert_allclose(floored.cov[:2, :2], ml.cov[:2, :2], rtol=0, atol=tol)
    shrunk = start.fit(None, w, np.ones(50), cov_shrinkage=0.25, cov_floor=1e-12)
    # ml.cov went through the eigen floor, shrunk (no eigenvalue below the floor) did not:
    # ml's zero-spread direction e₃ holds the floor 1e-12 · λ(Σ_old = I), 0.75 of it is in ref.
    ref = 0.75 * ml.cov + 0.25 * np.eye(3)
    tol += 0.75 * 1e-12 + fp_tol(2, scale=1.0)
    np.testing.assert_allclose(shrunk.cov, ref, rtol=0, atol=tol)
    assert isinstance(shrunk, GaussianPolicy)


def test_fit_leaves_old_policy_untouched_and_is_immutable():
    rng = np.random.default_rng(9)
    pol = random_policy(rng)
    before = pol.coefficients.copy(), pol.cov.copy()
    pol.fit(rng.normal(size=(20, 2)), rng.normal(size=(20, 3)), np.ones(20))
    np.testing.assert_array_equal(pol.coefficients, before[0])
    np.testing.assert_array_equal(pol.cov, before[1])
    with pytest.raises(ValueError):
        pol.cov[0, 0] = 5.0


def test_too_few_effective_samples():
    pol = GaussianPolicy(np.zeros(3), np.eye(3))
    w = np.random.default_rng(0).normal(size=(10, 3))
    with pytest.raises(ValueError, match="weights: effective sample size"):
        pol.fit(None, w[:3], np.ones(3))
    weights = np.full(10, 1e-9)
    weights[0] = 1.0  # one sample carries (almost) all weight
    with pytest.raises(ValueError, match="weights"):
        pol.fit(None, w, weights)
    assert effective_sample_size(np.ones(10)) == pytest.approx(10.0)


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="mean"):
        LinearGaussianPolicy([np.nan, 0.0], np.eye(2))
    with pytest.raises(ValueError, match="cov"):
        LinearGaussianPolicy([0.0, 0.0], [[1.0, 2.0], [2.0, 1.0]])  # indefinite
    with pytest.raises(ValueError, match="cov"):
        LinearGaussianPolicy([0.0, 0.0], [[1.0, 0.5], [0.0, 1.0]])  # not symmetric
    with pytest.raises(ValueError, match="cov"):
        LinearGaussianPolicy([0.0, 0.0], np.eye(3))
    with pytest.raises(ValueError, match="gain"):
        LinearGaussianPolicy([0.0, 0.0], np.eye(2), np.zeros((2, 3)), context_dim=2)
    with pytest.raises(ValueError, match="context_dim"):
        LinearGaussianPolicy([0.0], np.eye(1), context_dim=-1)
    with pytest.raises(ValueError, match="features"):
        LinearGaussianPolicy([0.0], np.eye(1), context_dim=1, features="cubic")
    pol = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2)
    with pytest.raises(ValueError, match="contexts"):
        pol.sample(np.zeros((4, 3)), 0)
    with pytest.raises(ValueError, match="contexts"):
        pol.sample(None, 0)
    with pytest.raises(ValueError, match="omegas"):
        pol.log_prob(np.zeros((4, 3)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="contexts"):
        pol.log_prob(np.zeros((4, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="contexts"):
        pol.fit(np.zeros((5, 2)), np.zeros((6, 2)), np.ones(6))
    with pytest.raises(ValueError, match="weights"):
        pol.fit(np.zeros((6, 2)), np.zeros((6, 2)), -np.ones(6))
    with pytest.raises(ValueError, match="weights"):
        pol.fit(np.zeros((6, 2)), np.zeros((6, 2)), np.full(6, np.nan))
    with pytest.raises(ValueError, match="contexts: the weighted contexts have no spread"):
        pol.fit(np.ones((6, 2)), np.random.default_rng(0).normal(size=(6, 2)), np.ones(6))
    with pytest.raises(ValueError, match="cov_shrinkage"):
        pol.fit(np.zeros((6, 2)), np.zeros((6, 2)), np.ones(6), cov_shrinkage=1.0)
    one_sample = np.eye(6)[0]  # Kish ESS 1: a NaN bound would switch the check off
    for bad in (np.nan, -1.0):
        with pytest.raises(ValueError, match="min_effective_samples"):
            pol.fit(np.zeros((6, 2)), np.zeros((6, 2)), one_sample, min_effective_samples=bad)
    with pytest.raises(ValueError, match="other"):
        pol.kl(GaussianPolicy(np.zeros(2), np.eye(2)), np.zeros((1, 2)))


def test_condition_number_guard_keeps_the_fitted_covariance_positive_definite():
    """Samples without spread in one direction would make Σ singular; the guard raises that
    eigenvalue to 1e-12 of the largest and reports it (FitInfo.n_conditioned)."""
    from skillkit.policies.gaussian import MIN_RELATIVE_EIGENVALUE

    rng = np.random.default_rng(0)
    pol = LinearGaussianPolicy(np.zeros(3), np.eye(3))
    omegas = np.column_stack([rng.normal(size=200), 0.1 * rng.normal(size=200), np.zeros(200)])
    new, info = pol.fit_with_info(np.zeros((200, 0)), omegas, np.ones(200), cov_floor=1e-300)
    lam = np.linalg.eigvalsh(new.cov)
    assert info.n_conditioned == 1
    assert lam[0] == pytest.approx(MIN_RELATIVE_EIGENVALUE * lam[-1], rel=1e-6)
    np.linalg.cholesky(new.cov)  # positive definite
    _, fine = pol.fit_with_info(np.zeros((200, 0)), rng.normal(size=(200, 3)), np.ones(200))
    assert fine.n_conditioned == 0
