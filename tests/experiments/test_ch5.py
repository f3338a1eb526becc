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
        assert (paper.test_pairs, paper.truth_rollouts, paper.cv_folds) == (200, 100, 10)
    assert get("fig5.6").settings["paper"].torque_noise == 4.0
    assert 4.0 in get("fig5.7").settings["paper"].torque_noise


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
    assert len(maps) == 2 and maps[0].zmin == maps[1].zmin and maps[0].zmax == maps[1].zmax
    assert np.shape(maps[0].z) == (4, 4)
    lo, hi = summary["shared_colour_range_log10"]
    assert lo <= np.min(maps[1].z) and np.max(maps[0].z) <= hi
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
        summary["claim_embedding_below_gp_holds"] and summary["claim_trajectory_below_step_holds"]
    )
    assert {s.name for s in series} >= {"GP sampling (M=4)", "embedding, step-based (5.17)"}
