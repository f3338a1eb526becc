"""Contextual BO glue: BoTorch's GP and UCB behind the search interface."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch

from skillkit.policies.gaussian import GaussianPolicy, LinearGaussianPolicy
from skillkit.search.base import Batch
from skillkit.search.cbo import CBODiagnostics, CBOSettings, ContextualBO
from skillkit.search.loop import collect, learn
from skillkit.tasks.functional import FunctionTask
from tests._snapshots import Snapshots
from tests._tolerances import SAFETY, fp_tol

# The GP's outcomes are standardised and its acquisition values never constant: BoTorch's
# warnings that they are not fail every test here.
pytestmark = [
    pytest.mark.filterwarnings("error::botorch.exceptions.warnings.InputDataWarning"),
    pytest.mark.filterwarnings("error::botorch.exceptions.warnings.BadInitialCandidatesWarning"),
]

#: Few evaluation contexts: every one costs a posterior-mean search per update.
EVAL = np.array([[-0.8, 0.6], [0.0, 0.0], [0.7, -0.9], [0.9, 0.9]])


def _target(context):
    """ω*(s) = 0.5 + s: inside the default box [−2, 2]² for every s ∈ [−1, 1]²."""
    return 0.5 + context


def _linear_target(omega, context, rng):
    """R = −‖ω − ω*(s)‖², optimum 0 in every context."""
    return -float(np.sum((omega - _target(context)) ** 2))


def _fails_far_right(omega, context, rng):
    if omega[0] > 1.0:
        raise RuntimeError("out of reach")
    return _linear_target(omega, context, rng)


def _contextual(rollout=_linear_target) -> FunctionTask:
    return FunctionTask(rollout, 2, context_low=[-1, -1], context_high=[1, 1])


def test_contextual_bo_closes_most_of_the_gap_to_the_optimum():
    task = _contextual()
    alg = ContextualBO.for_task(task, rng=0)
    res = learn(task, alg, 4, 10, rng=1, progress=False, eval_contexts=EVAL)
    # start: ω = 0, so the gap to the optimum (reward 0) is the mean of ‖ω*(s)‖²
    start_gap = float(np.mean(np.sum(_target(EVAL) ** 2, axis=1)))
    assert res["mean_reward"][0] == pytest.approx(-start_gap)
    assert -res["mean_reward"][-1] < 0.1 * start_gap  # 90 % of the gap closed
    assert res["explore_reward"][-1] > res["explore_reward"][0]  # UCB beats the Sobol design
    diag = res["diagnostics"]
    assert all(isinstance(d, CBODiagnostics) for d in diag)
    assert [d.random_batch for d in diag] == [True, False, False, False]
    assert [d.n_fitted for d in diag] == [10, 20, 30, 40]
    assert len(diag[-1].lengthscales) == 4 and diag[-1].best_reward <= 0.0
    assert diag[-1].fit_seconds > 0 and diag[-1].acquisition_seconds > 0
    # the policy mean follows the context: its error is a fraction of that of the best
    # context-independent ω (the average of ω*(s) over the contexts)
    err = np.mean(np.sum((alg.policy.mean_of(EVAL) - _target(EVAL)) ** 2, axis=1))
    constant_err = np.mean(np.sum((_target(EVAL) - _target(EVAL).mean(axis=0)) ** 2, axis=1))
    assert err < 0.25 * constant_err


def test_proposals_lie_in_the_box_around_the_initial_policy():
    task = _contextual()
    pol = LinearGaussianPolicy(np.array([0.3, -0.2]), np.diag([0.25, 1.0]), [[1, 0], [0, 0]], 2)
    alg = ContextualBO.for_task(task, pol, settings=CBOSettings(box_std=3.0), rng=0)
    # mean a + A s over s ∈ [−1, 1]²: ω₀ ∈ [−0.7, 1.3], ω₁ = −0.2; ± 3 std (a few roundings
    # of values ≤ 3.2: the corners' a + A s, the square root, the product and the sum)
    bounds = [[-2.2, -3.2], [2.8, 2.8]]
    np.testing.assert_allclose(alg.omega_bounds, bounds, rtol=0, atol=fp_tol(6, scale=3.2))
    s = task.sample_context(2, n=8)
    np.testing.assert_array_equal(alg.policy.mean_of(s), pol.mean_of(s))  # no data: π₀'s mean
    low, high = alg.omega_bounds
    for _ in range(2):  # the Sobol design, then UCB proposals
        omegas = alg.policy.sample(s, 3)
        assert omegas.shape == (8, 2)
        assert np.all((omegas >= low) & (omegas <= high))
        alg.update(collect(task, alg.policy, 6, rng=4))
    assert np.all((alg.policy.mean_of(s) >= low) & (alg.policy.mean_of(s) <= high))


def test_same_seed_same_proposals_and_global_torch_state_untouched():
    task = _contextual()
    batch = collect(task, ContextualBO.for_task(task, rng=0).policy, 10, rng=5)
    s = task.sample_context(6, n=5)

    def proposals(seed, sample_seed):
        alg = ContextualBO.for_task(task, rng=seed)
        alg.update(batch)
        return alg.policy.sample(s, sample_seed), alg.policy.mean_of(s)

    torch.manual_seed(123)
    state = torch.random.get_rng_state()
    a, mean_a = proposals(0, 7)
    assert torch.equal(torch.random.get_rng_state(), state)  # BoTorch ran under fork_rng
    b, mean_b = proposals(0, 7)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(mean_a, mean_b)
    c, _ = proposals(0, 8)
    assert not np.array_equal(a, c)  # another sample stream, other restarts
    # a context's mean does not depend on the contexts asked with it
    alg = ContextualBO.for_task(task, rng=0)
    alg.update(batch)
    np.testing.assert_array_equal(alg.policy.mean_of(s[2]), mean_a[2])


def test_checkpointed_run_resumes_to_identical_numbers_and_pickles():
    task = _contextual()
    full = Snapshots()
    reference = learn(
        task, ContextualBO.for_task(task, rng=3), 3, 6, 4, trial=full, eval_contexts=EVAL
    )
    alg = ContextualBO.for_task(task, rng=3)
    resumed = learn(task, alg, 3, 6, 4, trial=Snapshots(states=full.history[0]), eval_contexts=EVAL)
    for key in ("mean_reward", "explore_reward", "n_failed"):
        np.testing.assert_array_equal(reference[key], resumed[key], err_msg=key)
    assert alg.n_updates == 3 and alg.n_observations == 18
    copy = pickle.loads(pickle.dumps(alg))
    batch = collect(task, alg.policy, 6, rng=9)
    alg.update(batch)
    copy.update(batch)
    np.testing.assert_array_equal(alg.policy.sample(EVAL, 1), copy.policy.sample(EVAL, 1))


def test_failed_rollouts_enter_the_gp_at_the_worst_working_reward():
    task = _contextual(_fails_far_right)
    alg = ContextualBO.for_task(task, rng=0)
    with pytest.warns(RuntimeWarning):  # the task reports each failure
        batch = collect(task, alg.policy, 16, rng=2)  # Sobol over [−2, 2]²: some ω₀ > 1
    failed = np.array([t.failed for t in batch.trajectories])
    assert 0 < failed.sum() < 16
    diag = alg.update(batch)
    assert diag.n_failed == failed.sum()
    assert diag.best_reward == batch.rewards[~failed].max()
    targets = alg.policy.model.outcome_transform.untransform(
        alg.policy.model.train_targets[:, None]
    )[0]
    assert float(targets.min()) == pytest.approx(batch.rewards[~failed].min(), rel=1e-9)


def _always_fails(omega, context, rng):
    raise RuntimeError("diverged")


def test_while_every_rollout_failed_there_is_no_gp_and_the_design_goes_on():
    """All rewards equal (the worst): no GP is fitted (BoTorch would warn of a zero outcome
    std and constant acquisition values); the Sobol design and π₀'s mean continue."""
    task = _contextual(_always_fails)
    alg = ContextualBO.for_task(task, rng=0)
    for k in range(2):
        with pytest.warns(RuntimeWarning, match="rollout failed"):
            batch = collect(task, alg.policy, 6, rng=k)
        diag = alg.update(batch)
        assert diag.n_failed == 6 and diag.n_fitted == 0 and diag.random_batch
        assert np.isnan(diag.best_reward) and alg.policy.model is None
    np.testing.assert_array_equal(alg.policy.mean_of(EVAL), task.initial_policy().mean_of(EVAL))
    low, high = alg.omega_bounds
    omegas = alg.policy.sample(EVAL, 3)
    assert np.all((omegas >= low) & (omegas <= high)) and len({tuple(w) for w in omegas}) == 4
    # the failed rollouts enter at the lowest working reward: one working rollout leaves all
    # rewards equal, a second, other one makes them differ and the GP is fitted on all 14
    assert alg.update(Batch(EVAL[:1], omegas[:1], np.array([-1.0]))).n_fitted == 0
    assert alg.update(Batch(EVAL[1:2], omegas[1:2], np.array([-2.0]))).n_fitted == 14
    assert alg.policy.model is not None


