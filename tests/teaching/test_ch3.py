"""skillkit.teaching.ch3: one contextual REPS update taken apart (Sec. 3.3, Table 3.1).

Reference values are independent computations (the dual (3.9) and the weights (3.10) written
out with scipy's logsumexp, Monte Carlo moments, closed forms of the 1-σ ellipse), with
tolerances from round-off, the solver's tolerances or the Monte Carlo standard error.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import brentq
from scipy.special import logsumexp

from skillkit.experiments.sanity import LinearOptimumTask
from skillkit.policies.features import context_features
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search import ContextualREPS, collect, reps_weights
from skillkit.search.reps import KL_TOLERANCE
from skillkit.teaching import ch3
from skillkit.viz.plots import NotebookFigure
from tests._tolerances import fp_tol

EPS64 = np.finfo(float).eps


@pytest.fixture(scope="module")
def batch():
    """60 rollouts of LinearOptimumTask's initial policy (as the notebook's, smaller)."""
    task = LinearOptimumTask()
    policy = task.initial_policy()
    b = collect(task, policy, 60, rng=np.random.default_rng(3))
    return task, policy, b, context_features(b.contexts, "quadratic")


@pytest.fixture(scope="module")
def update(batch):
    """One REPS update by hand: the dual's solution and the weighted ML fit."""
    _, policy, b, phi = batch
    sol = reps_weights(b.rewards, phi, 0.5)
    return sol, policy.fit(b.contexts, b.omegas, sol.weights)


def _dual_by_hand(eta, gamma, rewards, phi, epsilon):
    """g(η, γ) of Eq. (3.9) written out, and the KL of its weights (3.10) from uniform."""
    a = (rewards - phi @ gamma) / eta
    g = eta * (logsumexp(a) - np.log(a.size)) + eta * epsilon + gamma @ phi.mean(axis=0)
    log_p = a - logsumexp(a)
    return g, float(np.sum(np.exp(log_p) * (log_p + np.log(a.size))))


def _trace(fig, name):
    """The plotly traces named ``name`` (one per panel it appears in)."""
    traces = [t for t in fig.data if t.name == name]
    assert traces, (name, [t.name for t in fig.data])
    return traces


# ----------------------------------------------------------------------------- (a) dual
def test_dual_slice_is_the_dual_3_9_and_its_minimum_is_where_the_kl_reaches_epsilon(batch):
    _, _, b, phi = batch
    s = ch3.dual_slice(b.rewards, phi, 0.5, span=10.0, n_points=41)
    sol = s.solution
    assert sol.kl_bound_active and sol.eta in s.eta and s.eta.size == 41  # η* is the middle
    assert ch3.dual_slice(b.rewards, phi, 0.5, n_points=40).eta.size == 41  # η* added
    for eta, value, kl in zip(s.eta, s.value, s.kl, strict=True):
        g, kl_hand = _dual_by_hand(eta, sol.gamma, b.rewards, phi, 0.5)
        scale = np.abs(b.rewards).max() + np.abs(sol.gamma).sum() * np.abs(phi).max()
        assert value == pytest.approx(g, abs=100 * EPS64 * scale * b.rewards.size)
        assert kl == pytest.approx(kl_hand, abs=1e-9)
    # along the slice the minimum is the grid point η*, where KL = ε (∂g/∂η = 0, A.11)
    k = int(np.argmin(s.value))
    assert s.eta[k] == sol.eta and s.value_at_minimum == s.value[k]
    assert abs(s.kl[k] - 0.5) <= KL_TOLERANCE * 0.5
    # g is convex in η: its slopes between grid points increase (up to round-off)
    slopes = np.diff(s.value) / np.diff(s.eta)
    assert np.all(np.diff(slopes) >= -1e-9 * np.abs(slopes).max())
    # the KL falls with η (larger η, flatter weights), from above ε to below it
    assert np.all(np.diff(s.kl) <= 1e-12) and s.kl[0] > 0.5 > s.kl[-1]


