"""Chapter 5 experiments: registry entries, task helpers and tiny end-to-end runs."""

import warnings

import numpy as np
import pytest

from skillkit.experiments import ch5
from skillkit.experiments.registry import get
from skillkit.trial import NullBar, TrialContext
from tests._tolerances import fp_tol


class _Bar(NullBar):
    def __init__(self):
        self.total, self.n = None, 0

    def reset(self, total=None):
        self.total, self.n = total, 0

    def update(self, n=1):
        self.n += n


def test_registered_with_thesis_settings_at_paper_scale():
    for exp_id in ("fig5.3", "fig5.4", "fig5.5"):
        paper = get(exp_id).settings["paper"]
        assert (paper.n_trajectories, paper.horizon, paper.control_noise) == (15, 20, 0.05)
        assert paper.cv_folds == 10
    for exp_id in ("fig5.6", "fig5.7"):
        paper = get(exp_id).settings["paper"]
        assert (paper.horizon, paper.initial_std, paper.gp_samples) == (40, 0.3, 100)
        assert paper.cv_folds == 10 and (paper.gp_target, paper.gp_curb) == ("next", True)
    assert (
        get("fig5.6").settings["paper"].test_pairs,
        get("fig5.6").settings["paper"].truth_rollouts,
    ) == (200, 100)
    assert get("fig5.6").settings["paper"].torque_noise == 4.0
    assert 4.0 in get("fig5.7").settings["paper"].torque_noise
    for exp_id in ("fig5.3", "fig5.6"):
        assert get(exp_id).settings["paper"].gp_target == "next"
    # λ ≥ 1e-3 wherever β is propagated over many steps; free (≥ 1e-6) for single steps.
    lam_min = {i: get(i).settings["paper"].lam_min for i in ("fig5.3", "fig5.5", "fig5.6")}
    assert lam_min == {"fig5.3": 1e-6, "fig5.5": 1e-3, "fig5.6": 1e-3}


def test_rollouts_from_a_start_state_are_the_tasks_episode():
    """Without torque noise the helper's rollout from x₀ is the task's own episode from x₀."""
    task = ch5._task(ch5.SCALES_5_6["smoke"], 0.0)
    gain = task.pd_gain()
    episode = task.rollout(gain.ravel(), None, np.random.default_rng(5))
    x0 = np.asarray(episode.info["initial_state"])
    xs, us, failed = ch5._rollouts_from(task, gain, x0, 2, np.random.default_rng(0))
    assert not failed.any()
    # the same simulation from the same floats (x₀ round-trips through the info list exactly,
    # and the torque noise is 0 · N(0, 1) = 0): equal exactly
    np.testing.assert_array_equal(xs[0], episode.states)
    np.testing.assert_array_equal(us[1], episode.controls)
    # Ground truth of a deterministic start: its reward, with zero Monte Carlo variance.
    settings = ch5.SCALES_5_6["smoke"]
    truth = ch5._balancing_truth(task, gain, x0[None], settings, np.random.default_rng(1))
    # Σ_t r_t vs the task's one-product reward (T·12 same-sign terms, in other orders), then
    # the mean of truth_rollouts equal returns (that many roundings)
    n_terms = episode.states[1:].size + episode.controls[1:].size
    rel = fp_tol(n_terms + 2 + settings.truth_rollouts)
    np.testing.assert_allclose(truth["truth"], [task.reward(episode)], rtol=rel)
    np.testing.assert_allclose(truth["truth_mc_var"], [0.0], atol=1e-20)


_TINY_PENDULUM = ch5.SCALES_PENDULUM["smoke"]  # 3 trajectories of 4 steps, a 4 × 4 grid


