"""skillkit.teaching.ch4: the GPREPS step-through (Table 4.1) and its tables and figures."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from skillkit.experiments import ch4_gpreps, stored_run
from skillkit.experiments.sanity import LinearOptimumTask
from skillkit.models.gp import report_event
from skillkit.policies.features import context_features
from skillkit.search import GPREPS, DirectRewardModel, GPREPSSettings, collect, learn
from skillkit.search.reps import reps_weights
from skillkit.tasks import make
from skillkit.teaching import ch4
from tests._tolerances import fp_tol

#: Sizes small enough for a test (each GP fit a few L-BFGS steps on tens of points).
TINY = dataclasses.replace(
    ch4.iteration_sizes("smoke"),
    n_initial=4,
    n_artificial=12,
    n_trajectories=2,
    n_inducing=5,
    gp_steps=3,
    robot_inducing=5,
    robot_steps=3,
    max_points=40,
)


def _step_through(task, model, settings, batch, seed):
    """The notebook's cells of Sec. 4.1, in GPREPS.update's order of draws."""
    rng = np.random.default_rng(seed)
    algo = GPREPS(task.initial_policy(), model, settings, rng=rng, task=task)
    algo.reward_model.fit(batch.contexts, batch.omegas, batch.rewards, batch.trajectories, rng)
    s = algo.sample_contexts(settings.n_artificial)
    w = algo.policy.sample(s, rng)
    r = algo.reward_model.expected_rewards(s, w, settings.n_trajectories, rng)
    phi = context_features(s, settings.baseline_features)
    weights = reps_weights(r, phi, settings.epsilon)
    new, _ = algo.policy.fit_with_info(
        s,
        w,
        weights.weights,
        ridge=settings.ridge,
        cov_shrinkage=settings.cov_shrinkage,
        cov_floor=settings.cov_floor,
        min_effective_samples=settings.min_effective_samples,
    )
    return algo, s, r, phi, weights, new


# ------------------------------------------------------------------ the step-through
def test_step_through_is_gpreps_update_bit_for_bit_gp_direct():
    task = LinearOptimumTask()
    settings = GPREPSSettings(n_artificial=60, context_model="prior")
    batch = collect(task, task.initial_policy(), 15, np.random.default_rng(3))
    with ch4.handled_events():  # noise-free rewards: the GP's noise ends at its floor
        algo, s, r, phi, weights, new = _step_through(task, DirectRewardModel(), settings, batch, 7)
        ref = GPREPS(task.initial_policy(), DirectRewardModel(), settings, rng=7, task=task)
        diag = ref.update(batch)
    table = ch4.update_comparison(weights, new, diag, ref.policy)
    assert table["equal"].all(), table
    # the dual's KL bound holds with equality and the weights are a distribution
    assert weights.kl == pytest.approx(settings.epsilon, rel=1e-3)
    # normalised by a sum of n terms (≲ n ε) and re-summed here (n ε)
    n = weights.weights.size
    assert weights.weights.sum() == pytest.approx(1.0, abs=fp_tol(2 * n + 2))


def test_step_through_is_gpreps_update_bit_for_bit_throwing_model():
    throw = make("throwing")
    settings = ch4.step_settings(TINY)
    batch = collect(throw, throw.initial_policy(), TINY.n_initial, np.random.default_rng(4))
    with ch4.handled_events():
        model = ch4.throwing_model(throw, TINY)
        algo, s, r, phi, weights, new = _step_through(throw, model, settings, batch, 0)
        ref = GPREPS(
            throw.initial_policy(), ch4.throwing_model(throw, TINY), settings, rng=0, task=throw
        )
        diag = ref.update(batch)
    assert ch4.update_comparison(weights, new, diag, ref.policy)["equal"].all()
    assert s.shape == (TINY.n_artificial, 2) and r.shape == (TINY.n_artificial,)


def test_update_comparison_flags_a_difference():
    task = LinearOptimumTask()
    settings = GPREPSSettings(n_artificial=40, context_model="prior")
    batch = collect(task, task.initial_policy(), 12, np.random.default_rng(3))
    with ch4.handled_events():
        _, _, _, _, weights, new = _step_through(task, DirectRewardModel(), settings, batch, 1)
        ref = GPREPS(task.initial_policy(), DirectRewardModel(), settings, rng=2, task=task)
        table = ch4.update_comparison(weights, new, ref.update(batch), ref.policy)
    assert not table["equal"].all()
    with pytest.raises(ValueError, match="weights"):
        ch4.update_comparison(None, new, None, new)


# ------------------------------------------------------------------ sizes and settings
def test_sizes_per_scale_and_bad_scale_named():
    assert ch4.iteration_sizes("paper").n_artificial == 500
    assert ch4.iteration_sizes("paper").n_trajectories == 25
    for sizes in ch4.SCALES.values():
        assert sizes.n_trajectories <= sizes.max_trajectories
    with pytest.raises(ValueError, match="scale"):
        ch4.iteration_sizes("huge")


def test_step_settings_and_model_follow_the_sizes():
    settings = ch4.step_settings(TINY, epsilon=0.5)
    assert (settings.n_artificial, settings.n_trajectories, settings.epsilon) == (12, 2, 0.5)
    assert settings.context_model == "prior"
    assert (settings.cov_floor, settings.min_effective_samples) == (
        ch4_gpreps.COV_FLOOR,
        ch4_gpreps.MIN_EFFECTIVE_SAMPLES,
    )  # fig4.6's regularisation
    model = ch4.throwing_model(make("throwing"), TINY)
    robot = model.make_robot_model()
    assert robot.gp.n_inducing == TINY.robot_inducing and model.max_robot_points == TINY.max_points
    with pytest.raises(ValueError, match="sizes"):
        ch4.step_settings({"n_artificial": 3})
    with pytest.raises(ValueError, match="sizes"):
        ch4.throwing_model(make("throwing"), None)


# ------------------------------------------------------------------ tables
def test_batch_table_has_one_row_per_throw_with_the_simulators_numbers():
    throw = make("throwing")
    batch = collect(throw, throw.initial_policy(), 3, np.random.default_rng(0))
    table = ch4.batch_table(batch)
    assert len(table) == 3
    np.testing.assert_array_equal(table["reward"], batch.rewards)
    np.testing.assert_array_equal(
        table["landing x [m]"], [t.info["landing_x"] for t in batch.trajectories]
    )
    with pytest.raises(ValueError, match="batch"):
        ch4.batch_table({"rewards": [1.0]})


def test_fit_table_lists_each_gp_and_its_events():
    stats = {
        "n_data": 10,
        "robot": {
            "n_data": 10,
            "log_ml": 1.0,
            "iterations": 3,
            "noise_var_max": 1e-6,
            "numerical_events": {"noise_at_floor": 2, "jitter_increased": 0},
        },
        "release": {"n_data": 5, "log_ml": -2.0, "iterations": 3, "noise_var_max": 0.1},
    }
    table = ch4.fit_table(stats)
    assert list(table.index) == ["robot", "release"]
    assert table.loc["robot", "handled events"] == "noise_at_floor ×2"
    assert table.loc["release", "handled events"] == "none"
    with pytest.raises(ValueError, match="stats"):
        ch4.fit_table({"n_data": 3})


def test_policy_change_table_matches_independent_numbers():
    task = LinearOptimumTask()
    rng = np.random.default_rng(0)
    old = task.initial_policy()
    s = task.sample_context(rng, n=50)
    w = old.sample(s, rng)
    r = -np.sum(w**2, axis=1)
    weights = reps_weights(r, context_features(s, "quadratic"), 0.5)
    new = old.fit(s, w, weights.weights)
    row = ch4.policy_change_table(old, new, s, weights, r).iloc[0]
    n = r.size
    assert row["KL(π_new ‖ π_old)"] == new.kl(old, s)  # the same call on the same floats
    # p @ r vs a pairwise sum of p r: n same-sign products (p ≥ 0, r < 0), ≲ (n + 1) ε
    assert row["Σ p R̂"] == pytest.approx(float(np.sum(weights.weights * r)), rel=fp_tol(n + 1))
    # (Σp)² / p·p vs 1 / Σp²: Σp is 1 up to 2n ε (normalisation and re-summation), squared 4n ε;
    # the two n-term sums of squares n ε each
    assert row["ESS"] == pytest.approx(1.0 / np.sum(weights.weights**2), rel=fp_tol(6 * n + 2))
    with pytest.raises(ValueError, match="rewards"):
        ch4.policy_change_table(old, new, s, weights, r[:-1])


def test_diagnostics_table_one_row_per_update():
    task = LinearOptimumTask()
    algo = GPREPS(
        task.initial_policy(),
        DirectRewardModel(),
        GPREPSSettings(n_artificial=50, context_model="uniform"),
        rng=0,
    )
    with ch4.handled_events():
        run = learn(task, algo, 3, 5, 1, initial_rollouts=15, progress=False)
    table = ch4.diagnostics_table(run["diagnostics"], run["mean_reward"][1:])
    assert len(table) == 3
    assert np.isnan(table["predicted R (new batch)"].iloc[0])  # no model before update 1
    assert table["predicted R (new batch)"].iloc[1:].notna().all()
    assert list(table["real samples"]) == [15, 20, 25]
    np.testing.assert_allclose(table["KL"], table["ε"], rtol=1e-3)  # bound met
    with pytest.raises(ValueError, match="diagnostics"):
        ch4.diagnostics_table([])
    with pytest.raises(ValueError, match="policy_rewards"):
        ch4.diagnostics_table(run["diagnostics"], [0.0])


def test_table_4_2_beside_the_thesis_and_the_stored_summary():
    run = stored_run("tab4.2")
    table = ch4.table_4_2(run)
    assert list(table.index[:3]) == ["PILCO", "GPREPS", "REPS"]
    thesis = table.xs("thesis [s]", axis=1, level=1)
    np.testing.assert_array_equal(thesis.loc["GPREPS"], [10.68, 20.52, 38.50])
    np.testing.assert_array_equal(thesis.loc["REPS"], [1425.0, 2300.0, 4075.0])
    ours = table.xs("ours [s]", axis=1, level=1)
    for key, label in (("pilco", "PILCO"), ("gpreps", "GPREPS")):
        for col, lim in zip(ours.columns, ("-100", "-10", "-1.5"), strict=True):
            mean = run.summary[key]["limits"][lim]["experience_s_mean"]
            value = ours.loc[label, col]
            assert np.isnan(value) if mean is None else value == round(mean, 2)
    medians = table.xs("median [s]", axis=1, level=1)
    for col, lim in zip(medians.columns, ("-100", "-10", "-1.5"), strict=True):
        per_trial = run.summary["gpreps"]["limits"][lim]["experience_s_per_trial"]
        expected = np.median([np.inf if x is None else x for x in per_trial])  # unreached: +∞
        value = medians.loc["GPREPS", col]
        assert np.isnan(value) if np.isinf(expected) else value == round(expected, 2)
    with pytest.raises(ValueError, match="run"):
        ch4.table_4_2({"gpreps": {}})


def test_gflops_table_one_row_per_thread_count():
    run = stored_run("fig4.4")
    table = ch4.gflops_table(run)
    assert list(table.index) == list(run.summary["mm_gflops"])
    assert table["MM GFLOP/s"].tolist() == list(run.summary["mm_gflops"].values())
    with pytest.raises(ValueError, match="run"):
        ch4.gflops_table({})


def _exploration_run(tmp_path, widths, kls, epsilon=0.5, method="gpreps"):
    """A run folder whose trial t has Σ_k = widths[t][k]² I₃ and the given KLs per update."""
    from skillkit.experiments.run import Run

    arrays = {}
    for t, (w, kl) in enumerate(zip(widths, kls, strict=True)):
        w = np.asarray(w, dtype=float)
        arrays[f"trial{t}__policy_cov"] = w[:, None, None] ** 2 * np.eye(3)
        arrays[f"trial{t}__{method}_kl"] = np.asarray(kl, dtype=float)
    np.savez(tmp_path / "trials.npz", **arrays)
    return Run(tmp_path, {"id": "figX", "settings": {"gpreps": {"epsilon": epsilon}}})


def test_exploration_table_is_the_width_ratio_and_the_share_at_the_bound(tmp_path):
    # Σ_k = c_k² I: √tr Σ_k / √tr Σ_0 = c_k / c_0 exactly; K = 4 updates, so the quarters
    # are updates 1, 2, 3, 4
    widths = [[2.0, 1.0, 0.5, 0.25, 0.2], [1.0, 0.9, 0.8, 0.7, 0.6]]
    kls = [[0.5, 0.5, 0.5, 0.5], [0.5, 0.3, 0.5, 0.2]]
    table = ch4.exploration_table(_exploration_run(tmp_path, widths, kls))
    ratios = table.iloc[:2, :4].to_numpy()
    expected = [[0.5, 0.25, 0.125, 0.1], [0.9, 0.8, 0.7, 0.6]]
    np.testing.assert_allclose(ratios, expected, rtol=0, atol=5e-4)  # cells: 3 decimals
    assert table.iloc[:2, 4].tolist() == [0.5, 0.2]
    assert table.iloc[:2, 5].tolist() == [1.0, 0.5]
    assert "ε = 0.5" in table.columns[4]
    # the median of the unrounded values, rounded to 3 decimals like every cell
    median = [0.7, 0.525, 0.4125, 0.35, 0.35, 0.75]
    np.testing.assert_allclose(table.loc["median"], median, rtol=0, atol=5e-4 + 1e-12)
    figure = ch4.exploration_figure(_exploration_run(tmp_path, widths, kls), backend="matplotlib")
    assert "75% of the updates" in figure.axes[0].get_title() + figure.texts[0].get_text()


def test_exploration_table_names_bad_input(tmp_path):
    with pytest.raises(ValueError, match="run"):
        ch4.exploration_table({"settings": {"epsilon": 1.0}})
    with pytest.raises(ValueError, match="run: .* no trials.npz"):
        from skillkit.experiments.run import Run

        ch4.exploration_table(Run(tmp_path, {"id": "figX", "settings": {"epsilon": 1.0}}))
    run = _exploration_run(tmp_path, [[1.0, 0.5]], [[0.5]])
    with pytest.raises(ValueError, match="method: .* 'reps'"):
        ch4.exploration_table(run, method="reps")
    with pytest.raises(ValueError, match="epsilon"):
        from skillkit.experiments.run import Run

        ch4.exploration_table(Run(tmp_path, {"id": "figX", "settings": {}}))


def test_exploration_table_of_the_stored_hockey_run():
    run = stored_run("fig4.10")
    table = ch4.exploration_table(run)
    assert len(table) == run.summary["n_trials"] + 1
    # the ratios fall over the run (the weighted ML fit shrinks Σ) and start below 1
    ratios = table.iloc[:-1, :4].to_numpy()
    assert np.all(np.diff(ratios, axis=1) < 0) and np.all(ratios < 1)


# ------------------------------------------------------------------ figures
def test_weights_figure_points_lie_on_the_closed_form():
    rng = np.random.default_rng(0)
    s = rng.uniform(-1, 1, (80, 2))
    r = -np.sum((s - 0.3) ** 2, axis=1) + 0.1 * rng.standard_normal(80)
    phi = context_features(s, "quadratic")
    weights = reps_weights(r, phi, 1.0)
    fig = ch4.weights_figure(weights, r, phi)
    points = fig.data[0]
    adv = np.asarray(points.x)
    # log p_j − A_j/η is the same constant −log Z for every sample (Eq. 3.10)
    offset = np.log(np.asarray(points.y)) - adv / weights.eta
    np.testing.assert_allclose(offset, offset[0], atol=1e-9 * max(1.0, np.abs(offset).max()))
    with pytest.raises(ValueError, match="features"):
        ch4.weights_figure(weights, r, phi[:, :2])


def test_contexts_and_throws_figures_draw_every_sample():
    throw = make("throwing")
    batch = collect(throw, throw.initial_policy(), 2, np.random.default_rng(0))
    fig = ch4.contexts_figure(batch.contexts, np.zeros((5, 2)))
    assert sorted(len(t.x) for t in fig.data) == [2, 5]
    with pytest.raises(ValueError, match="artificial"):
        ch4.contexts_figure(batch.contexts, np.zeros((5, 3)))
    with pytest.raises(ValueError, match="prediction"):
        ch4.predicted_throws_figure(None, batch)


# ------------------------------------------------------------------ M, L widget
class _FakeModel:
    """predict() returning Gaussian rewards with a known mean and spread per pair."""

    def __init__(self, sigma: float):
        self.sigma = sigma

    def predict(self, contexts, omegas, n_trajectories, rng):
        mean = -np.sum(np.asarray(omegas) ** 2, axis=1)
        rewards = mean[:, None] + self.sigma * rng.standard_normal((len(mean), n_trajectories))
        return type("P", (), {"rewards": rewards})()


def _pool(sigma=2.0, repeats=400):
    task = LinearOptimumTask()
    sizes = dataclasses.replace(TINY, pool_pairs=300, pool_repeats=repeats, max_trajectories=8)
    contexts = [[0.0, 0.0], [0.5, -0.5]]
    return ch4.reward_pool(_FakeModel(sigma), task.initial_policy(), task, sizes, contexts, 0)


def test_reward_estimates_spread_falls_like_one_over_root_l():
    sigma, n_repeats = 2.0, 400
    pool = _pool(sigma)
    for L in (1, 4):
        fixed, _ = ch4.reward_estimates(pool, 10, L, n_repeats, seed=1)
        sd = fixed.std(axis=1, ddof=1)
        # relative standard error of a sample std ≈ 1/√(2(R − 1)); allow 4 of them
        tol = 4.0 / np.sqrt(2 * (n_repeats - 1))
        np.testing.assert_allclose(sd, sigma / np.sqrt(L), rtol=tol)


def test_policy_estimate_spread_is_the_bootstrap_variance_over_m():
    pool = _pool(sigma=0.0)  # no trajectory noise: R̂_j is the pair's mean exactly
    n_repeats, M = 400, 25
    _, policy = ch4.reward_estimates(pool, M, 3, n_repeats, seed=2)
    expected = pool.pairs[:, 0].std() / np.sqrt(M)  # with replacement from Q pairs
    tol = 4.0 / np.sqrt(2 * (n_repeats - 1))
    assert policy.std(ddof=1) == pytest.approx(expected, rel=tol)


def test_reward_estimate_figure_same_seed_same_figure_and_bad_input_named():
    pool = _pool(repeats=20)
    a = ch4.reward_estimate_figure(pool, 10, 3, n_repeats=10, seed=3)
    b = ch4.reward_estimate_figure(pool, 10, 3, n_repeats=10, seed=3)
    assert a.to_json() == b.to_json()
    with pytest.raises(ValueError, match="n_trajectories"):
        ch4.reward_estimate_figure(pool, 10, 9)
    with pytest.raises(ValueError, match="n_artificial"):
        ch4.reward_estimate_figure(pool, 0, 2)
    with pytest.raises(ValueError, match="pool"):
        ch4.reward_estimate_figure(None, 10, 2)


# ------------------------------------------------------------------ handled events
def test_handled_events_counts_expected_and_reissues_the_rest():
    with warnings.catch_warnings(record=True) as outside:
        warnings.simplefilter("always")
        with ch4.handled_events() as events:
            report_event("noise_at_floor", "noise at its floor")
            message = "balancing: rollout failed (diverged); reward set to -1e7"
            warnings.warn(message, RuntimeWarning, stacklevel=1)
            warnings.warn("something else", UserWarning, stacklevel=1)
    assert [str(w.message) for w in outside] == ["something else"]
    assert events.numerical.counts["noise_at_floor"] == 1
    table = events.table()
    assert list(table["count"]) == [1, 1]
    assert "rollout failed" in table["example"].iloc[1]


def test_prediction_overlay_draws_rigid_links_and_the_real_hand_path():
    from types import SimpleNamespace

    from skillkit.tasks.balancing import stable_gains

    task = make("balancing")
    rng = np.random.default_rng(0)
    real = [task.rollout(w, rng=rng) for w in stable_gains(task, 2, rng)]
    states = np.stack([np.stack([r.states] * 3) for r in real])  # (B, L, T + 1, 8)
    view = ch4.prediction_overlay(task, SimpleNamespace(states=states), real, live=False, n_shown=2)
    *samples, hand, robot = view.figure.data
    assert len(samples) == 2 and view.shown.reason == "live=False"
    for path in samples:  # samples equal to the real rollout trace the real hand path
        np.testing.assert_allclose(path.x, hand.x, rtol=0, atol=0)
        np.testing.assert_allclose(path.y, hand.y, rtol=0, atol=0)
    links = np.stack([robot.x, robot.y], axis=1)  # ankle … hand at t = 0
    lengths = np.linalg.norm(np.diff(links, axis=0), axis=1)
    assert np.all(lengths > 0.1)
    shoulder_to_hand = np.hypot(hand.x - 0, hand.y - 0)  # the hand moves with the posture
    assert np.ptp(shoulder_to_hand) > 0
    assert (hand.x[0], hand.y[0]) == (robot.x[-1], robot.y[-1])
    with pytest.raises(ValueError, match="n_shown"):
        ch4.prediction_overlay(task, SimpleNamespace(states=states), real, live=False, n_shown=0)