def test_episode_based_dual_minimiser_matches_the_two_sample_closed_form():
    # Two rewards 0 and 1: p = (1 − σ, σ) with σ = 1/(1 + e^{−1/η}); KL = log 2 − H(σ).
    # For KL = ε the root σ* gives η* = 1/logit(σ*).
    epsilon = 0.2

    def kl(sig):
        return np.log(2) + sig * np.log(sig) + (1 - sig) * np.log1p(-sig) - epsilon

    s_star = brentq(kl, 0.5 + 1e-12, 1 - 1e-15, xtol=1e-15, rtol=4 * EPS64)
    eta_star = 1.0 / np.log(s_star / (1 - s_star))
    s = ch3.dual_slice([0.0, 1.0], None, epsilon)
    # the solver stops at a gradient of 1e-11 (DUAL_GTOL): η* to far better than 1e-7
    assert s.solution.eta == pytest.approx(eta_star, rel=1e-7)
    assert s.solution.gamma.shape == (0,)


def test_dual_figure_marks_the_minimiser_in_both_panels(batch):
    _, _, b, phi = batch
    fig = ch3.dual_figure(b.rewards, phi, 0.5)
    sol = reps_weights(b.rewards, phi, 0.5)
    marks = _trace(fig, f"minimiser η* = {sol.eta:.3g}")
    assert len(marks) == 2
    assert marks[0].x[0] == pytest.approx(sol.eta, rel=1e-9)
    assert marks[1].y[0] == pytest.approx(sol.kl, rel=1e-9)
    curve = _trace(fig, "g(η, γ*) (Eq. 3.9)")[0]
    # the mark is the curve's own value at its grid point η*, the curve's minimum (the other
    # grid points lie a factor ≥ 10^(2/(n−1)) away, far above round-off): equal exactly
    assert marks[0].y[0] == min(curve.y)
    assert fig.layout.xaxis.type == "log" and "η" in fig.layout.xaxis.title.text
    assert isinstance(ch3.dual_figure(b.rewards, phi, 0.5, backend="matplotlib"), NotebookFigure)


def test_unattainable_epsilon_is_said_in_the_title(batch):
    _, _, b, phi = batch
    fig = ch3.dual_figure(b.rewards, phi, 10.0)  # ε > log 60: no weighting reaches it
    assert "lower bound" in fig.layout.title.text


# ------------------------------------------------------------------- (b, c) weights, KL
def test_kl_sweep_meets_the_bound_and_never_exceeds_log_n(batch):
    _, _, b, phi = batch
    eps = np.geomspace(0.01, 10.0, 9)
    sweep = ch3.kl_sweep(b.rewards, phi, eps)
    n = b.rewards.size
    assert np.all(sweep.kl <= (1 + KL_TOLERANCE) * eps)
    active = sweep.active
    assert np.allclose(sweep.kl[active], eps[active], rtol=KL_TOLERANCE)
    assert not active[-1] and np.all(sweep.kl <= np.log(n) * (1 + 1e-12))
    # a looser bound allows a larger KL and fewer effective samples (up to solver tolerance)
    assert np.all(np.diff(sweep.kl) >= -KL_TOLERANCE * sweep.kl[1:])
    assert np.all(np.diff(sweep.ess) <= 1e-6 * n)
    assert np.all((sweep.ess >= 1 - 1e-12) & (sweep.ess <= n * (1 + 1e-12)))


def test_weights_figure_draws_the_weights_3_10_on_one_exponential(batch):
    _, _, b, phi = batch
    fig = ch3.weights_and_kl_figure(b.rewards, phi, 0.5, epsilons=[0.1, 0.5, 2.0])
    sol = reps_weights(b.rewards, phi, 0.5)
    n = b.rewards.size
    by_reward, by_advantage = _trace(fig, "samples")
    assert np.allclose(by_reward.x, b.rewards) and np.allclose(by_reward.y, n * sol.weights)
    adv = b.rewards - sol.baseline
    assert np.allclose(by_advantage.x, adv)
    # Eq. (3.10) written out: N p_i = N exp(A_i/η) / Σ_j exp(A_j/η)
    by_hand = n * np.exp(adv / sol.eta - logsumexp(adv / sol.eta))
    assert np.allclose(by_advantage.y, by_hand, rtol=1e-9)
    # the weights sum to one: normalised by a sum of n terms (≲ n ε), re-summed here (n ε)
    assert sum(by_reward.y) == pytest.approx(n, rel=fp_tol(2 * n + 2))
    # the drawn curve passes through the samples: linear interpolation between its 200 points
    # errs by at most (Δ/η)²/8 relative (Δ the grid step; the curve is exp(A/η))
    curve = _trace(fig, "N exp(A/η) / Σ exp(A_j/η) (Eq. 3.10)")[0]
    step = (adv.max() - adv.min()) / 199
    inside = np.interp(adv, curve.x, curve.y)
    assert np.allclose(inside, by_hand, rtol=(step / sol.eta) ** 2 / 8 + 1e-12)
    here = _trace(fig, "this ε = 0.5")
    assert [t.y[0] for t in here] == pytest.approx([sol.kl, sol.ess], rel=1e-9)
    assert isinstance(
        ch3.weights_and_kl_figure(b.rewards, phi, 0.5, epsilons=[0.5], backend="matplotlib"),
        NotebookFigure,
    )


