"""Contextual CMA-ES: sanity3's known optimum within a measured budget, its pure functions
against closed forms, and bad input refused by name."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from skillkit.experiments.sanity import (
    LinearOptimumTask,
    SanitySettings,
    context_grid,
    parameter_error,
)
from skillkit.search import CCMAES
from skillkit.search.base import Batch
from skillkit.search.ccmaes import (
    CCMAESDiagnostics,
    CCMAESSettings,
    adapt_covariance,
    advantage_weights,
    ccmaes_rates,
    default_population,
    fit_baseline,
    rank_weights,
    weighted_linear_regression,
)
from skillkit.search.loop import collect, learn
from skillkit.tasks.functional import FunctionTask
from tests._tolerances import fp_tol

#: Generations of the budget test: N = 40 rollouts each (default_population(3, 2)), so 1800
#: rollouts. Measured first reaching sanity3's threshold: 920–1400 rollouts over seeds 0–19;
#: final error after 1800 rollouts over seeds 100–119: median 2.6e-4, range 1.0e-4–1.3e-3.
BUDGET_GENERATIONS = 45


def test_ccmaes_reaches_sanity3s_threshold_within_1800_rollouts_on_ten_seeds():
    task = LinearOptimumTask()
    grid, optimum = context_grid(), task.optimal_coefficients
    threshold = SanitySettings().threshold
    assert parameter_error(task.initial_policy(), optimum, grid) > 100 * threshold
    errors = []
    for seed in range(200, 210):
        alg = CCMAES(task.initial_policy())
        assert alg.rollouts_per_update == 40
        res = learn(task, alg, BUDGET_GENERATIONS, alg.rollouts_per_update, seed, progress=False)
        assert res["rollouts"][-1] == 1800
        errors.append(parameter_error(alg.policy, optimum, grid))
    assert max(errors) < threshold, errors
    diag = res["diagnostics"][-1]
    assert isinstance(diag, CCMAESDiagnostics) and diag.generation == BUDGET_GENERATIONS
    assert diag.std_max < 0.05 * task.init_std  # the search distribution contracted


def test_context_free_ccmaes_is_an_evolution_strategy_on_a_quadratic():
    optimum = np.array([1.5, -0.5, 0.8])
    task = FunctionTask(lambda omega, context, rng: -float(np.sum((omega - optimum) ** 2)), 3)
    alg = CCMAES(task.initial_policy())
    assert alg.rollouts_per_update == 4 + math.floor(3 * math.log(3))  # CMA-ES's λ
    learn(task, alg, 60, alg.rollouts_per_update, 0, progress=False)  # 420 rollouts
    # Measured distance after 420 rollouts, seeds 0–9: median 2.4e-5, max 1.3e-4 (the cma
    # package's CMA-ES, λ = 7: median 7e-6, max 1.1e-4), from 1.8 at the start.
    assert np.linalg.norm(alg.policy.mean_of() - optimum) < 1e-3


def test_same_seed_same_run_and_a_pickled_search_resumes_identically():
    task = LinearOptimumTask()

    def run(alg, seed, k):
        learn(task, alg, k, 40, seed, progress=False)
        return alg.policy.coefficients, alg.policy.cov

    a, b = CCMAES(task.initial_policy()), CCMAES(task.initial_policy())
    for x, y in zip(run(a, 3, 5), run(b, 3, 5), strict=True):
        np.testing.assert_array_equal(x, y)
    c = pickle.loads(pickle.dumps(a))
    for x, y in zip(run(a, 4, 2), run(c, 4, 2), strict=True):
        np.testing.assert_array_equal(x, y)


# ----------------------------------------------------------------- pure functions
def test_rank_weights_are_cmas_log_weights_decreasing_and_summing_to_one():
    w = rank_weights(7)  # μ = 3
    raw = np.log(3.5) - np.log([1.0, 2.0, 3.0])
    np.testing.assert_allclose(w[:3], raw / raw.sum(), rtol=fp_tol(8))
    np.testing.assert_array_equal(w[3:], 0.0)
    for n in (1, 2, 7, 40):
        w = rank_weights(n)
        mu = max(n // 2, 1)
        assert w.sum() == pytest.approx(1.0, abs=fp_tol(2 * n))
        assert np.all(w[:mu] > 0) and np.all(np.diff(w[:mu]) < 0) and not np.any(w[mu:])
    assert default_population(3, 2) == (4 + math.floor(3 * math.log(5))) * 5


def test_advantage_weights_follow_the_rank_of_the_advantage():
    adv = np.array([0.3, -1.0, 2.0, 0.1])
    w = advantage_weights(adv)
    np.testing.assert_array_equal(w[[2, 0, 3, 1]], rank_weights(4))
    assert w[2] > w[0] > 0 and w[3] == w[1] == 0
    perm = np.array([3, 1, 0, 2])
    np.testing.assert_array_equal(advantage_weights(adv[perm]), w[perm])


def test_weighted_regression_equals_lstsq_on_root_weighted_data():
    rng = np.random.default_rng(0)
    phi, y = rng.standard_normal((30, 2)), rng.standard_normal((30, 3))
    w = rng.permutation(np.linspace(0.0, 1.0, 30))  # zero weights included
    x = np.column_stack([np.ones(30), phi])
    ref = np.linalg.lstsq(x * np.sqrt(w)[:, None], y * np.sqrt(w)[:, None], rcond=None)[0].T
    got = weighted_linear_regression(phi, y, w)
    np.testing.assert_allclose(got, ref, atol=fp_tol(30 * 3, np.abs(ref).max(), cond=10))
    lam = 0.5  # ridge on the gain only: the explicit normal equations
    reg = np.diag([0.0, lam, lam])
    explicit = np.linalg.solve(x.T @ np.diag(w) @ x + reg, x.T @ np.diag(w) @ y).T
    got = weighted_linear_regression(phi, y, w, ridge=lam)
    np.testing.assert_allclose(got, explicit, atol=fp_tol(30 * 3, np.abs(explicit).max(), 10))


def test_baseline_is_the_explicit_ridge_solve():
    rng = np.random.default_rng(1)
    psi, r = rng.standard_normal((25, 4)), rng.standard_normal(25)
    lam = 0.3
    x = np.column_stack([np.ones(25), psi])
    beta_ref = np.linalg.solve(x.T @ x + lam * np.diag([0.0, 1, 1, 1, 1]), x.T @ r)
    beta, values = fit_baseline(psi, r, lam)
    tol = fp_tol(25 * 5, np.abs(beta_ref).max(), cond=10)
    np.testing.assert_allclose(beta, beta_ref, atol=tol)
    np.testing.assert_allclose(values, x @ beta_ref, atol=fp_tol(5, 1.0) + 5 * tol)
    beta0, values0 = fit_baseline(np.zeros((25, 0)), r, lam)  # no features: V = mean reward
    np.testing.assert_allclose(values0, r.mean(), atol=fp_tol(25, np.abs(r).max()))


def test_rates_are_hansens_defaults():
    r = ccmaes_rates(10, 3, 2)
    mu_eff = 1.0 / np.sum(rank_weights(10) ** 2)
    n = 5
    assert r.mu_eff == pytest.approx(mu_eff)
    assert r.c_sigma == pytest.approx((mu_eff + 2) / (n + mu_eff + 5))
    assert r.c_1 == pytest.approx(2 / ((n + 1.3) ** 2 + mu_eff))
    assert 0 < r.c_1 + r.c_mu <= 1 and 0 < r.c_c <= 1 and r.d_sigma >= 1
    assert r.chi_d == pytest.approx(math.sqrt(3), rel=0.1)


def test_neutral_generation_shrinks_only_by_the_rank_one_rate():
    """Zero paths, no mean shift and rank-μ term equal to C: C ← (1 − c₁) C (h_σ = 1, the
    rank-μ term cancels) and σ ← σ exp(−c_σ / d_σ) (a zero path is too short)."""
    c = np.array([[2.0, 0.3], [0.3, 0.5]])
    root = np.linalg.cholesky(c)
    y = np.vstack([root.T, -root.T]) * np.sqrt(2.0)  # Σ_k y_k y_kᵀ / 4 = C with equal weights
    w = np.full(4, 0.25)
    rates = ccmaes_rates(4, 2, 0)
    z = np.zeros(2)
    new, sigma, p_s, p_c, h = adapt_covariance(c, 0.7, z, z, z, y, w, rates, 1, 0.6)
    assert h
    np.testing.assert_allclose(new, (1 - rates.c_1) * c, atol=fp_tol(16, 2.0))
    assert sigma == pytest.approx(0.7 * math.exp(-rates.c_sigma / rates.d_sigma))
    np.testing.assert_array_equal(p_s, z)
    np.testing.assert_array_equal(p_c, z)


# ----------------------------------------------------------------- bad input
def test_bad_input_is_refused_naming_the_argument():
    task = LinearOptimumTask()
    with pytest.raises(ValueError, match="policy: expected a LinearGaussianPolicy"):
        CCMAES("policy")
    with pytest.raises(ValueError, match="settings: expected CCMAESSettings"):
        CCMAES(task.initial_policy(), {"baseline_ridge": 1.0})
    with pytest.raises(ValueError, match="baseline_features"):
        CCMAESSettings(baseline_features="cubic")
    with pytest.raises(ValueError, match="baseline_ridge"):
        CCMAESSettings(baseline_ridge=-1.0)
    with pytest.raises(ValueError, match="max_log_step"):
        CCMAESSettings(max_log_step=0.0)
    with pytest.raises(ValueError, match="n: expected an integer"):
        rank_weights(0)
    with pytest.raises(ValueError, match="advantages: contains 1 non-finite"):
        advantage_weights([0.0, np.nan])
    with pytest.raises(ValueError, match="weights: expected non-negative"):
        weighted_linear_regression(np.zeros((3, 1)), np.zeros((3, 2)), [0.5, 0.6, -0.1])
    with pytest.raises(ValueError, match=r"targets: expected shape \(3, \?\)"):
        weighted_linear_regression(np.zeros((3, 1)), np.zeros((4, 2)), np.ones(3))
    with pytest.raises(ValueError, match=r"rewards: expected shape \(3,\)"):
        fit_baseline(np.zeros((3, 1)), np.zeros(4), 0.0)
    with pytest.raises(ValueError, match="ridge"):
        fit_baseline(np.zeros((3, 1)), np.zeros(3), -1.0)
    alg = CCMAES(task.initial_policy())
    batch = collect(task, alg.policy, 6, rng=0, extra_contexts=1)
    with pytest.raises(ValueError, match="batch: .*extra contexts"):
        alg.update(batch)
    one = collect(task, alg.policy, 1, rng=0)
    with pytest.raises(ValueError, match="batch: expected at least 2 rollouts"):
        alg.update(one)
    with pytest.raises(ValueError, match=r"contexts: expected shape \(N, 2\)"):
        alg.update(Batch(np.zeros((3, 1)), np.zeros((3, 3)), np.zeros(3)))
