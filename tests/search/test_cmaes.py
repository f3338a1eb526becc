"""CMA-ES glue: the search interface over cma's ask/tell, episodic and contextual."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from skillkit.policies.gaussian import GaussianPolicy, LinearGaussianPolicy
from skillkit.search.base import Batch
from skillkit.search.cmaes import CMAES, DEFAULT_CONTEXTS_PER_CANDIDATE, CMAESDiagnostics
from skillkit.search.loop import collect, learn
from skillkit.tasks.functional import FunctionTask
from tests._tolerances import fp_tol

OPTIMUM = np.array([1.5, -0.5, 0.8])


def _sphere(omega, context, rng):
    return -float(np.sum((omega - OPTIMUM) ** 2))


def _linear_target(omega, context, rng):
    """R = −‖ω − (1 + 2 s)‖²: the best linear mapping is b = 1, W = 2 I."""
    return -float(np.sum((omega - (1.0 + 2.0 * context)) ** 2))


def _episodic() -> FunctionTask:
    return FunctionTask(_sphere, 3)


def _contextual() -> FunctionTask:
    return FunctionTask(_linear_target, 2, context_low=[-1, -1], context_high=[1, 1])


def _offset_and_gain(pol, theta):
    """(b, W) of a θ = [b, vec(W)]."""
    return theta[: pol.dim], theta[pol.dim :].reshape(pol.dim, pol.context_dim)


def test_episodic_cmaes_approaches_the_optimum_of_a_quadratic():
    task = _episodic()
    alg = CMAES.for_task(task, rng=0)
    res = learn(task, alg, 30, alg.rollouts_per_update, rng=1, progress=False)
    start_gap = float(np.sum(OPTIMUM**2))  # −R at the start, ω = 0
    assert res["mean_reward"][0] == pytest.approx(-start_gap)
    assert -res["mean_reward"][-1] < 1e-2 * start_gap  # 100-fold closer in reward
    mean = alg.policy.mean_of()
    assert np.linalg.norm(mean - OPTIMUM) < 0.1 * np.linalg.norm(OPTIMUM)
    diag = res["diagnostics"][-1]
    assert isinstance(diag, CMAESDiagnostics)
    assert diag.generation == 30 and diag.n_evaluations == 30 * alg.popsize
    assert diag.sigma < 1.0  # the step size shrank from σ₀ = 1 towards the optimum


def test_contextual_cmaes_learns_the_linear_mapping():
    task = _contextual()
    alg = CMAES.for_task(task, rng=0)
    assert alg.contexts_per_candidate == DEFAULT_CONTEXTS_PER_CANDIDATE
    res = learn(task, alg, 25, alg.rollouts_per_update, rng=1, progress=False)
    assert -res["mean_reward"][-1] < 0.05 * -res["mean_reward"][0]
    b, w = _offset_and_gain(alg.policy, alg.policy.theta_mean)  # φ(s) = s on [−1, 1]²
    np.testing.assert_allclose(b, [1.0, 1.0], atol=0.3)
    np.testing.assert_allclose(w, 2.0 * np.eye(2), atol=0.3)


def test_the_initial_mean_is_the_initial_policys_mean():
    task = _contextual()
    pol = LinearGaussianPolicy(np.array([0.3, -0.2]), 0.25 * np.eye(2), [[1, 2], [3, 4]], 2)
    alg = CMAES.for_task(task, pol, context_center=[0.5, 0.0], context_scale=[0.5, 2.0], rng=0)
    s = task.sample_context(3, n=5)
    np.testing.assert_allclose(
        alg.policy.mean_of(s), pol.mean_of(s), atol=fp_tol(8, scale=np.abs(pol.mean).max() + 1.0)
    )
    assert alg.es.sigma == pytest.approx(0.5)  # √Σ_ii: the exploration REPS starts with


def test_default_population_is_cmas_and_the_batch_must_match_it():
    task = _episodic()
    alg = CMAES.for_task(task, rng=0)
    assert alg.popsize == 4 + math.floor(3 * math.log(3))  # cma's documented default
    assert alg.rollouts_per_update == alg.popsize
    batch = collect(task, alg.policy, alg.rollouts_per_update, rng=2)
    np.testing.assert_array_equal(batch.omegas, alg.policy.population)  # ask = the batch
    with pytest.raises(ValueError, match="contexts: .*rollouts_per_update to 7"):
        alg.policy.sample(np.zeros((5, 0)))
    with pytest.raises(ValueError, match="rollouts_per_update to 7"):
        learn(task, alg, 1, 5, rng=0, progress=False)
    moved = Batch(None, batch.omegas + 0.1, batch.rewards)
    with pytest.raises(ValueError, match="batch: its omegas are not this generation"):
        alg.update(moved)
    with pytest.raises(ValueError, match="batch: expected 7 rows"):
        alg.update(Batch(None, batch.omegas[:5], batch.rewards[:5]))
    rescored = Batch(None, np.vstack([batch.omegas] * 2), np.tile(batch.rewards, 2), None, 7)
    with pytest.raises(ValueError, match="extra contexts"):
        alg.update(rescored)
    assert alg.update(batch).generation == 1  # the matching batch is told
    bigger = CMAES.for_task(task, options={"popsize": 12}, rng=0)
    assert bigger.popsize == bigger.rollouts_per_update == 12
    assert bigger.policy.population.shape == (12, 3)


def test_contextual_rows_belong_to_candidates_in_blocks():
    task = _contextual()
    alg = CMAES.for_task(task, contexts_per_candidate=2, rng=0)
    pol = alg.policy
    s = task.sample_context(0, n=alg.rollouts_per_update)
    omegas = pol.sample(s)
    for i in (0, 1, 2, 3):
        b, w = _offset_and_gain(pol, pol.population[i // 2])
        np.testing.assert_allclose(
            omegas[i], b + w @ s[i], atol=fp_tol(8, scale=np.abs(omegas).max() + 1.0)
        )
    with pytest.raises(ValueError, match="contexts_per_candidate"):
        CMAES(GaussianPolicy(np.zeros(2), np.eye(2)), contexts_per_candidate=3)


def test_same_seed_same_result_and_pickled_state_resumes():
    task = _episodic()

    def run(seed):
        alg = CMAES.for_task(task, rng=seed)
        res = learn(task, alg, 4, alg.rollouts_per_update, rng=5, progress=False)
        return alg, res["mean_reward"]

    a, ra = run(3)
    b, rb = run(3)
    np.testing.assert_array_equal(ra, rb)
    np.testing.assert_array_equal(a.policy.population, b.policy.population)
    _, rc = run(4)
    assert not np.array_equal(ra, rc)
    copy = pickle.loads(pickle.dumps(a))
    batch = collect(task, a.policy, a.rollouts_per_update, rng=9)
    a.update(batch)
    copy.update(batch)
    np.testing.assert_array_equal(a.policy.population, copy.policy.population)


def test_bad_settings_are_named():
    pol = GaussianPolicy(np.zeros(2), np.eye(2))
    with pytest.raises(ValueError, match="options: 'seed'"):
        CMAES(pol, options={"seed": 1})
    with pytest.raises(ValueError, match="policy: expected a LinearGaussianPolicy"):
        CMAES("not a policy")
    quad = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=1, features="quadratic")
    with pytest.raises(ValueError, match="policy: CMAES maps contexts linearly"):
        CMAES(quad)
    with pytest.raises(ValueError, match="context_scale"):
        CMAES(LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=1), context_scale=[0.0])
    with pytest.raises(ValueError, match="sigma0"):
        CMAES(pol, sigma0=-1.0)
