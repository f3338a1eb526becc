"""Extra contexts (Sec. 3.4) without bias: the importance weights of re-scored rows, their use
in REPS ("naive" / "importance" / "dual_only"), the sample buffer's bookkeeping."""

import warnings

import numpy as np
import pytest
from _tolerances import fp_tol
from scipy import stats

from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.base import Batch, SampleBuffer, extra_context_importance
from skillkit.search.loop import collect
from skillkit.search.reps import ContextualREPS
from skillkit.tasks.toy import LinearTarget

GAIN = 2.0  # the optimal policy mean is ω = GAIN · s


Target = LinearTarget  # the optimal linear-Gaussian policy has gain A = GAIN I, offset 0


def optimal_policy(std=0.5):
    return LinearGaussianPolicy(np.zeros(2), std**2 * np.eye(2), GAIN * np.eye(2), context_dim=2)


def test_importance_weights_match_a_direct_computation():
    rng = np.random.default_rng(0)
    pol = LinearGaussianPolicy(
        np.array([0.1, -0.2]), np.array([[0.5, 0.1], [0.1, 0.3]]), rng.normal(size=(2, 2)), 2
    )
    batch = collect(Target(), pol, 6, rng, extra_contexts=3)
    w = extra_context_importance(pol, batch.contexts, batch.omegas, batch.n_rollouts)
    n, f = 6, 1 / 4
    dens = [
        [stats.multivariate_normal(pol.mean_of(sj), pol.cov).pdf(om) for sj in batch.contexts]
        for om in batch.omegas
    ]
    dens = np.array(dens)  # dens[r, j] = π(ω_r | s_j)
    own = np.diag(dens)
    mix = dens[:, :n].mean(axis=1)
    # Densities from two implementations: the exponent −½ dᵀΣ⁻¹d off by ~D ε κ(Σ)(1 + dᵀΣ⁻¹d)
    # (absolute, so relative in the density), then an n-term mean and the ratio.
    means = np.array([pol.mean_of(sj) for sj in batch.contexts])
    d = batch.omegas[:, None, :] - means[None, :, :]
    quad = float(np.einsum("rjd,de,rje->rj", d, np.linalg.inv(pol.cov), d).max())
    rel = fp_tol(len(pol.cov) + n + 4, scale=1 + quad, cond=np.linalg.cond(pol.cov))
    np.testing.assert_allclose(w, own / (f * own + (1 - f) * mix), rtol=rel)
    assert np.all(w > 0) and np.all(w <= 1 / f + 1e-12)
    # no extra rows: every weight is one
    np.testing.assert_array_equal(
        extra_context_importance(pol, batch.contexts[:n], batch.omegas[:n], n), np.ones(n)
    )


@pytest.mark.parametrize("seed", range(3))
def test_naive_extra_contexts_bias_the_gain_towards_zero_importance_does_not(seed):
    # One REPS update from the optimal policy N(2s, 0.25 I): the exact REPS solution
    # p ∝ π exp(R/η) keeps the mean 2s (the reward is symmetric about it), so an unbiased
    # update keeps the gain at 2 I. Measured over seeds 0–39 (entries of gain / 2 I − I): naive
    # −0.34 ± 0.034 on the diagonal, importance 0.00 ± 0.014, dual_only 0.00 ± 0.031 (mean ± SD
    # over seeds: the Monte Carlo spread of one update on 200 rollouts). Tolerances are five of
    # those standard deviations: unbiased modes within 5 SD of I, naive more than 5 SD below it.
    task = Target()
    batch = collect(task, optimal_policy(), 200, seed, extra_contexts=20)
    gains = {}
    for mode in ("naive", "importance", "dual_only"):
        reps = ContextualREPS(optimal_policy(), 0.5, extra_context_weighting=mode)
        diag = reps.update(batch)
        assert diag.success and diag.kl == pytest.approx(0.5, rel=1e-3)
        gains[mode] = reps.policy.gain / GAIN
    assert np.all(np.diag(gains["naive"]) < 1 - 5 * 0.034)
    for mode, sd in (("importance", 0.014), ("dual_only", 0.031)):
        np.testing.assert_allclose(gains[mode], np.eye(2), atol=5 * sd)


