"""Chapter 5 experiments: registry entries, task helpers and tiny end-to-end runs."""

import warnings

import numpy as np
import pytest

from skillkit.experiments import ch5
from skillkit.experiments.registry import get
from skillkit.trial import NullBar, TrialContext


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
    np.testing.assert_allclose(xs[0], episode.states, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(us[1], episode.controls, rtol=1e-12, atol=1e-12)
    # Ground truth of a deterministic start: its reward, with zero Monte Carlo variance.
    settings = ch5.SCALES_5_6["smoke"]
    truth = ch5._balancing_truth(task, gain, x0[None], settings, np.random.default_rng(1))
    np.testing.assert_allclose(truth["truth"], [task.reward(episode)], rtol=1e-10)
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
    assert summary["holds"] == (
        summary["mean_error_embedding"] < summary["mean_error_gp"]
        and summary["fraction_of_grid_where_embedding_better"] > 0.5
    )


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
    assert summary["holds"] == (
        summary["claim_embedding_below_gp_holds"]
        and summary["claim_trajectory_below_step_holds"]
        and summary["trajectory_based_below_constant_holds"]
    )
    names = {s.name for s in series}
    assert names >= {"GP sampling (M=4)", "embedding, step-based (5.17)"}
    assert names >= {label for _, label in ch5._FLOORS}
    # The constant predictor: the mean observed reward against the same ground truth.
    for case, e in zip(trial["cases"], summary["mean_e_r"]["constant"], strict=True):
        assert case["e_r_constant"] == pytest.approx(e)
    assert summary["mean_e_r"]["noise"][0] == pytest.approx(trial["truth_mc_floor"][0])
    assert {"item", "thesis", "ours", "why"} <= set(summary["setup"][0])
