"""REPS dual: the analytic Hessian and the Newton solver against finite differences, an
independent weighted covariance and the default L-BFGS-B solution."""

import numpy as np
import pytest
from _tolerances import fp_tol

from skillkit.policies.features import context_features
from skillkit.search.reps import (
    DEFAULT_DUAL_SOLVER,
    KL_TOLERANCE,
    reps_dual,
    reps_dual_hessian,
    reps_weights,
)


def _problem(seed: int, n_range=(30, 101), eps_range=(0.1, 1.0)):
    """Rewards, features (none / linear / quadratic by seed), ε and, for odd seeds, base
    weights."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(*n_range))
    s = rng.uniform(-1, 1, size=(n, 2))
    kind = ["none", "linear", "quadratic"][seed % 3]
    phi = np.zeros((n, 0)) if kind == "none" else context_features(s, kind)
    rewards = 3.0 * (-np.sum((s - 0.3) ** 2, axis=1) + rng.normal(size=n)) + 10.0
    q = rng.uniform(0.1, 2.0, size=n) if seed % 2 else None
    return rewards, phi, float(rng.uniform(*eps_range)), q


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("eta", [0.3, 2.0, 20.0])
def test_hessian_equals_finite_differences_of_the_gradient(seed, eta):
    rewards, phi, eps, q = _problem(seed)
    rng = np.random.default_rng(seed + 50)
    x = np.concatenate([[eta], rng.normal(size=phi.shape[1])])
    H = reps_dual_hessian(x, rewards, phi, eps, q)
    h = 1e-6 * np.maximum(1.0, np.abs(x))
    fd = np.stack(
        [
            (
                reps_dual(x + h[k] * e, rewards, phi, eps, q)[1]
                - reps_dual(x - h[k] * e, rewards, phi, eps, q)[1]
            )
            / (2 * h[k])
            for k, e in enumerate(np.eye(x.size))
        ],
        axis=1,
    )
    np.testing.assert_allclose(H, fd, rtol=1e-5, atol=1e-7 * np.abs(H).max())
    np.testing.assert_array_equal(H, H.T)


@pytest.mark.parametrize("seed", range(6))
def test_hessian_is_the_weighted_covariance_over_eta(seed):
    """∇²g = Cov_p([A/η, φ])/η with p the weights of Eq. (3.10) at (η, γ): numpy's weighted
    covariance of the explicitly formed weights; positive semi-definite."""
    rewards, phi, eps, q = _problem(seed)
    rng = np.random.default_rng(seed + 60)
    eta = 0.7
    gamma = rng.normal(size=phi.shape[1])
    adv = rewards - phi @ gamma
    base = np.ones_like(rewards) if q is None else q
    logp = np.log(base) + adv / eta
    p = np.exp(logp - logp.max())
    p /= p.sum()
    w = np.column_stack([adv / eta, phi])
    expected = np.atleast_2d(np.cov(w.T, aweights=p, bias=True)) / eta
    H = reps_dual_hessian(np.concatenate([[eta], gamma]), rewards, phi, eps, q)
    # Both are N-term weighted sums of products of w (shifted by the heaviest sample's A/η in
    # the Hessian, centred in np.cov) minus a product of means: absolute round-off N ε times
    # E_p[|w̃_k||w̃_l|] + E_p|w̃_k| E_p|w̃_l|; p is relatively off by ε |log p| (the exponent),
    # so that many more; over η. Two evaluations, each within the bound.
    wc = w - np.r_[w[np.argmax(p), 0], np.zeros(phi.shape[1])]
    m_abs = p @ np.abs(wc)
    scale = ((np.abs(wc).T * p) @ np.abs(wc) + np.outer(m_abs, m_abs)).max() / eta
    tol = 2 * fp_tol(len(p) + 2 + np.abs(logp - logp.max()).max(), scale=scale)
    np.testing.assert_allclose(H, expected, rtol=0, atol=tol)
    assert np.linalg.eigvalsh(H).min() >= -1e-12 * np.abs(H).max()


@pytest.mark.parametrize("seed", range(40))
def test_newton_reaches_the_lbfgsb_solution(seed):
    """Bound active (ε ≤ 1 on 30–100 samples), with and without base weights and features:
    the same η, γ, dual value, weights and KL; Newton's own gradient tolerance is met."""
    rewards, phi, eps, q = _problem(seed)
    ref = reps_weights(rewards, phi, eps, q)
    new = reps_weights(rewards, phi, eps, q, solver="newton")
    assert new.message == "Newton: projected gradient below tolerance"
    assert new.success and ref.success and new.kl_bound_active and ref.kl_bound_active
    # L-BFGS-B (ref) mostly stops on ftol = 1e-15 (relative reduction of g), Newton on the
    # projected gradient ≤ 1e-11: ref's distance to the minimiser is ≲ √ftol ≈ 3e-8 in
    # (log η, θ), which bounds η, γ and the weights below; the dual value is stationary there
    # (error second order, ~ftol) plus a log-sum-exp round-off of ~N eps = 2e-14 relative.
    assert new.eta == pytest.approx(ref.eta, rel=1e-6)
    np.testing.assert_allclose(new.gamma, ref.gamma, rtol=1e-5, atol=1e-6 * ref.eta)
    # In reward units g = r_max + r_scale g_n: the normalised dual's round-off is N ε times its
    # terms (max|r_n| + log N + |g_n|, as in test_reps's _dual_tol), each solver's; L-BFGS-B's
    # stop on ftol = 1e-15 leaves it that much (relative, at least absolute 1) above the minimum.
    r_scale, n = rewards.std(), rewards.size
    g_n = (ref.dual - rewards.max()) / r_scale
    spread = np.ptp(rewards) / r_scale + np.log(n) + abs(g_n)
    dual_tol = 2 * fp_tol(n, scale=abs(rewards.max()) + r_scale * spread)
    dual_tol += 1e-15 * max(abs(g_n), 1.0) * r_scale
    assert new.dual == pytest.approx(ref.dual, rel=0, abs=dual_tol)
    np.testing.assert_allclose(new.weights, ref.weights, rtol=0, atol=1e-7 * ref.weights.max())
    # Σ z_i / Σ z: N divisions and an N-term sum, each rounding ε relative.
    assert new.weights.sum() == pytest.approx(1.0, abs=fp_tol(n))
    # the bound (3.4) met with equality: Newton's stop |η_n (ε − KL)| ≤ 1e-11 with η_n ≳ 0.1
    # leaves |KL − ε| ≤ 1e-10 ≤ 1e-9 ε (ε ≥ 0.1), plus the KL's round-off (~N eps)
    assert abs(new.kl - eps) <= 1e-8 * eps
    base = np.full(rewards.size, 1.0 / rewards.size) if q is None else q / q.sum()
    if phi.shape[1]:
        # the γ-gradient at Newton's stop: ≤ 1e-11 whitened, times the feature spread (≤ 1)
        np.testing.assert_allclose(new.weights @ phi, base @ phi, atol=1e-9)
    # At Newton's solution the dual's gradient (original units) vanishes at least as well.
    x_new = np.concatenate([[new.eta], new.gamma])
    x_ref = np.concatenate([[ref.eta], ref.gamma])
    g_new = np.abs(reps_dual(x_new, rewards, phi, eps, q)[1]).max()
    g_ref = np.abs(reps_dual(x_ref, rewards, phi, eps, q)[1]).max()
    assert g_new <= max(g_ref, 1e-9)


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e6])
def test_newton_is_scale_invariant(scale):
    rewards, phi, eps, _ = _problem(2)
    ref = reps_weights(rewards, phi, eps, solver="newton")
    sol = reps_weights(scale * rewards - 1e3, phi, eps, solver="newton")
    np.testing.assert_allclose(sol.weights, ref.weights, atol=1e-9)
    assert sol.eta == pytest.approx(scale * ref.eta, rel=1e-7)