def test_weights_figure_draws_the_bound_as_the_identity_on_the_log_axis(batch):
    _, _, b, phi = batch
    fig = ch3.weights_and_kl_figure(b.rewards, phi, 0.5, epsilons=[0.01, 0.5, 10.0])
    line = _trace(fig, "KL = ε (the bound, Eq. 3.4)")[0]
    np.testing.assert_array_equal(line.x, line.y)  # the same grid drawn as x and y
    # read off as drawn (straight segments on a log-ε axis): at ε = 0.5 the line is at 0.5,
    # to within the chord error of y = ε between grid points a factor 1000^(1/199) apart
    drawn = np.interp(np.log(0.5), np.log(line.x), line.y)
    assert drawn == pytest.approx(0.5, rel=(1000 ** (1 / 199) - 1) ** 2)


def test_weights_figure_says_when_the_bound_is_inactive(batch):
    _, _, b, phi = batch
    fig = ch3.weights_and_kl_figure(b.rewards, phi, 10.0, epsilons=[0.5, 10.0])
    assert "bound inactive" in fig.layout.title.text


# ---------------------------------------------------------------------------- (d) ellipse
def test_policy_moments_match_monte_carlo_draws():
    rng = np.random.default_rng(7)
    pol = LinearGaussianPolicy(
        [0.3, -0.2], [[0.04, 0.01], [0.01, 0.09]], [[1.0, -0.5], [0.2, 0.4]], context_dim=2
    )
    contexts = rng.uniform(-1, 1, size=(5, 2))
    q = np.array([0.1, 0.2, 0.3, 0.25, 0.15])
    mean, cov = ch3.policy_moments(pol, contexts, q)
    n = 400_000
    s = contexts[rng.choice(5, size=n, p=q)]
    draws = pol.sample(s, rng)
    se_mean = np.sqrt(np.diag(cov) / n)
    assert np.all(np.abs(draws.mean(axis=0) - mean) <= 5 * se_mean)
    # the standard error of a sample covariance entry is at most sqrt(E[x²y²]/n) ≤ ~sqrt(3)σσ/√n
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(np.cov(draws.T) - cov) <= 5 * np.sqrt(3) * np.outer(sd, sd) / np.sqrt(n))
    # one context: the policy's own Σ around its mean there
    m1, c1 = ch3.policy_moments(pol, contexts[:1])
    assert np.allclose(m1, pol.mean_of(contexts[:1])[0]) and np.allclose(c1, pol.cov)


def test_new_policy_is_the_mean_and_covariance_of_the_reweighted_samples(batch, update):
    _, _, b, _ = batch
    sol, new = update
    p = sol.weights
    mean_p = p @ b.omegas
    cov_p = ((b.omegas - mean_p) * p[:, None]).T @ (b.omegas - mean_p)
    mean, cov = ch3.policy_moments(new, b.contexts)
    # exact for the plain weighted ML fit under (3.5); the fit's relative ridge (1e-6) and the
    # feature constraint's tolerance (1e-6 of the features' spread) perturb it at that level
    scale = np.abs(cov_p).max()
    assert np.allclose(mean, mean_p, atol=1e-5 * np.sqrt(scale))
    assert np.allclose(cov, cov_p, atol=1e-5 * scale)