@pytest.mark.parametrize("exp_id,key", [("fig5.3", "e_alpha"), ("fig5.5", "e_traj")])
def test_tiny_pendulum_run_is_reproducible_and_summarised(exp_id, key):
    exp = get(exp_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        runs = [
            exp.run_trial(_TINY_PENDULUM, np.random.default_rng(7), TrialContext(_Bar()))
            for _ in range(2)
        ]
    for m in ("emb", "emb_preimage", "gp"):
        err = runs[0][f"{m}_{key}"]
        assert err.shape == (4, 4) and np.all(np.isfinite(err)) and np.all(err >= 0)
        np.testing.assert_array_equal(err, runs[1][f"{m}_{key}"])  # same seed, same numbers
    series, summary = exp.summarize(_TINY_PENDULUM, runs[:1])
    maps = [s for s in series if s.kind == "heatmap"]
    # (a) embedding, (b) GP, (c) constant predictor share one colour range; (d) the noise floor.
    assert len(maps) == 4 and all(
        m.zmin == maps[0].zmin and m.zmax == maps[0].zmax for m in maps[:3]
    )
    assert np.shape(maps[0].z) == (4, 4)
    lo, hi = summary["shared_colour_range_log10"]
    assert lo <= np.min(maps[1].z) and np.max(maps[0].z) <= hi
    const = np.mean(runs[0][f"const_{key}"])
    assert summary["mean_error_constant"] == pytest.approx(const)
    # The Monte Carlo floor is far below every predictor's error (a variance / the sample count).
    assert 0 <= summary["mean_noise_floor"] < min(summary["mean_error_embedding"], const)
    assert [row["item"] for row in summary["setup"]][0] == "GP target"
    assert summary["holds"] is exp.verdict(_TINY_PENDULUM, summary).holds
    assert summary["own_checks"]["mean_error_below_gp"]["holds"] == (
        summary["mean_error_embedding"] < summary["mean_error_gp"]
    )
    for where in ("near_data", "far_from_data"):  # each model's median error on the cells
        assert set(summary[f"median_error_{where}"]) == {"embedding", "gp"}


@pytest.mark.slow
def test_tiny_balancing_run_reports_the_claims():
    exp = get("fig5.6")
    settings = exp.settings["smoke"]  # T = 5, 3 test pairs, 2 and 3 observed trajectories
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        trial = exp.run_trial(settings, np.random.default_rng(3), TrialContext(_Bar()))
    series, summary = exp.summarize(settings, [trial])
    assert summary["x"] == [2, 3]
    for m in ("gp", "step", "trajectory"):
        assert len(summary["mean_e_r"][m]) == 2 and np.all(np.isfinite(summary["mean_e_r"][m]))
    e = summary["mean_e_r"]
    ratios = [g / v for m in ("step", "trajectory") for g, v in zip(e["gp"], e[m], strict=True)]
    assert summary["holds"] == (
        min(ratios) >= 10**0.5
        and e["gp"][0] > e["gp"][1]
        and all(t < s for t, s in zip(e["trajectory"], e["step"], strict=True))
    )
    assert set(summary["own_checks"]) == {
        "trajectory_based_below_constant",
        "embeddings_10x_below_gp",
    }
    names = {s.name for s in series}
    assert names >= {"GP sampling (M=4)", "embedding, step-based (5.17)"}
    assert names >= {label for _, label in ch5._FLOORS}
    # The constant predictor: the mean observed reward against the same ground truth.
    for case, e in zip(trial["cases"], summary["mean_e_r"]["constant"], strict=True):
        assert case["e_r_constant"] == pytest.approx(e)
    assert summary["mean_e_r"]["noise"][0] == pytest.approx(trial["truth_mc_floor"][0])
    assert {"item", "thesis", "ours", "why"} <= set(summary["setup"][0])


# ------------------------------------------------------------------ verdicts on synthetic summaries
def _pendulum_summary(**changes) -> dict:
    """A fig5.3-shaped summary on which every part of the thesis's sentences holds, while our
    own check (grid-mean error below the GP's) fails."""
    summary = {
        "mean_error_embedding": 0.04,
        "mean_error_gp": 0.001,  # own check: the embedding's mean is above the GP's
        "mean_error_constant": 3.0,
        "mean_noise_floor": 1e-9,
        "median_log10_error_embedding": -5.0,
        "median_log10_error_gp": -4.0,
        "fraction_of_grid_where_embedding_better": 0.6,
        "fraction_of_grid_near_data": 0.9,
        "fraction_embedding_better_near_data": 0.62,
        "fraction_embedding_better_far_from_data": 0.55,
        "median_error_near_data": {"embedding": 1e-6, "gp": 1e-5},
        "median_error_far_from_data": {"embedding": 1e-2, "gp": 1e-4},
    }
    summary.update(changes)
    return summary


def _pendulum_holds(exp_id: str, summary: dict):
    exp = get(exp_id)
    return exp.verdict(exp.settings["paper"], summary).holds


def test_single_step_verdict_judges_the_three_sentences():
    """fig5.3 / fig5.4: more accurate on most of the grid, better away from the data, each
    model's median error lower near the data; each bound from both sides."""
    assert _pendulum_holds("fig5.3", _pendulum_summary()) is True
    assert _pendulum_holds("fig5.4", _pendulum_summary()) is True
    fails = [
        {"fraction_of_grid_where_embedding_better": 0.45},
        {"fraction_embedding_better_far_from_data": 0.4},
        {"median_error_near_data": {"embedding": 1e-6, "gp": 2e-4}},  # GP better away
        {"median_error_far_from_data": {"embedding": 1e-7, "gp": 1e-4}},  # embedding
    ]
    for change in fails:
        assert _pendulum_holds("fig5.3", _pendulum_summary(**change)) is False, change


def test_single_step_verdict_without_the_near_far_medians():
    """A stored run without the medians (before issue #32) is undecided unless another part
    fails; the statement says the number is not recorded."""
    summary = _pendulum_summary()
    for key in ("median_error_near_data", "median_error_far_from_data"):
        del summary[key]
    exp = get("fig5.3")
    verdict = exp.verdict(exp.settings["paper"], summary)
    assert verdict.holds is None and "not recorded in this run" in verdict.statement
    summary["fraction_embedding_better_far_from_data"] = 0.1
    assert _pendulum_holds("fig5.3", summary) is False


def test_trajectory_verdict_judges_outperforming_on_most_of_the_grid():
    assert _pendulum_holds("fig5.5", _pendulum_summary()) is True
    # fig5.5's sentence says nothing about near / far: those parts do not count
    summary = _pendulum_summary(
        fraction_embedding_better_far_from_data=0.1, median_error_near_data=None
    )
    assert _pendulum_holds("fig5.5", summary) is True
    summary["fraction_of_grid_where_embedding_better"] = 0.4
    assert _pendulum_holds("fig5.5", summary) is False


@pytest.mark.parametrize("exp_id", ["fig5.3", "fig5.4", "fig5.5"])
def test_pendulum_own_check_does_not_change_holds(exp_id):
    exp = get(exp_id)
    for emb, gp in ((0.04, 0.001), (0.001, 0.04)):  # the embedding's mean above, then below
        summary = _pendulum_summary(mean_error_embedding=emb, mean_error_gp=gp)
        own = ch5.OWN_CHECKS[exp_id](exp.settings["paper"], summary)
        assert own["mean_error_below_gp"]["holds"] is (emb < gp)
        assert _pendulum_holds(exp_id, summary) is True


def _reward_summary(**e) -> dict:
    """A fig5.6 / fig5.7-shaped summary at two x values: the mean e_r per predictor."""
    mean_e_r = {
        "gp": [1000.0, 500.0],
        "step": [50.0, 40.0],
        "trajectory": [30.0, 20.0],
        "constant": [10.0, 10.0],  # own check: the trajectory-based embedding is above it
        "noise": [1.0, 1.0],
    }
    mean_e_r.update(e)
    return {"x": [2, 10], "mean_e_r": mean_e_r}


def _reward(exp_id: str, summary: dict) -> tuple:
    exp = get(exp_id)
    st = exp.settings["paper"]
    own = {k: v["holds"] for k, v in ch5.OWN_CHECKS[exp_id](st, summary).items()}
    return exp.verdict(st, summary).holds, own


def test_fig5_6_verdict_judges_order_of_magnitude_fewer_trajectories_and_training():
    holds, own = _reward("fig5.6", _reward_summary())
    assert holds is True  # GP / embedding 12.5 … 33, GP worse with fewer, trajectory < step
    assert own == {"trajectory_based_below_constant": False, "embeddings_10x_below_gp": True}
    # GP / step = 5 at x = 2 (4.5 at x = 10): an order of magnitude to the nearest power of
    # ten (≥ √10), not 10×: the verdict holds, the strict own check does not
    holds, own = _reward("fig5.6", _reward_summary(gp=[250.0, 180.0]))
    assert holds is True and own["embeddings_10x_below_gp"] is False
    fails = [
        {"gp": [100.0, 90.0]},  # GP / step = 2 < √10 at x = 2
        {"gp": [500.0, 1000.0]},  # the GP's error is not larger with fewer trajectories
        {"trajectory": [60.0, 20.0]},  # trajectory-based above step-based at x = 2
    ]
    for change in fails:
        assert _reward("fig5.6", _reward_summary(**change))[0] is False, change


def test_fig5_7_verdict_judges_growth_flatness_and_gp_comparison():
    grows = {"gp": [100.0, 10000.0], "step": [20.0, 30.0], "trajectory": [15.0, 25.0]}
    holds, own = _reward("fig5.7", _reward_summary(**grows))
    assert holds is True
    assert own == {
        "trajectory_based_below_constant": False,
        "embeddings_flatter_than_gp": True,
        "trajectory_based_below_step_based": True,
    }
    fails = [
        {"gp": [10000.0, 5000.0]},  # the GP's error does not grow with the noise
        {"step": [20.0, 100.0]},  # max / min 5 ≥ √10: a visible difference
        {"trajectory": [120.0, 150.0]},  # above the GP at the smallest noise
    ]
    for change in fails:
        assert _reward("fig5.7", _reward_summary(**{**grows, **change}))[0] is False, change
    # a spread of 5 is not "barely any difference", though flatter than the GP's (own check)
    holds, own = _reward("fig5.7", _reward_summary(**{**grows, "step": [20.0, 100.0]}))
    assert holds is False and own["embeddings_flatter_than_gp"] is True


@pytest.mark.parametrize("exp_id", ["fig5.6", "fig5.7"])
def test_reward_own_checks_do_not_change_holds(exp_id):
    """Beating the constant predictor (both figures) and trajectory- below step-based (a
    claim of Fig. 5.6, our own check on Fig. 5.7) do not move fig5.7's verdict either way."""
    grows = {"gp": [100.0, 10000.0], "step": [20.0, 30.0]} if exp_id == "fig5.7" else {}
    trajectories = ([15.0, 25.0], [25.0, 35.0]) if exp_id == "fig5.7" else ([30.0, 20.0],)
    for constant in ([10.0, 10.0], [1000.0, 1000.0]):  # above / below the embeddings
        for trajectory in trajectories:  # below / above step-based
            summary = _reward_summary(**grows, constant=constant, trajectory=trajectory)
            holds, own = _reward(exp_id, summary)
            assert holds is True
            assert own["trajectory_based_below_constant"] is (constant[0] > 100)
            if exp_id == "fig5.7":
                below = own["trajectory_based_below_step_based"]
                assert below is (trajectory[0] < 20)