def test_importance_weights_are_the_dual_base_and_dual_only_fits_rollouts():
    task = Target()
    pol = task.initial_policy()
    batch = collect(task, pol, 10, 3, extra_contexts=4)
    imp = ContextualREPS(pol, 0.5, extra_context_weighting="importance")
    imp.update(batch)
    q = imp._buffer.importance()
    w = extra_context_importance(pol, batch.contexts, batch.omegas, 10)
    np.testing.assert_allclose(q, w / w.mean())  # stored normalised to mean one
    only = ContextualREPS(pol, 0.5, extra_context_weighting="dual_only")
    only._buffer.add(batch.contexts, batch.omegas, batch.rewards, batch.n_rollouts)
    weights, fields = only._weigh(batch.contexts, batch.rewards)
    assert fields["kl"] == pytest.approx(0.5, rel=1e-3)  # the dual on every row
    assert np.all(weights[10:] == 0) and weights.sum() == pytest.approx(1.0)
    assert only._buffer.importance() is None  # dual_only keeps no importance weights


def test_same_seed_same_result_and_batches_without_extras_are_unaffected():
    task = Target()
    runs = []
    for _ in range(2):
        reps = ContextualREPS(task.initial_policy(), 0.5, extra_context_weighting="importance")
        for k in range(3):
            reps.update(collect(task, reps.policy, 8, k, extra_contexts=5))
        runs.append(reps.policy)
    np.testing.assert_array_equal(runs[0].gain, runs[1].gain)
    np.testing.assert_array_equal(runs[0].cov, runs[1].cov)
    # without extra rows the three choices are one algorithm, to the bit
    batch = collect(task, task.initial_policy(), 20, 9)
    fits = []
    for mode in ("naive", "importance", "dual_only"):
        reps = ContextualREPS(task.initial_policy(), 0.5, extra_context_weighting=mode)
        reps.update(batch)
        fits.append(reps.policy)
    for other in fits[1:]:
        np.testing.assert_array_equal(other.gain, fits[0].gain)
        np.testing.assert_array_equal(other.cov, fits[0].cov)


def test_buffer_marks_rollouts_across_batches():
    buf = SampleBuffer(2)
    s, w, r = np.zeros((6, 1)), np.zeros((6, 1)), np.zeros(6)
    buf.add(s, w, r, 2, np.arange(1.0, 7.0))
    buf.add(s[:3], w[:3], r[:3])
    np.testing.assert_array_equal(buf.rollout_mask(), [1, 1, 0, 0, 0, 0, 1, 1, 1])
    np.testing.assert_allclose(buf.importance(), np.r_[np.arange(1.0, 7.0) / 3.5, np.ones(3)])


def test_bad_input_names_the_argument():
    pol = Target().initial_policy()
    with pytest.raises(ValueError, match="extra_context_weighting"):
        ContextualREPS(pol, 0.5, extra_context_weighting="unbiased")
    s, w, r = np.zeros((4, 2)), np.zeros((4, 2)), np.zeros(4)
    for bad in (0, 5, 1.5, True):
        with pytest.raises(ValueError, match="n_rollouts"):
            Batch(s, w, r, n_rollouts=bad)
        with pytest.raises(ValueError, match="n_rollouts"):
            extra_context_importance(pol, s, w, bad)
    with pytest.raises(ValueError, match="omegas"):
        extra_context_importance(pol, s, np.zeros((4, 3)), 2)
    assert Batch(s, w, r).n_rollouts == 4 and Batch(s, w, r, n_rollouts=2).n_rollouts == 2


def test_dual_only_with_no_weight_left_on_the_rollouts_is_a_clear_error():
    # All of the dual's weight on extra-context rows: the rollout rows' weights underflow to
    # zero; renormalised 0/0 they would be NaN (a RuntimeWarning, then an error about
    # non-finite "weights" from the fit).
    rng = np.random.default_rng(0)
    pol = LinearGaussianPolicy(np.zeros(1), np.eye(1), context_dim=1)
    reps = ContextualREPS(
        pol, epsilon=5.0, extra_context_weighting="dual_only", baseline_features="linear"
    )
    n, k = 5, 3
    s = rng.uniform(-1, 1, (n, 1))
    w = pol.sample(s, rng)
    rewards = np.r_[np.full(n, -1000.0), rng.normal(size=n * k)]
    batch = Batch(
        np.r_[s, rng.uniform(-1, 1, (n * k, 1))], np.r_[w, np.repeat(w, k, 0)], rewards, None, n
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(ValueError, match="extra_context_weighting: with 'dual_only'"):
            reps.update(batch)