def test_ellipse_points_lie_on_the_one_sigma_contour():
    mean = np.array([1.0, -2.0, 0.5])
    cov = np.array([[2.0, 0.3, 0.6], [0.3, 0.5, -0.1], [0.6, -0.1, 1.0]])
    xy = ch3.ellipse_points(mean, cov, dims=(0, 2), n_points=64)
    block = cov[np.ix_([0, 2], [0, 2])]
    d = xy - mean[[0, 2]]
    maha = np.einsum("ni,ij,nj->n", d, np.linalg.inv(block), d)
    assert np.allclose(maha, 1.0, atol=100 * EPS64 * np.linalg.cond(block))
    assert np.allclose(xy[0], xy[-1])  # closed
    # its extent along each axis is one standard deviation
    assert xy[:, 0].max() - mean[0] == pytest.approx(np.sqrt(2.0), rel=2e-3)  # 64 points


def test_heaviest_samples_are_the_fewest_holding_the_mass():
    w = np.array([0.2, 0.5, 0.3])
    assert ch3.heaviest_samples(w, 0.5).tolist() == [1]
    assert ch3.heaviest_samples(w, 0.6).tolist() == [1, 2]
    assert ch3.heaviest_samples(w, 1.0).tolist() == [0, 1, 2]
    assert ch3.heaviest_samples(np.ones(4), 0.5).tolist() == [0, 1]
    rng = np.random.default_rng(0)
    w = rng.exponential(size=50)
    k = ch3.heaviest_samples(w, 0.7)
    assert w[k].sum() >= 0.7 * w.sum() * (1 - 1e-12)
    assert w[k].sum() - w[k].min() < 0.7 * w.sum()  # one fewer would not do


def test_ellipse_figure_draws_the_moments_and_the_heavy_samples(batch, update):
    _, policy, b, _ = batch
    sol, new = update
    fig = ch3.ellipse_figure(policy, new, b.contexts, b.omegas, sol.weights, dims=(1, 2))
    heavy = ch3.heaviest_samples(sol.weights)
    samples = [t for t in fig.data if t.name.startswith("samples holding 50%")][0]
    assert np.allclose(samples.x, b.omegas[heavy, 1]) and np.allclose(samples.y, b.omegas[heavy, 2])
    ell = _trace(fig, "new policy, 1σ over the batch's contexts")[0]
    expected = ch3.ellipse_points(*ch3.policy_moments(new, b.contexts), (1, 2))
    assert np.allclose(ell.x, expected[:, 0]) and np.allclose(ell.y, expected[:, 1])
    old = _trace(fig, "old policy, 1σ over the batch's contexts")[0]
    assert np.allclose(np.hypot(np.array(old.x), np.array(old.y)), 0.5)  # N(0, 0.5² I)
    assert fig.layout.xaxis.title.text == "ω_2" and fig.layout.yaxis.title.text == "ω_3"
    assert isinstance(
        ch3.ellipse_figure(policy, new, b.contexts, b.omegas, sol.weights, backend="matplotlib"),
        NotebookFigure,
    )


# ------------------------------------------------------------------------------ tables
def test_update_table_reports_the_update(batch, update):
    task, policy, b, _ = batch
    sol, new = update
    table = ch3.update_table(sol, b.rewards, policy, new, b.contexts, task.optimal_coefficients)
    assert isinstance(table, pd.DataFrame) and table.shape[0] == 1
    row = table.iloc[0]
    four = 5e-4  # values are rounded to 4 significant digits
    assert row["N (samples used)"] == b.rewards.size and row["bound active"]
    assert row["η"] == pytest.approx(sol.eta, rel=four)
    assert row["KL(p ‖ q)"] == pytest.approx(0.5, rel=four)
    assert row["ESS"] == pytest.approx(1 / np.sum(sol.weights**2), rel=four)
    assert row["mean reward (batch)"] == pytest.approx(b.rewards.mean(), rel=four)
    assert row["KL(π_new ‖ π_old)"] == pytest.approx(new.kl(policy, b.contexts), rel=four)
    err = np.abs(new.coefficients - task.optimal_coefficients).max()
    assert row["max|θ − θ*| after"] == pytest.approx(err, rel=four)
    assert row["max|θ − θ*| before"] == pytest.approx(1.0, rel=four)  # |a*₁| = 1, θ₀ = 0
    assert list(table.columns[: len(ch3.COLUMNS)]) == list(ch3.COLUMNS)