def test_an_inactive_bound_without_features_is_solved_by_newton():
    """ε beyond log N with distinct rewards: η runs to its lower bound; Newton gets there by
    itself (capped log-η steps), with the same weights and flags as L-BFGS-B."""
    rewards = np.arange(6.0)
    ref = reps_weights(rewards, None, 3.0)
    new = reps_weights(rewards, None, 3.0, solver="newton")
    assert new.message == "Newton: projected gradient below tolerance"
    assert not new.kl_bound_active and not ref.kl_bound_active and new.success
    # Both stop at η's lower bound (η_n = 1e-8): exp(−Δr_n/η_n) underflows to 0 for every
    # sample but the best, whose weight is 1/1: equal by construction.
    np.testing.assert_array_equal(new.weights, ref.weights)
    assert new.weights[-1] == pytest.approx(1.0)


@pytest.mark.parametrize("seed", range(20))
def test_unattainable_epsilon_under_the_feature_constraint_falls_back_to_lbfgsb(seed):
    """ε of 1–5 nats on 10–40 samples with features: often more than (3.5) allows. Where
    Newton does not converge the answer is L-BFGS-B's exactly (said in the message); where
    it does, the weights agree."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(10, 41))
    s = rng.uniform(-1, 1, size=(n, 2))
    phi = context_features(s, ["linear", "quadratic"][seed % 2])
    rewards = -np.sum((s - 0.3) ** 2, axis=1) + rng.normal(size=n)
    eps = float(rng.uniform(1.0, 5.0))
    ref = reps_weights(rewards, phi, eps)
    new = reps_weights(rewards, phi, eps, solver="newton")
    assert new.kl_bound_active == ref.kl_bound_active and new.success == ref.success
    if "L-BFGS-B" in new.message:
        np.testing.assert_array_equal(new.weights, ref.weights)
        assert new.n_iterations > ref.n_iterations
    else:
        assert new.kl <= eps * (1 + KL_TOLERANCE)
        np.testing.assert_allclose(new.weights, ref.weights, atol=1e-6)


def test_newton_needs_fewer_iterations_at_the_benchmark_size():
    """N = 10,000 samples, quadratic baseline features of a 2-D context (bench_reps.py's
    problem shape): Newton's iterations (with its 1-D start) against L-BFGS-B's."""
    rng = np.random.default_rng(0)
    s = rng.uniform([5.0, 1.0], [15.0, 3.0], size=(10_000, 2))
    rewards = -np.sum((rng.normal(size=(10_000, 5)) - 0.2) ** 2, axis=1) - 0.1 * (s**2).sum(1)
    phi = context_features(s, "quadratic")
    ref = reps_weights(rewards, phi, 0.6)
    new = reps_weights(rewards, phi, 0.6, solver="newton")
    assert new.message == "Newton: projected gradient below tolerance"
    assert new.n_iterations < ref.n_iterations
    np.testing.assert_allclose(new.weights, ref.weights, atol=1e-7 * ref.weights.max())


def test_default_solver_is_unchanged():
    assert DEFAULT_DUAL_SOLVER == "lbfgsb"
    rewards, phi, eps, q = _problem(4)
    a, b = reps_weights(rewards, phi, eps, q), reps_weights(rewards, phi, eps, q, solver="lbfgsb")
    np.testing.assert_array_equal(a.weights, b.weights)
    assert "Newton" not in a.message


def test_bad_input_names_the_argument():
    rewards, phi, eps, _ = _problem(1)
    with pytest.raises(ValueError, match="solver"):
        reps_weights(rewards, phi, eps, solver="bfgs")
    x = np.ones(1 + phi.shape[1])
    with pytest.raises(ValueError, match="params"):
        reps_dual_hessian(np.concatenate([[0.0], x[1:]]), rewards, phi, eps)
    with pytest.raises(ValueError, match="params"):
        reps_dual_hessian(x[:-1], rewards, phi, eps)
    with pytest.raises(ValueError, match="epsilon"):
        reps_dual_hessian(x, rewards, phi, -1.0)
    with pytest.raises(ValueError, match="base_weights"):
        reps_dual_hessian(x, rewards, phi, eps, base_weights=-np.ones(rewards.size))
    with pytest.raises(ValueError, match="features"):
        reps_dual_hessian(x, rewards, phi[:-1], eps)


def test_contextual_reps_with_the_newton_solver_makes_the_same_updates():
    """Three updates with reuse: the same policies (to the solvers' agreement) and diagnostics;
    the option is validated and shown in the repr."""
    from skillkit.policies.gaussian import LinearGaussianPolicy
    from skillkit.search.base import Batch
    from skillkit.search.reps import ContextualREPS

    runs = {}
    for solver in ("lbfgsb", "newton"):
        rng = np.random.default_rng(3)
        pol = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2)
        reps = ContextualREPS(pol, epsilon=0.5, n_reuse_batches=2, dual_solver=solver)
        diags = []
        for _ in range(3):
            s = rng.uniform(-1, 1, size=(40, 2))
            w = reps.policy.sample(s, rng)
            diags.append(reps.update(Batch(s, w, -np.sum((w - s) ** 2, axis=1))))
        runs[solver] = (reps, diags)
    (a, da), (b, db) = runs["lbfgsb"], runs["newton"]
    assert "dual_solver='newton'" in repr(b) and "dual_solver" not in repr(a)
    np.testing.assert_allclose(
        b.policy.mean_of(np.zeros(2)), a.policy.mean_of(np.zeros(2)), atol=1e-6
    )
    for x, y in zip(da, db, strict=True):
        assert y.eta == pytest.approx(x.eta, rel=1e-5) and y.kl == pytest.approx(x.kl, rel=1e-6)
    with pytest.raises(ValueError, match="dual_solver"):
        ContextualREPS(
            LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2), 0.5, dual_solver="sgd"
        )