def test_context_free_task_is_plain_bo_and_max_observations_caps_the_fit():
    task = FunctionTask(lambda w, s, rng: -float(np.sum((w - 0.7) ** 2)), 3)
    alg = ContextualBO.for_task(task, settings=CBOSettings(max_observations=12), rng=0)
    assert alg.policy.mean_of().shape == (3,)
    diags = [alg.update(collect(task, alg.policy, 8, rng=k)) for k in range(2)]
    assert [d.n_fitted for d in diags] == [8, 12] and diags[-1].n_observations == 16
    assert alg.policy.sample(None, 0).shape == (3,)


def test_bad_input_is_named():
    task = _contextual()
    ok = task.initial_policy()
    with pytest.raises(ValueError, match="policy: expected a LinearGaussianPolicy"):
        ContextualBO("not a policy")
    with pytest.raises(ValueError, match="context_low, context_high"):
        ContextualBO(ok)
    with pytest.raises(ValueError, match="context_high"):
        ContextualBO(ok, context_low=[0, 0], context_high=[1, -1])
    with pytest.raises(ValueError, match="omega_low, omega_high"):
        ContextualBO.for_task(task, omega_low=[0, 0])
    with pytest.raises(ValueError, match="omega_high"):
        ContextualBO.for_task(task, omega_low=[0, 0], omega_high=[1, 0])
    quad = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2, features="quadratic")
    with pytest.raises(ValueError, match="policy: the ω box"):
        ContextualBO.for_task(task, quad)
    ContextualBO.for_task(task, quad, omega_low=[-1, -1], omega_high=[1, 1])  # box given: fine
    with pytest.raises(ValueError, match="settings"):
        ContextualBO.for_task(task, settings={"beta": 1.0})
    with pytest.raises(ValueError, match="dtype"):
        ContextualBO.for_task(task, dtype=torch.int64)
    with pytest.raises(ValueError, match="device"):
        ContextualBO.for_task(task, device="no-such-device")
    for field, value in [
        ("beta", -1.0),
        ("box_std", 0.0),
        ("initial_batches", 0),
        ("raw_samples", 5),
        ("max_observations", 1),
    ]:
        with pytest.raises(ValueError, match=field):
            CBOSettings(**{field: value})
    alg = ContextualBO.for_task(task, rng=0)
    with pytest.raises(ValueError, match="contexts: expected shape"):
        alg.policy.sample(np.zeros((3, 3)), 0)
    with pytest.raises(ValueError, match="contexts: this policy needs contexts"):
        alg.policy.mean_of()
    with pytest.raises(ValueError, match="batch: expected a skillkit.search.Batch"):
        alg.update("not a batch")
    with pytest.raises(ValueError, match="omegas"):
        alg.update(Batch(np.zeros((2, 2)), np.zeros((2, 3)), np.zeros(2)))
    with pytest.raises(ValueError, match="contexts: expected shape"):
        ContextualBO(GaussianPolicy(np.zeros(2), np.eye(2)), settings=CBOSettings()).update(
            Batch(np.zeros((2, 2)), np.zeros((2, 2)), np.zeros(2))
        )