def test_diagnostics_table_of_table_3_1_is_reproducible(batch):
    task = batch[0]

    def run(seed):
        reps = ContextualREPS(task.initial_policy(), epsilon=0.5, n_reuse_batches=2)
        rng = np.random.default_rng(seed)
        updates = [reps.update(collect(task, reps.policy, 20, rng)) for _ in range(3)]
        return ch3.diagnostics_table(updates)

    table = run(1)
    assert table.index.tolist() == [1, 2, 3] and table.index.name == "update"
    assert table["N (samples used)"].tolist() == [20, 40, 40]  # min(k, L) batches of 20
    assert np.all(table["KL(p ‖ q)"] <= 0.5 * (1 + KL_TOLERANCE) + 5e-4)
    pd.testing.assert_frame_equal(table, run(1))  # same seed ⇒ same updates


# ------------------------------------------------------------------------------ errors
@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda b, phi: ch3.dual_slice(np.ones(5), None, 0.5), "rewards: all rewards are equal"),
        (lambda b, phi: ch3.dual_slice(b.rewards, phi[:3], 0.5), "features"),
        (lambda b, phi: ch3.dual_slice(b.rewards, phi, -1.0), "epsilon"),
        (lambda b, phi: ch3.dual_slice(b.rewards, phi, 0.5, span=1.0), "span"),
        (lambda b, phi: ch3.dual_slice(b.rewards, phi, 0.5, n_points=2), "n_points"),
        (lambda b, phi: ch3.dual_slice([1.0], None, 0.5), "rewards"),
        (lambda b, phi: ch3.kl_sweep(b.rewards, phi, [0.5, 0.0]), "epsilons"),
        (lambda b, phi: ch3.weights_and_kl_figure(b.rewards, phi, 0.0), "epsilon"),
        (lambda b, phi: ch3.heaviest_samples([0.5, 0.5], 1.5), "mass"),
        (lambda b, phi: ch3.heaviest_samples([0.0, 0.0], 0.5), "weights"),
        (lambda b, phi: ch3.ellipse_points(np.zeros(2), np.eye(2), dims=(0, 0)), "dims"),
        (lambda b, phi: ch3.ellipse_points(np.zeros(2), -np.eye(2)), "cov"),
        (lambda b, phi: ch3.diagnostics_table([]), "updates"),
        (lambda b, phi: ch3.diagnostics_table([1.0]), r"updates\[0\]"),
    ],
)
def test_bad_input_is_named(batch, call, match):
    _, _, b, phi = batch
    with pytest.raises(ValueError, match=match):
        call(b, phi)


def test_bad_policies_and_shapes_are_named(batch, update):
    task, policy, b, _ = batch
    sol, new = update
    with pytest.raises(ValueError, match="dims"):
        ch3.ellipse_figure(policy, new, b.contexts, b.omegas, sol.weights, dims=(0, 3))
    with pytest.raises(ValueError, match="contexts"):
        ch3.ellipse_figure(policy, new, b.contexts[:5], b.omegas, sol.weights)
    with pytest.raises(ValueError, match="contexts"):
        ch3.policy_moments(policy, None)
    other = LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2)
    with pytest.raises(ValueError, match="new"):
        ch3.ellipse_figure(policy, other, b.contexts, b.omegas, sol.weights)
    with pytest.raises(ValueError, match="solution"):
        ch3.update_table(object(), b.rewards, policy, new, b.contexts)
    with pytest.raises(ValueError, match="optimum"):
        ch3.update_table(sol, b.rewards, policy, new, b.contexts, np.zeros((2, 2)))


def test_the_update_by_hand_is_one_contextual_reps_update(batch, update):
    # The notebook's claim: ContextualREPS.update is reps_weights (3.9, 3.10) and the weighted
    # ML fit (3.11–3.12) on the kept batches; with one batch, the same numbers as by hand.
    _, policy, b, _ = batch
    sol, new = update
    reps = ContextualREPS(policy, epsilon=0.5, n_reuse_batches=1)
    diag = reps.update(b)
    by_hand = ch3.update_table(sol, b.rewards, policy, new, b.contexts)
    in_loop = ch3.diagnostics_table([diag])
    assert by_hand[list(ch3.COLUMNS)].to_numpy().tolist() == in_loop.to_numpy().tolist()
    assert np.array_equal(reps.policy.coefficients, new.coefficients)
    assert np.array_equal(reps.policy.cov, new.cov)
