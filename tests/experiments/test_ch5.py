"""Chapter 5 experiments: registry entries, task helpers and tiny end-to-end runs."""

import warnings

import numpy as np
import pytest

from skillkit.experiments import ch5
from skillkit.experiments.registry import get


class _Bar:
    def __init__(self):
        self.total, self.n = None, 0

    def reset(self, total):
        self.total, self.n = total, 0

    def update(self):
        self.n += 1


def test_registered_with_thesis_settings_at_paper_scale():
    for exp_id in ("fig5.3", "fig5.4", "fig5.5"):
        paper = get(exp_id).settings["paper"]
        assert (paper["n_trajectories"], paper["horizon"], paper["control_noise"]) == (15, 20, 0.05)
        assert paper["cv_folds"] == 10
    for exp_id in ("fig5.6", "fig5.7"):
        paper = get(exp_id).settings["paper"]
        assert (paper["horizon"], paper["initial_std"], paper["gp_samples"]) == (40, 0.3, 100)
        assert (paper["test_pairs"], paper["truth_rollouts"], paper["cv_folds"]) == (200, 100, 10)
    assert get("fig5.6").settings["paper"]["torque_noise"] == 4.0
    assert 4.0 in get("fig5.7").settings["paper"]["torque_noise"]


_TINY_PENDULUM = {
    "n_trajectories": 3,
    "horizon": 4,
    "control_noise": 0.05,
    "grid": 4,
    "truth_samples": 20,
    "truth_rollouts": 5,
    "gp_samples": 4,
    "cv_folds": 3,
    "max_iter": 3,
    "lam0": 1e-3,
    "gp_steps": 3,
    "gp_target": "delta",
    "target_kernel": "se",
}


@pytest.mark.parametrize("exp_id,key", [("fig5.3", "e_alpha"), ("fig5.5", "e_traj")])
def test_tiny_pendulum_run_is_reproducible_and_summarised(exp_id, key):
    exp = get(exp_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        runs = [
            exp.run_trial(dict(_TINY_PENDULUM), np.random.default_rng(7), _Bar()) for _ in range(2)
        ]
    for m in ("emb", "emb_preimage", "gp"):
        err = runs[0][f"{m}_{key}"]
        assert err.shape == (4, 4) and np.all(np.isfinite(err)) and np.all(err >= 0)
        np.testing.assert_array_equal(err, runs[1][f"{m}_{key}"])  # same seed, same numbers
    series, summary = exp.summarize(_TINY_PENDULUM, runs[:1])
    maps = [s for s in series if s.kind == "heatmap"]
    assert len(maps) == 2 and maps[0].zmin == maps[1].zmin and maps[0].zmax == maps[1].zmax
    assert np.shape(maps[0].z) == (4, 4)
    lo, hi = summary["shared_colour_range_log10"]
    assert lo <= np.min(maps[1].z) and np.max(maps[0].z) <= hi
    assert summary["claim_holds"] == (
        summary["mean_error_embedding"] < summary["mean_error_gp"]
        and summary["fraction_of_grid_where_embedding_better"] > 0.5
    )


@pytest.mark.slow
def test_tiny_balancing_run_reports_the_claims():
    settings = {
        **ch5._BALANCING_COMMON,
        "horizon": 5,
        "gp_samples": 4,
        "initial_samples": 4,
        "torque_noise": 4.0,
        "n_trajectories": [2, 3],
        "test_pairs": 3,
        "truth_rollouts": 3,
        "max_iter": 2,
        "gp_steps": 2,
    }
    exp = get("fig5.6")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        trial = exp.run_trial(settings, np.random.default_rng(3), _Bar())
    series, summary = exp.summarize(settings, [trial])
    assert summary["x"] == [2, 3]
    for m in ("gp", "step", "trajectory"):
        assert len(summary["mean_e_r"][m]) == 2 and np.all(np.isfinite(summary["mean_e_r"][m]))
    assert summary["claim_holds"] == (
        summary["claim_embedding_below_gp_holds"] and summary["claim_trajectory_below_step_holds"]
    )
    assert {s.name for s in series} >= {"GP sampling (M=4)", "embedding, step-based (5.17)"}