def test_batched_proposals_equal_one_search_per_row():
    """``sample`` searches all rows in one optimiser call; each row's proposal is the UCB
    maximiser that ``optimize_acqf`` finds for that row alone with the row's seed (the same
    Sobol starts; the two runs differ only by round-off in the batched evaluation, which
    L-BFGS-B's stopping rule, a relative decrease below factr·ε ≈ 2.2e-9, passes on)."""
    from botorch.acquisition import UpperConfidenceBound

    task = _contextual()
    alg = ContextualBO.for_task(task, rng=0)
    alg.update(collect(task, alg.policy, 12, rng=1))
    policy = alg.policy
    s = task.sample_context(2, n=4)
    seeds = np.random.default_rng(3).integers(2**31, size=4)
    acqf = UpperConfidenceBound(policy.model, beta=policy.settings.beta)
    batched = policy._argmax_rows(acqf, s, seeds)
    alone = np.stack([policy._argmax(acqf, si, int(k)) for si, k in zip(s, seeds, strict=True)])

    def ucb(omega):
        z = torch.as_tensor(np.hstack([s, omega]), dtype=torch.float64)[:, None, :]
        with torch.no_grad():
            return acqf(z).numpy()

    a, b = ucb(batched), ucb(alone)
    # L-BFGS-B (scipy's default factr = 1e7) stops at a relative decrease of 1e7 ε per step
    lbfgsb = 1e7 * np.finfo(np.float64).eps
    assert np.all(np.abs(a - b) <= SAFETY * lbfgsb * np.maximum(np.abs(b), 1)), (a, b)
    assert np.all((batched >= policy.omega_bounds[0]) & (batched <= policy.omega_bounds[1]))
